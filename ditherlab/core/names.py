"""The names every layer shares: the wrench's components and the three regimes of a joint.

Defined once here, at the bottom of the package, so that the estimator, the recording, the
torque model and the reports agree on them without importing each other.
"""

from __future__ import annotations

from enum import IntEnum

#: The wrench at the tool point, in base axes: forces [N] then moments [N·m] (the recording's
#: F/T columns and the estimator's components).
WRENCH_COLUMNS = ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")
#: The force axes of the paper's detection table.
FORCE_AXES = ("x", "y", "z")
#: The robot vendor's own estimate of the external wrench (a controller's or a driver's, logged
#: beside the joints): the same point, axes and sign as the F/T columns :data:`WRENCH_COLUMNS`
#: (the wrench the robot exerts, at the tool point, base axes), forces [N] then moments [N·m].
#: A mapping file converts the vendor's frame and sign to this one where it can.
VENDOR_WRENCH_COLUMNS = (
    "f_vendor_x",
    "f_vendor_y",
    "f_vendor_z",
    "m_vendor_x",
    "m_vendor_y",
    "m_vendor_z",
)
#: The vendor's estimate of the external joint torques, ``tau_ext_vendor_1 .. _n`` [N·m]: the
#: term ``J(q)^T F`` of eq. (1), so with the sign of ``tau`` (a push P gives ``-J^T P``).
VENDOR_TAU_FAMILY = "tau_ext_vendor"
#: The name of the vendor's estimate beside ditherlab's variants in an estimates file
#: (``vendor/f_x .. vendor/m_z``) and in reports.
VENDOR = "vendor"


class Regime(IntEnum):
    """The regime of a joint at a sample (:func:`ditherlab.data.recording.regimes`): the one
    definition of the three codes and their names (``Regime.MOVING.label == "moving"``)."""

    STILL = 0
    DITHER = 1
    MOVING = 2

    @property
    def label(self) -> str:
        """The regime's name in model files, reports and options: still, dither, moving."""
        return self.name.lower()

    @classmethod
    def of(cls, label: str) -> Regime:
        """The regime called ``label`` (still, dither, moving); ValueError otherwise."""
        return cls[label.upper()]


STILL, DITHER, MOVING = Regime.STILL, Regime.DITHER, Regime.MOVING
#: the regimes' names in code order
REGIME_NAMES: tuple[str, ...] = tuple(r.label for r in Regime)

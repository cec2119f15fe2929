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

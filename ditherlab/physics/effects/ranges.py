"""The physical range of every fitted parameter of an effect, and the check against it.

Each effect declares its ranges once, as :class:`Bound` s in ``Effect.bounds``: the parameter
(or a quantity derived from the parameters, e.g. a drive gain ``k = 1 + gain_error``), its unit,
the range in words for the effect table (``docs/effects.md``), the source of the range in one
short phrase (a datasheet, physics, the literature) and how its limits follow from the robot and
the recordings. :meth:`Effect.outside_range <ditherlab.physics.effects.base.Effect.outside_range>`
checks a fit against them: ``identify --add`` refuses a fit outside its range and diagnosis does
not suggest it (:class:`OutOfRange` says which parameter, joint, value and range).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.physics.effects.signals import Signals

__all__ = [
    "RATED_PAYLOAD",
    "Bound",
    "OutOfRange",
    "effort_scale",
    "friction_scale",
    "payload_limit",
]

#: a limit: a number, or a function of (the recordings' Signals, the 0-based joint or None)
Limit = float | Callable[[Sequence[Signals], "int | None"], float]

#: rated payloads [kg] of the arms whose datasheet ditherlab knows, by the description's robot
#: name: ABB IRB 140 product specification (6 kg), Universal Robots UR10e datasheet (12.5 kg),
#: Franka Emika Panda datasheet (3 kg)
RATED_PAYLOAD: dict[str, float] = {"irb140": 6.0, "ur10e": 12.5, "panda": 3.0}


@dataclass(frozen=True)
class Bound:
    """The physical range of one fitted parameter of an effect.

    Attributes
    ----------
    param : the parameter as the model file names it, or a derived quantity (``k``)
    unit : its unit, e.g. ``"N·m"``, ``"-"``
    text : the range in words, for the effect table, e.g. ``"0.5 .. 2"``
    source : where the range comes from, one short phrase
    lo, hi : the limits, numbers or functions of (Signals of the recordings, 0-based joint or
        None for a shared effect)
    value : the checked value(s) from the parameters ``p`` of one joint (or of a shared effect)
        and the recordings' Signals; a sequence is checked element by element, None is not
        checked (default: ``p[param]``)
    per : what the elements of a sequence are: ``"joint"`` (joint 1, 2, ...) or ``"axis"``
        (``f_x``, ``f_y``, ...)
    linear : ``(name, offset)`` when the checked value is ``offset`` plus the linear parameter
        ``name`` (a drive's ``k = 1 + gain_error``): the range then bounds that parameter's fit
        (:func:`ditherlab.physics.effect_fit.bounded_fit`). A bound without ``value`` bounds
        its own ``param``.
    nominal : the value the robot's description gives the parameter (an inertia scale of 1),
        or None: a linear parameter the data cannot move (its term, across the whole range,
        stays below :data:`~ditherlab.physics.effect_fit.ACTS_SNR` noise sigmas) is held there
        (:func:`ditherlab.physics.effect_fit.bounded_fit`)
    """

    param: str
    unit: str
    text: str
    source: str
    lo: Limit = -math.inf
    hi: Limit = math.inf
    value: Callable[[dict[str, Any], Sequence[Signals]], Any] | None = None
    per: str = "joint"
    linear: tuple[str, float] | None = None
    nominal: float | None = None

    def limits(self, sigs: Sequence[Signals], j: int | None) -> tuple[float, float]:
        """``(lo, hi)`` in :attr:`unit` on these recordings, for joint ``j`` (0-based)."""

        def at(x: Limit) -> float:
            return float(x(sigs, j)) if callable(x) else float(x)

        return at(self.lo), at(self.hi)

    def values(
        self, p: dict[str, Any], sigs: Sequence[Signals], j: int | None
    ) -> list[tuple[str, float]]:
        """``[(where, value)]``: the checked values of the parameters ``p`` on these
        recordings and where they act (``"joint 3"``, ``"f_x"``, ``"all joints"``)."""
        v = self.value(p, sigs) if self.value is not None else p.get(self.param)
        if v is None:
            return []
        if isinstance(v, list | tuple | np.ndarray):
            names = WRENCH_COLUMNS if self.per == "axis" else None
            return [
                (names[i] if names else f"joint {i + 1}", float(x))
                for i, x in enumerate(v)
                if x is not None
            ]
        return [("all joints" if j is None else f"joint {j + 1}", float(v))]


@dataclass(frozen=True)
class OutOfRange:
    """A fitted value outside its physical range: the effect, the parameter, where (``"joint
    6"``, ``"f_x"``, ``"all joints"``), the value, the range ``lo..hi`` in ``unit`` and its
    source."""

    effect: str
    param: str
    where: str
    value: float
    lo: float
    hi: float
    unit: str
    source: str

    def text(self) -> str:
        """One line: ``drive_gain k 423 on joint 6 lies outside 0.5..2 (source)``."""
        u = "" if self.unit in ("-", "") else f" {self.unit}"
        return (
            f"{self.effect} {self.param} {self.value:.3g}{u} on {self.where} lies outside its "
            f"physical range {self.lo:.3g}..{self.hi:.3g}{u} ({self.source})"
        )

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain values (``lo``/``hi`` None where unbounded), for JSON."""

        def num(x: float) -> float | None:
            return round(float(x), 6) if math.isfinite(x) else None

        return {
            "effect": self.effect,
            "param": self.param,
            "where": self.where,
            "value": num(self.value),
            "lo": num(self.lo),
            "hi": num(self.hi),
            "unit": self.unit,
            "source": self.source,
        }


def effort_scale(sigs: Sequence[Signals], j: int | None) -> float:
    """[N·m]: joint ``j``'s torque scale: its effort limit in the description when there is one,
    else the largest logged ``|tau|`` of the joint in the recordings (all joints when None)."""
    robot = sigs[0].rec.robot()
    lim = robot.effort_limit if j is None else robot.effort_limit[j : j + 1]
    lim = lim[np.isfinite(lim) & (lim > 0)]
    if j is not None and lim.size:
        return float(lim.max())
    cols = slice(None) if j is None else slice(j, j + 1)
    return max(float(np.max(np.abs(s.tau[:, cols]), initial=0.0)) for s in sigs)


def friction_scale(sigs: Sequence[Signals], j: int | None) -> float:
    """[N·m]: joint ``j``'s sliding friction level, the median ``|tau - tau_grav|`` while it
    moves (``J^T F`` taken out where the sensor is seen); the largest over joints for None."""
    joints = range(sigs[0].n) if j is None else [j]
    out = 0.0
    for jj in joints:
        parts = []
        for s in sigs:
            mv = s.moving[:, jj]
            r = s.tau[mv, jj] - s.gravity[mv, jj]
            if s.has_wrench:
                r = r - s.sensor_torque("ranges")[mv, jj]
            parts.append(np.abs(r))
        v = np.concatenate(parts) if parts else np.zeros(0)
        out = max(out, float(np.median(v)) if v.size else 0.0)
    return out


def payload_limit(sigs: Sequence[Signals], j: int | None = None) -> tuple[float, str]:
    """([kg], where from): the largest payload of the recordings' arm: its rated payload
    (:data:`RATED_PAYLOAD`, by the description's robot name) when known, else the mass of its
    moving links (an arm lifts less than itself)."""
    robot = sigs[0].rec.robot()
    if robot.name in RATED_PAYLOAD:
        return RATED_PAYLOAD[robot.name], f"rated payload of the {robot.name}, datasheet"
    inertias = robot.model.inertias
    mass = float(sum(inertias[k].mass for k in range(1, robot.n + 1)))
    return mass, f"no rated payload known for {robot.name}: its moving links' mass"

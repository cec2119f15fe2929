"""The :class:`Effect` interface: one named physical effect of the torque model.

An effect is one class in one file of this package (``friction.py``, ``transmission.py``,
``rigid.py``, ``sensor.py``); defining it registers it in the library
(:mod:`ditherlab.physics.effects.library`) under its ``name``. Everything that applies, fits, scores,
prints or plots effects goes through the methods below, never through an effect's name: to add an
effect, write the class and its test (``docs/contributing.md``, "Add an effect").
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ditherlab.core.errors import ModelError
from ditherlab.data.torque_model import REGIMES
from ditherlab.physics.effects.ranges import Bound, OutOfRange
from ditherlab.physics.effects.signals import Signals

__all__ = ["EFFECTS", "Design", "Effect", "design_at", "fmt"]

#: one instance of every defined effect by name, in the order diagnosis tries them
#: (``Effect.order``, then the name); filled by :meth:`Effect.__init_subclass__`
EFFECTS: dict[str, Effect] = {}


@dataclass(frozen=True)
class Design:
    """The linear part of an effect on one joint (or all joints, for shared parameters).

    ``shift = centre @ w + offset`` moves the predicted torque; ``widen @ w`` widens the stick
    band's half-width (still/dither regimes only).

    Attributes
    ----------
    centre, widen : (N, k) per joint, (N, n, k) shared [N·m per unit parameter]
    offset : (N,) per joint, (N, n) shared [N·m], or None
    """

    centre: np.ndarray
    widen: np.ndarray | None = None
    offset: np.ndarray | None = None

    def rolled(self, lag: int) -> Design:
        """The design circularly shifted by ``lag`` samples along time (a surrogate)."""

        def r(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else np.roll(a, lag, axis=0)

        return Design(r(self.centre), r(self.widen), r(self.offset))

    def take(self, rows: np.ndarray) -> Design:
        """The design at some rows (M,) only."""

        def r(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return Design(r(self.centre), r(self.widen), r(self.offset))


class Effect(abc.ABC):
    """One named physical effect: its form, driving variables, parameters, fit and predict.

    Subclasses define :meth:`design` (the torque per unit linear parameter for a given value of
    the nonlinear parameter ``h``), :meth:`grid` (the values of ``h`` searched), and how
    parameters are named in the model file.
    """

    name: str = ""
    physics: str = ""
    driven_by: str = ""
    #: True: one parameter vector shared by all joints (payload, ft_bias).
    shared: bool = False
    #: Linear parameter names (per joint when not shared).
    linear: tuple[str, ...] = ()
    #: Linear parameters (by index) held at 0 together with the one that keys them when its
    #: sign constraint holds it there (a payload's first moments vanish with its mass).
    tied: ClassVar[dict[int, tuple[int, ...]]] = {}
    #: Name of the searched nonlinear parameter, or None; a tuple names the parts of a
    #: searched tuple (``attenuation_lag``: delay and lag).
    hyper: str | tuple[str, ...] | None = None
    #: The searched parameter is a continuous number, refined after the grid search.
    continuous: bool = False
    #: Which consumer applies it: "torque" (effects_torque), "external", "sensor".
    kind: str = "torque"
    #: Regimes in which the effect can be seen (documentation and diagnosis text).
    shows_in: tuple[str, ...] = REGIMES
    #: Where the effect is tried in diagnosis and listed (smaller first; ties by name).
    order: ClassVar[float] = 100.0
    #: The design at a sample depends on that sample's signals alone (q, dq, ddq, the wrench,
    #: the regime, the time...). False for a time filter (``attenuation_lag``): on
    #: :meth:`Signals.take` n rows it is computed on the whole recording, then taken at the rows
    #: (:func:`design_at`).
    pointwise: ClassVar[bool] = True
    #: The effect acts only where the dither is on: adding it needs at least one dithered
    #: recording (else one clear error rather than "cannot be told apart from the bands").
    needs_dither: ClassVar[bool] = False
    #: Every joint has the effect (the dither's extraction, a part of the measurement pipeline;
    #: a rotor's and the links' inertia, a part of every arm): it acts on every joint where its
    #: design is above the noise, so ``identify --add`` without joints fits it on all of them
    #: (:func:`ditherlab.analysis.scoring.select_joints`), not only where one recording's
    #: diagnosis evidence passed (the others would keep it in their residual: a false discovery
    #: next), and leaves out, with one line each, the joints where its fit cannot be told apart
    #: from the bands or lies outside a physical range.
    on_every_joint: ClassVar[bool] = False
    #: The physical range of every fitted parameter, with its source
    #: (:class:`~ditherlab.physics.effects.ranges.Bound`): a fit outside it is never written
    #: (:meth:`outside_range`), and diagnosis does not suggest it.
    bounds: ClassVar[tuple[Bound, ...]] = ()
    #: Evidence rules of a per-joint fit, or None (:func:`ditherlab.physics.effect_fit.pool_weak_joints`):
    #: ``stderr_max`` per linear parameter (the physical range is :attr:`bounds`); a joint
    #: failing them takes the median of the joints that pass, or the ``prior`` values when none
    #: does.
    evidence_rules: ClassVar[dict[str, Any] | None] = None
    #: Evidence plots show the residual times sign(dq) while moving (friction that grows with a
    #: load or falls with temperature acts against the motion).
    signed_evidence: ClassVar[bool] = False

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if cls.name:
            old = EFFECTS.get(cls.name)
            if old is not None and type(old).__qualname__ != cls.__qualname__:
                raise TypeError(f"two effects are called {cls.name!r}")
            EFFECTS[cls.name] = cls()
            ordered = sorted(EFFECTS.items(), key=lambda kv: (kv[1].order, kv[0]))
            EFFECTS.clear()
            EFFECTS.update(ordered)

    # -- to implement
    @abc.abstractmethod
    def design(self, sig: Signals, j: int | None, h: Any, ref: dict[str, Any]) -> Design:
        """The effect's :class:`Design` on joint j (0-based; None: all joints) for the value
        ``h`` of its searched parameter and the reference values ``ref`` (:meth:`reference`)."""

    def grid(self, sig: Sequence[Signals], j: int | None) -> list[Any]:
        """The values of the searched parameter tried on joint j of these recordings ([None]:
        nothing is searched), in the parameter's unit."""
        return [None]

    def reference(self, sig: Sequence[Signals], j: int | None) -> dict[str, Any]:
        """Fixed reference values of the driving variable (computed from the data, not the
        residual), e.g. the mean load; stored with the parameters."""
        return {}

    def unsupported(self, sig: Sequence[Signals], j: int | None, h: Any) -> str | None:
        """Why the data cannot support this effect at the searched value ``h`` on joint ``j``
        (None: they can), beyond what :func:`ditherlab.physics.effect_fit.identifiability` measures; e.g. a
        periodic effect seen over too few of its periods. Part of the one rule that decides
        both diagnosis's suggestions and ``identify --add``."""
        return None

    def outside_range(
        self, p: dict[str, Any], sigs: Sequence[Signals], j: int | None = None
    ) -> OutOfRange | None:
        """The first value of the fitted parameters ``p`` of joint ``j`` (0-based; None: a
        shared effect) outside its physical range (:attr:`bounds`) on the robot and recordings
        seen by ``sigs``, or None when all lie inside; such a fit is never written."""
        for b in self.bounds:
            vals = b.values(p, sigs, j)
            if not vals:
                continue
            lo, hi = b.limits(sigs, j)
            for where, v in vals:
                if not lo <= v <= hi:
                    return OutOfRange(self.name, b.param, where, v, lo, hi, b.unit, b.source)
        return None

    def check(self, sig: Signals) -> None:
        """Raise ModelError naming a column the effect needs but the recording lacks."""
        return None

    def shortlist(
        self,
        sc: Sequence[Any],
        j: int | None,
        grid: list[Any],
        masks: list[np.ndarray],
        lags: Sequence[int] | None = None,
    ) -> list[list[Any]]:
        """For each boolean training mask over the stacked samples, the grid values worth a full
        fit (default: the whole grid). Long grids override this with a fast pre-screen, which
        must shift its driving variable by ``lags`` (one per recording, samples; see
        :meth:`Design.rolled`) when they are given."""
        return [list(grid) for _ in masks]

    def signs(self, h: Any) -> tuple[int, ...]:
        """Physical sign of each linear parameter: +1 (>= 0), -1 (<= 0) or 0 (free)."""
        return (0,) * self.k

    def driver(self, sig: Signals, j: int, p: dict[str, Any]) -> tuple[np.ndarray, str]:
        """The driving variable of joint j (N,) and its axis label, for evidence plots."""
        return sig.dq[:, j], f"dq_{j + 1} [rad/s]"

    def term(self, p: dict[str, Any], j: int) -> str:
        """The effect's term in the printed equation of joint j (0-based)."""
        return self.name

    # -- parameters <-> the model file (override when the file names differ from `linear`)
    def to_range(self, w: np.ndarray) -> np.ndarray | None:
        """The linear parameters (k,) of a shared fit ``w`` moved to the nearest point inside
        every physical range whose value is a function of several of them (a rotation's angle,
        an offset's distance), or None where the effect has no such range
        (:func:`ditherlab.physics.effect_fit.physical_fits` holds a shared fit there when the
        data do not reject it)."""
        return None

    def weights(self, p: dict[str, Any]) -> np.ndarray:
        """The linear parameters (k,) from the parameters ``p`` of one joint (or shared)."""
        return np.array([p[c] for c in self.linear], dtype=float)

    def linear_params(self, w: np.ndarray) -> dict[str, Any]:
        """The model file's parameters of a shared effect from its linear parameters (k,)."""
        return {c: float(v) for c, v in zip(self.linear, w, strict=True)}

    def force_gain(self, p: dict[str, Any]) -> float:
        """How a torque effect of one joint (parameters ``p``) scales the external torque
        ``J^T F`` in the logged torque (1: it does not); the force estimator's ``J^T`` row of
        the joint is multiplied by it."""
        return 1.0

    # -- kind "external": how the servo shows the external torque
    def external(self, sig: Signals, j: int, X: np.ndarray, w: np.ndarray, h: Any) -> np.ndarray:
        """(N,) [N·m]: the external torque ``X`` (N,) of joint ``j`` (0-based) as the servo
        shows it (the joint matters beyond the parameters for ``dither_extraction``: its
        regime)."""
        raise ModelError(f"effect {self.name!r} does not act on the external torque")

    def external_text(self, p: dict[str, Any], ext: str) -> str:
        """The printed external-torque term of one joint, given the sensor's term ``ext``."""
        return ext

    # -- kind "sensor": how the F/T sensor reads the wrench
    def correct_wrench(self, F: np.ndarray, p: dict[str, Any], sig: Signals) -> np.ndarray:
        """(N, 6): the true wrench from the sensor's reading ``F`` (N, 6) [N, N·m] of the
        recording seen by ``sig`` (its pose, for a sensor whose error turns with the tool)."""
        raise ModelError(f"effect {self.name!r} does not act on the sensor")

    def sensor_text(self, ext: str) -> str:
        """The printed sensor term, e.g. ``J^T (F - ft_bias)``, given the plain ``ext``."""
        return ext

    @property
    def k(self) -> int:
        """The number of linear parameters."""
        return len(self.linear)


def design_at(e: Effect, sig: Signals, j: int | None, h: Any, ref: dict[str, Any]) -> Design:
    """``e.design(sig, j, h, ref)``, also on Signals of some rows (:meth:`Signals.take`): an
    effect that is not :attr:`Effect.pointwise` is computed on the whole recording and taken at
    the rows (kept for the next call with the same ``j``, ``h`` and ``ref``)."""
    rows = sig.rows
    if rows is None or e.pointwise:
        return e.design(sig, j, h, ref)
    key = ("design", e.name, j, repr(h), repr(sorted(ref.items())))
    if sig.whole is None and key not in sig._cache:
        raise ModelError(
            f"effect {e.name!r} filters in time and was not computed on every piece for "
            f"joint {'all' if j is None else j + 1}, {e.hyper or 'value'} {h!r}; expected its "
            "grid and reference to depend on the sample rate alone"
        )
    return sig._get(key, lambda: e.design(sig.whole, j, h, ref).take(rows))


def fmt(x: float) -> str:
    """A number in three significant digits, for printed equations."""
    return f"{x:.3g}"

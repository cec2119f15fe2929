"""The arrays of one recording that effects are driven by, computed once per recording.

``Signals(rec)`` sees the recording with its F/T sensor; ``Signals(rec, sensor=False)`` without
it (the force estimator's view: a sensorless estimate must not read the sensor through a model
effect). The robot quantities (gravity, Jacobian, mass matrix, regressors), the regimes and
``ddq`` do not depend on the sensor and are shared between the two views of one recording.

``signals(rec).take(rows)`` are the same arrays at some rows only (diagnosis scores candidate
effects on every k-th sample): the logged and filtered columns are the whole recording's at those
rows, the robot quantities are computed at those rows alone (they depend on the sample's own
``q, dq, ddq``), and an effect whose design needs the samples around a row (a time filter:
:attr:`ditherlab.physics.effects.base.Effect.pointwise` False) is computed on the whole recording and
then taken at the rows.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np

from ditherlab.core.errors import ModelError, where_prefix
from ditherlab.core.names import MOVING
from ditherlab.core.timeseries import jtf, smooth_wrench
from ditherlab.data.recording import Recording, regimes

__all__ = ["Signals", "release", "signals"]


class Signals:
    """Arrays of one recording that effects are driven by, computed once and cached.

    Parameters
    ----------
    rec : Recording
    sensor : see the F/T columns (when the recording has them); False hides them

    Attributes (all time-first, SI)
    -------------------------------
    t : (N,) [s] ; ts : (N,) [s] time since the recording's first sample (:attr:`Recording.t0`)
    q, dq, ddq : (N, n) [rad, rad/s, rad/s²]; ``ddq`` is :attr:`ditherlab.data.recording.Recording.ddq`
    tau : (N, n) [N·m] the logged torque ; temp : (N, n) [°C] or None
    regime : (N, n) int8 (``STILL``, ``DITHER``, ``MOVING``)
    gravity : (N, n) [N·m] ; jac : (N, 6, n) ; mass : (N, n, n) ; regressor : (N, n, 10)
    has_wrench : the F/T columns are seen
    whole : the Signals of every row (``self`` unless these are :meth:`take` n rows)
    index : (N,) int, the rows' numbers in the recording ; length : rows in the recording
    """

    def __init__(
        self,
        rec: Recording,
        sensor: bool = True,
        *,
        _shared: dict | None = None,
        _whole: Signals | None = None,
        _rows: np.ndarray | None = None,
    ):
        self.rec = rec
        self.n = rec.n
        self.length = len(rec)
        self.sample_rate = rec.sample_rate
        self.has_wrench = bool(sensor) and rec.has_wrench
        self._whole = _whole  # None: these are the whole recording's (not `self`: a cycle)
        self._detached = False
        self._rows = _rows
        src: Any = rec if _rows is None else _whole
        pick = (lambda a: a) if _rows is None else (lambda a: None if a is None else a[_rows])
        self.t = pick(src.t)
        self.ts = self.t - rec.t0
        self.q = pick(src.q)
        self.dq = pick(src.dq)
        self.tau = pick(src.tau)
        self.temp = pick(src.temp)
        self.index = np.arange(self.length) if _rows is None else _rows
        # quantities that do not depend on the sensor: shared by both views of a recording
        self._shared: dict[str, Any] = {} if _shared is None else _shared
        self._cache: dict[Any, Any] = {}

    @property
    def whole(self) -> Signals | None:
        """The Signals of every row: ``self``, or the Signals these rows were taken from, or
        None after :meth:`detach` / :meth:`join` (no whole recording behind them)."""
        if self._detached:
            return None
        return self if self._whole is None else self._whole

    @property
    def rows(self) -> np.ndarray | None:
        """(M,) the recording's rows these Signals hold, or None: all of them."""
        return self._rows

    def take(self, rows: np.ndarray) -> Signals:
        """These Signals at ``rows`` (M,) only (row numbers of this view, increasing): the
        logged columns and whole-recording quantities (regimes, ``ddq``, filtered wrench) taken
        at the rows, the robot quantities computed there alone (module docstring)."""
        rows = np.asarray(rows, dtype=np.int64)
        if self._rows is not None:
            return self.whole.take(self._rows[rows])
        return Signals(self.rec, self.has_wrench, _whole=self, _rows=rows)

    def detach(self, first_row: int, rec: Recording) -> None:
        """Make :meth:`take` n rows of a piece of a recording ready for :meth:`join`: the
        whole-recording quantities join needs (regimes, ``ddq``, the F/T columns raw and
        low-passed) kept at the rows, the rows numbered in the recording (the piece's row 0 is
        its row ``first_row``), and the piece let go (its Signals and table, most of its memory), with
        ``rec`` (one recording of the same robot and time base) in its place."""
        _ = self.regime, self.ddq
        if self.has_wrench:
            self.wrench("join")
            self.wrench_lp("join")
        self.index = first_row + self.index
        self._whole, self._detached = None, True
        self.rec = rec

    @classmethod
    def join(cls, parts: list[Signals], length: int) -> Signals:
        """One Signals of the rows of several :meth:`take` n parts of the same recording (its
        pieces read one after another, each part's ``index`` numbering the recording's rows):
        their arrays and cached quantities joined in order. There is no whole recording behind
        it: a design that needs one (not :attr:`Effect.pointwise`) must have been computed on
        every part (``design_at`` keeps it) before :meth:`detach`."""
        first = parts[0]
        out = cls.__new__(cls)
        out.rec = first.rec
        out.n = first.n
        out.length = int(length)
        out.sample_rate = first.sample_rate
        out.has_wrench = first.has_wrench
        out._whole, out._detached = None, True
        out._rows = np.concatenate([p.index for p in parts])
        out.index = out._rows

        def cat(xs: list[Any]) -> Any:
            if any(x is None for x in xs):
                return None
            if isinstance(xs[0], tuple):
                return tuple(cat([x[i] for x in xs]) for i in range(len(xs[0])))
            if isinstance(xs[0], np.ndarray):
                return np.concatenate(xs)
            d0 = xs[0]  # a Design
            return type(d0)(
                *(cat([getattr(x, f) for x in xs]) for f in ("centre", "widen", "offset"))
            )

        for f in ("t", "ts", "q", "dq", "tau", "temp"):
            setattr(out, f, cat([getattr(p, f) for p in parts]))
        out._shared = {
            k: cat([p._shared[k] for p in parts])
            for k in ("regime", "ddq")
            if all(k in p._shared for p in parts)
        }
        out._cache = {
            k: cat([p._cache[k] for p in parts])
            for k in first._cache
            if (k in ("wrench", "wrench_lp") or (isinstance(k, tuple) and k[0] == "design"))
            and all(k in p._cache for p in parts)
        }
        return out

    def without_sensor(self) -> Signals:
        """The same recording with its F/T columns hidden (robot quantities shared)."""
        if self._rows is not None and self.whole is None:  # joined parts: hide the columns
            out = copy.copy(self)
            out.has_wrench = False
            out._cache = {}
            return out
        if self._rows is not None:
            return Signals(
                self.rec,
                sensor=False,
                _shared=self._shared,
                _whole=self.whole.cached("_no_sensor", self.whole.without_sensor),
                _rows=self._rows,
            )
        return Signals(self.rec, sensor=False, _shared=self._shared)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """``make()`` computed once per recording and shared by both sensor views: for an
        effect's own quantities that do not depend on the F/T columns (e.g. gravity
        derivatives); anything computed from the sensor belongs in the per-view cache."""
        if key not in self._shared:
            self._shared[key] = make()
        return self._shared[key]

    def _get(self, key: str, make: Callable[[], np.ndarray]) -> np.ndarray:
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def _whole_or(self, key: str, make: Callable[[], Any]) -> Any:
        """A quantity of the whole recording (``make()``), at these rows."""
        if self._rows is None:
            return self.cached(key, make)
        rows = self._rows
        return self.cached(key, lambda: getattr(self.whole, key)[rows])

    @property
    def regime(self) -> np.ndarray:
        """(N, n) int8 regime codes (:func:`ditherlab.data.recording.regimes`)."""
        return self._whole_or("regime", lambda: regimes(self.rec))

    @property
    def moving(self) -> np.ndarray:
        """(N, n) bool: the joint slides (regime MOVING)."""
        return self.regime == MOVING

    @property
    def ddq(self) -> np.ndarray:
        """(N, n) [rad/s²] (:attr:`ditherlab.data.recording.Recording.ddq`)."""
        return self._whole_or("ddq", lambda: self.rec.ddq)

    @property
    def gravity(self) -> np.ndarray:
        """(N, n) [N·m] the robot model's gravity torque at ``q``."""
        return self.cached("gravity", lambda: self.rec.robot().gravity(self.q))

    @property
    def jac(self) -> np.ndarray:
        """(N, 6, n) [m or 1] the tool point's Jacobian at ``q`` (base axes)."""
        return self.cached("jac", lambda: self.rec.robot().jacobian(self.q))

    @property
    def mass(self) -> np.ndarray:
        """(N, n, n) [kg·m²] the mass matrix at ``q``."""
        return self.cached("mass", lambda: self.rec.robot().mass_matrix(self.q))

    @property
    def tool_rotation(self) -> np.ndarray:
        """(N, 3, 3): the tool frame's axes in base axes (:meth:`ditherlab.robot.RobotModel.tool_pose`)."""
        return self.cached(
            "tool_rotation", lambda: self.rec.robot().tool_pose(self.q)[:, :3, :3].copy()
        )

    @property
    def regressor(self) -> np.ndarray:
        """(N, n, 10) the gravity regressor of the tool link at ``q``
        (:meth:`ditherlab.robot.RobotModel.gravity_regressor`)."""
        return self.cached("regressor", lambda: self.rec.robot().gravity_regressor(self.q))

    @property
    def rigid_load(self) -> np.ndarray:
        """(N, n) [N·m]: ``tau_grav + J^T F`` (F from the F/T columns when seen), plus
        :attr:`dynamic_torque` where the joint moves: the torque the links ask of each gear."""

        def make() -> np.ndarray:
            L = self.gravity.copy()
            if self.has_wrench:
                L += self.sensor_torque("rigid_load")
            return L + np.where(self.moving, self.dynamic_torque, 0.0)

        return self._get("rigid_load", make)

    @property
    def dynamic_torque(self) -> np.ndarray:
        """(N, n) [N·m]: the links' dynamic torque ``M(q) ddq + C(q, dq) dq`` (pinocchio's RNEA
        less gravity) at :attr:`motion`; its Coriolis and centrifugal part is above the noise
        floor of the proximal joints in ordinary motions."""

        def make() -> np.ndarray:
            dq, ddq = self.motion
            return self.rec.robot().inverse_dynamics(self.q, dq, ddq) - self.gravity

        return self.cached("dynamic_torque", make)

    @property
    def motion(self) -> tuple[np.ndarray, np.ndarray]:
        """``(dq, ddq)``, each (N, n) [rad/s, rad/s²]: the one motion every rigid-body quantity
        is evaluated at. The logged values where any joint moves, 0 where the whole arm stands
        (there ``ddq`` is differentiation noise). A joint that reverses or pauses while others
        move keeps its acceleration: the links still feel it
        (``docs/design/physics-effect-models.md``)."""

        def make() -> tuple[np.ndarray, np.ndarray]:
            arm = self.moving.any(axis=1, keepdims=True)
            return np.where(arm, self.dq, 0.0), np.where(arm, self.ddq, 0.0)

        return self.cached("motion", make)

    @property
    def torque_regressor(self) -> np.ndarray:
        """(N, n, 10): :meth:`ditherlab.robot.RobotModel.torque_regressor` at :attr:`motion`
        (standing still: the gravity regressor)."""

        def make() -> np.ndarray:
            dq, ddq = self.motion
            return self.rec.robot().torque_regressor(self.q, dq, ddq)

        return self.cached("torque_regressor", make)

    @property
    def link_regressor(self) -> np.ndarray:
        """(N, n, 10 n): pinocchio's joint-torque regressor of every link
        (:meth:`ditherlab.robot.RobotModel.torque_regressor` with ``all_links``) at
        :attr:`motion`."""

        def make() -> np.ndarray:
            dq, ddq = self.motion
            return self.rec.robot().torque_regressor(self.q, dq, ddq, all_links=True)

        return self.cached("link_regressor", make)

    def wrench(self, what: str) -> np.ndarray:
        """The raw F/T columns (N, 6); ModelError naming the column when absent (or hidden)."""
        if not self.has_wrench:
            raise ModelError(
                f"{where_prefix(self.rec.name)}effect {what!r} needs the F/T sensor column f_x "
                "(f_x..m_z), which the recording lacks"
            )
        if self._rows is None:
            return self.rec.wrench
        rows = self._rows
        return self._get("wrench", lambda: self.whole.wrench(what)[rows])

    def wrench_lp(self, what: str) -> np.ndarray:
        """The F/T columns low-passed (N, 6): :func:`ditherlab.core.timeseries.smooth_wrench` of the
        whole recording (at these rows)."""
        w = self.wrench(what)
        if self._rows is None:
            return self._get("wrench_lp", lambda: smooth_wrench(w, self.sample_rate))
        rows = self._rows
        return self._get("wrench_lp", lambda: self.whole.wrench_lp(what)[rows])

    def sensor_torque(self, what: str) -> np.ndarray:
        """(N, n) [N·m]: ``J^T F`` of the raw F/T columns (computed once per view); ModelError
        naming ``what`` without them."""
        F = self.wrench(what)
        return self._get("sensor_torque", lambda: self.jtf(F))

    def jtf(self, F: np.ndarray) -> np.ndarray:
        """``J^T F`` : (N, n) [N·m] for a wrench F : (N, 6) (:func:`ditherlab.core.timeseries.jtf`)."""
        return jtf(self.jac, F)


def signals(rec: Recording, sensor: bool = True) -> Signals:
    """The cached :class:`Signals` of a recording (robot quantities computed once per recording,
    shared by the views with and without the sensor).

    Kept on the recording itself (``rec._signals``): the two refer to each other and are freed
    together once nothing uses the recording (a module-level ``WeakKeyDictionary`` would keep
    every recording alive: its values hold their key).
    """
    s = rec.__dict__.get("_signals")
    if s is None:
        s = Signals(rec)
        object.__setattr__(rec, "_signals", s)
    if sensor or not rec.has_wrench:
        return s
    return s.cached("_no_sensor", s.without_sensor)


def release(rec: Recording) -> None:
    """Drop the Signals cached on ``rec`` now, and everything they computed (a piece of a long
    log, done with). The recording and its Signals refer to each other, and so do the two
    sensor views through their shared cache: only Python's cycle collector would free them, and
    it may not run before many pieces have piled up. The robot's cached
    results go too (the pieces of a log share one robot; the next piece's poses are others)."""
    s = rec.__dict__.pop("_signals", None)
    if s is not None:
        s._shared.clear()
        s._cache.clear()
    robot = rec.__dict__.get("_robot")
    if robot is not None:  # shared by the pieces of a log: its results for this one go too
        robot.clear_cache()

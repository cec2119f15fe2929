"""The Recording: one time-indexed table plus metadata (contract: ``docs/recording-format.md``,
version 1).

Every reader and the simulator produce a :class:`Recording`; everything downstream consumes one.
Arrays returned by its accessors have time as the first axis and SI units (arm side of the
gearbox): ``q: (N, n) [rad]``, ``tau: (N, n) [N·m]``, ``wrench: (N, 6) [N, N·m]``.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.core.errors import RecordingError, where_prefix
from ditherlab.core.names import (
    DITHER,
    FORCE_AXES,
    MOVING,
    REGIME_NAMES,
    STILL,
    VENDOR_TAU_FAMILY,
    VENDOR_WRENCH_COLUMNS,
    WRENCH_COLUMNS,
    Regime,
)
from ditherlab.core.schema import Either, Flag, ListOf, Number, Table, Text, check
from ditherlab.core.timeseries import smooth_derivative
from ditherlab.robot import RobotModel

SCHEMA = "ditherlab.recording/1"
#: Per-joint column families: prefix -> (required, unit).
JOINT_FAMILIES: dict[str, tuple[bool, str]] = {
    "q": (True, "rad"),
    "dq": (False, "rad/s"),
    "tau": (True, "N·m"),
    "tau_ffw": (False, "N·m"),
    "temp": (False, "°C"),
    VENDOR_TAU_FAMILY: (False, "N·m"),
}
_JOINT_COL = re.compile(rf"^({'|'.join(JOINT_FAMILIES)})_(\d+)$")

#: Longest tool offset or payload lever accepted [m], heaviest payload [kg], fastest rate [Hz]:
#: far beyond any robot, small enough that nothing downstream overflows.
MAX_LENGTH_M, MAX_MASS_KG, MAX_RATE_HZ = 100.0, 1e4, 1e6
#: A recording's ``robot`` entry (also a model file's): a built-in name or an embedded URDF.
ROBOT_NODE = Either(
    options=(
        Text(nonempty=True),
        Table(
            keys={
                "urdf": Text(nonempty=True, what="URDF text"),
                "tool_frame": Text(nonempty=True, what="the name of a URDF link"),
                "name": Text(),
                # the description file it came from: `view` finds its meshes from there
                "path": Text(),
            },
            required=("urdf", "tool_frame"),
        ),
    ),
    what="a built-in robot name such as 'irb140' or an object {urdf, tool_frame}",
)
#: ``tool_offset``: [x, y, z] in the tool frame [m].
TOOL_OFFSET_NODE = ListOf(item=Number(-MAX_LENGTH_M, MAX_LENGTH_M, "m"), length=3, per="axis")
#: ``payload``: a point mass [kg] at ``com`` [m] in the tool frame.
PAYLOAD_NODE = Table(
    keys={"mass": Number(0.0, MAX_MASS_KG, "kg"), "com": TOOL_OFFSET_NODE},
    required=("mass",),
)
#: ``dither`` (and ``sim.dither``): whether the dither ran, or its period [s] / omega [rad/s]
#: (:func:`meta_dither_period`).
_DITHER_NODE = Either(
    options=(
        Flag(),
        Table(
            keys={
                "period": Number(0.0, 1e6, "s", lo_open=True),
                "omega": Number(0.0, 1e9, "rad/s", lo_open=True),
            },
            open=True,
        ),
    ),
    what="true, false or a table {period [s], omega [rad/s]}",
)
#: The recording's metadata (``docs/recording-format.md``); other keys (``sim``, ``mapping``, ...)
#: pass through.
META_SCHEMA = Table(
    keys={
        "schema": Text(choices=(SCHEMA,)),
        "robot": ROBOT_NODE,
        "tool_offset": TOOL_OFFSET_NODE,
        "payload": PAYLOAD_NODE,
        "known_load": PAYLOAD_NODE,
        "sample_rate_hz": Number(0.0, MAX_RATE_HZ, "Hz", lo_open=True),
        "source": Text(),
        "robot_id": Text(),
        "notes": Text(),
        "dither": _DITHER_NODE,
        "sim": Table(keys={"dither": _DITHER_NODE}, open=True),
    },
    required=("schema", "robot"),
    open=True,
)
#: The metadata a file stores (a sidecar, Parquet's or MCAP's): ``schema`` and ``robot`` may
#: come from reader options instead.
STORED_META_SCHEMA = dataclasses.replace(META_SCHEMA, required=())

__all__ = [
    "DITHER",
    "FORCE_AXES",
    "META_SCHEMA",
    "MOVING",
    "REGIME_NAMES",
    "STILL",
    "VENDOR_TAU_FAMILY",
    "VENDOR_WRENCH_COLUMNS",
    "WRENCH_COLUMNS",
    "Recording",
    "RecordingArrays",
    "Regime",
    "SharedMeta",
    "TimeBase",
    "differentiate",
    "meta_dither_period",
    "moving_mask",
    "regimes",
    "share_meta",
]


def _time_span(t: np.ndarray, bad: np.ndarray) -> str:
    idx = np.flatnonzero(bad)
    if t[idx[0]] == t[idx[-1]]:
        return f"at t={t[idx[0]]:.2f} s"
    return f"between t={t[idx[0]]:.2f} s and t={t[idx[-1]]:.2f} s"


@dataclass(frozen=True)
class TimeBase:
    """What a recording's time stamps say as a whole, fixed when a recording is processed in
    pieces (:mod:`ditherlab.io.stream`) so that every piece sees the same values.

    Attributes
    ----------
    t0 : [s] the first sample's time (``time since start`` counts from it)
    dt : [s] the median sample step
    uniform : every step within 1e-6 of ``dt`` (:func:`ditherlab.core.timeseries.smooth_derivative`
        takes its Savitzky–Golay path)
    dither_period : [s] the dither period (:func:`ditherlab.physics.dither.dither_period`), None when
        the recording has no dither
    """

    t0: float
    dt: float
    uniform: bool
    dither_period: float | None = None

    @classmethod
    def of(cls, t: np.ndarray, dither_period: float | None = None) -> TimeBase:
        """The time base of the time stamps ``t`` (N,) [s] of a whole recording."""
        t = np.asarray(t, dtype=float)
        if len(t) < 2:
            return cls(float(t[0]) if len(t) else 0.0, float("nan"), True, dither_period)
        steps = np.diff(t)
        dt = float(np.median(steps))
        return cls(float(t[0]), dt, bool(np.max(np.abs(steps - dt)) <= 1e-6 * dt), dither_period)


@dataclass(frozen=True, eq=False)
class RecordingArrays:
    """The arrays of a recording, time first, SI, for :meth:`Recording.from_arrays`.

    Attributes
    ----------
    t : (N,) [s]
    q : (N, n) [rad]
    tau : (N, n) [N·m]
    dq : (N, n) [rad/s], optional
    tau_ffw : (N, n) [N·m], optional
    wrench : (N, 6) [N, N·m], optional, ``f_x .. m_z``
    temp : (N, n) [°C], optional
    dither : (N,) bool, optional
    vendor_wrench : (N, 6) [N, N·m], optional, the vendor's estimate ``f_vendor_x .. m_vendor_z``
    tau_ext_vendor : (N, n) [N·m], optional, the vendor's external joint torques
    extra : further columns by name, each (N,), passed through untouched
    """

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    dq: np.ndarray | None = None
    tau_ffw: np.ndarray | None = None
    wrench: np.ndarray | None = None
    temp: np.ndarray | None = None
    dither: np.ndarray | None = None
    vendor_wrench: np.ndarray | None = None
    tau_ext_vendor: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] | None = None

    def columns(self) -> dict[str, np.ndarray]:
        """The table's columns by name (``docs/recording-format.md``), in the file's order."""
        q = np.atleast_2d(np.asarray(self.q, dtype=float))
        cols: dict[str, np.ndarray] = {"t": np.asarray(self.t, dtype=float)}
        for prefix, arr in (
            ("q", q),
            ("dq", self.dq),
            ("tau", self.tau),
            ("tau_ffw", self.tau_ffw),
            ("temp", self.temp),
            (VENDOR_TAU_FAMILY, self.tau_ext_vendor),
        ):
            if arr is None:
                continue
            arr = np.asarray(arr, dtype=float).reshape(len(cols["t"]), -1)
            for j in range(arr.shape[1]):
                cols[f"{prefix}_{j + 1}"] = arr[:, j]
        for names, arr in (
            (WRENCH_COLUMNS, self.wrench),
            (VENDOR_WRENCH_COLUMNS, self.vendor_wrench),
        ):
            if arr is not None:
                w = np.asarray(arr, dtype=float).reshape(len(cols["t"]), 6)
                cols.update({c: w[:, k] for k, c in enumerate(names)})
        if self.dither is not None:
            cols["dither"] = np.asarray(self.dither, dtype=bool)
        if self.extra:
            cols.update({k: np.asarray(v) for k, v in self.extra.items()})
        return cols


@dataclass(frozen=True, eq=False)
class Recording:
    """A validated joint log.

    Parameters
    ----------
    data : pandas.DataFrame
        One row per sample, columns per ``docs/recording-format.md`` (``t``, ``q_1..q_n``,
        ``tau_1..tau_n`` and optional families). Numeric columns are converted to float64,
        ``dither`` to bool.
    meta : dict
        Metadata; ``schema`` and ``robot`` are required.
    name : str, optional
        Where the recording came from (a file path), used in error messages.
    timebase : TimeBase, optional
        Set on a piece of a longer recording (:mod:`ditherlab.io.stream`): the whole
        recording's start, step and dither period, used instead of the piece's own.

    Raises
    ------
    RecordingError
        If the table or metadata break the contract; the message names the file, the column
        and what was expected.
    """

    data: pd.DataFrame
    meta: dict[str, Any]
    name: str | None = None
    timebase: TimeBase | None = None
    n: int = field(init=False)

    def __post_init__(self) -> None:
        data, meta, n = _validate(self.data, self.meta, self.name)
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "meta", meta)
        object.__setattr__(self, "n", n)

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_arrays(
        cls, arrays: RecordingArrays, meta: Mapping[str, Any], name: str | None = None
    ) -> Recording:
        """Build a recording from its arrays.

        Parameters
        ----------
        arrays : the columns, time first (:class:`RecordingArrays`)
        meta : metadata (``robot`` required; ``schema`` is filled in)
        name : where the recording came from, for messages
        """
        return cls(pd.DataFrame(arrays.columns()), {"schema": SCHEMA, **dict(meta)}, name=name)

    # ------------------------------------------------------------------ accessors
    def __len__(self) -> int:
        return len(self.data)

    def _family(self, prefix: str) -> np.ndarray | None:
        cols = [f"{prefix}_{j + 1}" for j in range(self.n)]
        if cols[0] not in self.data.columns:
            return None
        return self.data[cols].to_numpy(dtype=float)

    @property
    def t(self) -> np.ndarray:
        """Sample times, (N,) [s]."""
        return self.data["t"].to_numpy(dtype=float)

    @property
    def q(self) -> np.ndarray:
        """Joint positions, (N, n) [rad]."""
        return self._family("q")  # type: ignore[return-value]

    @property
    def tau(self) -> np.ndarray:
        """Logged motor torque (torque reference, arm side), (N, n) [N·m]."""
        return self._family("tau")  # type: ignore[return-value]

    @property
    def has_dq(self) -> bool:
        """True when ``dq_*`` columns were logged (not differentiated)."""
        return "dq_1" in self.data.columns

    @cached_property
    def dq(self) -> np.ndarray:
        """Joint velocities, (N, n) [rad/s].

        The logged ``dq_*`` columns when present; otherwise :func:`differentiate` of ``q``.
        """
        logged = self._family("dq")
        return logged if logged is not None else differentiate(self.t, self.q)

    @cached_property
    def ddq(self) -> np.ndarray:
        """Joint accelerations, (N, n) [rad/s²]: the quadratic Savitzky–Golay derivative of
        :attr:`dq` over 40 ms (:func:`ditherlab.core.timeseries.smooth_derivative`), on each stretch
        between gaps in ``t`` (:func:`derivative_by_segment`); the one ``ddq`` of
        identification, diagnosis and every effect."""
        tb = self.timebase or TimeBase.of(self.t)
        return derivative_by_segment(self.t, self.dq, tb.dt, tb.uniform)

    @property
    def tau_ffw(self) -> np.ndarray | None:
        """Torque feedforward sent (dither + static centre), (N, n) [N·m], or None."""
        return self._family("tau_ffw")

    @property
    def temp(self) -> np.ndarray | None:
        """Joint temperatures, (N, n) [°C], or None."""
        return self._family("temp")

    @property
    def has_wrench(self) -> bool:
        """True when the F/T sensor columns ``f_x .. m_z`` are present."""
        return "f_x" in self.data.columns

    @property
    def wrench(self) -> np.ndarray | None:
        """F/T sensor wrench at the tool point in base axes, (N, 6) [N, N·m], or None.

        Sign: the wrench the robot exerts on its environment (``docs/recording-format.md``).
        """
        if not self.has_wrench:
            return None
        return self.data[list(WRENCH_COLUMNS)].to_numpy(dtype=float)

    @property
    def has_vendor(self) -> bool:
        """True when the vendor's own estimate is logged: its wrench ``f_vendor_x .. m_vendor_z``
        or its external joint torques ``tau_ext_vendor_*``."""
        cols = self.data.columns
        return VENDOR_WRENCH_COLUMNS[0] in cols or f"{VENDOR_TAU_FAMILY}_1" in cols

    @property
    def vendor_wrench(self) -> np.ndarray | None:
        """The vendor's estimate of the external wrench, (N, 6) [N, N·m], or None; the F/T
        columns' point, axes and sign (``docs/recording-format.md``)."""
        if VENDOR_WRENCH_COLUMNS[0] not in self.data.columns:
            return None
        return self.data[list(VENDOR_WRENCH_COLUMNS)].to_numpy(dtype=float)

    @property
    def tau_ext_vendor(self) -> np.ndarray | None:
        """The vendor's estimate of the external joint torques ``J^T F``, (N, n) [N·m], or
        None."""
        return self._family(VENDOR_TAU_FAMILY)

    @property
    def dither(self) -> np.ndarray | None:
        """Dither flag, (N,) bool, or None when not logged."""
        if "dither" not in self.data.columns:
            return None
        return self.data["dither"].to_numpy(dtype=bool)

    @property
    def sample_rate(self) -> float:
        """Nominal sample rate [Hz]: metadata ``sample_rate_hz`` or 1 / :attr:`dt`."""
        if "sample_rate_hz" in self.meta:
            return float(self.meta["sample_rate_hz"])
        return 1.0 / self.dt

    @property
    def dt(self) -> float:
        """Median sample step [s] (of the whole recording for a piece; NaN below 2 samples)."""
        if self.timebase is not None:
            return self.timebase.dt
        if len(self) < 2:
            return float("nan")
        return float(np.median(np.diff(self.t)))

    @property
    def t0(self) -> float:
        """The recording's first time stamp [s] (of the whole recording for a piece)."""
        if self.timebase is not None:
            return self.timebase.t0
        t = self.t
        return float(t[0]) if len(t) else 0.0

    @property
    def duration(self) -> float:
        """t[-1] - t[0] [s]."""
        t = self.t
        return float(t[-1] - t[0]) if len(t) else 0.0

    @property
    def robot_spec(self) -> str | dict:
        """The ``robot`` metadata entry: a built-in name or ``{"urdf": ..., "tool_frame": ...}``."""
        return self.meta["robot"]

    @property
    def robot_label(self) -> str:
        """A short human-readable robot name."""
        return robot_label(self.robot_spec)

    def robot(self) -> RobotModel:
        """The :class:`~ditherlab.robot.RobotModel` described by the metadata (cached).

        Raises RobotError for an unknown name, a URDF that does not parse, or a joint count
        that differs from the recording's.
        """
        cached = self.__dict__.get("_robot")
        if cached is None:
            cached = RobotModel.from_recording_meta(self.meta, n_expected=self.n, where=self.name)
            object.__setattr__(self, "_robot", cached)
        return cached

    def share_robot(self, robot: RobotModel) -> None:
        """Use ``robot`` as this recording's :meth:`robot`: the robot of another piece of the
        same recording (the same metadata). Each piece would otherwise parse the URDF and build
        its own pinocchio model with its own result cache, which Python frees only at its next
        full collection (the model and its kernels refer to each other)."""
        object.__setattr__(self, "_robot", robot)

    # ------------------------------------------------------------------ transformations
    def slice(self, t0: float | None = None, t1: float | None = None) -> Recording:
        """The samples with ``t0 <= t < t1`` [s] (either bound may be None), as a new
        Recording."""
        t = self.t
        mask = np.ones(len(t), dtype=bool)
        if t0 is not None:
            mask &= t >= t0
        if t1 is not None:
            mask &= t < t1
        if not mask.any():
            raise RecordingError(
                f"{where_prefix(self.name)}no samples with {t0} <= t < {t1} s "
                f"(the recording spans t={t[0]:.3f}..{t[-1]:.3f} s)"
            )
        return self.with_data(self.data.loc[mask].reset_index(drop=True))

    def with_data(self, data: pd.DataFrame, **meta_updates: Any) -> Recording:
        """A new Recording with another table (and optionally updated metadata)."""
        meta = copy.deepcopy(self.meta)
        meta.update(meta_updates)
        return Recording(data, meta, name=self.name, timebase=self.timebase)

    def with_columns(self, **cols: np.ndarray) -> Recording:
        """A new Recording with columns added or replaced, each (N,)."""
        data = self.data.copy()
        for k, v in cols.items():
            data[k] = v
        return self.with_data(data)

    def meta_json(self) -> str:
        """The metadata as one JSON string (as stored in Parquet and MCAP)."""
        return json.dumps(self.meta, sort_keys=True)

    def __repr__(self) -> str:
        return (
            f"Recording({self.name or '<memory>'}: {len(self)} samples, {self.duration:.2f} s, "
            f"{self.n} joints, robot={self.robot_label})"
        )

    def equals(self, other: Recording) -> bool:
        """True when both tables (values, column order) and metadata are identical."""
        return (
            list(self.data.columns) == list(other.data.columns)
            and self.data.equals(other.data)
            and self.meta == other.meta
        )


# ---------------------------------------------------------------------- module functions
#: a step in ``t`` longer than this many median steps, and than GAP_MIN_S, is a gap: the log
#: stopped and resumed, and no derivative window spans it (:func:`derivative_by_segment`)
GAP_STEPS = 100
#: [s] the shortest gap
GAP_MIN_S = 1.0


def derivative_by_segment(t: np.ndarray, x: np.ndarray, dt: float, uniform: bool) -> np.ndarray:
    """:func:`ditherlab.core.timeseries.smooth_derivative` of ``x`` on each stretch of ``t`` between
    gaps (steps longer than ``GAP_STEPS`` median steps and ``GAP_MIN_S``); without a gap the
    one call on the whole of ``t``. Across a gap of 10⁷ s a quadratic fit's normal equations
    are singular, and a window spanning the gap means nothing anyway.

    Parameters
    ----------
    t : (N,) [s], increasing ; x : (N, n) any unit u
    dt : [s] the recording's median step ; uniform : its time base is uniform (TimeBase)

    Returns
    -------
    (N, n) [u/s]; a stretch of fewer than 7 samples gives zeros
    """
    t = np.asarray(t, dtype=float)
    if len(t) < 2 or not np.isfinite(dt):
        return smooth_derivative(t, x, dt=dt, uniform=uniform)
    cuts = np.flatnonzero(np.diff(t) > max(GAP_MIN_S, GAP_STEPS * dt)) + 1
    if not cuts.size:
        return smooth_derivative(t, x, dt=dt, uniform=uniform)
    x = np.asarray(x, dtype=float)
    out = np.empty_like(x)
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)], strict=True):
        out[a:b] = smooth_derivative(t[a:b], x[a:b], dt=dt, uniform=uniform)
    return out


def differentiate(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Time derivative of sampled signals.

    Second-order finite differences on the actual (possibly jittered) time stamps: central in the
    interior, one-sided second order at both ends (``numpy.gradient(x, t, edge_order=2)``). It
    has no phase lag and no smoothing: noise on ``x`` is amplified by about 1/dt.

    Parameters
    ----------
    t : (N,) [s], strictly increasing
    x : (N, ...) any unit u

    Returns
    -------
    (N, ...) [u/s]
    """
    x = np.asarray(x, dtype=float)
    if len(t) < 3:
        return np.zeros_like(x)
    return np.gradient(x, np.asarray(t, dtype=float), axis=0, edge_order=2)


def moving_mask(rec: Recording, threshold: float = 5e-3, window: float = 0.1) -> np.ndarray:
    """Which joints are moving at each sample.

    A joint moves when the magnitude of its velocity, averaged over a centred window, exceeds
    ``threshold``. The average keeps the dither's vibration (zero mean over its period) from
    counting as motion.

    Parameters
    ----------
    rec : Recording
    threshold : [rad/s]
    window : [s]

    Returns
    -------
    (N, n) bool
    """
    dq = rec.dq
    if len(rec) < 2:
        return np.zeros(dq.shape, dtype=bool)
    dt = rec.dt
    w = max(1, int(round(window / dt)))
    kernel = np.ones(w) / w
    smooth = np.empty_like(dq)
    # numpy's mode="same", also for a log shorter than the window (where "same" returns the
    # window's length): the centred part of the full convolution
    lo, N = (w - 1) // 2, len(dq)
    for j in range(dq.shape[1]):
        smooth[:, j] = np.convolve(dq[:, j], kernel, mode="full")[lo : lo + N]
    return np.abs(smooth) > threshold


def regimes(rec: Recording, threshold: float = 5e-3, window: float = 0.1) -> np.ndarray:
    """Regime of every joint at every sample: ``STILL`` (0), ``DITHER`` (1) or ``MOVING`` (2).

    A moving joint (:func:`moving_mask`) is MOVING; a joint that stands still while the
    ``dither`` column is true is DITHER; otherwise STILL.

    Returns
    -------
    (N, n) int8
    """
    moving = moving_mask(rec, threshold, window)
    out = np.full(moving.shape, STILL, dtype=np.int8)
    d = rec.dither
    if d is not None:
        out[d, :] = DITHER
    out[moving] = MOVING
    return out


def meta_dither_period(meta: Mapping[str, Any]) -> float | None:
    """The dither period [s] a recording's metadata states, or None.

    ``dither.period`` [s] or ``dither.omega`` [rad/s], at the top level or under ``sim``.
    """
    for d in (meta.get("dither"), (meta.get("sim") or {}).get("dither")):
        if isinstance(d, Mapping):
            if d.get("period"):
                return float(d["period"])
            if d.get("omega"):
                return float(2 * np.pi / float(d["omega"]))
    return None


# ---------------------------------------------------------------------- validation
def robot_label(spec: str | Mapping[str, Any]) -> str:
    """A short human-readable name of a ``robot`` metadata entry (a built-in name, or the
    URDF's ``name`` / its ``<robot name=...>``)."""
    if isinstance(spec, str):
        return spec
    return str(spec.get("name") or _urdf_name(spec.get("urdf", "")) or "urdf")


def _urdf_name(urdf: str) -> str | None:
    m = re.search(r"<robot[^>]*\bname\s*=\s*[\"']([^\"']+)", urdf or "")
    return m.group(1) if m else None


def _validate(
    data: pd.DataFrame, meta: Mapping[str, Any], name: str | None
) -> tuple[pd.DataFrame, dict[str, Any], int]:
    """The checked table (float64 columns, bool ``dither``, a fresh index), a copy of the
    metadata and the joint count; RecordingError at the first break of the contract."""
    where = where_prefix(name)
    if not isinstance(data, pd.DataFrame):
        raise RecordingError(f"{where}expected a pandas DataFrame, got {type(data).__name__}")
    meta = _checked_meta(meta, where)
    cols = list(data.columns)
    families, n = _joint_columns(cols, where)
    present_wrench = _wrench_columns(cols, where)
    numeric = ["t"] + [f"{p}_{j}" for p in JOINT_FAMILIES for j in sorted(families[p])]
    numeric += present_wrench
    out = _numeric_table(data, numeric, where)
    if len(out) == 0:
        raise RecordingError(f"{where}the table has no rows")
    t = out["t"].to_numpy()
    _check_finite(out, numeric, t, where)
    _check_increasing(t, where)
    if "dither" in out.columns and out["dither"].dtype != bool:
        out["dither"] = _dither_flags(out["dither"], where)
    return out, meta, n


class SharedMeta(dict):
    """Metadata checked and copied once (:func:`share_meta`) and shared, read-only, by the
    recordings built from it — the pieces of one long log (:mod:`ditherlab.io.stream`): a
    recording given one keeps it as it is instead of checking and deep-copying it again (a
    simulator's metadata is a large nested object; ``docs/design/long-logs.md``)."""


def share_meta(meta: Mapping[str, Any], name: str | None = None) -> SharedMeta:
    """``meta`` checked and deep-copied once, for many recordings to share; RecordingError as
    :class:`Recording`'s."""
    return SharedMeta(_checked_meta(meta, where_prefix(name)))


def _checked_meta(meta: Any, where: str) -> dict[str, Any]:
    """A deep copy of the metadata after the check against :data:`META_SCHEMA` (a
    :class:`SharedMeta` is already both: itself)."""
    if isinstance(meta, SharedMeta):
        return meta
    if not isinstance(meta, Mapping):
        raise RecordingError(f"{where}metadata must be a JSON object, got {type(meta).__name__}")
    check(meta, META_SCHEMA, where.removesuffix(": "), RecordingError, label="metadata key ")
    return copy.deepcopy(dict(meta))


def _joint_columns(cols: list[Any], where: str) -> tuple[dict[str, set[int]], int]:
    """Joint indices present per family and the joint count n; checks that the column names are
    unique, that ``t`` and ``q_1`` exist and that every present family has exactly 1..n."""
    if len(set(cols)) != len(cols):
        dup = sorted({c for c in cols if cols.count(c) > 1})
        raise RecordingError(f"{where}column {dup[0]} appears more than once")
    if "t" not in cols:
        raise RecordingError(f"{where}required column t is missing")
    families: dict[str, set[int]] = {p: set() for p in JOINT_FAMILIES}
    for c in cols:
        m = _JOINT_COL.match(str(c))
        if m:
            families[m.group(1)].add(int(m.group(2)))
    if not families["q"]:
        raise RecordingError(f"{where}required column q_1 is missing (joint positions, rad)")
    n = max(families["q"])
    for prefix, (required, unit) in JOINT_FAMILIES.items():
        idx = families[prefix]
        if not idx and not required:
            continue
        expected = set(range(1, n + 1))
        missing = sorted(expected - idx)
        if missing:
            raise RecordingError(
                f"{where}required column {prefix}_{missing[0]} is missing "
                f"(found q_1..q_{n}, so {prefix}_1..{prefix}_{n} [{unit}] are expected)"
            )
        extra = sorted(idx - expected)
        if extra:
            raise RecordingError(
                f"{where}column {prefix}_{extra[0]} has no matching q_{extra[0]} "
                f"(the recording has {n} joints)"
            )
    return families, n


def _wrench_columns(cols: list[Any], where: str) -> list[str]:
    """The wrench columns present, the F/T sensor's and the vendor's estimate: of each none or
    all six."""
    return _six_columns(cols, where, WRENCH_COLUMNS, "the F/T sensor") + _six_columns(
        cols, where, VENDOR_WRENCH_COLUMNS, "the vendor's estimate"
    )


def _six_columns(cols: list[Any], where: str, names: tuple[str, ...], what: str) -> list[str]:
    """The wrench columns ``names`` present (the F/T sensor's or the vendor's estimate): none
    or all six."""
    present_wrench = [c for c in names if c in cols]
    if present_wrench and len(present_wrench) != 6:
        missing_w = [c for c in names if c not in cols]
        raise RecordingError(
            f"{where}column {missing_w[0]} is missing: {what} needs all of {', '.join(names)}"
        )
    return present_wrench


def _numeric_table(data: pd.DataFrame, numeric: list[str], where: str) -> pd.DataFrame:
    """A copy of ``data`` with a fresh index and the ``numeric`` columns as float64; a value that
    is not a number is an error."""
    out = data.copy() if not data.index.equals(pd.RangeIndex(len(data))) else data.copy(deep=False)
    out = out.reset_index(drop=True)
    for c in numeric:
        col = out[c]
        if col.dtype != np.float64:
            conv = pd.to_numeric(col, errors="coerce")
            bad = conv.isna() & col.notna()
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                raise RecordingError(
                    f"{where}column {c} has a non-numeric value {col.iloc[i]!r} in row {i + 1} "
                    "(expected a number)"
                )
            out[c] = conv.astype(np.float64)
    return out


def _check_finite(out: pd.DataFrame, numeric: list[str], t: np.ndarray, where: str) -> None:
    """No NaN or infinite value in a numeric column (reported by time, or by row for ``t``)."""
    for c in numeric:
        v = out[c].to_numpy()
        bad = ~np.isfinite(v)
        if bad.any():
            kind = "NaN" if np.isnan(v[bad]).all() else "NaN or infinite"
            tt = t if c != "t" else np.arange(len(t), dtype=float)
            span = _time_span(tt, bad) if c != "t" else f"in rows {np.flatnonzero(bad)[0] + 1}.."
            raise RecordingError(f"{where}{c} has {int(bad.sum())} {kind} values {span}")


def _check_increasing(t: np.ndarray, where: str) -> None:
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.flatnonzero(dt <= 0)[0])
        raise RecordingError(
            f"{where}t is not strictly increasing: t={float(t[i + 1])!r} s in row {i + 2} "
            f"follows t={float(t[i])!r} s (expected increasing sample times)"
        )


def _dither_flags(d: pd.Series, where: str) -> pd.Series:
    """A non-bool ``dither`` column as bool: 1/0 (or true/false) accepted."""
    vals = pd.to_numeric(d, errors="coerce")
    ok = vals.isin([0, 1]) & vals.notna()
    if not ok.all():
        i = int(np.flatnonzero(~ok.to_numpy())[0])
        raise RecordingError(
            f"{where}column dither has value {d.iloc[i]!r} in row {i + 1} "
            "(expected true/false or 1/0)"
        )
    return vals.astype(bool)

"""Log a recording, its estimates, the torque model and a diagnosis to Rerun (``.rrd``).

Everything is sent as whole columns (``send_columns`` + one ``TimeColumn`` named ``time``, the
recording's ``t`` in seconds); styling is logged once as static data; the layout comes from
:func:`ditherlab.viz.blueprint.make_blueprint`.

Entity layout (``j`` = 1..n, ``a`` = x, y, z, ``V`` = estimator variant)::

    robot/links/<link>          Transform3D of each URDF link in the base frame   (rate_3d)
    robot/skeleton              line strip through the link origins               (rate_3d)
    robot/force/sensor          arrow of the F/T sensor force at the tool point   (rate_3d)
    robot/force/V               arrow of the estimated force                      (rate_3d)
    robot/force/V/interval      box spanned by the interval [lo, hi] per axis     (rate_3d)
    joints/j/tau                logged motor torque [N·m]
    joints/j/tau_bar            [tau - gravity(q) (- the model's effects), J^T F_sensor] [N·m]
    joints/j/band/<regime>      friction band edges [min, max] of the model [N·m]
    joints/j/dither/ffw         torque feedforward sent (dither square wave + centre) [N·m]
    joints/j/dither/centre/<s>  Fig. 5 centre: recording columns such as ``centre_ref_j``,
                                ``dither_centre_meas_j``
    joints/j/dither/amplitude/<s>  Fig. 5 amplitude: ``extracted`` ((upper - lower) / 2) and the
                                recording's columns such as ``amp_ref_j``
    joints/j/extract            [upper, lower, signal, centre, gravity] (the extraction: the
                                estimates file's columns where present; centre = window mean;
                                gravity = the centre's reference)
    joints/j/fig4/signal_bar    extracted signal - gravity (- effects) [N·m]
    joints/j/band/dither_shrunk the still band shrunk by the extracted amplitude under dither
    joints/j/residual/v<k>      friction residual of model version k [N·m]
    force/a/sensor              sensor force [N]
    force/a/V                   [estimate, lo, hi] of variant V [N]
    force/a/online              the recording's ``fhat_a`` column: an estimate used online [N]
    history/torque_rms/j        bar chart: residual RMS per model version (model history)
    events/dither_flag          the dither flag as a 0/1 series
    events/dither, events/pushes, events/pushes_simulated, events/detections/V, diagnosis
                                text logs (dither on/off; pushes found in the F/T sensor and the
                                simulator's own; detections per variant; worst windows)
    info/recording, info/model, info/history, info/diagnosis    text documents (static)

Forces are the wrench the robot exerts on its environment (RECORDING.md): a push P shows as -P.

Series that stay constant over runs of samples (dither extraction, loop outputs, estimates held
at the prior) are thinned losslessly: a sample is dropped only when it equals both neighbours, so
the plotted line (linear or step) is exactly the full-rate one and every logged value is a value
of the input, bit for bit.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ditherlab.errors import DitherlabError, FormatError, RecordingError
from ditherlab.recording import FORCE_AXES, Recording

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ditherlab.estimates import Estimates
    from ditherlab.model import TorqueModel
    from ditherlab.viz.diagnosis import DiagnosisReport

TIMELINE = "time"
WEB_PORT = 9090
EXTRACT_SIGNALS = ("upper", "lower", "signal")

#: Colours (RGB) per variant, sensor and joint-series role; chosen to stay apart in a legend.
VARIANT_COLORS: dict[str, tuple[int, int, int]] = {
    "nodither_band": (230, 120, 30),
    "nodither_noband": (240, 190, 60),
    "dither_band": (40, 110, 230),
    "dither_noband": (120, 190, 250),
}
SENSOR_COLOR = (30, 30, 30)
REGIME_COLORS = {"still": (200, 60, 60), "dither": (60, 60, 200), "moving": (150, 150, 150)}
_DITHER_COL = re.compile(r"^dither_(?P<name>[A-Za-z0-9_]+?)_(?P<j>\d+)$")
#: Fig. 5 signals a simulator or controller may log: centre_ref_3, amp_meas_3, centre_ffw_3 ...
_FIG5_COL = re.compile(r"^(?P<name>(?:centre|center|amp|amplitude)(?:_[a-z]+)?)_(?P<j>\d+)$")


# ---------------------------------------------------------------------- estimates file
def load_estimates(path: str | Path) -> Estimates:
    """Read an estimates file with :meth:`ditherlab.replay.Estimates.load` and check its columns.

    Raises
    ------
    FormatError
        Missing or unreadable file, not an estimates file, or a listed variant without columns.
    """
    from ditherlab.estimates import VARIANTS, Estimates

    est = Estimates.load(path)
    if "t" not in est.data.columns:
        raise FormatError(f"{path}: required column t is missing")
    for v in est.variants:
        if v not in VARIANTS:
            raise FormatError(f"{path}: metadata lists variant {v!r}, expected one of {VARIANTS}")
        missing = [c for c in (f"{v}/f_x", f"{v}/f_y", f"{v}/f_z") if c not in est.data.columns]
        if missing:
            raise FormatError(f"{path}: column {missing[0]} is missing (variant {v} is listed)")
    return est


def _plain_json(x: Any) -> Any:
    """Normalise a metadata object the way a JSON round trip does (tuples -> lists, numpy -> py)."""
    return json.loads(json.dumps(x, sort_keys=True, default=_json_default))


def _json_default(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return str(x)


def check_estimates_match(rec: Recording, est: Estimates) -> None:
    """Raise RecordingError unless ``est`` was computed from ``rec``.

    The time stamps must be identical (same count, same values) and the recording metadata stored
    in the estimates file must equal ``rec.meta``.

    Raises
    ------
    RecordingError
        One sentence naming both files and the first difference.
    """
    ename = est.name or "estimates"
    rname = rec.name or "the recording"
    t_rec, t_est = rec.t, est.data["t"].to_numpy(dtype=float)
    if len(t_rec) != len(t_est):
        raise RecordingError(
            f"{ename}: the estimates come from another recording: column t has {len(t_est)} "
            f"samples, {rname} has {len(t_rec)}"
        )
    diff = np.flatnonzero(t_rec != t_est)
    if diff.size:
        i = int(diff[0])
        raise RecordingError(
            f"{ename}: the estimates come from another recording: t in row {i + 1} is "
            f"{t_est[i]!r} s, {rname} has {t_rec[i]!r} s"
        )
    stored = est.meta.get("recording")
    if stored is None:
        raise RecordingError(f"{ename}: metadata key 'recording' is missing")
    a, b = _plain_json(stored), _plain_json(rec.meta)
    if a != b:
        key = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
        raise RecordingError(
            f"{ename}: the estimates come from another recording: metadata key {key!r} is "
            f"{_short(a.get(key))}, {rname} has {_short(b.get(key))}"
        )


def _short(v: Any, width: int = 60) -> str:
    s = repr(v)
    return s if len(s) <= width else s[: width - 3] + "..."


# ---------------------------------------------------------------------- small helpers
def thin_mask(values: np.ndarray) -> np.ndarray:
    """Samples to keep so that a line through the kept samples equals the full-rate line.

    A sample is dropped when it equals both of its neighbours (bitwise, NaN equal to NaN) in every
    column; the first and last samples are always kept.

    Parameters
    ----------
    values : (N,) or (N, k)

    Returns
    -------
    (N,) bool
    """
    v = np.asarray(values)
    if v.ndim == 1:
        v = v[:, None]
    N = len(v)
    keep = np.ones(N, dtype=bool)
    if N <= 2:
        return keep
    if v.dtype.kind == "f":
        same = (v[1:] == v[:-1]) | (np.isnan(v[1:]) & np.isnan(v[:-1]))
    else:
        same = v[1:] == v[:-1]
    same = same.all(axis=1)  # (N-1,): sample i+1 equals sample i
    keep[1:-1] = ~(same[:-1] & same[1:])
    return keep


def decimate_index(t: np.ndarray, rate: float | None) -> np.ndarray:
    """Indices of samples at most ``rate`` per second (first sample always kept).

    Parameters
    ----------
    t : (N,) [s], increasing
    rate : [Hz]; None or <= 0 keeps every sample

    Returns
    -------
    (M,) int
    """
    if rate is None or rate <= 0 or len(t) < 2:
        return np.arange(len(t))
    bins = np.floor((t - t[0]) * rate).astype(np.int64)
    first = np.ones(len(t), dtype=bool)
    first[1:] = bins[1:] != bins[:-1]
    return np.flatnonzero(first)


# ---------------------------------------------------------------------- the logger
@dataclass
class ViewSummary:
    """What was logged: entity path -> number of time-indexed rows (static rows not counted)."""

    rows: dict[str, int] = field(default_factory=dict)
    variants: list[str] = field(default_factory=list)
    n_joints: int = 0


class _Logger:
    """Sends columns to one RecordingStream and keeps the row counts."""

    def __init__(self, stream: rr.RecordingStream, t: np.ndarray) -> None:
        self.stream = stream
        self.t = t
        self.summary = ViewSummary()

    def series(
        self,
        path: str,
        values: np.ndarray,
        *,
        names: str | Sequence[str],
        colors: Any = None,
        widths: float | Sequence[float] | None = None,
        idx: np.ndarray | None = None,
        thin: bool = True,
        step: bool = False,
    ) -> None:
        """Log one scalar series (N,) or k series (N, k) at ``self.t`` (or ``self.t[idx]``)."""
        import rerun as rr

        v = np.asarray(values, dtype=np.float64)
        t = self.t if idx is None else self.t[idx]
        if idx is not None and len(v) == len(self.t):
            v = v[idx]  # otherwise the values are already given at t[idx]
        if thin:
            keep = thin_mask(v)
            v, t = v[keep], t[keep]
        names_l = [names] if isinstance(names, str) else list(names)
        style: dict[str, Any] = {"names": names_l}
        if colors is not None:
            style["colors"] = colors
        if widths is not None:
            style["widths"] = widths
        if step:
            style["interpolation_mode"] = rr.components.InterpolationMode.StepAfter
        self.stream.log(path, rr.SeriesLines(**style), static=True)
        self.stream.send_columns(
            path,
            indexes=[rr.TimeColumn(TIMELINE, duration=t)],
            columns=rr.Scalars.columns(scalars=v),
        )
        self.summary.rows[path] = len(t)

    def send(self, path: str, t: np.ndarray, columns: Any) -> None:
        import rerun as rr

        self.stream.send_columns(
            path, indexes=[rr.TimeColumn(TIMELINE, duration=t)], columns=columns
        )
        self.summary.rows[path] = len(t)

    def text_log(self, path: str, t: np.ndarray, text: Sequence[str], level: Sequence[str]) -> None:
        import rerun as rr

        if len(t) == 0:
            return
        self.send(
            path, np.asarray(t, dtype=float), rr.TextLog.columns(text=list(text), level=list(level))
        )


def log_view(
    rec: Recording,
    stream: rr.RecordingStream,
    *,
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: Any = None,
    rate_3d: float | None = 25.0,
    force_scale: float = 0.005,
    progress: Callable[[int, int], None] | None = None,
) -> ViewSummary:
    """Log a recording (and optionally estimates, model and diagnosis) to a Rerun stream.

    Parameters
    ----------
    rec : the recording (``t (N,)`` [s], ``q (N, n)`` [rad], ``tau (N, n)`` [N·m], ...)
    stream : an open ``rerun.RecordingStream`` (file sink, memory sink, viewer)
    estimates : estimates of this recording (checked with :func:`check_estimates_match`)
    model : torque model; gives the band edges, the effects in ``tau_bar`` and the residuals
    diagnosis : result of ``ditherlab.diagnose`` (candidates at worst windows), optional
    rate_3d : [Hz] rate of the 3D entities (robot pose, arrows, boxes); None = every sample.
        Time series are always logged at full rate.
    force_scale : [m/N] length of a force arrow per newton in the 3D view
    progress : callable(done, total), optional

    Returns
    -------
    ViewSummary
        Row counts per entity as sent (read the file back to verify them).
    """
    import rerun as rr

    if estimates is not None:
        check_estimates_match(rec, estimates)
    steps = 7
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, steps)

    if progress is not None:
        progress(0, steps)
    t = rec.t
    log = _Logger(stream, t)
    log.summary.n_joints = rec.n
    log.summary.variants = estimates.variants if estimates is not None else []
    stream.log(
        "info/recording",
        rr.TextDocument(_recording_markdown(rec, estimates), media_type="text/markdown"),
        static=True,
    )
    if model is not None:
        stream.log(
            "info/model", rr.TextDocument(model.dumps(), media_type="text/plain"), static=True
        )

    robot = rec.robot()
    _log_robot(log, rec, robot, estimates, rate_3d, force_scale)
    tick()
    g = robot.gravity(rec.q)  # (N, n) [N·m], shared by tau_bar and the residuals
    tb = tau_bar(rec, g, model)
    jtf = _external_sensor(rec, robot)
    _log_joints(log, rec, tb, jtf, model)
    tick()
    _log_dither(log, rec, estimates, g, tb, model)
    tick()
    _log_forces(log, rec, estimates)
    tick()
    _log_residuals(log, rec, g, model)
    tick()
    _log_events(log, rec, estimates)
    tick()
    _log_diagnosis(log, rec, diagnosis)
    tick()
    return log.summary


# ---------------------------------------------------------------------- 3D
def _log_robot(
    log: _Logger,
    rec: Recording,
    robot: Any,
    estimates: Estimates | None,
    rate_3d: float | None,
    force_scale: float,
) -> None:
    import rerun as rr

    s = log.stream
    s.log("robot", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    idx = decimate_index(rec.t, rate_3d)
    t3 = rec.t[idx]
    q3 = rec.q[idx]
    poses = robot.link_poses(q3)
    for name, T in poses.items():
        path = f"robot/links/{rr.escape_entity_path_part(name)}"
        s.log(path, rr.TransformAxes3D(0.06), static=True)
        log.send(
            path,
            t3,
            rr.Transform3D.columns(translation=T[:, :3, 3], quaternion=_quat_xyzw(T[:, :3, :3])),
        )
    # Skeleton through the link origins in kinematic order; coincident origins (wrist) collapse.
    origins = np.stack([T[:, :3, 3] for T in poses.values()], axis=1)  # (M, L, 3) [m]
    s.log("robot/skeleton", rr.LineStrips3D([], radii=0.02, colors=[160, 160, 170]), static=True)
    log.send(
        "robot/skeleton",
        t3,
        rr.LineStrips3D.columns(strips=list(origins)).partition(np.ones(len(t3), dtype=np.int32)),
    )
    tool = robot.tool_pose(q3)[:, :3, 3]  # (M, 3) [m]
    if rec.has_wrench:
        f = rec.wrench[idx, :3]
        _arrows(log, "robot/force/sensor", t3, tool, f * force_scale, SENSOR_COLOR, "sensor F")
    if estimates is not None:
        d = estimates.data
        for v in estimates.variants:
            fe = d[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)[idx]
            _arrows(log, f"robot/force/{v}", t3, tool, fe * force_scale, VARIANT_COLORS[v], v)
            lo_c = [f"{v}/f_{a}_lo" for a in FORCE_AXES]
            hi_c = [f"{v}/f_{a}_hi" for a in FORCE_AXES]
            if all(c in d.columns for c in lo_c + hi_c):
                lo = d[lo_c].to_numpy(dtype=float)[idx]
                hi = d[hi_c].to_numpy(dtype=float)[idx]
                # An unbounded side (a free component) is drawn at 4x the largest finite one.
                cap = 4 * max(float(np.nanmax(np.abs(np.where(np.isfinite(lo), lo, 0)))), 1.0)
                lo, hi = np.clip(lo, -cap, cap), np.clip(hi, -cap, cap)
                s.log(
                    f"robot/force/{v}/interval",
                    rr.Boxes3D(half_sizes=[[0, 0, 0]], colors=[VARIANT_COLORS[v]], radii=0.002),
                    static=True,
                )
                log.send(
                    f"robot/force/{v}/interval",
                    t3,
                    rr.Boxes3D.columns(
                        centers=tool + force_scale * (lo + hi) / 2,
                        half_sizes=force_scale * (hi - lo) / 2,
                    ),
                )


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (M, 3, 3) -> unit quaternions (M, 4), scalar last (Rerun's order)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()  # scipy returns (x, y, z, w)


def _arrows(
    log: _Logger,
    path: str,
    t: np.ndarray,
    origins: np.ndarray,
    vectors: np.ndarray,
    color: Any,
    label: str,
) -> None:
    import rerun as rr

    vec = np.where(np.isfinite(vectors), vectors, 0.0)
    log.stream.log(
        path,
        rr.Arrows3D(
            vectors=[[0, 0, 0]], colors=[color], radii=0.006, labels=[label], show_labels=False
        ),
        static=True,
    )
    log.send(path, t, rr.Arrows3D.columns(vectors=vec, origins=origins))


# ---------------------------------------------------------------------- per joint
def tau_bar(rec: Recording, gravity: np.ndarray, model: TorqueModel | None = None) -> np.ndarray:
    """Gravity-compensated torque ``tau - gravity(q) - effects_torque`` as replay uses it.

    Parameters
    ----------
    rec : recording with ``q (N, n)`` [rad], ``tau (N, n)`` [N·m]
    gravity : (N, n) [N·m], ``rec.robot().gravity(rec.q)``
    model : optional; its effects are subtracted when it has any

    Returns
    -------
    (N, n) [N·m]
    """
    from ditherlab.replay import model_effects

    return rec.tau - gravity - model_effects(model, rec)


def _external_sensor(rec: Recording, robot: Any) -> np.ndarray | None:
    """``J(q)^T F_sensor`` (N, n) [N·m]: the joint torque of the sensed wrench, or None."""
    if not rec.has_wrench:
        return None
    return np.einsum("nij,ni->nj", robot.jacobian(rec.q), rec.wrench)


def _log_joints(
    log: _Logger,
    rec: Recording,
    tb: np.ndarray,
    jtf: np.ndarray | None,
    model: TorqueModel | None,
) -> None:
    tau = rec.tau
    label = "tau - gravity" if model is None or not model.effects else "tau - gravity - effects"
    t = rec.t
    span = np.array([0, len(t) - 1]) if len(t) > 1 else np.array([0])
    for j in range(rec.n):
        base = f"joints/{j + 1}"
        log.series(
            f"{base}/tau", tau[:, j], names="tau", colors=[[120, 120, 120]], widths=1.0, thin=False
        )
        # tau_bar and J^T F of the sensor share one entity: same units and scale, and one time
        # column and row id for both halves the file size of the pair.
        if jtf is None:
            vals, names, colors = tb[:, j], label, [[0, 0, 0]]
        else:
            vals = np.column_stack([tb[:, j], jtf[:, j]])
            names, colors = [label, "J^T F (sensor)"], [[0, 0, 0], [0, 150, 150]]
        log.series(f"{base}/tau_bar", vals, names=names, colors=colors, widths=1.5, thin=False)
        if model is None:
            continue
        for regime in ("still", "dither"):
            if regime not in model.regimes:
                continue
            b = model.regimes[regime]
            edges = np.tile([b.tau_min[j], b.tau_max[j]], (len(span), 1))
            log.series(
                f"{base}/band/{regime}",
                edges,
                names=[f"{regime} band min", f"{regime} band max"],
                colors=[REGIME_COLORS[regime]] * 2,
                widths=1.0,
                idx=span,
                thin=False,
            )


def dither_period(rec: Recording, estimates: Estimates | None = None) -> float | None:
    """The dither period [s] of a recording, or None when it has no dither.

    In order: the estimates file's ``dither_period`` (what replay used), the metadata
    (``dither.period`` [s] or ``dither.omega`` [rad/s], also under ``sim``), the feedforward's
    square wave (:func:`ditherlab.dither.period_from_feedforward`).
    """
    if estimates is not None and estimates.meta.get("dither_period"):
        return float(estimates.meta["dither_period"])
    from ditherlab.dither import meta_dither_period

    stated = meta_dither_period(rec.meta)
    if stated is not None:
        return stated
    on = rec.dither
    if rec.tau_ffw is None or (on is not None and not on.any()):
        return None
    from ditherlab.dither import period_from_feedforward

    try:
        # its interpolation divides by zero where the square wave is flat; those entries are unused
        with np.errstate(invalid="ignore", divide="ignore"):
            return float(period_from_feedforward(rec.tau_ffw, rec.t))
    except DitherlabError:
        return None


def _fig5_group(col: str, n: int) -> tuple[str, str, int] | None:
    """Recording column -> (``centre``/``amplitude``/``other``, series name, joint) for Fig. 5."""
    m = _DITHER_COL.match(col) or _FIG5_COL.match(col)
    if m is None or not 1 <= int(m["j"]) <= n:
        return None
    name = m["name"]
    if name.startswith(("centre", "center")):
        group = "centre"
    elif name.startswith("amp"):
        group = "amplitude"
    else:
        group = "other"
    return group, name, int(m["j"])


def _log_dither(
    log: _Logger,
    rec: Recording,
    estimates: Estimates | None,
    g: np.ndarray,
    tb: np.ndarray,
    model: TorqueModel | None,
) -> None:
    """Fig. 5 (centre and amplitude: measured, reference, feedforward) and Fig. 4 (upper, lower,
    extracted signal; the signal minus gravity against J^T F of the sensor and the bands)."""
    ffw = rec.tau_ffw
    if ffw is not None:
        for j in range(rec.n):
            log.series(
                f"joints/{j + 1}/dither/ffw", ffw[:, j], names="tau_ffw", colors=[[150, 150, 150]]
            )
    shades = {"centre": (40, 110, 230), "amplitude": (230, 130, 30), "other": (120, 120, 120)}
    for col in rec.data.columns:
        hit = _fig5_group(str(col), rec.n)
        if hit is None:
            continue
        group, name, j = hit
        light = "ref" in name or "ffw" in name or "cmd" in name
        c = shades[group] if not light else tuple(int(x + (255 - x) * 0.5) for x in shades[group])
        vals = pd.to_numeric(rec.data[col], errors="coerce").to_numpy(dtype=float)
        log.series(f"joints/{j}/dither/{group}/{name}", vals, names=name, colors=[c], step=True)

    period = dither_period(rec, estimates)
    if period is None:
        return
    from ditherlab.dither import dithered_band, extract
    from ditherlab.signal import causal_mean

    d = estimates.data if estimates is not None else None
    have = d is not None and all(f"extract/{s}_1" in d.columns for s in EXTRACT_SIGNALS)
    # The estimates file's own columns when present (the numbers replay used); the extraction of
    # ditherlab.dither otherwise. The window is the extraction's: whole periods at this rate.
    window = max(2, int(round(period / float(np.median(np.diff(rec.t)))))) if len(rec) > 1 else 2
    ext = None if have else extract(rec.tau, rec.t, period)
    centre = causal_mean(rec.tau, window) if ext is None else ext.centre  # (N, n) [N·m]
    still = model.regimes.get("still") if model is not None else None
    # Dither quantities mean something only where the dither was on over the whole window; NaN
    # elsewhere (runs of NaN thin to their two ends, so the off stretches cost two rows each).
    on = _dither_window_on(rec, window)
    off = ~on
    # The simulator states its amplitude set-points (the reference of Fig. 5) in the metadata.
    setpoint = ((rec.meta.get("sim") or {}).get("dither_amplitudes") or {}).get("set_point")
    for j in range(1, rec.n + 1):
        sig: dict[str, np.ndarray] = {}
        for s in EXTRACT_SIGNALS:
            if ext is None:
                sig[s] = d[f"extract/{s}_{j}"].to_numpy(dtype=float)
            else:
                sig[s] = getattr(ext, s)[:, j - 1]
        # upper, lower, signal, the window mean (Fig. 5's measured centre) and its reference, the
        # gravity torque, share one entity (same units, scale and time base: one time column and
        # row id for five series).
        light = tuple(int(x + (255 - x) * 0.5) for x in shades["centre"])
        log.series(
            f"joints/{j}/extract",
            np.where(
                off[:, None],
                np.nan,
                np.column_stack(
                    [sig[s] for s in EXTRACT_SIGNALS] + [centre[:, j - 1], g[:, j - 1]]
                ),
            ),
            names=[*EXTRACT_SIGNALS, "centre (window mean)", "centre reference (gravity)"],
            colors=[[220, 50, 50], [40, 170, 60], [0, 0, 0], shades["centre"], light],
            widths=[1.0, 1.0, 2.0, 2.0, 1.5],
        )
        amp = (sig["upper"] - sig["lower"]) / 2
        log.series(
            f"joints/{j}/dither/amplitude/extracted",
            np.where(off, np.nan, amp),
            names="amplitude (extracted)",
            colors=[shades["amplitude"]],
            widths=2.0,
        )
        if setpoint is not None and j <= len(setpoint):
            log.series(
                f"joints/{j}/dither/amplitude/set_point",
                np.where(off, np.nan, float(setpoint[j - 1])),
                names="amplitude set-point",
                colors=[tuple(int(x + (255 - x) * 0.5) for x in shades["amplitude"])],
                widths=1.5,
            )
        # Fig. 4, lower: the extracted signal in the estimator's units (gravity and effects off).
        offset = rec.tau[:, j - 1] - tb[:, j - 1]  # gravity + effects [N·m]
        log.series(
            f"joints/{j}/fig4/signal_bar",
            np.where(off, np.nan, sig["signal"] - offset),
            names="extracted signal - gravity",
            colors=[[200, 0, 200]],
            widths=2.0,
        )
        if still is not None and (model is None or "dither" not in model.regimes):
            # The paper's rule (Fig. 4): the still band shrunk by the dither amplitude on each
            # side, where the dither was on over the whole window; the still band elsewhere.
            lo, hi = dithered_band(still.tau_min[j - 1], still.tau_max[j - 1], amp, on=on)
            log.series(
                f"joints/{j}/band/dither_shrunk",
                np.column_stack([lo, hi]),
                names=["shrunk band min", "shrunk band max"],
                colors=[REGIME_COLORS["dither"]] * 2,
            )


def _dither_window_on(rec: Recording, window: int) -> np.ndarray:
    """(N,) bool: the dither flag was on for each of the last ``window`` samples."""
    from ditherlab.dither import full_window

    on = rec.dither if rec.dither is not None else np.ones(len(rec), dtype=bool)
    return full_window(on, window)


# ---------------------------------------------------------------------- per force axis
def _log_forces(log: _Logger, rec: Recording, estimates: Estimates | None) -> None:
    if rec.has_wrench:
        w = rec.wrench
        for k, a in enumerate(FORCE_AXES):
            log.series(
                f"force/{a}/sensor",
                w[:, k],
                names="sensor",
                colors=[SENSOR_COLOR],
                widths=1.5,
                thin=False,
            )
    # An estimate the controller used online (the simulator's lead-through logs fhat_x..z).
    for a in FORCE_AXES:
        if f"fhat_{a}" in rec.data.columns:
            log.series(
                f"force/{a}/online",
                rec.data[f"fhat_{a}"].to_numpy(dtype=float),
                names="online estimate (controller)",
                colors=[[150, 60, 200]],
                widths=1.5,
            )
    if estimates is None:
        return
    d = estimates.data
    for v in estimates.variants:
        c = VARIANT_COLORS[v]
        light = tuple(int(x + (255 - x) * 0.55) for x in c)
        for a in FORCE_AXES:
            cols = [f"{v}/f_{a}", f"{v}/f_{a}_lo", f"{v}/f_{a}_hi"]
            have = [x for x in cols if x in d.columns]
            names = [v, f"{v} lo", f"{v} hi"][: len(have)]
            log.series(
                f"force/{a}/{v}",
                d[have].to_numpy(dtype=float),
                names=names,
                colors=[c, light, light][: len(have)],
                widths=[2.0, 1.0, 1.0][: len(have)],
            )


# ---------------------------------------------------------------------- residuals
def model_versions(model: TorqueModel) -> dict[int, TorqueModel]:
    """The model of every version in ``model.history`` that can be rebuilt exactly, and the model.

    ``add_effect`` appends an effect and keeps the earlier ones unchanged, so version k's effects
    are the first ones of the current model when the names of its history row (``effects``) are
    a prefix of the current names. Rows that are not (an effect replaced or removed since) are
    left out. Bands do not enter the residual, so they are not rebuilt.

    Returns
    -------
    dict version -> TorqueModel, in increasing version order
    """
    names = model.effect_names()
    out: dict[int, TorqueModel] = {}
    for h in model.history:
        if not isinstance(h, Mapping) or "version" not in h:
            continue
        effs = [e if isinstance(e, str) else e.get("name") for e in h.get("effects", [])]
        if names[: len(effs)] != effs:
            continue
        m = model.copy()
        m.effects = m.effects[: len(effs)]
        m.version = int(h["version"])
        out[m.version] = m
    out[model.version] = model
    return dict(sorted(out.items()))


def residual(rec: Recording, gravity: np.ndarray, model: TorqueModel) -> np.ndarray:
    """Friction residual ``tau - gravity - effects_torque - external_torque(sensor_wrench)``.

    Parameters
    ----------
    rec : recording with the F/T sensor columns
    gravity : (N, n) [N·m]
    model : TorqueModel (its effects, ``attenuation_lag`` and ``ft_bias`` included)

    Returns
    -------
    (N, n) [N·m]
    """
    from ditherlab.effects import effects_torque, external_torque, sensor_wrench

    ext = external_torque(model, rec, sensor_wrench(model, rec))
    return rec.tau - gravity - effects_torque(model, rec) - ext


def _log_residuals(log: _Logger, rec: Recording, g: np.ndarray, model: TorqueModel | None) -> None:
    """Residual per joint for every rebuildable model version, and the history's RMS per version."""
    import rerun as rr

    if model is None:
        return
    palette = [(200, 60, 60), (230, 150, 40), (60, 160, 60), (40, 110, 230), (140, 60, 200)]
    if rec.has_wrench:
        for k, (ver, m) in enumerate(model_versions(model).items()):
            rho = residual(rec, g, m)
            label = f"v{ver}: " + (" + ".join(m.effect_names()) or "base model")
            for j in range(rec.n):
                log.series(
                    f"joints/{j + 1}/residual/v{ver}",
                    rho[:, j],
                    names=label,
                    colors=[palette[k % len(palette)]],
                    widths=1.0,
                    thin=False,
                )
    rows = [h for h in model.history if isinstance(h, Mapping) and h.get("torque_rms")]
    if not rows:
        return
    rms = np.array([h["torque_rms"] for h in rows], dtype=float)  # (versions, n) [N·m]
    versions = np.array([float(h.get("version", i + 1)) for i, h in enumerate(rows)])
    for j in range(rms.shape[1]):
        log.stream.log(
            f"history/torque_rms/{j + 1}",
            rr.BarChart(rms[:, j], abscissa=versions, color=palette[j % len(palette)]),
            static=True,
        )
    lines = [
        "| version | effects | torque residual RMS per joint [N·m] | force RMS f_x f_y f_z [N] |",
        "|---|---|---|---|",
    ]
    for h in rows:
        fr = " ".join(f"{v:.3g}" for v in (h.get("force_rms") or [])[:3]) or "-"
        lines.append(
            f"| {h.get('version')} | {', '.join(h.get('effects', [])) or 'base'} | "
            f"{' '.join(f'{v:.3g}' for v in h['torque_rms'])} | {fr} |"
        )
    log.stream.log(
        "info/history", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True
    )


# ---------------------------------------------------------------------- events
def _log_events(log: _Logger, rec: Recording, estimates: Estimates | None) -> None:
    t = rec.t
    d = rec.dither
    if d is not None:
        from ditherlab.signal import runs

        on, off = runs(d)
        off = off[off < len(t)]  # a run to the end has no falling edge
        times = np.concatenate([t[on], t[off]])
        texts = ["dither on"] * len(on) + ["dither off"] * len(off)
        order = np.argsort(times, kind="stable")
        log.text_log(
            "events/dither", times[order], [texts[i] for i in order], ["INFO"] * len(order)
        )
        log.series(
            "events/dither_flag",
            d.astype(float),
            names="dither on",
            colors=[[150, 90, 200]],
            step=True,
        )
    if rec.has_wrench:
        from ditherlab.thresholds import find_pushes

        w = rec.wrench
        times, texts = [], []
        for k, p in enumerate(find_pushes(t, w), 1):
            ax = "xyz".index(p.axis)
            i = p.i0 + int(np.argmax(np.abs(w[p.i0 : p.i1, ax])))
            applied = f"{'+' if p.sign > 0 else '-'}{p.axis}"
            times += [p.start, float(t[i]), p.end]
            texts += [
                f"push {k} start ({applied})",
                f"push {k} peak: {p.peak:.1f} N applied along {applied}",
                f"push {k} end ({p.end - p.start:.2f} s)",
            ]
        log.text_log("events/pushes", np.array(times), texts, ["INFO"] * len(times))
    _log_commanded_pushes(log, rec)
    if estimates is None:
        return
    for v in estimates.variants:
        col = f"{v}/active"
        if col not in estimates.data.columns:
            continue
        bits = estimates.data[col].to_numpy().astype(np.int64)
        F = estimates.data[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)
        mag = np.linalg.norm(F, axis=1)
        spans = merge_spans(t, bits != 0, DETECTION_MERGE_GAP)
        texts = []
        for a, b in spans:
            i = a + int(np.argmax(mag[a:b]))
            joints = ",".join(str(j + 1) for j in range(rec.n) if np.any(bits[a:b] >> j & 1))
            texts.append(
                f"{v}: detection for {t[b - 1] - t[a]:.2f} s, joints {joints} outside band; "
                f"peak F=({', '.join(f'{x:+.1f}' for x in F[i])}) N at t={t[i]:.2f} s"
            )
        starts = np.array([t[a] for a, _ in spans])
        log.text_log(f"events/detections/{v}", starts, texts, ["WARN"] * len(spans))


#: Detections closer than this [s] are one event (a joint flickering at its band edge).
DETECTION_MERGE_GAP = 0.25


def merge_spans(t: np.ndarray, flag: np.ndarray, gap: float) -> list[tuple[int, int]]:
    """Runs of ``flag`` as ``[start, end)`` index pairs, runs less than ``gap`` [s] apart merged.

    Parameters
    ----------
    t : (N,) [s]
    flag : (N,) bool
    gap : [s]

    Returns
    -------
    list of (start, end) sample indices, in time order
    """
    from ditherlab.signal import merge_runs, runs

    return merge_runs(t, *runs(flag), gap)


def _log_commanded_pushes(log: _Logger, rec: Recording) -> None:
    """The simulator's pushes (``meta["sim"]["pushes"]``: t0, duration, axis, sign, magnitude)."""
    pushes = (rec.meta.get("sim") or {}).get("pushes") or []
    times, texts = [], []
    for k, p in enumerate(pushes, 1):
        try:
            t0, dur = float(p["t0"]), float(p["duration"])
            what = f"{'+' if p['sign'] > 0 else '-'}{p['axis']} {float(p['magnitude']):.1f} N"
        except (KeyError, TypeError, ValueError):
            continue
        times += [t0, t0 + dur / 2, t0 + dur]
        texts += [
            f"push {k} (simulated) start: {what} for {dur:.2f} s",
            f"push {k} (simulated) peak: {what}",
            f"push {k} (simulated) end",
        ]
    if times:
        order = np.argsort(times, kind="stable")
        log.text_log(
            "events/pushes_simulated",
            np.array(times)[order],
            [texts[i] for i in order],
            ["DEBUG"] * len(order),
        )


# ---------------------------------------------------------------------- diagnosis
def _log_diagnosis(log: _Logger, rec: Recording, diagnosis: Any) -> None:
    """Diagnosis at its worst windows: one entry per window naming the worst joint and the
    suggested effects that act on it; the ranked candidates as a document.

    ``diagnosis`` is a :class:`ditherlab.viz.diagnosis.DiagnosisReport` (:func:`load_report` of a
    report.json), a :class:`ditherlab.diagnose.Diagnosis` or its ``to_dict()``. Windows of other
    recordings (by name) are skipped.
    """
    import rerun as rr

    from ditherlab.viz.diagnosis import as_report

    if diagnosis is None:
        return
    d = as_report(diagnosis)
    cands = d.candidates
    recs = d.recordings
    mine = [
        w
        for w in d.worst_windows
        if len(recs) <= 1 or w["recording"] in (rec.name, Path(rec.name or "").name)
    ]
    times, texts = [], []
    for w in mine:
        j = int(w["worst_joint"])
        sugg = [c for c in cands if c["suggested"] and (not c["joints"] or j in c["joints"])]
        text = (
            f"worst window t={w['t0']:.1f}..{w['t1']:.1f} s: joint {j} at "
            f"{w['worst_joint_ratio']:.2g}x the noise floor"
        )
        text += (
            ("; suggested: " + "; ".join(c["text"] for c in sugg))
            if sugg
            else ("; no suggested effect acts on this joint")
        )
        times.append(float(w["t0"]))
        texts.append(text)
    order = np.argsort(times, kind="stable")
    log.text_log(
        "diagnosis", np.array(times)[order], [texts[i] for i in order], ["WARN"] * len(order)
    )
    ranked = [f"{i}. {c['text']}" for i, c in enumerate(cands, 1)]
    doc = "# Diagnosis\n\n" + ("\n".join(ranked) if ranked else "no candidates")
    log.stream.log("info/diagnosis", rr.TextDocument(doc, media_type="text/markdown"), static=True)


# ---------------------------------------------------------------------- text
def _recording_markdown(rec: Recording, est: Estimates | None) -> str:
    lines = [
        f"# {rec.name or 'recording'}",
        "",
        f"- robot: {rec.robot_label}, {rec.n} joints",
        f"- {len(rec)} samples, {rec.duration:.2f} s, {rec.sample_rate:.1f} Hz",
        f"- F/T sensor: {'yes' if rec.has_wrench else 'no'}; dither flag: "
        f"{'yes' if rec.dither is not None else 'no'}",
    ]
    if est is not None:
        iv = est.meta.get("interval", {})
        lines += [
            f"- estimates: {est.name}, variants {', '.join(est.variants)}",
            f"- interval: {iv.get('method', '?')} at level {iv.get('level', '?')}",
        ]
    lines += [
        "",
        "Force signs: the wrench the robot exerts on its environment (a push P shows as -P).",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------- entry points
def new_stream(
    rec: Recording,
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    application_id: str = "ditherlab",
) -> rr.RecordingStream:
    """A RecordingStream whose recording id is derived from its inputs.

    The same recording, estimates and model give the same id (the viewer shows a re-written file
    in place of the old one); another recording or other estimates of it give another id (the
    viewer keeps them apart instead of merging them).
    """
    import hashlib

    import rerun as rr

    h = hashlib.sha256()
    h.update(rec.meta_json().encode())
    h.update(np.asarray(rec.t).tobytes())
    if estimates is not None:
        h.update(json.dumps(_plain_json(estimates.meta), sort_keys=True).encode())
    if model is not None:
        h.update(model.dumps().encode())
    return rr.RecordingStream(application_id, recording_id=h.hexdigest()[:32])


def save_view(
    rec: Recording,
    path: str | Path,
    *,
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: Any = None,
    inputs: Sequence[str | Path] = (),
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
) -> ViewSummary:
    """Write the view of ``rec`` to an ``.rrd`` file atomically; see :func:`log_view`.

    Raises DitherlabError when ``path`` is one of ``inputs``.
    """
    from ditherlab.io.atomic import atomic_path, check_not_input
    from ditherlab.viz.blueprint import make_blueprint

    out = Path(path)
    if out.suffix != ".rrd":
        raise DitherlabError(f"{out}: a Rerun recording must end in .rrd")
    check_not_input(out, [*inputs, *([rec.name] if rec.name else [])])
    if estimates is not None:
        check_estimates_match(rec, estimates)
    with atomic_path(out) as tmp:
        stream = new_stream(rec, estimates, model)
        bp = make_blueprint(
            rec.n, estimates.variants if estimates else [], has_wrench=rec.has_wrench
        )
        stream.save(tmp, default_blueprint=bp)
        try:
            summary = log_view(
                rec,
                stream,
                estimates=estimates,
                model=model,
                diagnosis=diagnosis,
                rate_3d=rate_3d,
                progress=progress,
            )
        finally:
            stream.flush()
            stream.disconnect()
    return summary


def show_view(
    rec: Recording,
    *,
    mode: str = "spawn",
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: Any = None,
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
) -> str | None:
    """Send the view to a viewer: ``mode="spawn"`` starts the native viewer (``rr.spawn``),
    ``mode="serve"`` serves it over gRPC and a web viewer (``rr.serve_grpc`` +
    ``rr.serve_web_viewer``) and returns the web viewer's URL; the servers live as long as this
    process (see :func:`wait_until_interrupted`).
    """
    import rerun as rr

    from ditherlab.viz.blueprint import make_blueprint

    stream = new_stream(rec, estimates, model)
    bp = make_blueprint(rec.n, estimates.variants if estimates else [], has_wrench=rec.has_wrench)
    url = None
    if mode == "spawn":
        rr.spawn(recording=stream, default_blueprint=bp)
    elif mode == "serve":
        grpc = rr.serve_grpc(recording=stream, default_blueprint=bp)
        rr.serve_web_viewer(web_port=WEB_PORT, connect_to=grpc, open_browser=False)
        url = f"http://localhost:{WEB_PORT}/?url={grpc}"
    else:
        raise DitherlabError(f"view mode is {mode!r}, expected 'spawn' or 'serve'")
    log_view(
        rec,
        stream,
        estimates=estimates,
        model=model,
        diagnosis=diagnosis,
        rate_3d=rate_3d,
        progress=progress,
    )
    stream.flush()
    return url


def wait_until_interrupted() -> None:
    """Block until Ctrl-C (keeps the servers of ``show_view(mode="serve")`` alive)."""
    import time

    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        return


# ---------------------------------------------------------------------- reading back (Rerun's API)
def rrd_contents(path: str | Path) -> dict[str, dict[str, int]]:
    """What an ``.rrd`` file holds, read with Rerun's own reader (``rerun.chunk.RrdReader``).

    Returns
    -------
    dict entity path (without the leading ``/``) -> component name (e.g. ``Scalars:scalars``) ->
    number of time-indexed rows; static components are counted under the key ``"static"``
    """
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, int]] = {}
    for ch in RrdReader(str(path)).stream():
        ent = out.setdefault(ch.entity_path.lstrip("/"), {})
        if ch.is_static:
            ent["static"] = ent.get("static", 0) + ch.num_rows
            continue
        rb = ch.to_record_batch()
        for f in rb.schema:
            meta = f.metadata or {}
            if meta.get(b"rerun:kind") == b"data":
                ent[f.name] = ent.get(f.name, 0) + ch.num_rows
    return out


def rrd_scalars(path: str | Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """Read one Scalars entity back from an ``.rrd`` file with Rerun's reader.

    Returns
    -------
    t : (M,) [s] the ``time`` timeline
    values : (M, k) the scalars of each row
    """
    from rerun.chunk import RrdReader

    want = "/" + entity.lstrip("/")
    ts, vs = [], []
    for ch in RrdReader(str(path)).stream():
        if ch.entity_path != want or ch.is_static:
            continue
        rb = ch.to_record_batch()
        names = rb.schema.names
        if "Scalars:scalars" not in names:
            continue
        tcol = rb.column(names.index(TIMELINE)).cast("int64").to_numpy()
        sc = rb.column(names.index("Scalars:scalars"))
        vs.append(np.asarray(sc.flatten().to_numpy(zero_copy_only=False)).reshape(len(tcol), -1))
        ts.append(tcol)
    if not ts:
        raise DitherlabError(f"{path}: entity {entity!r} has no Scalars")
    t = np.concatenate(ts)
    v = np.concatenate(vs)
    order = np.argsort(t, kind="stable")
    return t[order] / 1e9, v[order]


@dataclass
class ViewRequest:
    """Inputs of ``ditherlab view``, read and checked: see :func:`load_view_request`."""

    rec: Recording
    estimates: Estimates | None = None
    model: TorqueModel | None = None
    save: Path | None = None
    mode: str | None = None
    inputs: list[Path] = field(default_factory=list)
    diagnosis: DiagnosisReport | None = None


@dataclass
class ViewResult:
    """What :func:`run_view` did: the file written (or the URL served) and what was logged."""

    summary: ViewSummary
    path: Path | None = None
    url: str | None = None


def load_view_request(
    recording: str | Path,
    *,
    estimates: str | Path | None = None,
    model: str | Path | None = None,
    diagnosis: str | Path | None = None,
    save: str | Path | None = None,
    mode: str | None = None,
    read_options: Mapping[str, Any] | None = None,
) -> ViewRequest:
    """Read and check every input of a view before anything is logged or written.

    Exactly one of ``save`` (an ``.rrd`` path) and ``mode`` (``"spawn"`` or ``"serve"``) must be
    given; the estimates must come from the recording; the model must be for its robot.
    ``read_options`` go to :func:`ditherlab.io.read` (``mapping``, ``robot`` for foreign logs).

    Raises
    ------
    DitherlabError
        Missing or unreadable files, estimates from another recording, no or two outputs.
    """
    from ditherlab.errors import ConfigError
    from ditherlab.io import read
    from ditherlab.model import TorqueModel
    from ditherlab.viz.diagnosis import load_report

    if (save is None) == (mode is None):
        raise ConfigError("view needs exactly one output: --save out.rrd, --spawn or --serve")
    if mode is not None and mode not in ("spawn", "serve"):
        raise ConfigError(f"view mode is {mode!r}, expected 'spawn' or 'serve'")
    if save is not None and Path(save).suffix != ".rrd":
        raise ConfigError(f"{save}: a Rerun recording must end in .rrd")
    rec = read(recording, **dict(read_options or {}))
    est = load_estimates(estimates) if estimates is not None else None
    if est is not None:
        check_estimates_match(rec, est)
    mdl = TorqueModel.load(model) if model is not None else None
    if mdl is not None:
        mdl.check_robot(rec)
    diag = load_report(diagnosis) if diagnosis is not None else None
    inputs = [Path(p) for p in (recording, estimates, model, diagnosis) if p is not None]
    if save is not None:
        from ditherlab.io.atomic import check_not_input

        check_not_input(save, inputs)
    return ViewRequest(rec, est, mdl, Path(save) if save is not None else None, mode, inputs, diag)


def run_view(
    req: ViewRequest,
    *,
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
) -> ViewResult:
    """Write (``req.save``) or show (``req.mode``) the view of a checked request."""
    kw = {
        "estimates": req.estimates,
        "model": req.model,
        "diagnosis": req.diagnosis,
        "rate_3d": rate_3d,
        "progress": progress,
    }
    if req.save is not None:
        summary = save_view(req.rec, req.save, inputs=req.inputs, **kw)
        return ViewResult(summary, path=req.save)
    url = show_view(req.rec, mode=str(req.mode), **kw)
    return ViewResult(ViewSummary(), url=url)


def save_view_files(
    recording: str | Path,
    out: str | Path,
    *,
    estimates: str | Path | None = None,
    model: str | Path | None = None,
    diagnosis: str | Path | None = None,
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Read the files, check them and write the view to ``out`` (``.rrd``); returns ``out``.

    The one call a script (``make demo``) needs; see :func:`load_view_request` for the checks.
    """
    req = load_view_request(
        recording, estimates=estimates, model=model, diagnosis=diagnosis, save=out
    )
    run_view(req, rate_3d=rate_3d, progress=progress)
    return Path(out)

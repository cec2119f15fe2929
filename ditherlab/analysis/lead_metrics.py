"""Lead-through quality from a recording of the simulator's lead-through (paper §V), and the
means that compare its two admittance laws (``lead_through.law``: the 10 N dead zone, or the
confidence interval) over runs on the same operator pushes (:func:`law_means`; the runs are
simulated by :func:`ditherlab.app.leadthrough.compare_laws`).

Everything is measured on the tool point, from the logged joint angles through the robot's
forward kinematics, against the operator's true push (rebuilt exactly from the plan in
``meta["sim"]["operator"]`` by :func:`ditherlab.sim.guidance.operator_push`):

path          per push (onset to the next onset, so the coast after the release counts): the
              displacement along the pushed direction ``along`` [mm], the displacement across it
              ``off_axis`` [mm], and ``along`` as a share of the *intended* displacement, the one
              the same admittance would give driven by the true push (no estimate, no dead zone):
              ``admittance * integral(P . d) dt``.
jerk          RMS and 99th percentile of ``|d^3 x / dt^3|`` [m/s^3] of the tool point after a
              centred moving average over one dither period applied twice (the dither's 80 rad/s
              vibration, ~1e-4 arm rad, would otherwise dominate a third derivative: it is felt as
              a hum, not as jerky motion); over the whole run from ``SETTLE_S`` to two smoothing
              widths before the end.
false motion  path length of the tool point [mm] while the operator does not push, from
              ``REST_AFTER_S`` after each release (the commanded motion has died out by then:
              the smoothing's time constant is 0.3 s) to the next onset; and during the rise of
              each push while it is below the dead zone (the dead-zone law cannot move there; the
              interval law may, and whether that is *false* depends on the operator's intent).
force steps   the force that drives the admittance, rebuilt from the logged estimate (dead zone)
              or interval (interval law): the 99th percentile and the maximum of its change
              between two controller updates ``|dP_cmd|`` [N] (the paper's §V worry: the
              interval narrows when the robot starts to move, so the force jumps).
delay         per push, the time from the onset until the tool moves at more than
              ``DELAY_SPEED`` along the pushed direction [s] (NaN when it never does).
coverage      with the interval law's ``flo_x..z, fhi_x..z``: the share of samples whose true
              push lies inside the interval the controller acted on, per axis, at rest and
              while pushing, the mean width [N], and the share of samples whose interval is
              empty (NaN: the set membership found no force consistent with the data; the
              interval law then commands 0).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording
from ditherlab.sim.guidance import EDGE_S, interval_command, operator_push

#: Start of the measured span: the first second settles and ramps the dither on [s].
SETTLE_S = 1.5
#: Rest (false motion) is counted from this long after a release [s].
REST_AFTER_S = 1.5
#: Tool speed along the push that counts as a response [m/s].
DELAY_SPEED = 0.005
AXES = "xyz"


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average of ``x (N, 3)`` over ``width`` samples, applied twice (edges:
    the mean of the samples available)."""
    if width <= 1:
        return x.copy()
    k = np.ones(width)
    out = x
    for _ in range(2):
        num = np.stack([np.convolve(out[:, i], k, mode="same") for i in range(out.shape[1])], 1)
        den = np.convolve(np.ones(len(out)), k, mode="same")[:, None]
        out = num / den
    return out


def _nanmean(values: Iterable[float]) -> float:
    """The mean of the finite values; NaN (without numpy's warning) when there is none."""
    v = np.asarray(list(values), dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else float("nan")


def _lead_meta(rec: Recording, name: str) -> dict[str, Any]:
    sim = rec.meta.get("sim") or {}
    if sim.get("scenario") != "lead-through" or "operator" not in sim:
        raise ConfigError(
            f"{name}: not a lead-through simulation (meta.sim.scenario is "
            f"{sim.get('scenario')!r}); expected a recording of `ditherlab simulate lead-through`"
        )
    return sim


def tool_path(rec: Recording) -> np.ndarray:
    """The tool point's position ``(N, 3)`` [m, base axes] from the logged joint angles."""
    return rec.robot().evaluate(rec.q, ["tool_pose"])["tool_pose"][:, :3, 3]


def lead_metrics(rec: Recording, name: str = "recording") -> dict[str, Any]:
    """The lead-through metrics of one recording (module docstring for their definitions).

    Parameters
    ----------
    rec : a recording of the simulator's lead-through (``meta["sim"]["operator"]`` present)
    name : how errors name it

    Returns
    -------
    dict
        ``pushes``: per push ``direction``, ``magnitude`` [N], ``along_mm``, ``off_axis_mm``,
        ``intended_mm``, ``along_share`` [-], ``delay_s``; ``summary``: ``along_share``,
        ``off_axis_mm`` and ``delay_s`` (means over the pushes), ``jerk_rms``, ``jerk_p99``
        [m/s^3], ``rest_path_mm``, ``rest_s``, ``sub_dead_zone_path_mm``, ``fhat_rms_error``,
        ``cmd_step_p99``, ``cmd_step_max`` [N]
        and, with interval columns, ``coverage``, ``coverage_rest``, ``coverage_push``,
        ``width_mean`` [N], ``empty_share``; ``law``, ``dither``, ``seed``.

    Raises
    ------
    ConfigError
        The recording is not a lead-through simulation.
    """
    sim = _lead_meta(rec, name)
    run = _lead_run(rec, sim)
    pushes = [_push_row(run, i) for i in range(len(run.segs))]
    rest = _rest(run)
    fhat = np.column_stack([rec.data[f"fhat_{a}"].to_numpy(float) for a in AXES])
    bounds = _interval_bounds(rec)
    cmd = _force_command(fhat, bounds, run.lt["dead_zone"])
    summary: dict[str, Any] = {
        **_push_means(pushes),
        **_jerk(run),
        **_rest_motion(run, rest),
        "fhat_rms_error": float(np.sqrt(np.mean(np.sum((fhat - run.push)[run.span] ** 2, axis=1)))),
        **_command_steps(cmd, run.span),
    }
    if bounds is not None:
        summary.update(_coverage(run, rest, *bounds))
    return {
        "law": run.lt.get("law", "dead-zone"),
        "dither": bool(sim.get("dither", False)),
        "seed": int(sim.get("seed", 0)),
        "pushes": pushes,
        "summary": summary,
    }


@dataclass(frozen=True)
class _LeadRun:
    """What the metrics of one lead-through recording read.

    Attributes
    ----------
    t : (N,) [s] time; dt [s] its step
    lt : the simulator's ``lead_through`` parameters; segs : the operator's pushes
    push : (N, 3) [N] the operator's true push; pnorm : (N,) [N] its magnitude
    x, v : (N, 3) [m, m/s] the smoothed tool point and its velocity
    width : [samples] the smoothing's width (one dither period)
    span : (N,) bool the measured span (from :data:`SETTLE_S` on)
    """

    t: np.ndarray
    dt: float
    lt: Mapping[str, Any]
    segs: Sequence[Mapping[str, Any]]
    push: np.ndarray
    pnorm: np.ndarray
    x: np.ndarray
    v: np.ndarray
    width: int
    span: np.ndarray


def _lead_run(rec: Recording, sim: Mapping[str, Any]) -> _LeadRun:
    """The true push and the smoothed tool motion of ``rec`` (its ``meta["sim"]``: ``sim``)."""
    t, dt = rec.t, rec.dt
    push = operator_push(t, sim["operator"])
    omega = float(sim["params"]["dither"]["frequency"])
    width = max(1, round(2 * np.pi / omega / dt))
    x = _smooth(tool_path(rec), width)
    return _LeadRun(
        t, dt, sim["params"]["lead_through"], sim["operator"], push,
        pnorm=np.linalg.norm(push, axis=1),
        x=x,
        v=np.gradient(x, dt, axis=0),
        width=width,
        span=t >= t[0] + SETTLE_S,
    )  # fmt: skip


def _push_row(run: _LeadRun, i: int) -> dict[str, Any]:
    """Push ``i``'s path (onset to the next onset) and delay."""
    t, dt, x, s = run.t, run.dt, run.x, run.segs[i]
    onsets = [float(g["t0"]) for g in run.segs] + [float(t[-1]) + dt]
    d = np.asarray(s["direction"], dtype=float)
    a = int(np.searchsorted(t, onsets[i]))
    b = min(int(np.searchsorted(t, onsets[i + 1])), len(t) - 1)
    dx = x[b] - x[a]
    along = float(dx @ d)
    off = float(np.linalg.norm(dx - along * d))
    intended = float(run.lt["admittance"] * np.sum(run.push[a:b] @ d) * dt)
    moving = np.nonzero(run.v[a:b] @ d > DELAY_SPEED)[0]
    return {
        "direction": [float(c) for c in d],
        "magnitude": float(s["magnitude"]),
        "along_mm": 1e3 * along,
        "off_axis_mm": 1e3 * off,
        "intended_mm": 1e3 * intended,
        "along_share": along / intended if intended > 0 else float("nan"),
        "delay_s": float(moving[0] * dt) if len(moving) else float("nan"),
    }


def _push_means(pushes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The pushes' means: ``along_share``, ``off_axis_mm``, ``delay_s``; the missed ones."""
    return {
        "along_share": _nanmean(p["along_share"] for p in pushes),
        "off_axis_mm": float(np.mean([p["off_axis_mm"] for p in pushes])),
        "delay_s": _nanmean(p["delay_s"] for p in pushes),
        "missed_pushes": int(sum(np.isnan(p["delay_s"]) for p in pushes)),
    }


def _jerk(run: _LeadRun) -> dict[str, float]:
    """RMS and 99th percentile of the tool point's jerk [m/s^3] over the measured span."""
    t, dt = run.t, run.dt
    jerk = np.gradient(np.gradient(run.v, dt, axis=0), dt, axis=0)
    # the smoothing's partial windows at the ends would read as jerk: leave two widths out
    jn = np.linalg.norm(jerk[run.span & (np.arange(len(t)) < len(t) - 2 * run.width)], axis=1)
    return {"jerk_rms": float(np.sqrt(np.mean(jn**2))), "jerk_p99": float(np.percentile(jn, 99))}


def _rest(run: _LeadRun) -> np.ndarray:
    """(N,) bool rest: no push, from :data:`REST_AFTER_S` after each release (and after
    :data:`SETTLE_S` at the start)."""
    t = run.t
    rest = run.span & (run.pnorm == 0)
    for s in run.segs:
        end = s["t0"] + 2 * EDGE_S + s["flat"]
        rest &= ~((t > s["t0"]) & (t < end + REST_AFTER_S))
    return rest


def _rest_motion(run: _LeadRun, rest: np.ndarray) -> dict[str, float]:
    """The tool point's path [mm] at ``rest`` and during the rise of each push while it is
    below the dead zone; the rest's length [s]."""
    t = run.t
    step = np.linalg.norm(np.diff(run.x, axis=0), axis=1)
    both = rest[1:] & rest[:-1]
    rest_path = float(step[both].sum())
    rise = np.zeros(len(t), dtype=bool)
    for s in run.segs:
        rise |= (t >= s["t0"]) & (t <= s["t0"] + EDGE_S) & (run.pnorm < run.lt["dead_zone"])
    sub_path = float(step[rise[1:] & rise[:-1]].sum())
    return {
        "rest_path_mm": 1e3 * rest_path,
        "rest_s": float(rest.sum() * run.dt),
        "sub_dead_zone_path_mm": 1e3 * sub_path,
    }


def _interval_bounds(rec: Recording) -> tuple[np.ndarray, np.ndarray] | None:
    """The interval law's bounds ``flo``, ``fhi`` (N, 3) [N], or None without them."""
    cols = [f"flo_{a}" for a in AXES] + [f"fhi_{a}" for a in AXES]
    if not all(c in rec.data.columns for c in cols):
        return None
    lo = np.column_stack([rec.data[f"flo_{a}"].to_numpy(float) for a in AXES])
    hi = np.column_stack([rec.data[f"fhi_{a}"].to_numpy(float) for a in AXES])
    return lo, hi


def _force_command(
    fhat: np.ndarray, bounds: tuple[np.ndarray, np.ndarray] | None, dead_zone: float
) -> np.ndarray:
    """The force (N, 3) [N] that drives the admittance: from the interval (``bounds``), else
    the estimate ``fhat`` beyond the ``dead_zone`` [N]."""
    if bounds is not None:
        return interval_command(*bounds)
    mag = np.linalg.norm(fhat, axis=1, keepdims=True)
    beyond = np.maximum(mag - dead_zone, 0.0)
    return np.where(mag > 0, beyond * fhat / np.where(mag > 0, mag, 1.0), 0.0)


def _command_steps(cmd: np.ndarray, span: np.ndarray) -> dict[str, float]:
    """The 99th percentile and the maximum [N] of the command's changes over ``span``."""
    steps = np.linalg.norm(np.diff(cmd, axis=0), axis=1)[span[1:]]
    steps = steps[steps > 0]  # the updates that changed the command
    return {
        "cmd_step_p99": float(np.percentile(steps, 99)) if len(steps) else 0.0,
        "cmd_step_max": float(steps.max()) if len(steps) else 0.0,
    }


def _coverage(run: _LeadRun, rest: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> dict[str, Any]:
    """The interval's coverage of the true push (all, rest, pushing), its empty share and mean
    width [N] per axis."""
    push, span = run.push, run.span
    inside = (lo <= push) & (push <= hi)  # NaN bounds count as a miss
    pushing = span & (run.pnorm > 0)
    width_ok = np.isfinite(hi - lo)[span]
    return {
        "coverage": [float(c) for c in inside[span].mean(0)],
        "coverage_rest": [float(c) for c in inside[rest].mean(0)],
        "coverage_push": [float(c) for c in inside[pushing].mean(0)],
        "empty_share": float(np.isnan(hi - lo).any(axis=1)[span].mean()),
        "width_mean": [
            float((hi - lo)[span][width_ok[:, i], i].mean()) if width_ok[:, i].any() else np.nan
            for i in range(3)
        ],
    }


#: The summary metrics the comparison averages over seeds: (key, header, format, better).
COMPARED = (
    ("along_share", "along / intended", "{:.2f}", "closer to 1"),
    ("off_axis_mm", "off-axis [mm]", "{:.1f}", "lower"),
    ("delay_s", "delay [s]", "{:.2f}", "lower"),
    ("jerk_rms", "jerk RMS [m/s³]", "{:.3f}", "lower"),
    ("jerk_p99", "jerk p99 [m/s³]", "{:.3f}", "lower"),
    ("rest_path_mm", "rest motion [mm]", "{:.2f}", "lower"),
    ("sub_dead_zone_path_mm", "motion < dead zone [mm]", "{:.2f}", "see text"),
    ("cmd_step_p99", "force step p99 [N]", "{:.1f}", "lower"),
    ("cmd_step_max", "force step max [N]", "{:.1f}", "lower"),
    ("fhat_rms_error", "F̂ RMS error [N]", "{:.1f}", "lower"),
)


def law_means(
    runs: Sequence[Mapping[str, Any]], dithers: Sequence[bool], laws: Sequence[str]
) -> list[dict[str, Any]]:
    """Per ``(law, dither)``: the mean of each :data:`COMPARED` metric over the runs'
    :func:`lead_metrics` summaries (and of the coverage lists), the runs and the missed pushes
    counted."""
    means = []
    for dither in dithers:
        for law in laws:
            sel = [r["summary"] for r in runs if r["law"] == law and r["dither"] == dither]
            row: dict[str, Any] = {"law": law, "dither": dither, "runs": len(sel)}
            for key, *_ in COMPARED:
                row[key] = _nanmean(s[key] for s in sel)
            row["missed_pushes"] = int(sum(s["missed_pushes"] for s in sel))
            if sel and "empty_share" in sel[0]:
                row["empty_share"] = _nanmean(s["empty_share"] for s in sel)
            for key in ("coverage", "coverage_rest", "coverage_push", "width_mean"):
                if sel and key in sel[0]:
                    row[key] = [float(c) for c in np.mean([s[key] for s in sel], 0)]
            means.append(row)
    return means


def path_trace(rec: Recording, every: int = 5) -> dict[str, list[float]]:
    """Down-sampled tool displacement and true push of one run, for the figure: ``t`` [s],
    ``x`` (N, 3) [mm] from the start, ``intended`` (N, 3) [mm] (the admittance driven by the true
    push), ``push`` (N, 3) [N], ``fhat`` (N, 3) [N]."""
    sim = rec.meta["sim"]
    x = tool_path(rec)
    sl = slice(None, None, every)
    fhat = np.column_stack([rec.data[f"fhat_{a}"].to_numpy(float) for a in AXES])
    push = operator_push(rec.t, sim["operator"])
    intended = sim["params"]["lead_through"]["admittance"] * np.cumsum(push, axis=0) * rec.dt
    return {
        "t": rec.t[sl].tolist(),
        "x": (1e3 * (x - x[0]))[sl].tolist(),
        "intended": (1e3 * intended)[sl].tolist(),
        "push": push[sl].tolist(),
        "fhat": fhat[sl].tolist(),
    }


def means_table(result: Mapping[str, Any]) -> str:
    """The comparison's means as a Markdown table, one row per (dither, law)."""
    head = ["dither", "law"] + [h for _, h, _, _ in COMPARED] + ["missed", "coverage x/y/z (empty)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in result["means"]:
        cells = ["on" if row["dither"] else "off", row["law"]]
        cells += [fmt.format(row[key]) for key, _, fmt, _ in COMPARED]
        cells.append(str(row["missed_pushes"]))
        cov = row.get("coverage")
        cells.append(
            "/".join(f"{c:.2f}" for c in cov) + f" ({row['empty_share']:.2f})" if cov else "–"
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)

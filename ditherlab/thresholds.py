"""Detection statistics of the force estimate per push direction (the paper's §VI-C).

Pushes are found from the F/T sensor (:func:`find_pushes`). For every estimator variant the
**noise level** is the 99.9 % quantile of ``|F̂|`` along the push axis over the **rest samples**
(more than ``rest_margin`` seconds from any push), per recording and axis. A push **gave a
response** when its estimate along the push axis, with the sign of the sensor reading, rose above
that noise level within the push or ``lag`` seconds after it (the dither extraction lags); it
**exceeded 10 N** when that estimate rose above 10 N. The paper's two statistics per direction
(pooling both signs, as the paper does) are then

- ``response_min``: the smallest applied force among the pushes that gave a response (the paper:
  "no force smaller than 32 N gave any response");
- ``above10_from``: the smallest applied force beyond which every push gave an estimate above
  10 N (the paper: "an applied force of 40 N was needed").

plus a logistic detection curve ``P(response | F) = 1 / (1 + exp(-(F - F50) / s))`` fitted by
maximum likelihood (on a grid, which stays finite when the data separate perfectly), with
``F90 = F50 + s ln 9`` and percentile intervals from a seeded bootstrap over pushes; the RMS of the
force error during pushes, and the width and coverage of the interval during pushes.

Signs: the sensor columns hold the wrench the robot exerts, ``F = -P`` for an applied force ``P``
(RECORDING.md). A push's ``sign`` is the sign of the applied force ``P`` along its axis; its
``peak`` is ``max |F_axis|`` over the push [N].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ditherlab.errors import DitherlabError
from ditherlab.recording import FORCE_AXES
from ditherlab.signal import merge_runs, runs

AXES = FORCE_AXES
#: The paper's numbers (§VI-C): smallest force with a response, force needed for > 10 N [N].
PAPER = {
    "no dither": {
        "response": {"x": 32.0, "y": 22.0, "z": 22.0},
        "above10": {"x": 40.0, "y": 30.0, "z": 30.0},
    },
    "dither": {
        "response": {"x": 10.0, "y": 10.0, "z": 10.0},
        "above10": {"x": 20.0, "y": 20.0, "z": 20.0},
    },
}


class NoPushesError(DitherlabError):
    """Estimates without pushes (or without the F/T columns to find them)."""


@dataclass
class Push:
    """One push found in the F/T sensor.

    Attributes
    ----------
    start, end : [s]
    axis : "x", "y" or "z"
    sign : +1 or -1, sign of the applied force along ``axis``
    peak : largest ``|F_axis|`` during the push [N]
    i0, i1 : sample indices, ``[i0, i1)``
    """

    start: float
    end: float
    axis: str
    sign: int
    peak: float
    i0: int
    i1: int


def find_pushes(
    t: np.ndarray,
    wrench: np.ndarray,
    *,
    threshold: float | None = None,
    min_duration: float = 0.1,
    merge_gap: float = 0.15,
) -> list[Push]:
    """Pushes in the F/T sensor: stretches where the force magnitude exceeds a threshold.

    Parameters
    ----------
    t : (N,) [s]
    wrench : (N, 6) [N, N·m] sensor columns ``f_x .. m_z``
    threshold : [N] start of a push (it ends below half of it); default ``max(1 N, 6 sigma)``
        with sigma the sensor noise from first differences of ``|f|``
    min_duration : shorter stretches are ignored [s]
    merge_gap : stretches closer than this are one push [s]

    Returns
    -------
    list of Push, in time order
    """
    f = np.asarray(wrench, dtype=float)[:, :3]
    t = np.asarray(t, dtype=float)
    mag = np.linalg.norm(f, axis=1)
    if threshold is None:
        d = np.diff(mag)
        sig = float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2) if len(d) else 0.0
        threshold = max(1.0, 6.0 * sig)
    base = float(np.median(mag[mag < threshold])) if np.any(mag < threshold) else 0.0
    hi_thr = base + threshold
    lo_thr = base + 0.5 * threshold
    starts, ends = runs(mag > lo_thr)
    peaked = np.array([np.any(mag[s:e] > hi_thr) for s, e in zip(starts, ends, strict=True)], bool)
    segs = merge_runs(t, starts[peaked], ends[peaked], merge_gap)
    out = []
    for s, e in segs:
        if t[e - 1] - t[s] < min_duration:
            continue
        seg = f[s:e]
        k = int(np.argmax(np.abs(seg).max(axis=0)))
        i = int(np.argmax(np.abs(seg[:, k])))
        out.append(
            Push(
                start=float(t[s]),
                end=float(t[e - 1]),
                axis=AXES[k],
                sign=int(-np.sign(seg[i, k])) or 1,
                peak=float(abs(seg[i, k])),
                i0=int(s),
                i1=int(e),
            )
        )
    return out


def rest_mask(t: np.ndarray, pushes: Sequence[Push], margin: float = 1.0) -> np.ndarray:
    """Samples farther than ``margin`` [s] before the start or after the end of every push, (N,)."""
    t = np.asarray(t, dtype=float)
    rest = np.ones(len(t), dtype=bool)
    for p in pushes:
        rest &= ~((t >= p.start - margin) & (t <= p.end + margin))
    return rest


@dataclass
class PushResult:
    """One push seen by one variant."""

    push: Push
    response: float  # largest estimate along the axis, sensor sign [N]
    detected: bool
    above10: bool
    error_rms: float  # RMS of estimate - sensor along the axis during the push [N]
    width: float  # mean interval width along the axis during the push [N]
    coverage: float  # fraction of push samples whose interval holds the sensor value


def push_results(
    t: np.ndarray,
    F_sensor: np.ndarray,
    F_hat: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    pushes: Sequence[Push],
    noise: dict[str, float],
    *,
    lag: float = 0.3,
    big: float = 10.0,
) -> list[PushResult]:
    """Score every push for one variant.

    Parameters
    ----------
    t : (N,) [s]
    F_sensor, F_hat, lo, hi : (N, 6) [N, N·m]
    pushes : from :func:`find_pushes`
    noise : axis -> noise level [N]
    lag : seconds after a push's end still counted for its response (capped at the next push)
    big : the "significant" estimate [N] (the paper: 10 N)
    """
    out = []
    starts = [p.start for p in pushes] + [np.inf]
    for k, p in enumerate(pushes):
        a = AXES.index(p.axis)
        t_end = min(p.end + lag, starts[k + 1])
        win = (t >= p.start) & (t <= t_end)
        s = np.sign(F_sensor[p.i0 : p.i1, a][np.argmax(np.abs(F_sensor[p.i0 : p.i1, a]))]) or 1.0
        resp = float(np.max(s * F_hat[win, a])) if win.any() else float("nan")
        sl = slice(p.i0, p.i1)
        err = F_hat[sl, a] - F_sensor[sl, a]
        w = hi[sl, a] - lo[sl, a]
        cov = (lo[sl, a] <= F_sensor[sl, a]) & (F_sensor[sl, a] <= hi[sl, a])
        out.append(
            PushResult(
                push=p,
                response=resp,
                detected=bool(resp > noise[p.axis]),
                above10=bool(resp > big),
                error_rms=float(np.sqrt(np.mean(err**2))),
                width=float(np.mean(w[np.isfinite(w)])) if np.isfinite(w).any() else float("inf"),
                coverage=float(np.mean(cov)),
            )
        )
    return out


# ------------------------------------------------------------------------------ logistic fit
def fit_logistic(
    force: np.ndarray, hit: np.ndarray, *, n_boot: int = 200, seed: int = 0, level: float = 0.9
) -> dict[str, Any]:
    """Detection probability against applied force: ``1 / (1 + exp(-(F - F50) / s))``.

    Maximum likelihood on a grid (F50 over 0 .. 1.5 max F in 300 steps, s log-spaced over
    0.25 .. 50 N in 60 steps), so perfectly separated data give the steepest curve on the grid
    instead of diverging; percentile intervals from a seeded bootstrap over pushes.

    Parameters
    ----------
    force : (P,) applied peak forces [N]
    hit : (P,) bool, response or not
    n_boot : bootstrap replicates
    seed : bootstrap seed
    level : central probability of the intervals

    Returns
    -------
    dict with ``F50``, ``F90``, ``scale`` [N] and ``F50_ci``, ``F90_ci`` (lo, hi) [N]; NaNs for
    fewer than 3 pushes; when every push (or none) was seen, NaNs and ``bound`` = ``"below"``
    (``"above"``) with ``bound_force`` the smallest (largest) force [N].
    """
    force = np.asarray(force, dtype=float)
    hit = np.asarray(hit, dtype=bool)
    nan = float("nan")
    if len(force) < 3:
        return {"F50": nan, "F90": nan, "scale": nan, "F50_ci": [nan, nan], "F90_ci": [nan, nan]}
    if hit.all() or not hit.any():
        # no transition in the data: F50 and F90 lie below the smallest (all seen) or above
        # the largest force (none seen); report the bound instead of a grid edge
        bound = float(force.min()) if hit.all() else float(force.max())
        return {
            "F50": nan,
            "F90": nan,
            "scale": nan,
            "F50_ci": [nan, nan],
            "F90_ci": [nan, nan],
            "bound": ("below" if hit.all() else "above"),
            "bound_force": bound,
        }
    fmax = float(force.max())
    g50 = np.linspace(0.0, 1.5 * fmax, 300)
    gs = np.geomspace(0.25, 50.0, 60)
    G50, GS = np.meshgrid(g50, gs, indexing="ij")
    z = (force[None, None, :] - G50[..., None]) / GS[..., None]  # (300, 60, P)
    lp = -np.logaddexp(0.0, -z)  # log p(hit)
    lq = -np.logaddexp(0.0, z)  # log p(miss)

    def best(weights: np.ndarray) -> tuple[float, float]:
        ll = lp @ (weights * hit) + lq @ (weights * ~hit)
        i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)
        return float(g50[i]), float(gs[j])

    f50, s = best(np.ones(len(force)))
    ln9 = float(np.log(9.0))
    out: dict[str, Any] = {"F50": f50, "F90": f50 + s * ln9, "scale": s}
    if n_boot > 1:
        rng = np.random.default_rng(seed)
        reps = np.empty((n_boot, 2))
        for r in range(n_boot):
            w = np.bincount(rng.integers(0, len(force), len(force)), minlength=len(force))
            b50, bs = best(w.astype(float))
            reps[r] = (b50, b50 + bs * ln9)
        q = [(1 - level) / 2, (1 + level) / 2]
        out["F50_ci"] = np.quantile(reps[:, 0], q).tolist()
        out["F90_ci"] = np.quantile(reps[:, 1], q).tolist()
    else:
        out["F50_ci"] = [nan, nan]
        out["F90_ci"] = [nan, nan]
    return out


# ------------------------------------------------------------------------------ analysis
def condition_of(variant: str, dithered: bool) -> str:
    """The row label: the variant, qualified when a no-dither variant runs on a dithered log."""
    if variant.startswith("nodither") and dithered:
        return f"{variant} (dither on)"
    return variant


@dataclass
class Group:
    """The pushes of one condition (variant on recordings with/without dither) and its noise."""

    condition: str
    variant: str
    dithered: bool
    results: list[PushResult] = field(default_factory=list)
    noise: dict[str, list[float]] = field(default_factory=lambda: {a: [] for a in AXES})
    rest_coverage: list[float] = field(default_factory=list)
    all_coverage: list[float] = field(default_factory=list)
    rest_width: list[float] = field(default_factory=list)


def direction_stats(results: Sequence[PushResult], n_boot: int, seed: int) -> dict[str, Any]:
    """The paper's two statistics and the detection curve for the pushes of one direction."""
    peaks = np.array([r.push.peak for r in results])
    det = np.array([r.detected for r in results])
    a10 = np.array([r.above10 for r in results])
    resp_min = float(peaks[det].min()) if det.any() else None
    if a10.any():
        miss = peaks[~a10]
        worst_miss = float(miss.max()) if len(miss) else -np.inf
        beyond = peaks[a10 & (peaks > worst_miss)]
        above10_from = float(beyond.min()) if len(beyond) else None
    else:
        above10_from = None
    d = {
        "pushes": len(results),
        "peak_range": [float(peaks.min()), float(peaks.max())] if len(peaks) else None,
        "detected": int(det.sum()),
        "response_min": resp_min,
        "above10_min": float(peaks[a10].min()) if a10.any() else None,
        "above10_from": above10_from,
        "error_rms": float(np.sqrt(np.mean([r.error_rms**2 for r in results]))),
        "width": float(np.mean([r.width for r in results])),
        "coverage": float(np.mean([r.coverage for r in results])),
        "never_detected_max": float(peaks[~det].max()) if (~det).any() else None,
    }
    d["curve"] = fit_logistic(peaks, det, n_boot=n_boot, seed=seed)
    return d


def analyse(
    estimates: Sequence[Any],
    *,
    quantile: float = 0.999,
    floor: float = 1.0,
    big: float = 10.0,
    lag: float = 0.3,
    rest_margin: float = 1.0,
    n_boot: int = 200,
    seed: int = 0,
) -> dict[str, Any]:
    """Pushes, noise levels and the detection statistics of every variant.

    Parameters
    ----------
    estimates : :class:`ditherlab.replay.Estimates` objects (with the F/T columns)
    quantile : noise level = this quantile of ``|F̂_axis|`` at rest ...
    floor : ... but at least this [N]: a variant whose estimate is exactly zero at rest (all
        joints inside their bands) would otherwise count any 1e-9 N as a response
    big : the "significant" estimate [N]
    lag, rest_margin : see :func:`push_results` and :func:`rest_mask` [s]
    n_boot, seed : bootstrap of the detection curve

    Returns
    -------
    dict (JSON-ready): ``definitions``, ``recordings`` (pushes per file), ``conditions`` (per
    condition: noise level per axis, coverage, per-direction statistics), ``paper``.

    Raises
    ------
    NoPushesError
        An estimates file without the F/T columns, or no pushes in any file.
    """
    groups: dict[str, Group] = {}
    recs_out = []
    total_pushes = 0
    for est in estimates:
        rec_out, pushes, rest = _pushes_and_rest(est, rest_margin)
        recs_out.append(rec_out)
        total_pushes += len(pushes)
        if pushes:
            _add_variants(groups, est, pushes, rest, rec_out["dithered"], quantile, floor, lag, big)
    if total_pushes == 0:
        names = ", ".join(r["file"] for r in recs_out)
        raise NoPushesError(
            f"{names}: no pushes found (the F/T force never rose above the push threshold); "
            "the report needs push experiments"
        )
    conditions = {
        cond: _condition_stats(g, n_boot, seed + 100 * ci)
        for ci, (cond, g) in enumerate(sorted(groups.items()))
    }
    return {
        "definitions": {
            "noise_level": f"{quantile:.1%} quantile of |F_hat| along the axis at rest, at least "
            f"{floor:g} N (rest: more than "
            f"{rest_margin:g} s from any push, robot still"
            f"{', dither on' if any(r['dithered'] for r in recs_out) else ''}), "
            "per recording; the largest over recordings",
            "response": f"largest estimate along the push axis (sign of the sensor) within the "
            f"push and {lag:g} s after it",
            "response_min": "smallest applied force among pushes whose response exceeded the noise level",
            "above10_from": f"smallest applied force beyond which every push's response exceeded {big:g} N",
            "curve": "logistic P(response | F), ML on a grid; F50, F90 with 90 % bootstrap intervals over pushes",
            "sign": "applied force P = -F_sensor (the sensor holds the wrench the robot exerts)",
        },
        "recordings": recs_out,
        "conditions": conditions,
        "paper": PAPER,
    }


def _pushes_and_rest(est: Any, rest_margin: float) -> tuple[dict[str, Any], list[Push], np.ndarray]:
    """One estimates file's pushes (from its F/T columns) and rest mask (N,): away from pushes,
    the robot still, and the dither on where the file has it; with its summary row."""
    where = est.name or "estimates"
    if not est.has_wrench:
        raise NoPushesError(
            f"{where}: no F/T columns f_x..m_z, so no pushes to find; the report needs "
            "estimates of a recording with a reference sensor"
        )
    t = est.t
    pushes = find_pushes(t, est.wrench)
    dith = est.dither
    dithered = bool(dith is not None and dith.any())
    rest = rest_mask(t, pushes, rest_margin)
    for t0, t1 in est.meta.get("moving_spans", []):
        rest &= ~((t >= t0 - 0.5) & (t <= t1 + 0.5))
    if dithered:
        rest &= dith
    row = {
        "file": where,
        "dithered": dithered,
        "samples": len(t),
        "pushes": [asdict(p) for p in pushes],
        "rest_samples": int(rest.sum()),
    }
    return row, pushes, rest


def _add_variants(
    groups: dict[str, Group],
    est: Any,
    pushes: list[Push],
    rest: np.ndarray,
    dithered: bool,
    quantile: float,
    floor: float,
    lag: float,
    big: float,
) -> None:
    """Add every variant of one estimates file to its condition's group: noise level per axis
    at rest, push results, interval coverage (all samples, at rest) and width at rest."""
    t, Fs = est.t, est.wrench
    for v in est.variants:
        cond = condition_of(v, dithered)
        g = groups.setdefault(cond, Group(cond, v, dithered))
        Fh = est.F(v)
        lo, hi = est.interval(v)
        noise = {}
        for k, a in enumerate(AXES):
            vals = np.abs(Fh[rest, k])
            q = float(np.quantile(vals, quantile)) if len(vals) else float("nan")
            noise[a] = max(q, floor) if np.isfinite(q) else float("nan")
            g.noise[a].append(noise[a])
        g.results += push_results(t, Fs, Fh, lo, hi, pushes, noise, lag=lag, big=big)
        cov = (lo[:, :3] <= Fs[:, :3]) & (Fs[:, :3] <= hi[:, :3])
        g.all_coverage.append(float(cov.mean()))
        g.rest_coverage.append(float(cov[rest].mean()) if rest.any() else float("nan"))
        wr = (hi - lo)[rest, :3]
        g.rest_width.append(
            float(np.mean(wr[np.isfinite(wr)])) if np.isfinite(wr).any() else float("nan")
        )


def _condition_stats(g: Group, n_boot: int, seed: int) -> dict[str, Any]:
    """The JSON-ready statistics of one condition (per direction, seeded ``seed + axis``)."""
    dirs = {}
    for ai, a in enumerate(AXES):
        rs = [r for r in g.results if r.push.axis == a]
        if rs:
            dirs[a] = direction_stats(rs, n_boot, seed + ai)
    return {
        "variant": g.variant,
        "dithered": g.dithered,
        "noise_level": {a: float(np.nanmax(v)) if v else None for a, v in g.noise.items()},
        "coverage_all": float(np.nanmean(g.all_coverage)),
        "coverage_rest": float(np.nanmean(g.rest_coverage)),
        "width_rest": float(np.nanmean(g.rest_width)),
        "directions": dirs,
        "pushes": [
            {
                "start": r.push.start,
                "axis": r.push.axis,
                "sign": r.push.sign,
                "peak": r.push.peak,
                "response": r.response,
                "detected": r.detected,
                "above10": r.above10,
            }
            for r in g.results
        ],
    }

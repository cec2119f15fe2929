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
  10 N (the paper: "an applied force of 40 N was needed"; the issue's reading);
- ``above10_min``: the smallest applied force among the pushes whose estimate exceeded 10 N
  (the same sentence read as the first statistic is worded, "no force smaller than ... gave").

plus a logistic detection curve ``P(response | F) = 1 / (1 + exp(-(F - F50) / s))`` fitted by
maximum likelihood (on a grid, which stays finite when the data separate perfectly), with
``F90 = F50 + s ln 9`` and percentile intervals from a seeded bootstrap over pushes; the RMS of the
force error during pushes, and the width and coverage of the interval during pushes.

Signs: the sensor columns hold the wrench the robot exerts, ``F = -P`` for an applied force ``P``
(``docs/recording-format.md``). A push's ``sign`` is the sign of the applied force ``P`` along its axis; its
``peak`` is ``max |F_axis|`` over the push [N].
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from ditherlab.analysis.curves import fit_logistic
from ditherlab.analysis.steady import steady_dither
from ditherlab.core.errors import DitherlabError, FormatError, RecordingError
from ditherlab.core.names import FORCE_AXES
from ditherlab.core.timeseries import merge_runs, runs
from ditherlab.data.estimates import COMPONENTS, Estimates, EstimatesSource

AXES = FORCE_AXES
#: rows of an estimates file read at a time by :func:`analyse` (memory grows with it)
CHUNK_ROWS = 65_536
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


class NoRestError(RecordingError):
    """Estimates with pushes but no rest to measure the noise level they are judged against."""


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
    wrench : (N, 6) or (N, 3) [N, N·m] sensor columns ``f_x .. m_z`` (the forces first)
    threshold : [N] start of a push (it ends below half of it); default ``max(1 N, 6 sigma)``
        with sigma the sensor noise from first differences of ``|f|``
    min_duration : shorter stretches are ignored [s]
    merge_gap : stretches closer than this are one push [s]

    Returns
    -------
    list of Push, in time order
    """
    f = np.asarray(wrench, dtype=float)[:, :3]
    return find_pushes_in_blocks(
        t, lambda: iter([f]), threshold=threshold, min_duration=min_duration, merge_gap=merge_gap
    )


def find_pushes_in_blocks(
    t: np.ndarray,
    blocks: Callable[[], Iterable[np.ndarray]],
    *,
    threshold: float | None = None,
    min_duration: float = 0.1,
    merge_gap: float = 0.15,
) -> list[Push]:
    """:func:`find_pushes` over forces read a block of rows at a time (a long log).

    ``blocks()`` gives the forces ``f_x, f_y, f_z`` (m, 3) [N] of consecutive rows, from the
    first row to the last; it is called twice (the magnitudes, then the rows of the pushes). Only
    ``t`` and the magnitude (8 bytes per sample each) and one push's rows are held. The result
    is :func:`find_pushes` of the whole arrays, exactly.
    """
    t = np.asarray(t, dtype=float)
    mag = np.empty(len(t))
    a = 0
    for f in blocks():
        f = np.asarray(f, dtype=float)
        b = a + len(f)
        mag[a:b] = np.sqrt(f[:, 0] ** 2 + f[:, 1] ** 2 + f[:, 2] ** 2)
        a = b
    if a != len(t):
        raise DitherlabError(f"force blocks hold {a} rows, expected {len(t)} (one per t)")
    segs = _push_segments(t, mag, threshold, min_duration, merge_gap)
    del mag
    out: list[Push] = []
    parts: list[np.ndarray] = []
    k, a = 0, 0
    for f in blocks():
        f = np.asarray(f, dtype=float)
        b = a + len(f)
        while k < len(segs) and segs[k][0] < b:
            s, e = segs[k]
            parts.append(f[max(s, a) - a : min(e, b) - a, :3])
            if e > b:
                break  # the push goes on in the next block
            out.append(_push_of(t, np.concatenate(parts), s, e))
            parts, k = [], k + 1
        a = b
    return out


def _push_segments(
    t: np.ndarray,
    mag: np.ndarray,
    threshold: float | None,
    min_duration: float,
    merge_gap: float,
) -> list[tuple[int, int]]:
    """The pushes' sample ranges ``[s, e)`` from the force magnitude ``mag`` (N,) [N]."""
    if threshold is None:
        d = np.diff(mag)
        sig = float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2) if len(d) else 0.0
        del d
        threshold = max(1.0, 6.0 * sig)
    below = mag < threshold
    base = float(np.median(mag[below])) if np.any(below) else 0.0
    del below
    hi_thr = base + threshold
    lo_thr = base + 0.5 * threshold
    starts, ends = runs(mag > lo_thr)
    peaked = np.array([np.any(mag[s:e] > hi_thr) for s, e in zip(starts, ends, strict=True)], bool)
    segs = merge_runs(t, starts[peaked], ends[peaked], merge_gap)
    return [(s, e) for s, e in segs if t[e - 1] - t[s] >= min_duration]


def _push_of(t: np.ndarray, seg: np.ndarray, s: int, e: int) -> Push:
    """The Push of rows ``[s, e)`` whose forces are ``seg`` (e - s, 3) [N]."""
    k = int(np.argmax(np.abs(seg).max(axis=0)))
    i = int(np.argmax(np.abs(seg[:, k])))
    return Push(
        start=float(t[s]),
        end=float(t[e - 1]),
        axis=AXES[k],
        sign=int(-np.sign(seg[i, k])) or 1,
        peak=float(abs(seg[i, k])),
        i0=int(s),
        i1=int(e),
    )


def rest_mask(t: np.ndarray, pushes: Sequence[Push], margin: float = 1.0) -> np.ndarray:
    """Samples farther than ``margin`` [s] before the start or after the end of every push, (N,).

    ``t`` increasing (as every recording's is)."""
    t = np.asarray(t, dtype=float)
    rest = np.ones(len(t), dtype=bool)
    for p in pushes:
        _clear(rest, t, p.start - margin, p.end + margin)
    return rest


def _clear(mask: np.ndarray, t: np.ndarray, t0: float, t1: float) -> None:
    """``mask[(t >= t0) & (t <= t1)] = False`` for increasing ``t``, in time log(N)."""
    mask[np.searchsorted(t, t0, "left") : np.searchsorted(t, t1, "right")] = False


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
    for p, t_end in zip(pushes, _window_ends(pushes, lag), strict=True):
        a = AXES.index(p.axis)
        nums = _push_numbers(
            t, F_sensor[:, a], F_hat[:, a], lo[:, a], hi[:, a], p.start, t_end, p.i0, p.i1
        )
        out.append(_push_result(p, nums, noise, big))
    return out


def _window_ends(pushes: Sequence[Push], lag: float) -> list[float]:
    """Per push, the end [s] of the window of its response: ``lag`` after it, capped at the
    next push's start."""
    starts = [p.start for p in pushes] + [np.inf]
    return [min(p.end + lag, starts[k + 1]) for k, p in enumerate(pushes)]


def _push_numbers(
    t: np.ndarray,
    fs: np.ndarray,
    fh: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    start: float,
    t_end: float,
    i0: int,
    i1: int,
) -> tuple[float, float, float, float]:
    """Response, error RMS, mean width and coverage of one push along its axis, from arrays
    (M,) [s, N] holding every row of the push ``[i0, i1)`` and of its window
    ``start <= t <= t_end`` (row indices into these arrays)."""
    win = (t >= start) & (t <= t_end)
    seg = fs[i0:i1]
    s = np.sign(seg[np.argmax(np.abs(seg))]) or 1.0
    resp = float(np.max(s * fh[win])) if win.any() else float("nan")
    err = fh[i0:i1] - seg
    w = hi[i0:i1] - lo[i0:i1]
    cov = (lo[i0:i1] <= seg) & (seg <= hi[i0:i1])
    width = float(np.mean(w[np.isfinite(w)])) if np.isfinite(w).any() else float("inf")
    return resp, float(np.sqrt(np.mean(err**2))), width, float(np.mean(cov))


def _push_result(
    p: Push, nums: tuple[float, float, float, float], noise: dict[str, float], big: float
) -> PushResult:
    resp, err_rms, width, coverage = nums
    return PushResult(
        push=p,
        response=resp,
        detected=bool(resp > noise[p.axis]),
        above10=bool(resp > big),
        error_rms=err_rms,
        width=width,
        coverage=coverage,
    )


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
    #: per recording, per axis (3,): coverage and mean interval width at rest [-, N]
    rest_coverage_axes: list[np.ndarray] = field(default_factory=list)
    rest_width_axes: list[np.ndarray] = field(default_factory=list)


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
    estimates: Sequence[Estimates | EstimatesSource],
    *,
    quantile: float = 0.999,
    floor: float = 1.0,
    big: float = 10.0,
    lag: float = 0.3,
    rest_margin: float = 1.0,
    n_boot: int = 200,
    seed: int = 0,
    chunk_rows: int = CHUNK_ROWS,
) -> dict[str, Any]:
    """Pushes, noise levels and the detection statistics of every variant.

    Parameters
    ----------
    estimates : :class:`ditherlab.data.estimates.Estimates` in memory, or
        :class:`ditherlab.data.estimates.EstimatesSource` s read ``chunk_rows`` rows at a time (with
        the F/T columns); the numbers do not depend on ``chunk_rows``
    quantile : noise level = this quantile of ``|F̂_axis|`` at rest ...
    floor : ... but at least this [N]: a variant whose estimate is exactly zero at rest (all
        joints inside their bands) would otherwise count any 1e-9 N as a response
    big : the "significant" estimate [N]
    lag, rest_margin : see :func:`push_results` and :func:`rest_mask` [s]
    n_boot, seed : bootstrap of the detection curve
    chunk_rows : rows per block of an estimates file

    Memory: per file its ``t`` column, the force magnitude and the rest mask (17 bytes per
    sample), one block of rows, the longest push's rows, and the largest ``1 - quantile`` of
    ``|F̂|`` at rest per variant and axis.

    Returns
    -------
    dict (JSON-ready): ``definitions``, ``recordings`` (pushes per file), ``conditions`` (per
    condition: noise level per axis, coverage, per-direction statistics), ``paper``.

    Raises
    ------
    NoPushesError
        An estimates file without the F/T columns, or no pushes in any file.
    NoRestError
        A file with pushes but no rest (the robot always moves): no noise level to judge them.
    """
    groups: dict[str, Group] = {}
    recs_out = []
    total_pushes = 0
    for est in estimates:
        src = est if isinstance(est, EstimatesSource) else EstimatesSource.of(est)
        rec_out, t, pushes, rest = pushes_and_rest(src, rest_margin, chunk_rows)
        recs_out.append(rec_out)
        total_pushes += len(pushes)
        if pushes and not rest.any():
            raise NoRestError(
                f"{src.name or 'estimates'}: {len(pushes)} pushes but no rest (the robot never "
                f"stands still more than {rest_margin:g} s from a push); the noise level that "
                "every detection is judged against is measured at rest; for the force error "
                "of a log without push experiments: ditherlab diagnose REC --model M"
            )
        if pushes:
            f = _File(src, t, pushes, rest, rec_out["dithered"])
            _add_variants(groups, f, _Judging(quantile, floor, lag, big, chunk_rows))
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
            "above10_min": f"smallest applied force among pushes whose response exceeded {big:g} N "
            '(the other reading of the paper\'s "an applied force of 40 N was needed")',
            "curve": "logistic P(response | F), ML on a grid; F50, F90 with 90 % bootstrap intervals over pushes",
            "sign": "applied force P = -F_sensor (the sensor holds the wrench the robot exerts)",
        },
        "recordings": recs_out,
        "conditions": conditions,
        "paper": PAPER,
    }


def pushes_of(src: EstimatesSource, chunk_rows: int = CHUNK_ROWS) -> tuple[np.ndarray, list[Push]]:
    """The time stamps (N,) [s] of an estimates file and its pushes (:func:`find_pushes` of its
    F/T columns), read ``chunk_rows`` rows at a time."""
    t = src.column("t").astype(float)
    cols = list(COMPONENTS[:3])
    pushes = find_pushes_in_blocks(
        t, lambda: (b.to_numpy(dtype=float) for b in src.blocks(chunk_rows, cols))
    )
    return t, pushes


def pushes_and_rest(
    src: EstimatesSource, rest_margin: float, chunk_rows: int
) -> tuple[dict[str, Any], np.ndarray, list[Push], np.ndarray]:
    """One estimates file's summary row, time stamps (N,) [s], pushes (from its F/T columns)
    and rest mask (N,): away from pushes, the robot still, and the dither on at its working
    amplitude (:func:`steady_dither`) where the file has it."""
    where = src.name or "estimates"
    if not src.has_wrench:
        raise NoPushesError(
            f"{where}: no F/T columns f_x..m_z, so no pushes to find; the report needs "
            "estimates of a recording with a reference sensor"
        )
    t, pushes = pushes_of(src, chunk_rows)
    dith = src.column("dither").astype(bool) if "dither" in src.columns else None
    dithered = bool(dith is not None and dith.any())
    rest = rest_mask(t, pushes, rest_margin)
    for t0, t1 in src.meta.get("moving_spans", []):
        _clear(rest, t, t0 - 0.5, t1 + 0.5)
    if dithered:
        rest &= steady_dither(src, dith)  # within the flag
    row = {
        "file": where,
        "dithered": dithered,
        "samples": len(t),
        "pushes": [asdict(p) for p in pushes],
        "rest_samples": int(rest.sum()),
    }
    return row, t, pushes, rest


class _Quantile:
    """``np.quantile(x, q)`` of a stream of ``n`` values (``n`` known in advance), keeping only
    the largest ``n - floor((n - 1) q) + 2``: the order statistics the quantile interpolates
    between. NaN when any value is NaN (as ``np.quantile``)."""

    def __init__(self, n: int, q: float):
        self.n, self.q = int(n), float(q)
        self.m = min(self.n, self.n - int(np.floor((self.n - 1) * self.q)) + 2)
        self.top = np.zeros(0)
        self.nan = False

    def add(self, x: np.ndarray) -> None:
        bad = np.isnan(x)
        if bad.any():
            self.nan, x = True, x[~bad]
        c = np.concatenate([self.top, x])
        if len(c) > self.m:
            c = np.partition(c, len(c) - self.m)[len(c) - self.m :]
        self.top = c

    def value(self) -> float:
        if self.n == 0 or self.nan:
            return float("nan")
        top = np.sort(self.top)
        # the values below the kept ones replaced by the smallest kept: the same order
        # statistics where the quantile reads them, so the same number bit for bit
        x = np.empty(self.n)
        x[: self.n - len(top)] = top[0]
        x[self.n - len(top) :] = top
        return float(np.quantile(x, self.q))


class _BlockMean:
    """The mean of a stream of values summed in consecutive blocks of :attr:`BLOCK` values of
    the stream (numpy's sum within a block, the blocks' sums in order): the same number however
    the stream is cut into pieces."""

    BLOCK = 1 << 16

    def __init__(self) -> None:
        self.total = 0.0
        self.count = 0
        self.buf = np.zeros(0)

    def add(self, x: np.ndarray) -> None:
        self.buf = np.concatenate([self.buf, np.ravel(x)])
        while len(self.buf) >= self.BLOCK:
            self.total += float(np.sum(self.buf[: self.BLOCK]))
            self.count += self.BLOCK
            self.buf = self.buf[self.BLOCK :]

    def mean(self) -> float:
        total = self.total + (float(np.sum(self.buf)) if len(self.buf) else 0.0)
        count = self.count + len(self.buf)
        return total / count if count else float("nan")


class _PushRows:
    """The rows of each push and of its response window, gathered across blocks; a push's
    numbers (:func:`_push_numbers`) per variant as soon as its last row is read."""

    def __init__(self, t: np.ndarray, pushes: list[Push], variants: list[str], lag: float):
        self.pushes, self.variants = pushes, variants
        ends = _window_ends(pushes, lag)
        self.t_end = ends
        # the rows [i0, stop) hold the push and its window start <= t <= t_end
        # (a push's window ends at the next one's start, so a push is complete in the block
        # where the next one starts: one push is gathered at a time)
        self.stop = [
            max(p.i1, int(np.searchsorted(t, e, "right")))
            for p, e in zip(pushes, ends, strict=True)
        ]
        self.k = 0
        self.parts: list[pd.DataFrame] = []
        self.nums: dict[str, list[tuple[float, float, float, float]]] = {v: [] for v in variants}

    def columns(self, axis: str) -> list[str]:
        out = ["t", f"f_{axis}"]
        for v in self.variants:
            out += [f"{v}/f_{axis}", f"{v}/f_{axis}_lo", f"{v}/f_{axis}_hi"]
        return out

    def add(self, block: pd.DataFrame, a: int) -> None:
        """Rows ``[a, a + len(block))`` of the file (at least the columns of :meth:`columns`)."""
        b = a + len(block)
        while self.k < len(self.pushes) and self.pushes[self.k].i0 < b:
            p, stop = self.pushes[self.k], self.stop[self.k]
            cols = self.columns(p.axis)
            self.parts.append(block.iloc[max(p.i0, a) - a : min(stop, b) - a][cols])
            if stop > b:
                return  # the push or its window goes on in the next block
            rows = (
                pd.concat(self.parts, ignore_index=True) if len(self.parts) > 1 else self.parts[0]
            )
            t = rows["t"].to_numpy(dtype=float)
            fs = rows[cols[1]].to_numpy(dtype=float)
            for i, v in enumerate(self.variants):
                fh, lo, hi = (rows[c].to_numpy(dtype=float) for c in cols[2 + 3 * i : 5 + 3 * i])
                self.nums[v].append(
                    _push_numbers(t, fs, fh, lo, hi, p.start, self.t_end[self.k], 0, p.i1 - p.i0)
                )
            self.parts, self.k = [], self.k + 1


class _Judging(NamedTuple):
    """How every estimates file of one :func:`analyse` is judged: the noise level is the
    ``quantile`` of ``|F̂|`` at rest, at least ``floor`` [N]; the response is read up to ``lag``
    [s] after a push; ``big`` [N] is the "significant" estimate; a file is read ``chunk_rows``
    rows at a time."""

    quantile: float
    floor: float
    lag: float
    big: float
    chunk_rows: int


class _File(NamedTuple):
    """One estimates file with pushes: its source, time ``t`` (N,) [s], its pushes, the rest
    mask ``rest`` (N,) and whether it is dithered."""

    src: EstimatesSource
    t: np.ndarray
    pushes: list[Push]
    rest: np.ndarray
    dithered: bool


@dataclass
class _VariantSums:
    """One pass over a file, per variant: the noise's quantile per axis at rest, the interval's
    coverage (all samples, count; at rest, per axis) and its width at rest (all axes, per
    axis), the pushes' numbers; ``rows`` read and ``n_rest`` rest samples."""

    noise_q: dict[str, list[_Quantile]]
    covered: dict[str, int]
    covered_rest: dict[str, np.ndarray]
    width: dict[str, _BlockMean]
    width_axes: dict[str, list[_BlockMean]]
    pushes: _PushRows
    rows: int
    n_rest: int


def _add_variants(groups: dict[str, Group], f: _File, how: _Judging) -> None:
    """Add every variant of one estimates file to its condition's group: noise level per axis
    at rest, push results, interval coverage (all samples, at rest) and width at rest."""
    variants = f.src.variants
    for v in variants:
        for c in [f"{v}/{c}{x}" for c in COMPONENTS for x in ("", "_lo", "_hi")]:
            if c not in f.src.columns:
                raise FormatError(f"{f.src.name}: column {c} is missing (variant {v} is listed)")
    sums = _variant_sums(f, how)
    a, n_rest = sums.rows, sums.n_rest
    for v in variants:
        cond = condition_of(v, f.dithered)
        g = groups.setdefault(cond, Group(cond, v, f.dithered))
        noise = {}
        for k, ax in enumerate(AXES):
            q = sums.noise_q[v][k].value()
            noise[ax] = max(q, how.floor) if np.isfinite(q) else float("nan")
            g.noise[ax].append(noise[ax])
        g.results += [
            _push_result(p, n, noise, how.big)
            for p, n in zip(f.pushes, sums.pushes.nums[v], strict=True)
        ]
        g.all_coverage.append(sums.covered[v] / (3 * a) if a else float("nan"))
        cr = sums.covered_rest[v] / n_rest if n_rest else np.full(len(AXES), np.nan)
        g.rest_coverage.append(float(np.mean(cr)))
        g.rest_coverage_axes.append(cr)
        g.rest_width.append(sums.width[v].mean())
        g.rest_width_axes.append(np.array([m.mean() for m in sums.width_axes[v]]))


def _variant_sums(f: _File, how: _Judging) -> _VariantSums:
    """Read the file ``how.chunk_rows`` rows at a time and sum what every variant needs."""
    variants, rest = f.src.variants, f.rest
    n_rest = int(rest.sum())
    sums = _VariantSums(
        noise_q={v: [_Quantile(n_rest, how.quantile) for _ in AXES] for v in variants},
        covered=dict.fromkeys(variants, 0),
        covered_rest={v: np.zeros(len(AXES), dtype=np.int64) for v in variants},
        width={v: _BlockMean() for v in variants},
        width_axes={v: [_BlockMean() for _ in AXES] for v in variants},
        pushes=_PushRows(f.t, f.pushes, variants, how.lag),
        rows=0,
        n_rest=n_rest,
    )
    a = 0
    for block in f.src.blocks(how.chunk_rows):
        b = a + len(block)
        r = rest[a:b]
        est = f.src.estimates(block)
        Fs = est.wrench
        for v in variants:
            Fh = est.F(v)
            lo, hi = est.interval(v)
            for k in range(len(AXES)):
                sums.noise_q[v][k].add(np.abs(Fh[r, k]))
            cov = (lo[:, :3] <= Fs[:, :3]) & (Fs[:, :3] <= hi[:, :3])
            sums.covered[v] += int(cov.sum())
            sums.covered_rest[v] += cov[r].sum(axis=0)
            wr = (hi - lo)[r, :3]
            sums.width[v].add(wr[np.isfinite(wr)])
            for k in range(len(AXES)):
                wk = wr[:, k]
                sums.width_axes[v][k].add(wk[np.isfinite(wk)])
        sums.pushes.add(block, a)
        a = b
    sums.rows = a
    return sums


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
        "coverage_rest_axes": _axes_mean(g.rest_coverage_axes),
        "width_rest_axes": _axes_mean(g.rest_width_axes),
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


def _axes_mean(rows: list[np.ndarray]) -> dict[str, float | None]:
    """Axis -> the mean over recordings of per-recording values (each (3,)), NaN-skipping;
    None where no recording has one (JSON-ready)."""
    if not rows:
        return dict.fromkeys(AXES)
    m = np.array(rows, dtype=float)
    out: dict[str, float | None] = {}
    for k, a in enumerate(AXES):
        col = m[:, k][np.isfinite(m[:, k])]
        out[a] = float(col.mean()) if len(col) else None
    return out

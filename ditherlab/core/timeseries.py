"""Pure numpy helpers on sampled signals: runs of a mask, causal window means, derivatives,
stick transitions, the F/T low-pass, ``J^T F``.

Nothing here knows a recording, a robot or a model: arrays in, arrays out, time as the first
axis. Every other module imports these; they import nothing of ditherlab.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.core.names import MOVING

#: Savitzky–Golay window of :func:`smooth_derivative` [s]
DERIVATIVE_WINDOW_S = 0.04


def jtf(J: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``J^T F`` per sample: the joint torques of a wrench at the tool point.

    Parameters
    ----------
    J : (N, 6, n) tool-point Jacobian in base axes [m, -]
    F : (N, 6) [N, N·m] wrench at the tool point in base axes

    Returns
    -------
    (N, n) [N·m]
    """
    return np.einsum("tkn,tk->tn", J, F)


def smooth_derivative(
    t: np.ndarray,
    x: np.ndarray,
    window_s: float = DERIVATIVE_WINDOW_S,
    *,
    dt: float | None = None,
    uniform: bool | None = None,
) -> np.ndarray:
    """Time derivative of sampled signals by a local quadratic least-squares fit over
    ``window_s`` (a Savitzky–Golay derivative on the actual time stamps).

    Plain differencing of a velocity amplifies its noise by 1/dt (at 250 Hz, 250x); the
    quadratic fit over ~40 ms keeps motions (a robot's accelerations last far longer) and damps
    the noise about 20x. The window holds ``w`` samples (odd, at least 5) for the median step;
    near the ends it is the first or last ``w`` samples. On a uniform time base (steps equal to
    1e-6 of a step) this is :func:`scipy.signal.savgol_filter` (fast path); on a jittered one
    (vendor logs) each sample's quadratic is fitted on the real time stamps
    (:func:`local_quadratic_derivative`), which is exact for a quadratic whatever the jitter.
    Fewer than 7 samples give zeros.

    Parameters
    ----------
    t : (N,) [s], increasing
    x : (N, n) any unit u
    window_s : [s]
    dt, uniform : the median step [s] and whether the time base is uniform, when ``t`` is a
        piece of a longer recording (:class:`ditherlab.data.recording.TimeBase`); default: from ``t``

    Returns
    -------
    (N, n) [u/s]
    """
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    N = len(t)
    if N < 7:
        return np.zeros_like(x)
    steps = np.diff(t)
    if dt is None:
        dt = float(np.median(steps))
    if uniform is None:
        uniform = bool(np.max(np.abs(steps - dt)) <= 1e-6 * dt)
    w = max(5, int(round(window_s / dt)) | 1)
    w = min(w, N - (1 - N % 2))
    if uniform:
        return savgol(x, w, deriv=1, delta=dt)
    return local_quadratic_derivative(t, x, w, span=dt * max(w // 2, 1))


def savgol(x: np.ndarray, w: int, deriv: int = 0, delta: float = 1.0, order: int = 2) -> np.ndarray:
    """Savitzky–Golay filter along the first axis: at each sample the value (``deriv = 0``) or
    a derivative of the least-squares polynomial of degree ``order`` through the ``w`` samples
    centred on it (``w`` odd, ``order < w <= N``); the first and last ``w // 2`` samples use the
    polynomial of the first or last ``w`` samples (scipy's ``mode="interp"``).

    What :func:`scipy.signal.savgol_filter` computes (tested against it to 1e-12), without
    importing scipy.signal (slow to import: it would lengthen every command's start).

    Parameters
    ----------
    x : (N, ...) any unit u ; w : window [samples] ; deriv : derivative order ; delta : step [s]

    Returns
    -------
    (N, ...) [u / s^deriv]
    """
    x = np.asarray(x, dtype=float)
    N, h = len(x), w // 2
    if w % 2 == 0 or not order < w <= N or not 0 <= deriv <= order:
        raise ValueError(
            f"savgol: window {w} must be odd, above {order} and at most {N}, and the "
            f"derivative {deriv} at most {order}"
        )
    # the weights of the centred window: row `deriv` of the pseudo-inverse of the Vandermonde
    V = np.arange(-h, h + 1, dtype=float)[None, :] ** np.arange(order + 1)[:, None]
    e = np.zeros(order + 1)
    e[deriv] = math.factorial(deriv) / delta**deriv
    c, *_ = np.linalg.lstsq(V, e, rcond=None)
    y = np.empty_like(x)
    y[h : N - h] = c[0] * x[: N - 2 * h]
    for m in range(1, w):
        y[h : N - h] += c[m] * x[m : N - 2 * h + m]
    # the edges: the polynomial of the first / last w samples, at their first / last h points
    for start, at in ((0, np.arange(h)), (N - w, np.arange(w - h, w))):
        seg = x[start : start + w].reshape(w, -1)
        p = np.polyfit(np.arange(w, dtype=float), seg, order)
        for _ in range(deriv):
            p = p[:-1] * np.arange(len(p) - 1, 0, -1)[:, None]
        vals = np.stack([np.polyval(p[:, k], at) for k in range(p.shape[1])], axis=1)
        y[start + at] = (vals / delta**deriv).reshape((len(at), *x.shape[1:]))
    return y


def local_quadratic_derivative(
    t: np.ndarray, x: np.ndarray, w: int, chunk: int = 32768, span: float | None = None
) -> np.ndarray:
    """Derivative at every sample of the quadratic fitted by least squares to the ``w`` samples
    around it (odd ``w``; the first/last ``w`` samples near the ends), on the time stamps ``t``.

    The reference of :func:`smooth_derivative` and its path for jittered time bases.

    Parameters
    ----------
    t : (N,) [s] ; x : (N,) or (N, n) any unit u ; w : window [samples], 3 <= w <= N
    span : [s] the time scale of the fit's normal equations (default: median step × w // 2)

    Returns
    -------
    same shape as x [u/s]
    """
    x = np.asarray(x, dtype=float)
    flat = x.ndim == 1
    X = x[:, None] if flat else x.reshape(len(x), -1)
    N = len(t)
    h = w // 2
    start = np.clip(np.arange(N) - h, 0, N - w)
    out = np.empty_like(X)
    if span is None:  # scale: the normal equations stay O(1)
        span = float(np.median(np.diff(t))) * max(h, 1)
    for a in range(0, N, chunk):
        b = min(a + chunk, N)
        idx = start[a:b, None] + np.arange(w)[None, :]
        u = (t[idx] - t[a:b, None]) / span  # (c, w)
        V = np.stack([np.ones_like(u), u, u * u], axis=2)  # (c, w, 3)
        A = np.einsum("cwi,cwj->cij", V, V)
        rhs = np.einsum("cwi,cwn->cin", V, X[idx])
        coef = np.linalg.solve(A, rhs)  # (c, 3, n)
        out[a:b] = coef[:, 1, :] / span
    return out[:, 0] if flat else out.reshape(x.shape)


#: low-pass window for the F/T sensor in residuals [s]
WRENCH_SMOOTH_S = 0.1


def smooth_wrench(
    F: np.ndarray, sample_rate: float, window_s: float = WRENCH_SMOOTH_S
) -> np.ndarray:
    """F/T columns ``F`` (N, 6) [N, N·m] low-passed by a quadratic Savitzky–Golay filter over
    ``window_s`` [s] (its noise std falls about 3× for 0.1 s at 250 Hz).

    Why: the sensor's white noise enters the torque residual through ``J^T F``; unfiltered, any
    effect that scales ``J^T F`` (``attenuation_lag`` with a gain below 1) "explains" that noise
    (errors in variables). Pushes and contacts last far longer than the window.
    """
    if not math.isfinite(sample_rate):  # a one-sample log without a stated rate
        return np.asarray(F, dtype=float)
    w = int(round(window_s * sample_rate)) | 1
    if w < 5 or len(F) <= w:
        return np.asarray(F, dtype=float)
    return savgol(np.asarray(F, dtype=float), w)


def causal_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Mean over the last ``w`` samples (fewer at the start), per column.

    Each output is the sum of its own window, added oldest first, over the count: the value at
    a sample does not depend on where the array starts (a running cumulative sum would carry the
    rounding of everything before it), so a piece of a long log with ``w - 1`` rows of context
    gives the whole log's values exactly (:mod:`ditherlab.io.stream`).

    Parameters
    ----------
    x : (N, ...) any unit
    w : window [samples]

    Returns
    -------
    (N, ...), same unit
    """
    x = np.asarray(x, dtype=float)
    N = len(x)
    w = max(int(w), 1)
    acc = np.zeros_like(x)
    for k in range(min(w, N) - 1, -1, -1):
        # the sample k steps back, for every row that has one (zeros add nothing before it)
        acc[k:] += x[: N - k]
    cnt = np.minimum(np.arange(1, N + 1), w).reshape((-1,) + (1,) * (x.ndim - 1))
    return acc / cnt


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of True in ``mask`` (N,) bool, as sample indices ``[start, end)``.

    Returns
    -------
    starts, ends : (R,) int
        First sample of each run, and the first sample after it (``N`` for a run at the end).
    """
    e = np.diff(np.r_[0, np.asarray(mask, dtype=bool).astype(np.int8), 0])
    return np.flatnonzero(e == 1), np.flatnonzero(e == -1)


def merge_runs(
    t: np.ndarray, starts: Sequence[int], ends: Sequence[int], gap: float
) -> list[tuple[int, int]]:
    """Runs ``[start, end)`` (in time order) merged where less than ``gap`` [s] apart.

    Parameters
    ----------
    t : (N,) [s]
    starts, ends : (R,) sample indices, e.g. from :func:`runs`
    gap : [s] from the last sample of one run to the first of the next

    Returns
    -------
    list of (start, end) sample indices, in time order
    """
    merged: list[list[int]] = []
    for a, b in zip(starts, ends, strict=True):
        if merged and t[a] - t[merged[-1][1] - 1] < gap:
            merged[-1][1] = int(b)
        else:
            merged.append([int(a), int(b)])
    return [(a, b) for a, b in merged]


def time_spans(t: np.ndarray, mask: np.ndarray) -> list[list[float]]:
    """``[[t_start, t_end], ...]`` [s] of the runs of True in ``mask`` (N,)."""
    s0, s1 = runs(mask)
    return [[float(t[a]), float(t[b - 1])] for a, b in zip(s0, s1, strict=True)]


#: a joint stopped for at least this long has stuck [s]
MIN_STICK_S = 0.04
#: moving samples this close to a stick are break-away / stopping transients [s]
STICK_SETTLE_S = 0.2
#: moving samples slower than this are a velocity reversal (the regime threshold) [rad/s]
REVERSAL_V = 5e-3
#: a moving run at least this long is a motion (shorter: a slip) [s]
MIN_MOTION_S = 0.5


def stick_transitions(
    reg: np.ndarray,
    sample_rate: float,
    min_stick_s: float = MIN_STICK_S,
    settle_s: float = STICK_SETTLE_S,
    min_motion_s: float = MIN_MOTION_S,
) -> np.ndarray:
    """(N, n) bool: the first and last ``settle_s`` [s] of every motion that starts or ends in a
    stick.

    A stick is a run of at least ``min_stick_s`` [s] of non-moving samples of one joint
    (``reg`` (N, n) from :func:`ditherlab.data.recording.regimes`); a motion is a run of at least
    ``min_motion_s`` [s] of moving samples. Where a motion leaves or enters a stick, the
    friction passes between the static level Fs and the sliding level Fc (break-away) while the
    servo and the gear spring settle: a transient that neither the band nor the sliding line
    describes. A velocity reversal of continuous motion (a few non-moving samples) is not a stick.
    A short slip between sticks (shorter than ``min_motion_s``, e.g. a pose giving way under a
    push beyond the band) is break-away and stop with nothing in between: it is marked whole
    (on the simulator such slips of a wrist joint leave a residual far above the noise floor).

    Parameters
    ----------
    reg : (N, n) int
        Regime codes (:class:`~ditherlab.core.names.Regime`).
    sample_rate : float [Hz]
    min_stick_s, settle_s, min_motion_s : float [s]

    Returns
    -------
    (N, n) bool
    """
    N, n = reg.shape
    out = np.zeros((N, n), dtype=bool)
    if not math.isfinite(sample_rate):  # a one-sample log without a stated rate: no run
        return out
    lmin = max(1, int(round(min_stick_s * sample_rate)))
    lmot = max(1, int(round(min_motion_s * sample_rate)))
    g = int(round(settle_s * sample_rate))
    if g <= 0:
        return out
    for j in range(n):
        mv = reg[:, j] == MOVING
        d = np.diff(np.r_[0, mv.astype(np.int8), 0])
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
            before = a - (ends[k - 1] if k > 0 else 0)
            after = (starts[k + 1] if k + 1 < len(starts) else N) - b
            if b - a < lmot:
                if a > 0 and b < N and before >= lmin and after >= lmin:
                    out[a:b, j] = True
                continue
            if a > 0 and before >= lmin:
                out[a : min(b, a + g), j] = True
            if b < N and after >= lmin:
                out[max(a, b - g) : b, j] = True
    return out


def tmm(W: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``W.T @ X`` for tall skinny matrices ``W (M, f)``, ``X (M, p)`` (any units; the result
    ``(f, p)`` in their product) without BLAS threads, which oversubscribe a shared machine
    where this single-threaded loop does not."""
    return np.einsum("mf,mp->fp", W, X)


# ------------------------------------------------------------------ the dither's period
#: samples of feedforward the dither period is measured on (about 9 min at 250 Hz): enough for
#: thousands of crossings, and a long log is not read whole for it
PERIOD_SAMPLES = 131_072


def period_from_feedforward(tau_ffw, t) -> float:
    """The dither period [s] from the zero crossings of the dither feedforward.

    Half-periods are the intervals between sign changes of ``tau_ffw - median``; those within
    25 % of their median are averaged (gaps where the dither is off are ignored).

    Parameters
    ----------
    tau_ffw : (N,) or (N, n) [N·m]
        The dither feedforward; with several joints the one with the most crossings is used.
    t : (N,) [s]

    Raises
    ------
    ConfigError
        Fewer than four sign changes (no dither in the feedforward).
    """
    f = np.asarray(tau_ffw, dtype=float)
    t = np.asarray(t, dtype=float)
    if f.ndim == 1:
        f = f[:, None]
    best = None
    for j in range(f.shape[1]):
        x = f[:, j] - np.median(f[:, j])
        sgn = np.signbit(x)
        idx = np.flatnonzero(sgn[1:] != sgn[:-1])
        if best is None or len(idx) > len(best[1]):
            best = (j, idx, x)
    j, idx, x = best
    if len(idx) < 4:
        raise ConfigError(
            f"dither: tau_ffw has {len(idx)} sign changes; expected a dither square wave "
            "(give the period instead)"
        )
    # crossing times, linearly interpolated between the samples around each sign change
    x0, x1 = x[idx], x[idx + 1]
    # (+0.0 and -0.0 differ in sign bit only: the crossing is halfway, without a 0/0 warning)
    step = x0 - x1
    frac = np.divide(x0, step, out=np.full(len(x0), 0.5), where=step != 0)
    tc = t[idx] + frac * (t[idx + 1] - t[idx])
    half = np.diff(tc)
    med = np.median(half)
    good = np.abs(half - med) <= 0.25 * med
    return float(2.0 * half[good].mean())


def period_from_spectrum(seg: np.ndarray, fs: float, name: str | None = None) -> float:
    """The dither period [s]: the strongest spectral line above 2 Hz of a dithered stretch of
    torque ``seg`` (M, n) [N·m] sampled at ``fs`` [Hz] (parabolic peak refinement)."""
    if len(seg) < 32:
        raise ConfigError(
            f"{name or 'recording'}: only {len(seg)} samples with the dither on; "
            "cannot find its period"
        )
    seg = seg - seg.mean(axis=0)
    spec = (np.abs(np.fft.rfft(seg * np.hanning(len(seg))[:, None], axis=0)) ** 2).sum(axis=1)
    f = np.fft.rfftfreq(len(seg), 1.0 / fs)
    spec[f < 2.0] = 0.0
    i = int(np.argmax(spec))
    if 0 < i < len(spec) - 1:  # parabolic refinement of the peak
        y0, y1, y2 = np.log(spec[i - 1 : i + 2] + 1e-300)
        den = y0 - 2 * y1 + y2
        delta = 0.5 * (y0 - y2) / den if den != 0 else 0.0
        fpk = f[i] + delta * (f[1] - f[0])
    else:
        fpk = f[i]
    if fpk <= 0:
        raise ConfigError(f"{name or 'recording'}: no dither line found in the spectrum")
    return float(1.0 / fpk)


def autocorrelation_time(x: np.ndarray, max_lag: int = 1000) -> float:
    """Integrated autocorrelation time [samples] of a series x (N,) (>= 1): ``1 + 2 Σ ρ_k``,
    summed until the autocorrelation ρ drops below 0.05 (at most ``max_lag`` lags). N samples
    of the series carry about as much information as N / this many independent ones."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    n = len(x)
    if n < 10 or not np.any(x):
        return 1.0
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: min(max_lag, n - 1) + 1]
    ac = ac / ac[0]
    s = 0.0
    for k in range(1, len(ac)):
        if ac[k] < 0.05:
            break
        s += ac[k]
    return 1.0 + 2.0 * s

"""Dither: the square wave, the extraction of the torque signal, and the band variants (§III-B, §IV).

The paper (§III-B) computes, over a causal window holding an integer number of whole dither
periods::

    centre    = mean(window)
    upper     = mean(window[window > centre])
    lower     = mean(window[window < centre])
    amplitude = (upper - lower) / 2

and (§IV-A, Fig. 4) uses ``signal = (upper + lower) / 2`` as the new torque signal: an external
torque shifts both sides of the dithered torque, and the mean of the two sides follows it with a
delay of about one window while the square wave itself cancels. With dither the friction band is
effectively shrunk by the dither amplitude on each side (Fig. 4), see :func:`dithered_band`; the
variant without the uniform term moves the band's variance into the Gaussian noise (§IV-C), see
:func:`band_as_noise`. For a recording, :func:`extract_dither` finds where the dither is on and
its period (:func:`dither_period`) and extracts the signal: the one extraction that identify,
diagnose and replay use (replay writes it to the estimates file, which report and view read).

The window holds ``round(periods * period / dt)`` samples. At 80 rad/s and 250 Hz one period is
19.63 samples, so a window of 20 samples holds 1.019 periods. Measured in
``tests/test_dither.py`` (amplitude A): on a clean square wave ``upper`` and ``lower`` are exact
(``signal`` has no ripple) and only ``centre`` ripples, by one unbalanced sample, ``2 A / W``;
through a 4 ms first-order lag (a servo-like edge) ``signal`` ripples by 3.7 % of A with one
period per window, 1.6 % with two and 1.0 % with three (59 samples for 58.9).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.errors import ConfigError
from ditherlab.recording import Recording
from ditherlab.signal import runs


@dataclass
class DitherSignal:
    """The per-window statistics of a dithered torque.

    Attributes
    ----------
    upper, lower : (N, n) [N·m]
        Mean of the window's samples above / below its centre.
    signal : (N, n) [N·m]
        ``(upper + lower) / 2``, the extracted torque signal (§IV-A).
    centre : (N, n) [N·m]
        Mean of the window.
    amplitude : (N, n) [N·m]
        ``(upper - lower) / 2``, the measured dither amplitude.
    window : int
        Samples per window (a whole number of dither periods, rounded).
    period : float [s]
        The dither period used.
    full : (N,) bool
        True where the window is full; the first ``window - 1`` samples use the samples so far.
    """

    upper: np.ndarray
    lower: np.ndarray
    signal: np.ndarray
    centre: np.ndarray
    amplitude: np.ndarray
    window: int
    period: float
    full: np.ndarray


def square_wave(t, omega: float, amplitude, phase: float = 0.0) -> np.ndarray:
    """The dither square wave ``amplitude * sign(sin(omega t + phase))`` (``sign(0) = +1``).

    Parameters
    ----------
    t : (N,) [s]
    omega : float [rad/s]
        Angular frequency (the paper uses 80 rad/s).
    amplitude : float or (n,) [N·m]
    phase : float [rad]

    Returns
    -------
    (N,) or (N, n) [N·m]
    """
    t = np.asarray(t, dtype=float)
    s = np.where(np.sin(omega * t + phase) >= 0.0, 1.0, -1.0)
    amp = np.asarray(amplitude, dtype=float)
    return s * amp if amp.ndim == 0 else s[:, None] * amp[None, :]


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
    frac = np.where(x1 != x0, x0 / (x0 - x1), 0.5)
    tc = t[idx] + frac * (t[idx + 1] - t[idx])
    half = np.diff(tc)
    med = np.median(half)
    good = np.abs(half - med) <= 0.25 * med
    return float(2.0 * half[good].mean())


def full_window(on: np.ndarray, window: int) -> np.ndarray:
    """Where ``on`` held for each of the last ``window`` samples, the current one included.

    Parameters
    ----------
    on : (N,) bool
        E.g. the dither flag.
    window : int
        Samples per window (>= 1).

    Returns
    -------
    (N,) bool
        False for the first ``window - 1`` samples (the window is not full yet).
    """
    on = np.asarray(on, dtype=bool)
    off = np.cumsum(np.r_[0, (~on).astype(np.int64)])
    idx = np.arange(len(on))
    lo = np.maximum(idx - window + 1, 0)
    return (off[idx + 1] - off[lo] == 0) & (idx >= window - 1)


def _window_stats(x: np.ndarray, W: int, chunk: int = 65536):
    """Causal window mean, and means above / below it, of every column of x (N, n)."""
    N, n = x.shape
    # centre by a cumulative sum (offset by the first sample to keep the sums small)
    off = x[0] if N else np.zeros(n)
    cs = np.cumsum(np.vstack([np.zeros((1, n)), x - off]), axis=0)
    k = np.arange(N)
    start = np.maximum(0, k - W + 1)
    count = (k - start + 1).astype(float)
    centre = (cs[k + 1] - cs[start]) / count[:, None] + off
    # upper / lower: per window a different threshold, so compare the window itself with it.
    # Pad the start with NaN (comparisons false) so that every sample has a window of W values.
    pad = np.vstack([np.full((W - 1, n), np.nan), x])
    upper = np.empty((N, n))
    lower = np.empty((N, n))
    for c0 in range(0, N, chunk):
        c1 = min(N, c0 + chunk)
        win = np.lib.stride_tricks.sliding_window_view(pad[c0 : c1 + W - 1], W, axis=0)  # (c, n, W)
        ctr = centre[c0:c1, :, None]
        above = win > ctr
        below = win < ctr
        na = above.sum(axis=2)
        nb = below.sum(axis=2)
        sa = np.where(above, win, 0.0).sum(axis=2)
        sb = np.where(below, win, 0.0).sum(axis=2)
        # no sample above (or below) the centre: a constant window; its level is the centre
        upper[c0:c1] = np.where(na > 0, sa / np.maximum(na, 1), centre[c0:c1])
        lower[c0:c1] = np.where(nb > 0, sb / np.maximum(nb, 1), centre[c0:c1])
    return centre, upper, lower


def extract(
    tau,
    t,
    period: float | None = None,
    tau_ffw=None,
    periods: int = 1,
) -> DitherSignal:
    """Extract the torque signal from a dithered torque (the paper's CALCDITHERSIGNALPARS).

    Parameters
    ----------
    tau : (N, n) or (N,) [N·m]
        Measured (gravity-compensated or raw) joint torque.
    t : (N,) [s]
        Sample times (uniform sampling assumed; the median step is used).
    period : float [s], optional
        Dither period (``2 pi / omega``; 80 rad/s -> 0.0785 s). Taken from ``tau_ffw`` when not
        given.
    tau_ffw : (N,) or (N, n) [N·m], optional
        The dither feedforward, used to find the period (:func:`period_from_feedforward`).
    periods : int
        Whole dither periods per window (the paper: an integer number of periods).

    Returns
    -------
    DitherSignal
        ``upper, lower, signal, centre, amplitude (N, n)`` (``(N,)`` for a 1-D ``tau``).
    """
    x = np.asarray(tau, dtype=float)
    one_d = x.ndim == 1
    if one_d:
        x = x[:, None]
    t = np.asarray(t, dtype=float)
    if x.ndim != 2 or t.shape != (x.shape[0],):
        raise ConfigError(
            f"dither: tau has shape {np.shape(tau)} and t {t.shape}; expected (N, n) and (N,)"
        )
    if not np.isfinite(x).all():
        k = int(np.argwhere(~np.isfinite(x))[0][0])
        raise ConfigError(f"dither: tau at sample {k} is not finite; expected finite torques")
    if int(periods) != periods or periods < 1:
        raise ConfigError(f"dither: periods is {periods!r}; expected a positive integer")
    if period is None:
        if tau_ffw is None:
            raise ConfigError("dither: neither period nor tau_ffw given; expected one of them")
        period = period_from_feedforward(tau_ffw, t)
    if not (np.isfinite(period) and period > 0):
        raise ConfigError(f"dither: period is {period!r}; expected a positive time [s]")
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    W = max(2, int(round(periods * period / dt)))
    centre, upper, lower = _window_stats(x, W)
    out = DitherSignal(
        upper=upper,
        lower=lower,
        signal=0.5 * (upper + lower),
        centre=centre,
        amplitude=0.5 * (upper - lower),
        window=W,
        period=float(period),
        full=np.arange(len(t)) >= W - 1,
    )
    if one_d:
        for k in ("upper", "lower", "signal", "centre", "amplitude"):
            setattr(out, k, getattr(out, k)[:, 0])
    return out


def dithered_band(tau_min, tau_max, amplitude, on=None) -> tuple[np.ndarray, np.ndarray]:
    """The friction band shrunk by the dither amplitude on each side (§IV-A, Fig. 4).

    ``tau_min' = tau_min + A``, ``tau_max' = tau_max - A``. When ``A >= (tau_max - tau_min) / 2``
    the band collapses to its midpoint (zero width) instead of inverting: the dither then covers
    the whole band and any external torque shows.

    Parameters
    ----------
    tau_min, tau_max : (n,) or (N, n) [N·m]
    amplitude : (n,) or (N, n) [N·m]
        Dither amplitude (e.g. :attr:`DitherSignal.amplitude`); negative values are treated as 0.
    on : bool array broadcasting against the band, optional
        Where the shrink applies (e.g. the dither was on over the whole window); the band is
        returned unchanged elsewhere. Default: everywhere.

    Returns
    -------
    tau_min', tau_max' : broadcast shape [N·m]
    """
    a = np.asarray(tau_min, dtype=float)
    b = np.asarray(tau_max, dtype=float)
    A = np.maximum(np.asarray(amplitude, dtype=float), 0.0)
    mid = 0.5 * (a + b)
    lo, hi = np.minimum(a + A, mid), np.maximum(b - A, mid)
    if on is None:
        return lo, hi
    return np.where(on, lo, a), np.where(on, hi, b)


def band_as_noise(tau_min, tau_max, sigma) -> np.ndarray:
    """Noise level with the uniform band moved into it: ``sqrt(sigma^2 + (b - a)^2 / 12)`` (§IV-C).

    The variant without the uniform term drops ``tau_f``: pass this ``sigma'`` to the estimator
    with a zero-width band at the band's midpoint (``tau_min = tau_max = (a + b) / 2``), so that
    the band's mean stays as an offset and its variance joins the Gaussian noise.

    Parameters
    ----------
    tau_min, tau_max, sigma : (n,) or (N, n) [N·m]

    Returns
    -------
    sigma' : broadcast shape [N·m]
    """
    a = np.asarray(tau_min, dtype=float)
    b = np.asarray(tau_max, dtype=float)
    s = np.asarray(sigma, dtype=float)
    return np.sqrt(s**2 + (b - a) ** 2 / 12.0)


# ------------------------------------------------------------------ a recording's dither
@dataclass
class Extraction:
    """The dither signal extracted from one recording (paper §IV-A).

    Attributes
    ----------
    upper, lower, signal, centre, amplitude : (N, n) [N·m]
        One-period means of the samples above / below the period mean, their average (the new
        torque signal), the period mean, and half their difference (the dither amplitude).
    on : (N,) bool
        Dither active.
    valid : (N,) bool
        Dither active over the whole one-period window ending at the sample.
    period : [s]
    """

    upper: np.ndarray
    lower: np.ndarray
    signal: np.ndarray
    centre: np.ndarray
    amplitude: np.ndarray
    on: np.ndarray
    valid: np.ndarray
    period: float


def dither_on(rec: Recording) -> np.ndarray | None:
    """Where the dither is active, (N,) bool: the ``dither`` column, else where the ``tau_ffw``
    square wave has a non-zero amplitude; None when the recording has neither."""
    if rec.dither is not None:
        return rec.dither
    ffw = rec.tau_ffw
    if ffw is None:
        return None
    period = dither_period(rec)
    w = max(int(round(period * rec.sample_rate)), 2)
    hi = pd.DataFrame(ffw).rolling(w, min_periods=1, center=True).max().to_numpy()
    lo = pd.DataFrame(ffw).rolling(w, min_periods=1, center=True).min().to_numpy()
    return ((hi - lo) > 1e-6).any(axis=1)


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


def dither_period(rec: Recording) -> float:
    """The dither period [s].

    From the metadata when it states it (``dither.omega`` [rad/s] or ``dither.period`` [s], also
    under ``sim``), else from the zero crossings of ``tau_ffw``
    (:func:`period_from_feedforward`), else the strongest spectral line above
    2 Hz of ``tau`` over the longest stretch with the dither on.
    """
    stated = meta_dither_period(rec.meta)
    if stated is not None:
        return stated
    if rec.tau_ffw is not None:
        ffw = rec.tau_ffw
        if rec.dither is not None and rec.dither.sum() > 8:
            ffw, tt = ffw[rec.dither], rec.t[rec.dither]
        else:
            tt = rec.t
        try:
            return period_from_feedforward(ffw, tt)
        except ConfigError:
            pass
    x = rec.tau
    on = rec.dither if rec.dither is not None else np.ones(len(rec), bool)
    starts, ends = runs(on)  # the longest run of dither-on samples
    if len(starts) == 0:
        raise ConfigError(f"{rec.name or 'recording'}: the dither is never on; no period to find")
    k = int(np.argmax(ends - starts))
    seg = x[starts[k] : ends[k]]
    seg = seg[: min(len(seg), 16384)]
    fs = rec.sample_rate
    if len(seg) < 32:
        raise ConfigError(
            f"{rec.name or 'recording'}: only {len(seg)} samples with the dither on; "
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
        raise ConfigError(f"{rec.name or 'recording'}: no dither line found in the spectrum")
    return float(1.0 / fpk)


def extract_dither(rec: Recording, tau: np.ndarray | None = None) -> Extraction | None:
    """Extract the torque signal of a dithered recording (paper §IV-A), or None without dither.

    Parameters
    ----------
    rec : Recording with a ``dither`` column or ``tau_ffw``
    tau : (N, n) [N·m], optional — the torque to extract from (default ``rec.tau``)

    Returns
    -------
    Extraction, or None when the recording has no dither information or the dither is never on.
    """
    on = dither_on(rec)
    if on is None or not on.any():
        return None
    period = dither_period(rec)
    x = rec.tau if tau is None else tau
    sig = extract(x, rec.t, period)
    w = max(int(round(period * rec.sample_rate)), 1)
    valid = full_window(on, w)  # the dither was on for the whole window (t - period, t]
    return Extraction(
        upper=np.asarray(sig.upper),
        lower=np.asarray(sig.lower),
        signal=np.asarray(sig.signal),
        centre=np.asarray(sig.centre),
        amplitude=np.asarray(sig.amplitude),
        on=on,
        valid=valid,
        period=period,
    )

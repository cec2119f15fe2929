"""Dither: the waveforms, the extraction of the torque signal, and the band variants (§III-B, §IV).

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

The window holds ``round(periods * period / dt)`` samples, the whole number nearest to the
dither's periods (at 80 rad/s and 250 Hz a period is not a whole number of samples). On a clean
square wave ``upper`` and ``lower`` are then exact and only ``centre`` ripples, by the one
unbalanced sample (``2 A / W`` for amplitude A); through a servo-like edge ``signal`` ripples a
little, less with more periods per window (``tests/test_dither.py``).

Waveforms (§VII left them open): ``square`` (the paper's), ``sine`` and ``triangle``
(:data:`WAVEFORMS`, :func:`wave`), each of unit peak, zero mean over whole periods and
positive on the first half period. A recording names its waveform in its metadata
(``dither.waveform``, :func:`dither_waveform`); without the key it is square. What this module
decides per waveform (``tests/test_dither_waveforms.py``; the reasoning:
``docs/design/physics-dither-window.md``):

- the **signal**. Each waveform is symmetric about its mean, so ``(upper + lower) / 2`` and the
  window mean both follow an external torque. For the square wave the paper's
  ``(upper + lower) / 2`` stays (no ripple on a clean square wave, where the window mean
  ripples). For a sine or a triangle the split above / below the centre moves with the partial
  period a whole-sample window holds, so ``(upper + lower) / 2`` ripples more than the window
  mean; the signal is therefore the mean over *exactly* ``periods`` periods (the oldest sample
  weighted by the fraction of it inside, :func:`_period_mean`), which hardly ripples at all.
- the **amplitude**. ``(upper - lower) / 2`` is the mean of ``|w|``: ``A`` for a square wave of
  peak ``A``, ``2 A / pi`` for a sine, ``A / 2`` for a triangle. What shrinks the friction band
  is the peak (the joint slips once ``centre + tau_ext + peak`` reaches the band's edge), so
  :attr:`DitherSignal.amplitude` is the peak, ``(upper - lower) / 2`` times :data:`PEAK_FACTOR`
  (1, pi/2, 2), and every band variant built on it (:func:`dithered_band`, identify's shrunk
  dither band, replay, view) is right for each waveform. ``upper``, ``lower`` and ``centre``
  stay the paper's statistics for every waveform.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numba import njit

from ditherlab.core.errors import ConfigError
from ditherlab.core.timeseries import (
    PERIOD_SAMPLES,
    period_from_feedforward,
    period_from_spectrum,
    runs,
)
from ditherlab.data.recording import Recording, meta_dither_period

if TYPE_CHECKING:
    from ditherlab.data.torque_model import TorqueModel


@dataclass
class DitherSignal:
    """The per-window statistics of a dithered torque.

    Attributes
    ----------
    upper, lower : (N, n) [N·m]
        Mean of the window's samples above / below its centre.
    signal : (N, n) [N·m]
        The extracted torque signal: ``(upper + lower) / 2`` (§IV-A) for the square wave, the
        mean over exactly ``periods`` whole periods for a sine or triangle (module docstring).
    centre : (N, n) [N·m]
        Mean of the window.
    amplitude : (N, n) [N·m]
        The measured dither amplitude (the peak): ``(upper - lower) / 2`` times the waveform's
        :data:`PEAK_FACTOR` (1 for the square wave).
    window : int
        Samples per window (a whole number of dither periods, rounded).
    period : float [s]
        The dither period used.
    full : (N,) bool
        True where the window is full (``window`` samples, and for a sine or triangle the
        fractional sample too); before, the samples so far are used.
    waveform : str
        The dither waveform (:data:`WAVEFORMS`).
    """

    upper: np.ndarray
    lower: np.ndarray
    signal: np.ndarray
    centre: np.ndarray
    amplitude: np.ndarray
    window: int
    period: float
    full: np.ndarray
    waveform: str = "square"


#: The dither waveforms: the paper's square wave and the two §VII left to try.
WAVEFORMS = ("square", "sine", "triangle")
#: Peak over mean absolute value of each unit-peak waveform: the dither's peak amplitude is
#: ``PEAK_FACTOR[w] * (upper - lower) / 2`` of the paper's window statistics [-].
PEAK_FACTOR = {"square": 1.0, "sine": math.pi / 2, "triangle": 2.0}

#: The dither counts as up (its ramp-in over, its ramp-out not begun) on a joint while the
#: extracted amplitude is at least this fraction of its median over the dithered samples:
#: the report's rest (:func:`ditherlab.analysis.steady.steady_dither`) and diagnosis's scoring
#: (:mod:`ditherlab.physics.residual`) leave the ramps out by it [-].
AMPLITUDE_UP_FRACTION = 0.8


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


def check_waveform(name: Any, where: str = "dither.waveform") -> str:
    """``name`` if it is one of :data:`WAVEFORMS`, else a ConfigError naming ``where`` and it."""
    if not isinstance(name, str) or name not in WAVEFORMS:
        raise ConfigError(f"{where} = {name!r}; expected one of {', '.join(WAVEFORMS)}")
    return name


def wave(t, omega: float, amplitude, waveform: str = "square", phase: float = 0.0) -> np.ndarray:
    """The dither ``amplitude * w(omega t + phase)`` for a unit-peak waveform ``w``.

    ``square``: ``sign(sin)`` with ``sign(0) = +1`` (:func:`square_wave`, bit for bit);
    ``sine``: ``sin``; ``triangle``: ``(2 / pi) asin(sin)``, linear between its peaks at
    ``omega t + phase = pi/2 (+1)`` and ``3 pi/2 (-1)``. The simulator's feedforward uses the
    same formulas (:mod:`ditherlab.sim.plant`).

    Parameters
    ----------
    t : (N,) [s]
    omega : float [rad/s]
    amplitude : float or (n,) [N·m] — the peak
    waveform : one of :data:`WAVEFORMS`
    phase : float [rad]

    Returns
    -------
    (N,) or (N, n) [N·m]
    """
    check_waveform(waveform, "waveform")
    if waveform == "square":
        return square_wave(t, omega, amplitude, phase)
    t = np.asarray(t, dtype=float)
    s = np.sin(omega * t + phase)
    if waveform == "triangle":
        s = (2.0 / np.pi) * np.arcsin(s)
    amp = np.asarray(amplitude, dtype=float)
    return s * amp if amp.ndim == 0 else s[:, None] * amp[None, :]


def dither_waveform(meta: Mapping[str, Any]) -> str:
    """The dither waveform a recording's metadata states: ``dither.waveform``, else the
    simulator's ``sim.params.dither.waveform``, else ``"square"`` (``docs/recording-format.md``:
    a recording without the key is square). A name not in :data:`WAVEFORMS` is a ConfigError."""
    d = meta.get("dither")
    if isinstance(d, Mapping) and d.get("waveform") is not None:
        return check_waveform(d["waveform"], "metadata key dither.waveform")
    sim = meta.get("sim")
    p = sim.get("params") if isinstance(sim, Mapping) else None
    d = p.get("dither") if isinstance(p, Mapping) else None
    if isinstance(d, Mapping) and d.get("waveform") is not None:
        return check_waveform(d["waveform"], "metadata key sim.params.dither.waveform")
    return "square"


def window_samples(period: float, sample_rate: float) -> int:
    """Samples in one dither period ``period`` [s] at ``sample_rate`` [Hz] (at least 1): the
    window of the extraction's means, and of everything compared with the extracted signal."""
    return max(int(round(period * sample_rate)), 1)


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
    """Causal window mean, and means above / below it, of every column of x (N, n): ``(centre,
    upper, lower)``, each (N, n) [the unit of x].

    Sample i's window is ``x[max(0, i - W + 1) : i + 1]`` alone (summed oldest first; no running
    sum), so a piece of a recording with ``W - 1`` samples of history gives exactly the whole
    recording's values; ``upper`` / ``lower`` are the means of the window's values above / below
    its mean (the mean itself when there are none). Compiled with numba;
    :func:`_window_stats_reference` is the same in numpy (``chunk`` bounds its memory).
    """
    x = np.ascontiguousarray(x, dtype=float)
    return _window_kernel(x, int(W))


@njit(cache=True)
def _window_kernel(x, W):  # pragma: no cover - compiled
    N, n = x.shape
    centre = np.empty((N, n))
    upper = np.empty((N, n))
    lower = np.empty((N, n))
    for j in range(n):
        for i in range(N):
            a = max(0, i - W + 1)
            s = 0.0
            for k in range(a, i + 1):
                s += x[k, j]
            c = s / (i + 1 - a)
            sa = 0.0
            sb = 0.0
            na = 0
            nb = 0
            for k in range(a, i + 1):
                v = x[k, j]
                if v > c:
                    sa += v
                    na += 1
                elif v < c:
                    sb += v
                    nb += 1
            centre[i, j] = c
            upper[i, j] = sa / na if na > 0 else c
            lower[i, j] = sb / nb if nb > 0 else c
    return centre, upper, lower


def _period_mean(x: np.ndarray, L: float) -> np.ndarray:
    """Causal mean of every column of x (N, n) over exactly ``L`` samples (``L`` real >= 1): the
    ``floor(L)`` newest samples and the one before weighted by ``L - floor(L)``, over ``L`` (the
    mean over whole dither periods when ``L`` is their length in samples). Fewer samples than
    that at the start: the mean of the samples so far. Each value comes from its own window
    (no running sum), so a piece with ``floor(L)`` samples of history gives the whole's values.
    """
    return _period_mean_kernel(np.ascontiguousarray(x, dtype=float), float(L))


@njit(cache=True)
def _period_mean_kernel(x, L):  # pragma: no cover - compiled
    N, n = x.shape
    m = int(np.floor(L))
    fr = L - m
    out = np.empty((N, n))
    for j in range(n):
        for i in range(N):
            if i < m:
                s = 0.0
                for k in range(i + 1):
                    s += x[k, j]
                out[i, j] = s / (i + 1)
                continue
            s = fr * x[i - m, j]
            for k in range(i - m + 1, i + 1):
                s += x[k, j]
            out[i, j] = s / L
    return out


def _window_stats_reference(x: np.ndarray, W: int, chunk: int = 65536):
    """Causal window mean, and means above / below it, of every column of x (N, n), in numpy.

    Each sample's values come from its own window alone (no running sum), so a piece of a
    recording with ``W - 1`` samples of history gives exactly the whole recording's values.
    """
    N, n = x.shape
    # Pad the start with NaN (comparisons false, sums skip it) so that every sample has a
    # window of W values; the first W - 1 windows hold fewer real samples.
    pad = np.vstack([np.full((W - 1, n), np.nan), x])
    centre = np.empty((N, n))
    upper = np.empty((N, n))
    lower = np.empty((N, n))
    for c0 in range(0, N, chunk):
        c1 = min(N, c0 + chunk)
        win = np.lib.stride_tricks.sliding_window_view(pad[c0 : c1 + W - 1], W, axis=0)  # (c, n, W)
        count = np.minimum(np.arange(c0, c1) + 1, W).astype(float)
        ctr = np.nansum(win, axis=2) / count[:, None]
        centre[c0:c1] = ctr
        above = win > ctr[:, :, None]
        below = win < ctr[:, :, None]
        na = above.sum(axis=2)
        nb = below.sum(axis=2)
        sa = np.where(above, win, 0.0).sum(axis=2)
        sb = np.where(below, win, 0.0).sum(axis=2)
        # no sample above (or below) the centre: a constant window; its level is the centre
        upper[c0:c1] = np.where(na > 0, sa / np.maximum(na, 1), ctr)
        lower[c0:c1] = np.where(nb > 0, sb / np.maximum(nb, 1), ctr)
    return centre, upper, lower


def extract(
    tau,
    t,
    period: float | None = None,
    tau_ffw=None,
    periods: int = 1,
    dt: float | None = None,
    waveform: str = "square",
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
    dt : float [s], optional
        The sample step (default: the median step of ``t``; a piece of a longer recording
        passes the whole recording's, :attr:`ditherlab.data.recording.Recording.dt`).
    waveform : one of :data:`WAVEFORMS`: scales ``amplitude`` to the peak
        (:data:`PEAK_FACTOR`); the other statistics do not depend on it.

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
    peak = PEAK_FACTOR[check_waveform(waveform, "dither: waveform")]
    if period is None:
        if tau_ffw is None:
            raise ConfigError("dither: neither period nor tau_ffw given; expected one of them")
        period = period_from_feedforward(tau_ffw, t)
    if not (np.isfinite(period) and period > 0):
        raise ConfigError(f"dither: period is {period!r}; expected a positive time [s]")
    if dt is None:
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    W = max(2, int(round(periods * period / dt)))
    centre, upper, lower = _window_stats(x, W)
    amplitude = 0.5 * (upper - lower)
    if waveform == "square":  # the paper's extraction (§IV-A)
        signal, first = 0.5 * (upper + lower), W - 1
    else:  # a smooth wave: the mean over exactly `periods` periods (module docstring)
        L = max(1.0, periods * period / dt)
        signal, first = _period_mean(x, L), max(W - 1, int(np.ceil(L)))
    out = DitherSignal(
        upper=upper,
        lower=lower,
        signal=signal,
        centre=centre,
        amplitude=amplitude if peak == 1.0 else peak * amplitude,
        window=W,
        period=float(period),
        full=np.arange(len(t)) >= first,
        waveform=waveform,
    )
    if one_d:
        for k in ("upper", "lower", "signal", "centre", "amplitude"):
            setattr(out, k, getattr(out, k)[:, 0])
    return out


def band_amplitude(still_min, still_max, dither_min, dither_max) -> np.ndarray:
    """The dither amplitude [N·m] a model's bands were built with: the inverse of identify's
    dithered band (:func:`ditherlab.analysis.identification._shrunk_dither_band`).

    That band is the static friction shrunk by the amplitude ``A`` about its centre ``c``:
    either the paper's ``[a + A, b - A]`` of the still band ``[a, b]`` (centre ``(a + b) / 2``)
    or ``c ± (max(c - a, b - c) - A)``; in both ``A = max(c - a, b - c) - w``, with ``c`` and
    ``w`` the dithered band's centre and half-width. Where the dither broke the band (``w = 0``)
    this is the static friction, a lower bound of ``A``.

    Parameters
    ----------
    still_min, still_max, dither_min, dither_max : (n,) band edges [N·m]

    Returns
    -------
    (n,) [N·m], at least 0
    """
    a, b = np.asarray(still_min, dtype=float), np.asarray(still_max, dtype=float)
    lo, hi = np.asarray(dither_min, dtype=float), np.asarray(dither_max, dtype=float)
    c, w = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return np.maximum(np.maximum(c - a, b - c) - w, 0.0)


#: The longest ramp-in [s] :func:`ramp_in` marks after the dither switches on: the paper's
#: loops ramp up over about a second and settle within 1-2 s more (Fig. 5); a joint whose
#: amplitude is not up 5 s after the switch dithers below the model's amplitude and is read as
#: dithered. Shorter than diagnosis's context (``ditherlab.analysis.diagnosis.HALO_S``, 12 s),
#: so a log read in pieces is cut where the whole is.
RAMP_MAX_S = 5.0


def ramp_level(model: TorqueModel) -> np.ndarray | None:
    """(n,) [N·m] the extracted amplitude at which a joint's ramp-in ends (:func:`ramp_in`):
    :data:`AMPLITUDE_UP_FRACTION` of the amplitude the model's dithered band was built with
    (:func:`band_amplitude`); None when the model has no ``still`` and ``dither`` bands to read
    it from (then no ramp-in is marked)."""
    if "still" not in model.regimes or "dither" not in model.regimes:
        return None
    st, db = model.regimes["still"], model.regimes["dither"]
    return AMPLITUDE_UP_FRACTION * band_amplitude(st.tau_min, st.tau_max, db.tau_min, db.tau_max)


def ramp_samples(rate: float) -> int:
    """:data:`RAMP_MAX_S` in samples at ``rate`` [Hz]."""
    return int(round(RAMP_MAX_S * rate))


def ramp_state(n: int) -> np.ndarray:
    """A fresh state of :func:`ramp_in` for ``n`` joints, (1 + n,) int64: the previous sample's
    dither flag (-1: none seen, so the first sample is no switch-on), then per joint the
    samples since the switch-on of its ramp-in (-1: not in one)."""
    return np.full(1 + n, -1, dtype=np.int64)


@njit(cache=True, inline="always")
def ramp_step(on, valid, amp, level, longest, state, out):  # pragma: no cover - compiled
    """One sample of the ramp-in rule (:func:`ramp_in`): the dither flag ``on``, whether the
    extraction's window is whole (``valid``), the extracted amplitudes ``amp`` (n,) [N·m]
    against ``level`` (n,) [N·m], at most ``longest`` samples; ``state`` (:func:`ramp_state`)
    carried from the previous sample and updated; ``out`` (n,) bool: the joints in their
    ramp-in at this sample."""
    rise = on and state[0] == 0
    state[0] = 1 if on else 0
    for j in range(len(level)):
        s = state[1 + j]
        if rise and level[j] > 0.0:
            s = 0
        elif s >= 0:
            s += 1
        # NaN amplitudes compare false: not up
        if s >= 0 and (not on or s >= longest or (valid and amp[j] >= level[j])):
            s = -1
        state[1 + j] = s
        out[j] = s >= 0


@njit(cache=True)
def _ramp_kernel(flag, valid, amp, level, longest, state, out):  # pragma: no cover - compiled
    for i in range(len(flag)):
        ramp_step(flag[i], valid[i], amp[i], level, longest, state, out[i])


def ramp_in(
    flag: np.ndarray,
    valid: np.ndarray,
    amp: np.ndarray,
    level: np.ndarray | None,
    longest: int,
    state: np.ndarray | None = None,
) -> np.ndarray:
    """(N, n) bool: the dither's ramp-in, per joint, from the past alone.

    After each switch-on of the dither ``flag`` (N,) (a false sample followed by a true one),
    a joint is in its ramp-in up to the first sample, with the extraction's whole window
    (``valid`` (N,)), at which its extracted amplitude ``amp`` (N, n) [N·m] reaches ``level``
    (n,) [N·m] (:func:`ramp_level`), at most ``longest`` samples (:func:`ramp_samples`) and
    while the flag stays on. While the amplitude grows the joint's dithered band is wider than
    the working one (the static friction less a smaller amplitude) and the loops settle: its
    extracted torque is not the dither regime's. A joint with ``level`` 0, or every joint when
    ``level`` is None, is never in one.

    The flag's switch-on, not a joint's dither regime (which a creeping joint leaves and
    re-enters under a push while its amplitude dips); a log that starts with the dither on
    shows no switch-on there. ``state`` (:func:`ramp_state`; a fresh one when None) carries the
    rule across pieces of a stream and is updated in place: the pieces give the whole's marks.
    """
    amp = np.ascontiguousarray(amp, dtype=float)
    out = np.zeros(amp.shape, dtype=np.bool_)
    if level is None:
        return out
    st = ramp_state(amp.shape[1]) if state is None else state
    _ramp_kernel(
        np.ascontiguousarray(flag, dtype=np.bool_), np.ascontiguousarray(valid, dtype=np.bool_),
        amp, np.ascontiguousarray(level, dtype=float), int(longest), st, out,
    )  # fmt: skip
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
        One-period means of the samples above / below the period mean, the new torque signal
        (their average for the square wave, the exact one-period mean for a sine or triangle:
        :attr:`DitherSignal.signal`), the period mean, and the dither's peak amplitude (half
        their difference times the waveform's :data:`PEAK_FACTOR`).
    on : (N,) bool
        Dither active.
    valid : (N,) bool
        Dither active over the whole one-period window ending at the sample.
    period : [s]
    waveform : str
        The recording's dither waveform (:func:`dither_waveform`).
    ramp : (N, n) bool or None
        The dither's ramp-in per joint (:func:`ramp_in` with a model's level), where the
        estimator reads the raw torque and not the extraction; None: none marked.
    """

    upper: np.ndarray
    lower: np.ndarray
    signal: np.ndarray
    centre: np.ndarray
    amplitude: np.ndarray
    on: np.ndarray
    valid: np.ndarray
    period: float
    waveform: str = "square"
    ramp: np.ndarray | None = None


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


def has_dither(rec: Recording) -> bool:
    """True when the recording has dither information and the dither is on somewhere
    (:func:`dither_on`); for a piece of a longer recording, when the whole recording does (its
    TimeBase has a dither period)."""
    if rec.timebase is not None:
        return rec.timebase.dither_period is not None
    on = dither_on(rec)
    return on is not None and bool(on.any())


def dither_period(rec: Recording) -> float:
    """The dither period [s].

    From the metadata when it states it (``dither.omega`` [rad/s] or ``dither.period`` [s], also
    under ``sim``), else from the zero crossings of ``tau_ffw`` over the first
    :data:`PERIOD_SAMPLES` dithered samples (:func:`period_from_feedforward`), else the strongest
    spectral line above 2 Hz of ``tau`` over the longest stretch with the dither on
    (:func:`period_from_spectrum`). A piece of a longer recording
    (:class:`ditherlab.data.recording.TimeBase`) takes the whole recording's.
    """
    if rec.timebase is not None and rec.timebase.dither_period is not None:
        return rec.timebase.dither_period
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
            return period_from_feedforward(ffw[:PERIOD_SAMPLES], tt[:PERIOD_SAMPLES])
        except ConfigError:
            pass
    x = rec.tau
    on = rec.dither if rec.dither is not None else np.ones(len(rec), bool)
    starts, ends = runs(on)  # the longest run of dither-on samples
    if len(starts) == 0:
        raise ConfigError(f"{rec.name or 'recording'}: the dither is never on; no period to find")
    k = int(np.argmax(ends - starts))
    return period_from_spectrum(x[starts[k] : ends[k]][:16384], rec.sample_rate, rec.name)


def extract_dither(rec: Recording, tau: np.ndarray | None = None) -> Extraction | None:
    """Extract the torque signal of a dithered recording (paper §IV-A), or None without dither.

    Parameters
    ----------
    rec : Recording with a ``dither`` column or ``tau_ffw``
    tau : (N, n) [N·m], optional — the torque to extract from (default ``rec.tau``)

    Returns
    -------
    Extraction, or None when the recording has no dither information or the dither is never on
    (:func:`has_dither`; a piece of a dithered recording is extracted even where its own rows
    have the dither off, as the whole recording is).
    """
    if not has_dither(rec):
        return None
    on = dither_on(rec)
    period = dither_period(rec)
    waveform = dither_waveform(rec.meta)
    x = rec.tau if tau is None else tau
    sig = extract(x, rec.t, period, dt=rec.dt if len(rec) > 1 else None, waveform=waveform)
    w = window_samples(period, rec.sample_rate)
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
        waveform=waveform,
    )

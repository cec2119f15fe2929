"""Rest with dither: the samples of a log flagged ``dither`` once the dither's loops have
settled and before its ramp-out, where the report (:mod:`ditherlab.analysis.detection`) measures the
noise level that every detection is judged against."""

from __future__ import annotations

import warnings
from statistics import NormalDist

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ditherlab.data.estimates import EstimatesSource
from ditherlab.physics.dither import AMPLITUDE_UP_FRACTION

#: The dither ramps in until, and out after, every dithering joint's extracted amplitude is at
#: least this fraction of its median over the dither-on samples (one definition, in
#: :mod:`ditherlab.physics.dither`).
STEADY_FRACTION = AMPLITUDE_UP_FRACTION
#: ... counted for joints whose median amplitude exceeds this fraction of the model's still band
#: half-width (the others do not dither; their "amplitude" is the noise's spread).
DITHERS_FRACTION = 0.2
#: The report's noise level is the 99.9 % quantile of ``|F̂|`` at rest: a dithering joint's
#: centre has settled once the level its extracted signal held and the level it holds next
#: differ by at most this many noise standard deviations, the two-sided 99.9 % quantile of the
#: normal (3.29): no more than the rest noise itself moves the signal in the share of samples
#: the noise level reads.
SETTLE_SIGMAS = NormalDist().inv_cdf(0.5 + 0.999 / 2)
#: The levels the signal held and holds next are its medians over this many seconds before
#: and after a sample: longer than the time constant of a centre loop of the paper's kind
#: (integral, Fig. 5 settles within 1-2 s; the simulator's 1/s gain) so that while the signal
#: still approaches the two differ by most of the offset, and not longer than the campaigns'
#: longest push (2 s), so that a push fills at most half a window, which a median ignores.
SETTLE_WINDOW_S = 2.0


def _spans(flag: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each stretch of a (N,) bool flag."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], flag.astype(np.int8), [0]))))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _medians(x: np.ndarray, window: int) -> np.ndarray:
    """(len(x) - window + 1,) medians of ``x`` over each ``window`` consecutive samples, NaN
    (outside the stretch, or no extraction yet) left out; NaN where a window holds none."""
    view = sliding_window_view(x, window)
    if not np.isnan(x).any():
        return np.median(view, axis=1)
    with warnings.catch_warnings():  # a window of NaN only: its median is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(view, axis=1)


def _settled(sig: np.ndarray, a: int, b: int, tol: float, window: int) -> int:
    """The first sample ``k`` in ``[a, b)`` at which the level the extracted signal ``sig`` (N,)
    [N·m] held over the last ``window`` samples (its median over ``(k - window, k]``, from
    ``a`` on) and the level it holds next (over ``[k, k + window)``, up to ``b``) agree within
    ``tol`` [N·m]: the signal has stopped approaching; ``a`` when there is no such sample
    (nothing is left out)."""
    block = 512
    x = np.full(b - a + 2 * (window - 1), np.nan)  # the stretch, NaN-padded by a window
    x[window - 1 : window - 1 + b - a] = sig[a:b]
    for i0 in range(0, b - a, block):
        i1 = min(i0 + block, b - a)
        seg = x[i0 : i1 + 2 * (window - 1)]  # sample a + i sits at x[i + window - 1]
        back = _medians(seg[: i1 - i0 + window - 1], window)  # over (k - window, k]
        fwd = _medians(seg[window - 1 :], window)[: i1 - i0]  # over [k, k + window)
        near = np.abs(back - fwd) <= tol  # NaN: False
        if near.any():
            return a + i0 + int(np.argmax(near))
    return a


def steady_dither(src: EstimatesSource, dith: np.ndarray) -> np.ndarray:
    """(N,) bool: the samples flagged ``dither`` (``dith (N,)``) where the dither is at work —
    in each stretch of the flag, from the sample at which its loops have settled to the last
    one at which every dithering joint's amplitude is still up.

    Read from the estimates' ``extract/`` columns (per joint ``upper_j``, ``lower_j``,
    ``signal_j`` [N·m]) and the model in the file's metadata, for every stretch of the flag:

    1. *Amplitude* (the ramps): a joint dithers when its median extracted amplitude
       ``(upper - lower) / 2`` over the flag exceeds :data:`DITHERS_FRACTION` of its still
       band's half-width; the stretch runs from the first sample at which every dithering
       joint's amplitude has reached :data:`STEADY_FRACTION` of that median to the last one
       at which it still has. A log's ``dither`` flag is true while the feedforward is on, its
       ramps included (``docs/recording-format.md``); while it ramps out the centre term moves
       the extracted signal by up to the band (~8 N·m on the simulator's joint 1), which
       counted as rest would set the dithered noise level at 10.6 N instead of 1 N. A dip inside the stretch (a joint
       slipping under a push) is kept.
    2. *Centre* (the start-up): the centre loop (paper §IV-B, Fig. 5) drives the extracted
       signal from where the torque stood before the dither to the gravity torque and then
       holds it there; until it has, the estimator reads the start-up's offset as force (on
       the simulator 2-3 N·m on joints 1 and 3 when the amplitude is up, joint 3 still
       0.2-1 N·m off 1.4 s later; in its campaigns that start-up lies mostly in the arm's own
       motion and the first push's margin, which the report leaves out anyway, but in a log
       with a longer still start it counted as rest). Rest starts at the first sample from which every dithering
       joint's ``signal_j`` has stopped approaching the level the loop holds: its median
       over the last :data:`SETTLE_WINDOW_S` seconds (from the amplitude's start on) and
       over the next agree within :data:`SETTLE_SIGMAS` noise standard deviations (the
       model's ``[regimes.dither]`` sigma, the extracted signal's noise at rest; without it
       the signal's own robust spread over the stretch). Medians, so a dip of the noise does
       not end the start-up early and a push inside a window does not hold it up. Only a
       stretch's start is searched, up to the first such sample, so later pushes and long
       rests are never left out; a joint without such a sample leaves the start where the
       amplitude put it.

    ``dith`` itself when the file has no extraction columns.
    """
    steady = dith.copy()
    model = src.meta.get("model") or {}
    regimes = model.get("regimes", {})
    still = regimes.get("still", {})
    lo, hi = still.get("tau_min"), still.get("tau_max")
    sigma = (regimes.get("dither") or {}).get("sigma")
    spans = _spans(dith)
    t = src.column("t") if "t" in src.columns else None
    dt = float(np.median(np.diff(t))) if t is not None and len(t) > 1 else 0.0
    window = max(int(round(SETTLE_WINDOW_S / dt)), 1) if dt > 0 else 1
    starts = [a for a, _ in spans]  # per stretch: where rest may begin
    ends = [b for _, b in spans]
    signals = []  # (signal, noise sigma) of each dithering joint
    j = 1
    while f"extract/upper_{j}" in src.columns and f"extract/lower_{j}" in src.columns:
        amp = 0.5 * (src.column(f"extract/upper_{j}") - src.column(f"extract/lower_{j}"))
        on = dith & np.isfinite(amp)
        level = float(np.median(amp[on])) if on.any() else 0.0
        # a joint that dithers: its amplitude a sizeable part of its band (the paper's set-points
        # are 50-90 % of it); one that does not shows the noise's spread (a few %)
        half = 0.5 * (hi[j - 1] - lo[j - 1]) if lo and hi and len(lo) >= j else 0.0
        if level > DITHERS_FRACTION * half and level > 0.0:
            for i, (a, b) in enumerate(spans):
                up = np.flatnonzero(amp[a:b] >= STEADY_FRACTION * level)  # NaN: False
                if len(up) == 0:
                    starts[i], ends[i] = b, b
                else:
                    starts[i] = max(starts[i], a + int(up[0]))
                    ends[i] = min(ends[i], a + int(up[-1]) + 1)
            name = f"extract/signal_{j}"
            if name in src.columns:
                s = float(sigma[j - 1]) if sigma and len(sigma) >= j else np.nan
                signals.append((src.column(name).astype(float), s))
        j += 1
    for i, (a, b) in enumerate(spans):
        k0, k1 = starts[i], ends[i]
        settle = k0
        for sig, s in signals:
            if k0 >= k1:
                break
            if not np.isfinite(s) or s <= 0.0:  # no model noise: the signal's own robust spread
                x = sig[k0:k1][np.isfinite(sig[k0:k1])]
                s = 1.4826 * float(np.median(np.abs(x - np.median(x)))) if len(x) else 0.0
            settle = max(settle, _settled(sig, k0, k1, SETTLE_SIGMAS * s, window))
        steady[a:settle] = False
        steady[k1:b] = False
    return steady


__all__ = [
    "DITHERS_FRACTION",
    "SETTLE_SIGMAS",
    "SETTLE_WINDOW_S",
    "STEADY_FRACTION",
    "steady_dither",
]

"""Rest with dither: the samples of a log flagged ``dither`` outside the dither's ramps, where the
report (:mod:`ditherlab.thresholds`) measures the noise level that every detection is judged
against."""

from __future__ import annotations

import numpy as np

from ditherlab.estimates import EstimatesSource

#: The dither ramps in until, and out after, every dithering joint's extracted amplitude is at
#: least this fraction of its median over the dither-on samples.
STEADY_FRACTION = 0.8
#: ... counted for joints whose median amplitude exceeds this fraction of the model's still band
#: half-width (the others do not dither; their "amplitude" is the noise's spread).
DITHERS_FRACTION = 0.2


def steady_dither(src: EstimatesSource, dith: np.ndarray) -> np.ndarray:
    """(N,) bool: the samples flagged ``dither`` (``dith (N,)``) outside the dither's ramps —
    in each stretch of the flag, from the first sample at which every dithering joint's
    extracted amplitude ``(upper - lower) / 2`` (the estimates' ``extract/`` columns) has
    reached :data:`STEADY_FRACTION` of its median to the last one at which it still has.

    A log's ``dither`` flag is true while the feedforward is on, its ramps included (RECORDING.md);
    while it ramps out the centre term moves the extracted signal by up to the band (~8 N·m on
    the simulator's joint 1), which counted as rest set the dithered noise level at 10.6 N
    instead of 1 N. Within a stretch the amplitude may dip (a joint slipping under a push or a
    strong dither): only the ramps at its ends are left out. ``dith`` itself when the file has
    no extraction columns.
    """
    steady = dith.copy()
    still = (src.meta.get("model") or {}).get("regimes", {}).get("still", {})
    lo, hi = still.get("tau_min"), still.get("tau_max")
    edges = np.flatnonzero(np.diff(np.concatenate(([0], dith.astype(np.int8), [0]))))
    spans = list(zip(edges[0::2], edges[1::2], strict=True))  # [start, stop) of each stretch
    j = 1
    while f"extract/upper_{j}" in src.columns and f"extract/lower_{j}" in src.columns:
        amp = 0.5 * (src.column(f"extract/upper_{j}") - src.column(f"extract/lower_{j}"))
        on = dith & np.isfinite(amp)
        level = float(np.median(amp[on])) if on.any() else 0.0
        # a joint that dithers: its amplitude a sizeable part of its band (the paper's set-points
        # are 50-90 % of it); one that does not shows the noise's spread (a few %)
        half = 0.5 * (hi[j - 1] - lo[j - 1]) if lo and hi and len(lo) >= j else 0.0
        if level > DITHERS_FRACTION * half and level > 0.0:
            for a, b in spans:
                up = np.flatnonzero(amp[a:b] >= STEADY_FRACTION * level)  # NaN: False
                if len(up) == 0:
                    steady[a:b] = False
                else:
                    steady[a : a + up[0]] = False
                    steady[a + up[-1] + 1 : b] = False
        j += 1
    return steady


__all__ = ["DITHERS_FRACTION", "STEADY_FRACTION", "steady_dither"]

"""Sending whole columns to a Rerun stream: the ``time`` timeline, the lossless thinning of
constant runs, the 3D decimation, the colours shared by the panels, and the row counts.

Series that stay constant over runs of samples (dither extraction, loop outputs, estimates held
at the prior) are thinned losslessly: a sample is dropped only when it equals both neighbours, so
the plotted line (linear or step) is exactly the full-rate one and every logged value is a value
of the input, bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rerun as rr

from ditherlab.core.names import REGIME_NAMES

TIMELINE = "time"

#: Colours (RGB) per variant, sensor and joint-series role; chosen to stay apart in a legend.
VARIANT_COLORS: dict[str, tuple[int, int, int]] = {
    "nodither_band": (230, 120, 30),
    "nodither_noband": (240, 190, 60),
    "dither_band": (40, 110, 230),
    "dither_noband": (120, 190, 250),
}
SENSOR_COLOR = (30, 30, 30)
#: Colour per regime name (:data:`ditherlab.core.names.REGIME_NAMES`: still, dither, moving).
REGIME_COLORS: dict[str, tuple[int, int, int]] = dict(
    zip(REGIME_NAMES, ((200, 60, 60), (60, 60, 200), (150, 150, 150)), strict=True)
)


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


def envelope_mask(t: np.ndarray, values: np.ndarray, rate: float, t0: float) -> np.ndarray:
    """Samples to keep so that a plot at ``rate`` bins per second shows the same envelope.

    The time axis is cut into bins of ``1 / rate`` seconds from ``t0``; in every bin the first
    and last samples are kept, and in every column the (first) sample of its smallest and of
    its largest value (NaN ignored). Every kept value is a value of the input at its own time
    stamp, bit for bit; between kept samples the line is drawn straight, so a bin's inner wiggles
    (a square wave's flanks, noise) show as the band between its extremes.

    Parameters
    ----------
    t : (M,) [s], non-decreasing ; values : (M,) or (M, k) ; rate : [1/s] > 0 ; t0 : [s]

    Returns
    -------
    (M,) bool
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    M = len(t)
    keep = np.zeros(M, dtype=bool)
    if M <= 2:
        keep[:] = True
        return keep
    bins = np.floor((np.asarray(t, dtype=float) - t0) * rate).astype(np.int64)
    new_bin = np.ones(M, dtype=bool)
    new_bin[1:] = bins[1:] != bins[:-1]
    starts = np.flatnonzero(new_bin)
    keep[starts] = True
    keep[np.r_[starts[1:] - 1, M - 1]] = True
    seg = np.cumsum(new_bin) - 1  # bin number of every sample, 0..len(starts)-1
    for c in range(v.shape[1]):
        col = v[:, c]
        for red in (np.fmin, np.fmax):
            ext = red.reduceat(col, starts)[seg]
            hit = np.flatnonzero(col == ext)  # NaN never equals: an all-NaN bin keeps its ends
            if len(hit):
                first = np.ones(len(hit), dtype=bool)
                first[1:] = seg[hit[1:]] != seg[hit[:-1]]
                keep[hit[first]] = True
    return keep


# ---------------------------------------------------------------------- the logger
@dataclass
class ViewSummary:
    """What was logged: entity path -> number of time-indexed rows (static rows not counted)."""

    rows: dict[str, int] = field(default_factory=dict)
    variants: list[str] = field(default_factory=list)
    n_joints: int = 0


class ColumnLogger:
    """Sends columns to one RecordingStream and keeps the row counts.

    A recording logged in pieces (:func:`ditherlab.output.rerun.pieces.log_pieces`) sets the time stamps
    of each piece's rows with :meth:`next_piece`; a series' style is logged once, and its lossless
    thinning (:func:`thin_mask`) runs across the cuts: each piece's last sample is held back until
    the next piece's first says whether it equals both neighbours, so the rows sent are those of
    the whole recording sent at once.
    """

    def __init__(
        self,
        stream: rr.RecordingStream,
        t: np.ndarray,
        series_rate: float | None = None,
        t0: float = 0.0,
    ) -> None:
        self.stream = stream
        self.t = t
        #: [1/s] bins per second of :func:`envelope_mask` for the time series (None: full rate)
        self.series_rate = series_rate if series_rate and series_rate > 0 else None
        #: [s] where the bins start (the recording's first time stamp)
        self.t0 = t0
        self.summary = ViewSummary()
        #: the current piece is the recording's last (nothing is held back)
        self.last = True
        self._styled: set[str] = set()
        # path -> (the sample before the held one or None, the held sample, its time [s])
        self._held: dict[str, tuple[np.ndarray | None, np.ndarray, float]] = {}

    def next_piece(self, t: np.ndarray, last: bool) -> None:
        """The next piece's time stamps (M,) [s]; ``last`` for the recording's last piece."""
        self.t = t
        self.last = last

    def static(self, path: str, value: Any) -> None:
        """Log static data once per path (later calls for the same path are ignored)."""
        if path not in self._styled:
            self._styled.add(path)
            self.stream.log(path, value, static=True)

    def series(
        self,
        path: str,
        values: np.ndarray,
        *,
        names: str | Sequence[str],
        colors: Any = None,
        widths: float | Sequence[float] | None = None,
        t: np.ndarray | None = None,
        thin: bool = True,
        step: bool = False,
    ) -> None:
        """Log one scalar series (M,) or k series (M, k) at ``self.t`` (or at ``t`` [s])."""
        v = np.asarray(values, dtype=np.float64)
        t = self.t if t is None else np.asarray(t, dtype=float)
        if thin:
            v, t = self._thin(path, v, t)
        if self.series_rate is not None and len(t) > 2:
            keep = envelope_mask(t, v, self.series_rate, self.t0)
            v, t = v[keep], t[keep]
        names_l = [names] if isinstance(names, str) else list(names)
        style: dict[str, Any] = {"names": names_l}
        if colors is not None:
            style["colors"] = colors
        if widths is not None:
            style["widths"] = widths
        if step:
            style["interpolation_mode"] = rr.components.InterpolationMode.StepAfter
        self.static(path, rr.SeriesLines(**style))
        if len(t):
            self.send(path, t, rr.Scalars.columns(scalars=v))

    def _thin(self, path: str, v: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The samples of ``v`` (M,) or (M, k) at ``t`` (M,) to send: :func:`thin_mask` across
        pieces (the sample held back from the previous piece first, this piece's last held)."""
        held = self._held.pop(path, None)
        off = 0
        if held is not None:
            prev, hv, ht = held
            head = [hv] if prev is None else [prev, hv]
            off = len(head) - 1
            v = np.concatenate([np.stack(head), v])
            t = np.concatenate([np.full(off, np.nan), [ht], t])
        keep = thin_mask(v)
        keep[:off] = False  # the sample before the held one was decided with its piece
        if not self.last and len(v):
            keep[-1] = False
            self._held[path] = (v[-2] if len(v) > 1 else None, v[-1], float(t[-1]))
        return v[keep], t[keep]

    def send(self, path: str, t: np.ndarray, columns: Any) -> None:
        self.stream.send_columns(
            path, indexes=[rr.TimeColumn(TIMELINE, duration=t)], columns=columns
        )
        self.summary.rows[path] = self.summary.rows.get(path, 0) + len(t)

    def text_log(self, path: str, t: np.ndarray, text: Sequence[str], level: Sequence[str]) -> None:
        if len(t) == 0:
            return
        self.send(
            path, np.asarray(t, dtype=float), rr.TextLog.columns(text=list(text), level=list(level))
        )

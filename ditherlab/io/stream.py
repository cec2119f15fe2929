"""Recordings read in pieces, for logs longer than memory: ``open_source(path) -> Source``.

A :class:`Source` reads a recording's table a batch of rows at a time through its format's
:class:`~ditherlab.io.format.Table` (Parquet by row-group batches, CSV by blocks of lines,
ditherlab MCAP by its messages in file order, one chunk decompressed at a time, ROS 2 bags message
by message after a first pass that keeps only the time stamps) and hands it out as overlapping
:class:`Piece` s: each piece is a
:class:`~ditherlab.data.recording.Recording` of the rows it owns plus ``halo`` rows on either side,
carrying the whole recording's :class:`~ditherlab.data.recording.TimeBase` (first time stamp, median
step, dither period). Every quantity downstream is computed from a bounded neighbourhood of a
sample (velocity and acceleration filters ≤ 40 ms, the moving mask's 0.1 s window, the dither's
one-period windows, the regimes), so on the rows a piece owns it gives the whole recording's
values exactly; :data:`HALO_S` (2 s) covers every window with room to spare.

Memory: a piece of ``rows`` rows (default :data:`CHUNK_ROWS`) and the ``t`` column of the whole
recording (8 bytes per sample: 72 MB for ten hours at 250 Hz) are held at once. Formats without
a batch reader (mapped vendor logs, and ROS 2 bags whose header stamps go back in the bag's order,
which must be sorted) are read whole and then cut into the same pieces: results are the same,
memory is not bounded (``ditherlab convert`` them to Parquet first).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ditherlab.core.errors import ConfigError, FormatError, RecordingError
from ditherlab.core.timeseries import (
    PERIOD_SAMPLES,
    period_from_feedforward,
    period_from_spectrum,
    runs,
)
from ditherlab.data.recording import Recording, TimeBase, meta_dither_period, share_meta
from ditherlab.data.recording import _joint_columns as joint_columns
from ditherlab.data.recording import _wrench_columns as wrench_columns
from ditherlab.io import registry
from ditherlab.io.common import check_units, checked_times
from ditherlab.io.format import CHUNK_ROWS

if TYPE_CHECKING:  # pragma: no cover
    from ditherlab.robot import RobotModel

__all__ = [
    "CHUNK_ROWS",
    "HALO_S",
    "Piece",
    "Source",
    "open_source",
    "pieces_of",
    "write_stream",
]

#: rows of context on either side of a piece, in seconds of recording
HALO_S = 2.0


@dataclass
class Piece:
    """One piece of a recording.

    Attributes
    ----------
    rec : the rows ``[start, start + len(rec))`` of the whole recording, with its TimeBase
    start : index of ``rec``'s first row in the whole recording
    keep : the rows of ``rec`` this piece owns (the pieces' owned rows tile the recording)
    index : 0-based piece number ; count : how many pieces there are
    """

    rec: Recording
    start: int
    keep: slice
    index: int
    count: int

    @property
    def owned(self) -> tuple[int, int]:
        """``[first, end)`` row indices of the owned rows in the whole recording."""
        return self.start + self.keep.start, self.start + self.keep.stop


class Source:
    """A recording file read in batches of rows (see the module docstring).

    Parameters
    ----------
    path : a recording file or ROS 2 bag folder
    **options : the reader options of :func:`ditherlab.io.read`

    Attributes
    ----------
    name : the path, for messages ; meta : the metadata (with reader options applied)
    n_rows : samples in the recording ; columns : column names in table order
    bounded : True when the format is read in batches (memory does not grow with length)
    kind : the name of the file's format (:class:`ditherlab.io.format.Format`)
    """

    def __init__(self, path: str | Path, **options: Any):
        self.path = Path(path)
        self.name = str(self.path)
        fmt, self._table = registry.open_table(self.path, **options)
        self.kind = fmt.name
        self._rec: Recording | None = self._table.rec
        self._t: np.ndarray | None = self._table.t
        self.meta = self._table.meta
        self.n_rows = self._table.n_rows
        self.columns = list(self._table.columns)
        self.bounded = self._rec is None
        self._timebase: TimeBase | None = None
        # the column names as the Recording checks them (t, q_1..q_n, tau_1..tau_n, whole
        # families, all six wrench columns or none), before any consumer reads a column alone
        # (report, view): a repeated name would come back 2-D, a missing one unnoticed
        joint_columns(self.columns, f"{self.name}: ")
        wrench_columns(self.columns, f"{self.name}: ")
        if self.n_rows == 0:
            raise RecordingError(
                f"{self.name}: the recording holds no samples (its columns and no rows); "
                "expected at least one row of data"
            )

    # ------------------------------------------------------------------ reading
    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive blocks of ``rows`` rows (the last one shorter), optionally
        only some columns (the format's :meth:`ditherlab.io.format.Table.frames`); FormatError
        naming the file for a corrupt block."""
        return self._table.frames(rows, columns)

    def column(self, name: str) -> np.ndarray:
        """One whole column, (N,)."""
        if self._rec is not None:
            return self._rec.data[name].to_numpy()
        parts = [f[name].to_numpy() for f in self.frames(CHUNK_ROWS, [name])]
        return np.concatenate(parts) if parts else np.zeros(0)

    def times(self) -> np.ndarray:
        """The whole ``t`` column, (N,) [s], read once and kept (8 bytes per sample).

        RecordingError, as the Recording's, when a time stamp is not a finite number or ``t`` is
        not strictly increasing: a reader of columns (``report``, ``view``) relies on it."""
        if self._t is None:
            if "t" not in self.columns:
                raise RecordingError(f"{self.name}: column 't' is missing")
            self._t = checked_times(self.column("t"), self.name)
        return self._t

    def read(self) -> Recording:
        """The whole recording in memory (what :func:`ditherlab.io.read` returns)."""
        if self._rec is not None:
            return self._rec
        data = pd.concat(list(self.frames(CHUNK_ROWS)), ignore_index=True)
        rec = Recording(data, self.meta, name=self.name)
        check_units(rec)
        return rec

    # ------------------------------------------------------------------ the whole recording
    def timebase(self) -> TimeBase:
        """The whole recording's :class:`~ditherlab.data.recording.TimeBase` (read once)."""
        if self._timebase is None:
            t = self.times()
            # numpy's warnings on absurd values (1e308 N·m): the pieces' checks report them
            with np.errstate(all="ignore"):
                self._timebase = TimeBase.of(t, self._dither_period(t))
        return self._timebase

    def _dither_period(self, t: np.ndarray) -> float | None:
        """:func:`ditherlab.physics.dither.dither_period` of the whole recording, reading only
        what it needs: the dither flags, the first :data:`PERIOD_SAMPLES` dithered rows of
        ``tau_ffw`` or the longest dithered run's first rows of ``tau``."""
        has_flag, has_ffw = "dither" in self.columns, "tau_ffw_1" in self.columns
        if not (has_flag or has_ffw):
            return None
        stated = meta_dither_period(self.meta)
        if stated is not None:
            return stated
        on = self.column("dither").astype(bool) if has_flag else None
        if on is not None and not on.any():
            return None  # the dither is never on: nothing is extracted
        if has_ffw:
            ffw_cols = [c for c in self.columns if c.startswith("tau_ffw_")]
            use = on if on is not None and on.sum() > 8 else np.ones(len(t), bool)
            idx = np.flatnonzero(use)[:PERIOD_SAMPLES]
            ffw = self._rows(idx, ffw_cols)
            try:
                return period_from_feedforward(ffw, t[idx])
            except ConfigError:
                if not has_flag and not self._varies(ffw_cols):
                    return None  # a constant feedforward: the dither is never on
        mask = on if on is not None else np.ones(len(t), bool)
        starts, ends = runs(mask)
        if len(starts) == 0:
            return None  # the dither is never on: nothing is extracted
        k = int(np.argmax(ends - starts))
        idx = np.arange(starts[k], min(ends[k], starts[k] + 16384))
        tau = self._rows(idx, [c for c in self.columns if c.startswith("tau_") and c[4:].isdigit()])
        fs = float(self.meta["sample_rate_hz"]) if "sample_rate_hz" in self.meta else None
        if fs is None:
            step = float(np.median(np.diff(t))) if len(t) > 1 else math.nan
            if not step > 0:
                return None  # t does not increase: the first piece says where
            fs = 1.0 / step
        try:
            return period_from_spectrum(tau, fs, self.name)
        except ConfigError:
            return None  # each piece then fails (or finds it) as the whole recording would

    def _varies(self, cols: list[str]) -> bool:
        """Whether any of the columns spans more than 1e-6
        (:func:`ditherlab.physics.dither.dither_on`)."""
        lo = hi = None
        for f in self.frames(CHUNK_ROWS, cols):
            x = f.to_numpy(dtype=float)
            lo = x.min(axis=0) if lo is None else np.minimum(lo, x.min(axis=0))
            hi = x.max(axis=0) if hi is None else np.maximum(hi, x.max(axis=0))
        return lo is not None and bool(((hi - lo) > 1e-6).any())

    def _rows(self, idx: np.ndarray, cols: list[str]) -> np.ndarray:
        """The rows ``idx`` (sorted) of some columns, (len(idx), len(cols)) float."""
        out = np.empty((len(idx), len(cols)))
        a, k = 0, 0
        for f in self.frames(CHUNK_ROWS, cols):
            b = a + len(f)
            sel = idx[(idx >= a) & (idx < b)]
            if len(sel):
                out[k : k + len(sel)] = f.to_numpy(dtype=float)[sel - a]
                k += len(sel)
            a = b
            if k == len(idx):
                break
        return out

    # ------------------------------------------------------------------ pieces
    def pieces(self, rows: int = CHUNK_ROWS, halo_s: float = HALO_S) -> Iterator[Piece]:
        """The recording as overlapping pieces of ``rows`` owned rows (module docstring).

        A piece must hold four halos (its context on both sides and as much again of its own):
        the default ``rows`` (:data:`CHUNK_ROWS`) grows to that at a sample rate where it falls
        short (12 s halos at 5 kHz: 240 004 rows); a smaller ``rows`` given on purpose raises
        ConfigError, unless the whole recording fits in one piece. The Recording's own errors are
        raised for a piece that breaks the contract.
        """
        tb = self.timebase()
        # a median step of 0 or less (t repeats or goes back): one row, and the first piece's
        # Recording names the row where t stops increasing
        ok = math.isfinite(tb.dt) and tb.dt > 0
        halo = max(int(math.ceil(halo_s / tb.dt)), 1) if ok else 1
        rows = int(rows)
        if rows < 4 * halo and rows == CHUNK_ROWS:
            rows = 4 * halo  # the default holds four contexts at any sample rate
        if rows < 4 * halo and rows < self.n_rows:  # a log within one piece needs no context
            raise ConfigError(
                f"{self.name}: chunk size {rows} rows is below four times the {halo}-row context "
                f"({halo_s:g} s at {1 / tb.dt if ok else math.nan:.4g} Hz, carried on either side "
                f"of every piece); expected at least {4 * halo} rows ({4 * halo_s:g} s of this "
                "recording), or no --chunk: the default holds four contexts at any sample rate"
            )
        N = self.n_rows
        count = max(1, math.ceil(N / rows))
        buf: pd.DataFrame | None = None
        buf_start = 0
        a = 0
        k = 0

        robot: RobotModel | None = None  # the first piece's robot serves every piece
        meta = share_meta(self.meta, self.name)  # checked and copied once for every piece

        def cut(a: int, b: int) -> Piece:
            nonlocal robot
            lo, hi = max(a - halo, 0), min(b + halo, N)
            assert buf is not None
            data = buf.iloc[lo - buf_start : hi - buf_start].reset_index(drop=True)
            rec = Recording(data, meta, name=self.name, timebase=tb)
            if robot is None:
                check_units(rec)
                robot = rec.robot()
            else:
                rec.share_robot(robot)
            return Piece(rec, lo, slice(a - lo, b - lo), k, count)

        for frame in self.frames(rows):
            buf = frame if buf is None else pd.concat([buf, frame], ignore_index=True)
            end = buf_start + len(buf)
            while a < N and end >= min(a + rows + halo, N):
                b = min(a + rows, N)
                yield cut(a, b)
                k += 1
                a = b
                drop = max(a - halo - buf_start, 0)
                if drop:
                    buf = buf.iloc[drop:].reset_index(drop=True)
                    buf_start += drop
        if buf is None or a < N:
            raise RecordingError(
                f"{self.name}: {buf_start + (0 if buf is None else len(buf))} rows read, "
                f"{N} expected from the file's row count"
            )


def pieces_of(
    r: Recording | Source, rows: int = CHUNK_ROWS, halo_s: float = HALO_S
) -> Iterator[Piece]:
    """A recording in memory is one piece (all its rows owned); a :class:`Source`, its pieces."""
    if isinstance(r, Recording):
        return iter([Piece(r, 0, slice(0, len(r)), 0, 1)])
    return r.pieces(rows, halo_s)


def open_source(path: str | Path, **options: Any) -> Source:
    """A :class:`Source` over a recording file (``options`` as for :func:`ditherlab.io.read`)."""
    return Source(path, **options)


def write_stream(
    src: Source,
    dst: str | Path,
    rows: int = CHUNK_ROWS,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write the recording ``src`` piece by piece (memory holds one piece) in the format of the
    suffix of ``dst``, when that format has a ``write_stream`` (Parquet, CSV, ditherlab MCAP);
    other formats, and sources read whole, are written from the whole recording
    (:func:`ditherlab.io.write`).

    The file equals what :func:`ditherlab.io.write` makes of ``src.read()``: the same table and
    metadata (Parquet in row groups of :data:`ditherlab.io.parquet.ROW_GROUP` rows or fewer, CSV
    and MCAP the same bytes). Written atomically; every piece is checked against the contract
    first. ``progress(done, total)`` is told the samples written [-] after each piece.
    """
    p = Path(dst)
    fmt = registry.output_format(p)
    if fmt is None or fmt.write_stream is None or not src.bounded:
        out = registry.write(src.read(), p)
        if progress is not None:
            progress(src.n_rows, src.n_rows)
        return out
    blocks = _counted(
        (piece.rec.data.iloc[piece.keep].reset_index(drop=True) for piece in src.pieces(rows)),
        src.n_rows,
        progress,
    )
    try:
        return fmt.write_stream(blocks, src.meta, p, src.name)
    except OSError as exc:
        raise FormatError(
            f"{p}: cannot write the {fmt.name} file ({exc.strerror or exc})"
        ) from None


def _counted(
    blocks: Iterator[pd.DataFrame], total: int, progress: Callable[[int, int], None] | None
) -> Iterator[pd.DataFrame]:
    """``blocks`` as they are, telling ``progress(rows so far, total)`` after each one."""
    done = 0
    for b in blocks:
        yield b
        done += len(b)
        if progress is not None:
            progress(min(done, total), total)

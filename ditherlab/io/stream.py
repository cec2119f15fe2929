"""Recordings read in pieces, for logs longer than memory: ``open_source(path) -> Source``.

A :class:`Source` reads a recording's table a batch of rows at a time (Parquet by row-group
batches, CSV by blocks of lines, ditherlab MCAP by its messages in file order, one chunk
decompressed at a time, ROS 2 bags message by message after a first pass that keeps only the time
stamps) and hands it out as overlapping :class:`Piece` s: each piece is a
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

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.core.errors import ConfigError, FormatError, RecordingError, one_line
from ditherlab.core.files import atomic_path, damaged
from ditherlab.core.timeseries import (
    PERIOD_SAMPLES,
    period_from_feedforward,
    period_from_spectrum,
    runs,
)
from ditherlab.data.recording import Recording, TimeBase, meta_dither_period, share_meta
from ditherlab.data.recording import _check_increasing as check_increasing
from ditherlab.data.recording import _joint_columns as joint_columns
from ditherlab.data.recording import _wrench_columns as wrench_columns
from ditherlab.io import _module, detect_format, read, write
from ditherlab.io import csv as csv_io
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    check_units,
    dumps_meta,
    loads_meta,
    meta_from_options,
)
from ditherlab.io.parquet import META_KEY, ROW_GROUP, check_schema, file_metadata

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

#: rows a piece owns by default (about 4.4 min at 250 Hz; replay then peaks near 1 GB in all)
CHUNK_ROWS = 65_536
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
    """

    def __init__(self, path: str | Path, **options: Any):
        self.path = Path(path)
        self.name = str(self.path)
        self._rec: Recording | None = None
        self._t: np.ndarray | None = None
        mapping = options.get("mapping")
        kind = None if mapping is not None else detect_format(self.path)
        self.kind = kind
        if kind == "parquet":
            self._open_parquet(options)
        elif kind == "csv":
            self._open_csv(options)
        elif kind == "mcap":
            self._open_mcap(options)
        elif kind == "rosbag":
            self._open_rosbag(options)
        else:  # mapped logs
            self._read_whole(options)
        self.bounded = self._rec is None
        self._timebase: TimeBase | None = None
        # the column names as the Recording checks them (t, q_1..q_n, tau_1..tau_n, whole
        # families, all six wrench columns or none), before any consumer reads a column alone
        # (report, view): a repeated name would come back 2-D, a missing one unnoticed
        joint_columns(self.columns, f"{self.name}: ")
        wrench_columns(self.columns, f"{self.name}: ")

    # ------------------------------------------------------------------ formats
    def _open_parquet(self, options: dict[str, Any]) -> None:
        check_options(options, META_OPTIONS, "Parquet", self.name)
        try:
            # pre_buffer=False: read one batch at a time (pre-buffering holds whole row groups)
            self._pf = pq.ParquetFile(self.path, page_checksum_verification=True, pre_buffer=False)
            check_schema(self._pf.schema_arrow, self.name)
        except (pa.ArrowException, OSError) as exc:
            raise damaged(self.name, exc) from None
        kv = file_metadata(self._pf)
        stored = loads_meta(kv[META_KEY], self.name) if META_KEY in kv else None
        self.meta = meta_from_options(stored, options, where=self.name)
        self.n_rows = int(self._pf.metadata.num_rows)
        self.columns = list(self._pf.schema_arrow.names)

    def _open_mcap(self, options: dict[str, Any]) -> None:
        # the summary's message counts and the metadata record: no message is read
        self._mcap = _module("mcap").layout(self.path, **options)
        self.meta = self._mcap.meta
        self.n_rows = self._mcap.n_rows
        self.columns = [c for c, _ in self._mcap.columns]

    def _read_whole(self, options: dict[str, Any]) -> None:
        self._rec = read(self.path, **options)
        self.meta = self._rec.meta
        self.n_rows = len(self._rec)
        self.columns = [str(c) for c in self._rec.data.columns]

    def _open_rosbag(self, options: dict[str, Any]) -> None:
        # one pass over the messages keeps their stamps: the rows' times, the wrench's span
        lay = _module("rosbag").layout(self.path, **options)
        if not lay.ordered:  # sorting needs every message
            self._read_whole(options)
            return
        self._bag = lay
        self.meta, self.n_rows, self.columns = lay.meta, lay.n_rows, list(lay.columns)
        self._t = lay.t

    def _open_csv(self, options: dict[str, Any]) -> None:
        check_options(options, csv_io.OPTIONS, "CSV", self.name)
        self.meta = csv_io.read_meta(self.path, options)
        self.columns = csv_io.header(self.path)
        try:
            if "t" not in self.columns:  # counted here; Recording names the missing column
                blocks = pd.read_csv(self.path, skipinitialspace=True, chunksize=CHUNK_ROWS)
                self.n_rows = sum(len(b) for b in blocks)
        except (ValueError, pd.errors.EmptyDataError) as exc:  # UnicodeDecodeError too
            raise FormatError(f"{self.name}: not a readable CSV file ({one_line(exc)})") from None
        if "t" in self.columns:
            self.n_rows = len(self.times())  # one pass: the rows counted as t is read

    # ------------------------------------------------------------------ reading
    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive blocks of (about) ``rows`` rows, optionally only some
        columns; FormatError naming the file for a corrupt block."""
        if self._rec is not None:
            data = self._rec.data if columns is None else self._rec.data[columns]
            for a in range(0, max(self.n_rows, 1), rows):
                yield data.iloc[a : a + rows].reset_index(drop=True)
            return
        if self.kind == "parquet":
            try:
                for batch in self._pf.iter_batches(batch_size=rows, columns=columns):
                    yield batch.to_pandas()
            except (pa.ArrowException, OSError) as exc:
                raise damaged(self.name, exc) from None
            return
        if self.kind == "mcap":
            yield from _module("mcap").frames(self._mcap, rows, columns)
            return
        if self.kind == "rosbag":
            yield from _module("rosbag").frames(self._bag, rows, columns)
            return
        start = 0
        try:
            reader = pd.read_csv(self.path, skipinitialspace=True, chunksize=rows, usecols=columns)
            for data in reader:
                csv_io.check_fields(data, self.path)
                csv_io.check_numeric(data, self.path, header_lines=1, row_offset=start)
                csv_io.parse_dither(data)
                start += len(data)
                yield data
        except ValueError as exc:  # pandas' ParserError and UnicodeDecodeError among them
            raise FormatError(f"{self.name}: not a readable CSV file ({one_line(exc)})") from None

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
            if self.kind == "csv":
                # every column parsed: a row with more fields than the header is an error here
                # (pandas reads one column of a ragged file, slowly, without a word)
                parts = [f["t"].to_numpy() for f in self.frames(CHUNK_ROWS)]
                t = np.concatenate(parts) if parts else np.zeros(0)
            else:
                t = self.column("t")
            t = pd.to_numeric(pd.Series(t), errors="coerce").to_numpy(float)
            check_times(t, self.name)
            self._t = t
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
        """:func:`ditherlab.physics.dither.dither_period` of the whole recording, reading only what it
        needs: the dither flags, the first :data:`PERIOD_SAMPLES` dithered rows of ``tau_ffw``
        or the longest dithered run's first rows of ``tau``."""
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
        """Whether any of the columns spans more than 1e-6 (:func:`ditherlab.physics.dither.dither_on`)."""
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

        Raises ConfigError for ``rows`` below four halos (a piece must be longer than its
        context) and the Recording's own errors for a piece that breaks the contract.
        """
        tb = self.timebase()
        # a median step of 0 or less (t repeats or goes back): one row, and the first piece's
        # Recording names the row where t stops increasing
        ok = math.isfinite(tb.dt) and tb.dt > 0
        halo = max(int(math.ceil(halo_s / tb.dt)), 1) if ok else 1
        rows = int(rows)
        if rows < 4 * halo:
            raise ConfigError(
                f"chunk size {rows} rows is below four times the {halo}-row context "
                f"({halo_s:g} s at {1 / tb.dt if ok else math.nan:.4g} Hz); expected at least "
                f"{4 * halo} rows"
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


def check_times(t: np.ndarray, name: str) -> None:
    """RecordingError, in the Recording's words, for a time stamp that is not a finite number
    or ``t`` (N,) [s] that does not strictly increase."""
    bad = ~np.isfinite(t)
    if bad.any():
        kind = "NaN" if np.isnan(t[bad]).all() else "NaN or infinite"
        first = int(np.flatnonzero(bad)[0]) + 1
        raise RecordingError(f"{name}: t has {int(bad.sum())} {kind} values in rows {first}..")
    check_increasing(t, f"{name}: ")


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


def write_stream(src: Source, dst: str | Path, rows: int = CHUNK_ROWS) -> Path:
    """Write the recording ``src`` to a Parquet, CSV or ditherlab MCAP file piece by piece
    (memory holds one piece); other formats, and sources read whole, are written from the whole
    recording (:func:`ditherlab.io.write`).

    The file equals what :func:`ditherlab.io.write` makes of ``src.read()``: the same table and
    metadata (Parquet in row groups of :data:`ditherlab.io.parquet.ROW_GROUP` rows or fewer, CSV
    and MCAP the same bytes). Written atomically; every piece is checked against the contract
    first.
    """
    p = Path(dst)
    kind = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".mcap": "mcap"}.get(
        p.suffix.lower()
    )
    if kind is None or not src.bounded:
        return write(src.read(), p)
    try:
        if kind == "parquet":
            return _parquet_pieces(src, p, rows)
        if kind == "mcap":
            blocks = (data for _, data in _owned(src, rows))
            return _module("mcap").write_frames(blocks, src.meta, p, name=src.name)
        return _csv_pieces(src, p, rows)
    except OSError as exc:
        raise FormatError(f"{p}: cannot write the {kind} file ({exc.strerror or exc})") from None


def _owned(src: Source, rows: int) -> Iterator[tuple[int, pd.DataFrame]]:
    for piece in src.pieces(rows):
        yield piece.owned[0], piece.rec.data.iloc[piece.keep].reset_index(drop=True)


def _parquet_pieces(src: Source, path: Path, rows: int) -> Path:
    schema: pa.Schema | None = None
    with atomic_path(path) as tmp, contextlib.ExitStack() as stack:
        writer: pq.ParquetWriter | None = None
        for start, data in _owned(src, rows):
            if writer is None:
                table = pa.Table.from_pandas(data, preserve_index=False)
                kv = dict(table.schema.metadata or {})
                kv[META_KEY] = dumps_meta(src.meta).encode("utf-8")
                schema = table.schema.with_metadata(kv)
                writer = stack.enter_context(
                    pq.ParquetWriter(tmp, schema, compression="zstd", write_page_checksum=True)
                )
            try:
                table = pa.Table.from_pandas(data, schema=schema, preserve_index=False)
            except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
                raise FormatError(
                    f"{src.name}: a column changes type at row {start + 1} ({one_line(exc)}); expected "
                    "one type per column"
                ) from None
            writer.write_table(table, row_group_size=ROW_GROUP)
    return path


def _csv_pieces(src: Source, path: Path, rows: int) -> Path:
    side = csv_io.sidecar_path(path)
    with atomic_path(side) as tmp_side, atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            for start, data in _owned(src, rows):
                f.write(
                    data.to_csv(
                        index=False,
                        header=start == 0,
                        lineterminator="\n",
                        float_format=csv_io.repr_float,
                    )
                )
        tmp_side.write_text(csv_io.sidecar_text(src.meta), encoding="utf-8")
    return path

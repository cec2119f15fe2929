"""The estimates file: what ``ditherlab replay`` writes and ``report`` and ``view`` read.

Parquet with ``t``, the sensor columns ``f_x..m_z`` and ``dither`` when present, and per variant
V among :data:`VARIANTS`: ``V/f_x .. V/m_z`` (the estimate), ``V/f_x_lo .. V/m_z_lo`` and
``V/f_x_hi .. V/m_z_hi`` (the interval), ``V/active`` (bitmask of the joints outside their
band); dither variants add ``extract/upper_j``, ``extract/lower_j``, ``extract/signal_j`` [N·m]
(the paper's extraction, written once by replay). Its key-value metadata ``ditherlab`` is JSON:
``{"schema": "ditherlab.estimates/1", "recording": ..., "model": ..., "variants": [...],
"interval": {"method": ..., "level": ...}, "components": [...], "moving_spans": ...}``.
:class:`Estimates` reads, checks and writes it (atomically).
"""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.core.errors import ConfigError, FormatError, RecordingError
from ditherlab.core.files import atomic_path, damaged, plain
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.recording import Recording

__all__ = [
    "COMPONENTS",
    "META_KEY",
    "SCHEMA",
    "VARIANTS",
    "Estimates",
    "EstimatesSource",
    "EstimatesWriter",
    "check_estimates_match",
    "check_times_match",
]

SCHEMA = "ditherlab.estimates/1"
META_KEY = b"ditherlab"
#: the estimator variants, in file order
VARIANTS = ("nodither_band", "nodither_noband", "dither_band", "dither_noband")
#: the estimated wrench components
COMPONENTS = WRENCH_COLUMNS


@dataclass
class Estimates:
    """Estimator output per sample (see the module docstring for the columns).

    Attributes
    ----------
    data : DataFrame, one row per sample
    meta : dict with ``schema``, ``recording``, ``recording_name``, ``model``, ``variants``,
        ``interval`` (``method``, ``level``), ``components``, and ``moving_spans`` (the time spans
    in which some joint moved, [s], so that the report can tell rest from motion)
    name : where it was read from (for messages)
    """

    data: pd.DataFrame
    meta: dict[str, Any]
    name: str | None = field(default=None)

    @property
    def variants(self) -> list[str]:
        """The estimator variants in the file (of :data:`VARIANTS`), in file order."""
        return list(self.meta.get("variants", []))

    @property
    def t(self) -> np.ndarray:
        """Sample times, (N,) [s]."""
        return self.data["t"].to_numpy(dtype=float)

    @property
    def has_wrench(self) -> bool:
        """True when the F/T sensor columns ``f_x .. m_z`` are present."""
        return "f_x" in self.data.columns

    @property
    def wrench(self) -> np.ndarray | None:
        """F/T sensor wrench (N, 6) [N, N·m] or None."""
        if not self.has_wrench:
            return None
        return self.data[list(COMPONENTS)].to_numpy(dtype=float)

    @property
    def dither(self) -> np.ndarray | None:
        """Dither flag, (N,) bool, or None when not logged."""
        return self.data["dither"].to_numpy(dtype=bool) if "dither" in self.data.columns else None

    def F(self, variant: str) -> np.ndarray:
        """Estimated wrench of a variant, (N, 6) [N, N·m]."""
        self._check_variant(variant)
        return self.data[[f"{variant}/{c}" for c in COMPONENTS]].to_numpy(dtype=float)

    def interval(self, variant: str) -> tuple[np.ndarray, np.ndarray]:
        """Interval bounds ``(lo, hi)`` of a variant, each (N, 6) [N, N·m]."""
        self._check_variant(variant)
        lo = self.data[[f"{variant}/{c}_lo" for c in COMPONENTS]].to_numpy(dtype=float)
        hi = self.data[[f"{variant}/{c}_hi" for c in COMPONENTS]].to_numpy(dtype=float)
        return lo, hi

    def active(self, variant: str) -> np.ndarray:
        """Joints outside their band, (N, n) bool (decoded from the ``V/active`` bitmask)."""
        self._check_variant(variant)
        mask = self.data[f"{variant}/active"].to_numpy(dtype=np.int64)
        n = int(self.meta.get("n_joints") or _n_from_meta(self.meta))
        return ((mask[:, None] >> np.arange(n)) & 1).astype(bool)

    def _check_variant(self, variant: str) -> None:
        if variant not in self.variants:
            raise ConfigError(
                f"{self.name or 'estimates'}: variant {variant!r} is not in the file "
                f"(it has {', '.join(self.variants) or 'none'})"
            )

    def save(self, path: str | Path) -> Path:
        """Write the estimates as Parquet atomically (LZ4; metadata JSON under ``ditherlab``)."""
        table = pa.Table.from_pandas(self.data, preserve_index=False)
        kv = dict(table.schema.metadata or {})
        kv[META_KEY] = json.dumps(self.meta, sort_keys=True, allow_nan=True).encode("utf-8")
        table = table.replace_schema_metadata(kv)
        with atomic_path(path) as tmp:
            pq.write_table(table, tmp, **_write_options(table.schema))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Estimates:
        """Read an estimates file; FormatError for anything that is not one."""
        pf, meta = _open(path)
        try:
            table = pf.read()
        except (pa.ArrowException, OSError) as exc:
            raise damaged(path, exc) from None
        return cls(table.to_pandas(), meta, name=str(path))


def _open(path: str | Path, pre_buffer: bool = True) -> tuple[pq.ParquetFile, dict[str, Any]]:
    """An estimates file opened (not read) and its metadata checked; FormatError otherwise."""
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such estimates file")
    try:
        pf = pq.ParquetFile(p, pre_buffer=pre_buffer, page_checksum_verification=True)
    except (pa.ArrowException, OSError) as exc:
        raise damaged(p, exc) from None
    # the footer's key-value metadata: a file written piece by piece (EstimatesWriter)
    # stores it there only, not in the Arrow schema
    kv = {**(pf.schema_arrow.metadata or {}), **(pf.metadata.metadata or {})}
    if META_KEY not in kv:
        raise FormatError(
            f"{p}: key-value metadata 'ditherlab' is missing, expected an estimates file "
            "written by `ditherlab replay`"
        )
    try:
        meta = json.loads(kv[META_KEY].decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(f"{p}: metadata 'ditherlab' is not valid JSON ({exc})") from None
    if meta.get("schema") != SCHEMA:
        raise FormatError(
            f"{p}: metadata key 'schema' is {meta.get('schema')!r}, expected {SCHEMA!r} "
            "(a recording, not estimates? run `ditherlab replay` first)"
        )
    return pf, meta


class EstimatesSource:
    """An estimates file read a block of rows at a time (for files longer than memory), or an
    :class:`Estimates` in memory behind the same interface (:meth:`of`).

    Attributes
    ----------
    name : the path, for messages ; meta : the file's metadata ; n_rows : rows in the file
    columns : column names in file order
    """

    def __init__(self, path: str | Path):
        # pre_buffer=False: one batch at a time (pre-buffering holds whole row groups)
        self._pf, self.meta = _open(path, pre_buffer=False)
        self._est: Estimates | None = None
        self.name = str(path)
        self.n_rows = int(self._pf.metadata.num_rows)
        self.columns = list(self._pf.schema_arrow.names)

    @classmethod
    def of(cls, est: Estimates) -> EstimatesSource:
        """Estimates in memory read through the same interface."""
        self = cls.__new__(cls)
        self._est, self.meta, self.name = est, est.meta, est.name or "estimates"
        self.n_rows = len(est.data)
        self.columns = [str(c) for c in est.data.columns]
        return self

    @property
    def variants(self) -> list[str]:
        """The estimator variants in the file (of :data:`VARIANTS`), in file order."""
        return list(self.meta.get("variants", []))

    @property
    def has_wrench(self) -> bool:
        """True when the F/T sensor columns ``f_x .. m_z`` are present."""
        return "f_x" in self.columns

    def blocks(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive blocks of exactly ``rows`` rows (the last one shorter),
        optionally only some columns; FormatError naming the file for a corrupt block."""
        rows = max(int(rows), 1)
        if self._est is not None:
            data = self._est.data if columns is None else self._est.data[columns]
            for a in range(0, self.n_rows, rows):
                yield data.iloc[a : a + rows].reset_index(drop=True)
            return
        buf: list[pa.RecordBatch] = []
        have = 0
        try:
            for batch in self._pf.iter_batches(batch_size=rows, columns=columns):
                buf.append(batch)
                have += batch.num_rows
                while have >= rows:
                    table = pa.Table.from_batches(buf)
                    yield table.slice(0, rows).to_pandas()
                    buf = table.slice(rows).to_batches()
                    have -= rows
        except (pa.ArrowException, OSError) as exc:
            raise damaged(self.name, exc) from None
        if have:
            yield pa.Table.from_batches(buf).to_pandas()

    def column(self, name: str, rows: int = 1 << 16) -> np.ndarray:
        """One whole column, (N,), in the column's unit (``t`` [s], a force [N], ...)."""
        if name not in self.columns:
            raise FormatError(f"{self.name}: required column {name} is missing")
        parts = [b[name].to_numpy() for b in self.blocks(rows, [name])]
        return np.concatenate(parts) if parts else np.zeros(0)

    def estimates(self, block: pd.DataFrame) -> Estimates:
        """A block of rows as :class:`Estimates` (the file's metadata and name)."""
        return Estimates(block, self.meta, name=self.name)


class EstimatesWriter:
    """An estimates file written piece by piece (:func:`ditherlab.app.replay.replay_stream`): each
    :meth:`write` appends row groups, :meth:`close` stores the metadata in the footer and
    renames the temporary file onto ``path`` (atomic: an exception leaves nothing). The file is
    the one :meth:`Estimates.save` writes for the concatenated rows.

    Use as a context manager: ``with EstimatesWriter(path) as w: w.write(df); w.meta = {...}``.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.meta: dict[str, Any] | None = None
        self.rows = 0
        self._stack = contextlib.ExitStack()
        self._writer: pq.ParquetWriter | None = None
        self._schema: pa.Schema | None = None

    def __enter__(self) -> EstimatesWriter:
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        return self

    def write(self, data: pd.DataFrame | Mapping[str, np.ndarray]) -> None:
        """Append rows, as a DataFrame or a dict of columns (each (N,), in file order): the same
        columns and dtypes every time."""
        if isinstance(data, pd.DataFrame):
            table = pa.Table.from_pandas(data, schema=self._schema, preserve_index=False)
        else:  # straight from the arrays: no DataFrame built and copied on the way
            arrays = [pa.array(np.asarray(v)) for v in data.values()]
            if self._schema is None:
                table = pa.Table.from_arrays(arrays, names=list(data))
            else:
                table = pa.Table.from_arrays(arrays, schema=self._schema)
        if self._writer is None:
            self._schema = table.schema
            self._writer = pq.ParquetWriter(self._tmp, self._schema, **_write_options(self._schema))
        self._writer.write_table(table)
        self.rows += table.num_rows

    def __exit__(self, kind, exc, tb) -> bool:  # noqa: ANN001
        try:
            if kind is None:
                if self._writer is None or self.meta is None:
                    raise FormatError(f"{self.path}: no rows or no metadata to write")
                text = json.dumps(self.meta, sort_keys=True, allow_nan=True)
                self._writer.add_key_value_metadata({META_KEY: text.encode("utf-8")})
            if self._writer is not None:
                self._writer.close()
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        return bool(self._stack.__exit__(kind, exc, tb))


def _write_options(schema: pa.Schema) -> dict[str, Any]:
    """The Parquet writer's options: LZ4, dictionary encoding only for the integer columns
    (``dither``, ``V/active``; the float columns are all distinct), page checksums (a reader
    finds a damaged page). Why these: ``docs/design/data-estimates-file.md``."""
    ints = [f.name for f in schema if not pa.types.is_floating(f.type)]
    return {"compression": "lz4", "use_dictionary": ints, "write_page_checksum": True}


def _n_from_meta(meta: dict[str, Any]) -> int:
    model = meta.get("model") or {}
    return int(model.get("n_joints", 0))


def check_estimates_match(rec: Recording, est: Estimates) -> None:
    """Raise RecordingError unless ``est`` was computed from ``rec``.

    The time stamps must be identical (same count, same values) and the recording metadata stored
    in the estimates file must equal ``rec.meta`` (:func:`check_times_match`).

    Raises
    ------
    RecordingError
        One sentence naming both files and the first difference.
    """
    check_times_match(
        rec.t,
        rec.meta,
        rec.name or "the recording",
        est.data["t"].to_numpy(dtype=float),
        est.meta,
        est.name or "estimates",
    )


def check_times_match(
    t_rec: np.ndarray,
    rec_meta: dict[str, Any],
    rname: str,
    t_est: np.ndarray,
    est_meta: dict[str, Any],
    ename: str,
) -> None:
    """:func:`check_estimates_match` from the parts it compares: the recording's time stamps
    ``t_rec`` (N,) [s] and metadata, the estimates file's ``t_est`` (M,) [s] and metadata (for a
    recording and an estimates file read in pieces). Raises RecordingError naming both."""
    if len(t_rec) != len(t_est):
        raise RecordingError(
            f"{ename}: the estimates come from another recording: column t has {len(t_est)} "
            f"samples, {rname} has {len(t_rec)}"
        )
    diff = np.flatnonzero(t_rec != t_est)
    if diff.size:
        i = int(diff[0])
        raise RecordingError(
            f"{ename}: the estimates come from another recording: t in row {i + 1} is "
            f"{t_est[i]!r} s, {rname} has {t_rec[i]!r} s"
        )
    stored = est_meta.get("recording")
    if stored is None:
        raise RecordingError(f"{ename}: metadata key 'recording' is missing")
    # both as plain JSON values (tuples as lists, numpy values as Python ones); a recording's
    # metadata is JSON by contract (Recording.meta_json), so no other conversion is needed
    a, b = plain(stored), plain(rec_meta)
    if a != b:
        key = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
        raise RecordingError(
            f"{ename}: the estimates come from another recording: metadata key {key!r} is "
            f"{_short(a.get(key))}, {rname} has {_short(b.get(key))}"
        )


def _short(v: Any, width: int = 60) -> str:
    s = repr(v)
    return s if len(s) <= width else s[: width - 3] + "..."

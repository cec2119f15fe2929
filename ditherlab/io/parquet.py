"""Parquet: the table as written by pyarrow, the metadata as a JSON string under the key-value
metadata key ``ditherlab``. The round trip is exact (column order, dtypes, extra columns,
metadata). Read whole, by row-group batches (:class:`ParquetTable`) and written whole or block by
block (:func:`write_frames`): :data:`FORMAT`."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.core.errors import FormatError, one_line
from ditherlab.core.files import atomic_path, damaged
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.recording import Recording
from ditherlab.io.common import (
    META_OPTIONS,
    NUMERIC,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
)
from ditherlab.io.format import Format

META_KEY = b"ditherlab"
#: rows per row group: a reader of blocks (:class:`ParquetTable`) decodes one at a time
ROW_GROUP = 131_072


def read(path: Path, **options: Any) -> Recording:
    """Read a ditherlab Parquet file.

    Options ``robot``, ``tool_offset``, ... (see :data:`~ditherlab.io.common.META_OPTIONS`)
    override the stored metadata; a file without ``ditherlab`` metadata needs ``robot=``.
    Raises FormatError for a truncated or corrupt file.
    """
    check_options(options, META_OPTIONS, "Parquet", str(path))
    try:
        pf = pq.ParquetFile(path, page_checksum_verification=True)
        check_schema(pf.schema_arrow, path)
        table = pf.read()
    except (pa.ArrowException, OSError) as exc:
        raise damaged(path, exc) from None
    kv = file_metadata(pf)
    stored = loads_meta(kv[META_KEY], str(path)) if META_KEY in kv else None
    meta = meta_from_options(stored, options, where=str(path))
    return Recording(table.to_pandas(), meta, name=str(path))


def check_schema(schema: pa.Schema, path: Path | str) -> None:
    """FormatError for a recording column (``t``, ``q_j``, ..., ``f_x``..``m_z``) whose Parquet
    type is not a number (e.g. numbers stored as text), naming the column and its type."""
    for f in schema:
        if not (NUMERIC.match(f.name) or f.name in WRENCH_COLUMNS):
            continue
        t = f.type
        if not (pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_decimal(t)):
            raise FormatError(
                f"{path}: column {f.name} has Parquet type {t}, expected numbers (float64)"
            )


def file_metadata(pf: pq.ParquetFile) -> dict[bytes, bytes]:
    """A Parquet file's key-value metadata: the Arrow schema's and the footer's (a file written
    by another writer may hold ``ditherlab`` in the footer's key-value metadata only)."""
    return {**(pf.schema_arrow.metadata or {}), **(pf.metadata.metadata or {})}


class ParquetTable:
    """A Parquet file read by row-group batches (:class:`ditherlab.io.format.Table`): opening it
    reads the footer only (metadata, row count, schema)."""

    t = None
    rec = None

    def __init__(self, path: Path, **options: Any):
        self.path = Path(path)
        self.name = str(self.path)
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

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive batches of ``rows`` rows, optionally only some ``columns``;
        FormatError naming the file for a damaged page."""
        try:
            for batch in self._pf.iter_batches(batch_size=rows, columns=columns):
                yield batch.to_pandas()
        except (pa.ArrowException, OSError) as exc:
            raise damaged(self.name, exc) from None


def write(rec: Recording, path: Path) -> Path:
    """Write ``rec`` atomically to ``path`` (zstd-compressed Parquet)."""
    table = pa.Table.from_pandas(rec.data, preserve_index=False)
    kv = dict(table.schema.metadata or {})
    kv[META_KEY] = dumps_meta(rec.meta).encode("utf-8")
    table = table.replace_schema_metadata(kv)
    with atomic_path(path) as tmp:
        pq.write_table(
            table, tmp, compression="zstd", write_page_checksum=True, row_group_size=ROW_GROUP
        )
    return Path(path)


def write_frames(
    frames: Iterable[pd.DataFrame], meta: dict[str, Any], path: Path, name: str | None = None
) -> Path:
    """Write a recording given as consecutive blocks of its table, atomically; memory holds one
    block. The table and metadata are :func:`write`'s, in row groups of :data:`ROW_GROUP` rows
    or fewer (one or more per block). FormatError naming ``name`` (default ``path``) for a
    column whose type differs from the first block's."""
    path = Path(path)
    schema: pa.Schema | None = None
    start = 0
    with atomic_path(path) as tmp, contextlib.ExitStack() as stack:
        writer: pq.ParquetWriter | None = None
        for data in frames:
            if writer is None:
                table = pa.Table.from_pandas(data, preserve_index=False)
                kv = dict(table.schema.metadata or {})
                kv[META_KEY] = dumps_meta(meta).encode("utf-8")
                schema = table.schema.with_metadata(kv)
                writer = stack.enter_context(
                    pq.ParquetWriter(tmp, schema, compression="zstd", write_page_checksum=True)
                )
            try:
                table = pa.Table.from_pandas(data, schema=schema, preserve_index=False)
            except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
                raise FormatError(
                    f"{name or path}: a column changes type at row {start + 1} ({one_line(exc)}); "
                    "expected one type per column"
                ) from None
            writer.write_table(table, row_group_size=ROW_GROUP)
            start += len(data)
    return path


FORMAT = Format(
    name="parquet",
    title="a Parquet file",
    read=read,
    suffixes=(".parquet", ".pq"),
    magic=(b"PAR1",),
    open=ParquetTable,
    write=write,
    output_suffixes=(".parquet", ".pq"),
    write_stream=write_frames,
)

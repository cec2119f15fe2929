"""Parquet: the table as written by pyarrow, the metadata as a JSON string under the key-value
metadata key ``ditherlab``. The round trip is exact (column order, dtypes, extra columns,
metadata)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.core.errors import FormatError
from ditherlab.core.files import atomic_path, damaged
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.recording import Recording
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
)
from ditherlab.io.csv import NUMERIC

META_KEY = b"ditherlab"
#: rows per row group: a reader of pieces (:mod:`ditherlab.io.stream`) decodes one at a time
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
    piece by piece, :class:`RecordingWriter`, stores ``ditherlab`` in the footer only)."""
    return {**(pf.schema_arrow.metadata or {}), **(pf.metadata.metadata or {})}


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

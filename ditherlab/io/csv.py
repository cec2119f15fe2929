"""CSV: one header line with the recording's column names, one line per sample; the metadata in a
sidecar JSON file beside it (``run.csv`` → ``run.json``) or from reader options.

Floats are written with the shortest representation that reads back to the same float64
(Python's ``repr``), so the round trip of float64 columns is exact. ``dither`` is written as
``True``/``False``. Read whole, in blocks of lines (:class:`CsvTable`) and written whole or
block by block (:func:`write_frames`): :data:`FORMAT`.
"""

from __future__ import annotations

import csv as pycsv
import json
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.core.errors import FormatError, one_line
from ditherlab.core.files import atomic_path
from ditherlab.core.names import VENDOR_WRENCH_COLUMNS, WRENCH_COLUMNS
from ditherlab.data.recording import Recording
from ditherlab.io.common import (
    META_OPTIONS,
    NUMERIC,
    check_options,
    checked_times,
    dumps_meta,
    loads_meta,
    looks_numeric,
    meta_from_options,
)
from ditherlab.io.format import CHUNK_ROWS, Format

OPTIONS = (*META_OPTIONS, "meta")


def sidecar_path(path: Path) -> Path:
    """The metadata sidecar of a CSV file: same folder and stem, suffix ``.json``."""
    return Path(path).with_suffix(".json")


def read(path: Path, **options: Any) -> Recording:
    """Read a ditherlab CSV file.

    Metadata comes from the sidecar ``<stem>.json`` when it exists, then reader options
    (``robot="irb140"`` or a URDF path, ``tool_offset``, ``meta={...}``) fill in or override it.
    Raises FormatError for a non-numeric cell (naming column, row, line and value) or a missing
    robot.
    """
    path = Path(path)
    check_options(options, OPTIONS, "CSV", str(path))
    meta = read_meta(path, options)
    header(path)
    try:
        data = pd.read_csv(path, skipinitialspace=True)
    except (ValueError, pd.errors.EmptyDataError) as exc:  # ParserError, UnicodeDecodeError too
        raise FormatError(f"{path}: not a readable CSV file ({one_line(exc)})") from None
    check_fields(data, path)
    check_numeric(data, path, header_lines=1)
    parse_dither(data)
    return Recording(data, meta, name=str(path))


def check_fields(data: pd.DataFrame, path: Path | str) -> None:
    """FormatError when the first data line has more fields than the header: pandas then takes
    the leading fields of every line as an index and shifts the values under the wrong names
    (without a word)."""
    if not isinstance(data.index, pd.RangeIndex):
        n = len(data.columns)
        raise FormatError(
            f"{path}: line 2 has {n + data.index.nlevels} fields but the header line has {n}; "
            "expected one field per column name on every line"
        )


def header(path: Path) -> list[str]:
    """The column names of a CSV file's header line, as written (pandas would rename a second
    ``q_1`` to ``q_1.1``); FormatError for a name that appears more than once or a file that
    cannot be parsed."""
    try:
        row = pd.read_csv(path, header=None, nrows=1, dtype=str, skipinitialspace=True)
    except (ValueError, pd.errors.EmptyDataError) as exc:  # ParserError, UnicodeDecodeError too
        raise FormatError(f"{path}: not a readable CSV file ({one_line(exc)})") from None
    names = ["" if pd.isna(v) else str(v) for v in row.iloc[0]] if len(row) else []
    if names and all(looks_numeric(c) for c in names):
        raise FormatError(
            f"{path}: the first line holds numbers ({', '.join(names[:3])}, ...), not column "
            "names; a CSV without a header line is read through a mapping file (--mapping)"
        )
    first: dict[str, int] = {}
    for i, c in enumerate(names):
        if c in first:
            raise FormatError(
                f"{path}: column {c or '(empty)'} appears more than once in the header line "
                f"(fields {first[c] + 1} and {i + 1}); expected unique column names"
            )
        first[c] = i
    _check_first_line(path, len(names))
    return names


def _check_first_line(path: Path, n: int) -> None:
    """FormatError when the first data line has more fields than the ``n`` names of the header
    line, counted before pandas parses the file: given such a line pandas builds an index of
    every extra field, which for a line of 200 000 fields takes minutes. A file this check
    cannot read (not UTF-8, a field beyond the csv module's limit) is left to pandas."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = pycsv.reader(fh, skipinitialspace=True)
            next(reader, None)  # the header line
            row = next((r for r in reader if r), None)  # pandas skips blank lines
    except (UnicodeDecodeError, pycsv.Error, OSError):
        return
    if row is not None and len(row) > n:
        raise FormatError(
            f"{path}: line {reader.line_num} has {len(row)} fields but the header line has {n}; "
            "expected one field per column name on every line"
        )


def read_meta(path: Path, options: dict[str, Any]) -> dict[str, Any]:
    """The metadata of a CSV file: its sidecar when there is one, then the reader options."""
    stored: dict[str, Any] | None = None
    side = sidecar_path(path)
    if side.is_file():
        stored = loads_meta(side.read_bytes(), str(side))
    if options.get("meta"):
        stored = {**(stored or {}), **options["meta"]}
    return meta_from_options(stored, options, base_dir=path.parent, where=str(path))


def parse_dither(data: pd.DataFrame) -> None:
    """A ``dither`` column of the words True / False (any case) becomes bool, in place."""
    if "dither" in data.columns and data["dither"].dtype == object:
        low = data["dither"].astype(str).str.strip().str.lower()
        if low.isin(["true", "false"]).all():
            data["dither"] = low == "true"


def check_numeric(
    data: pd.DataFrame, path: Path | str, header_lines: int = 1, row_offset: int = 0
) -> None:
    """FormatError for the first non-numeric cell of a numeric recording column.

    The message names the file, the column, the data row (1-based), the file line and the value;
    ``row_offset`` is the file row of ``data``'s first row (a block of a longer file).
    """
    for c in data.columns:
        if not (NUMERIC.match(str(c)) or c in WRENCH_COLUMNS or c in VENDOR_WRENCH_COLUMNS):
            continue
        col = data[c]
        if col.dtype.kind in "fiub":
            continue
        conv = pd.to_numeric(col, errors="coerce")
        bad = conv.isna().to_numpy() & col.notna().to_numpy()
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            i = k + row_offset
            raise FormatError(
                f"{path}: column {c} has a non-numeric value {col.iloc[k]!r} in row {i + 1} "
                f"(line {i + 1 + header_lines}), expected a number"
            )


class CsvTable:
    """A ditherlab CSV file read in blocks of lines (:class:`ditherlab.io.format.Table`).

    Opening it reads the ``t`` column with every column parsed (a line with more fields than
    the header, a cell that is not a number is an error here: pandas reads one column of a
    ragged file, slowly, without a word), which counts the rows; RecordingError, as the
    Recording's, when ``t`` is not finite or not strictly increasing.
    """

    rec = None

    def __init__(self, path: Path, **options: Any):
        self.path = Path(path)
        self.name = str(self.path)
        check_options(options, OPTIONS, "CSV", self.name)
        self.meta = read_meta(self.path, options)
        self.columns = header(self.path)
        self.t: np.ndarray | None = None
        if "t" not in self.columns:  # counted here; the Recording names the missing column
            self.n_rows = self._count()
            return
        parts = [f["t"].to_numpy() for f in self.frames(CHUNK_ROWS)]
        self.t = checked_times(np.concatenate(parts) if parts else np.zeros(0), self.name)
        self.n_rows = len(self.t)

    def _count(self) -> int:
        """The data lines of the file."""
        try:
            blocks = pd.read_csv(self.path, skipinitialspace=True, chunksize=CHUNK_ROWS)
            return sum(len(b) for b in blocks)
        except (ValueError, pd.errors.EmptyDataError) as exc:  # UnicodeDecodeError too
            raise FormatError(f"{self.name}: not a readable CSV file ({one_line(exc)})") from None

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive blocks of ``rows`` lines, optionally only some ``columns``,
        each checked as :func:`read` checks the whole (a cell's row and line counted from the
        file's start); FormatError naming the file."""
        start = 0
        try:
            reader = pd.read_csv(self.path, skipinitialspace=True, chunksize=rows, usecols=columns)
            for data in reader:
                check_fields(data, self.path)
                check_numeric(data, self.path, header_lines=1, row_offset=start)
                parse_dither(data)
                start += len(data)
                yield data
        except ValueError as exc:  # pandas' ParserError and UnicodeDecodeError among them
            raise FormatError(f"{self.name}: not a readable CSV file ({one_line(exc)})") from None


def write(rec: Recording, path: Path) -> Path:
    """Write ``rec`` atomically to ``path`` and its metadata to the sidecar ``<stem>.json``."""
    path = Path(path)
    text = rec.data.to_csv(index=False, lineterminator="\n", float_format=repr_float)
    side = sidecar_path(path)
    with atomic_path(side) as tmp_side, atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
        tmp_side.write_text(sidecar_text(rec.meta), encoding="utf-8")
    return path


def write_frames(
    frames: Iterable[pd.DataFrame], meta: dict[str, Any], path: Path, name: str | None = None
) -> Path:
    """Write a recording given as consecutive blocks of its table, atomically, with its sidecar;
    memory holds one block. The bytes are :func:`write`'s of the whole table (the header line
    comes with the first block). ``name`` (the recording's) is not stored."""
    path = Path(path)
    side = sidecar_path(path)
    with atomic_path(side) as tmp_side, atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            for k, data in enumerate(frames):
                text = data.to_csv(
                    index=False, header=k == 0, lineterminator="\n", float_format=repr_float
                )
                f.write(text)
        tmp_side.write_text(sidecar_text(meta), encoding="utf-8")
    return path


def sidecar_text(meta: dict[str, Any]) -> str:
    """The sidecar JSON of a recording's metadata (indented, sorted keys)."""
    return json.dumps(json.loads(dumps_meta(meta)), indent=1) + "\n"


def repr_float(x: float) -> str:
    """Shortest text that reads back to the same float64."""
    return repr(float(x))


FORMAT = Format(
    name="csv",
    title="a ditherlab CSV file",
    read=read,
    suffixes=(".csv",),
    open=CsvTable,
    write=write,
    output_suffixes=(".csv",),
    write_stream=write_frames,
)

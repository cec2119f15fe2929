"""What a recording file format is to ditherlab, and what a new one implements.

A format is a :class:`Format`: a name, how a path is recognised, and the functions that read and
write it. Each format lives in one module of ``ditherlab/io`` (``parquet.py``, ``csv.py``,
``mcap.py``, ``rosbag.py``, ``mapping.py``) that ends with its ``FORMAT``; the registry
(:mod:`ditherlab.io.registry`) finds the format of a path, a suffix or a name, and
:func:`ditherlab.io.read`, :func:`ditherlab.io.write`, :func:`ditherlab.io.detect_format`,
:func:`ditherlab.io.stream.open_source`, :func:`ditherlab.io.stream.write_stream` and
:func:`ditherlab.io.convert` dispatch through it. Nothing else in ``ditherlab.io`` asks which
format a file is.

Adding a format
---------------
One module (and its test); no other file changes.

1. ``read(path, **options) -> Recording``: the whole recording. ``options`` are the reader
   options of :func:`ditherlab.io.read`: accept :data:`ditherlab.io.common.META_OPTIONS` (and
   any of the format's own), refuse the others with :func:`ditherlab.io.common.check_options`,
   and make the metadata with :func:`ditherlab.io.common.meta_from_options` so that ``robot=``,
   ``tool_offset=``, ... work as for every format. Errors are one line naming the file
   (FormatError for the file's content, ConfigError for an option). The caller checks the units
   (:func:`ditherlab.io.common.check_units`).
2. ``open(path, **options) -> Table`` (optional): the file read in blocks of rows, for the
   commands that work piece by piece (:class:`ditherlab.io.stream.Source`). A :class:`Table`
   knows the metadata, the column names and the row count before any block is read, and
   ``frames(rows)`` hands out consecutive blocks of exactly ``rows`` rows (the last one shorter)
   whose concatenation is ``read(path).data`` to the bit: values, dtypes, column order. Whatever
   crosses a block boundary (a CSV block's first file line, a ROS 2 bag's wrench samples around
   the cut) is the table's to carry. Without ``open`` the file is read whole and cut into the
   same pieces: the results are the same, the memory is not bounded.
3. ``write(rec, path, **write_options) -> Path`` (optional; atomic, with
   :func:`ditherlab.core.files.atomic_path`) and ``write_stream(blocks, meta, path, name) ->
   Path`` (optional): the same file from consecutive blocks of the table, memory holding one
   block. A format without ``write`` is read only (``write`` refuses it); one without
   ``write_stream`` is written from the whole recording.
4. ``FORMAT = Format(name=..., title=..., suffixes=..., read=read, ...)``, registered with
   :func:`ditherlab.io.registry.register` (the built-in ones in ``ditherlab/io/__init__.py``).
5. The test: the round trip is exact (``read(write(rec)).equals(rec)``), blocks of every size
   equal the whole read, a damaged file is one FormatError naming it (tests/test_io.py and
   tests/test_stream*.py hold the pattern; ``test_a_format_registered_at_run_time`` in
   tests/test_io.py is the smallest whole example).

How a path is recognised: a format chosen by a reader option (``option``: ``mapping=`` for a
foreign log) whatever the path; else the formats whose ``suffixes`` hold the file's suffix (a
folder: those with ``folder``), else those whose ``magic`` begins the file; among these, the
first whose ``check`` accepts the content (``.mcap`` is ditherlab's own MCAP or a ROS 2 bag).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd

from ditherlab.data.recording import Recording
from ditherlab.io.common import check_units

__all__ = ["CHUNK_ROWS", "Format", "Table", "WholeTable", "whole"]

#: rows read at a time by default, and rows a piece owns (about 4.4 min at 250 Hz; replay then
#: peaks near 1 GB in all)
CHUNK_ROWS = 65_536


class Table(Protocol):
    """A recording file opened for reading in blocks of rows (:attr:`Format.open`).

    Attributes
    ----------
    name : the file, for messages ; meta : the metadata, reader options applied
    columns : the column names, in table order ; n_rows : rows of the table
    t : (n_rows,) [s] the rows' times when the reader has them already (finite, strictly
        increasing), else None (read from the ``t`` column when asked)
    rec : the whole recording when the file was read whole (memory not bounded), else None
    """

    name: str
    meta: dict[str, Any]
    columns: list[str]
    n_rows: int
    t: np.ndarray | None
    rec: Recording | None

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The table in consecutive blocks of ``rows`` rows (the last one shorter), optionally
        only some ``columns``; FormatError naming the file for a damaged block."""
        ...


class WholeTable:
    """A :class:`Table` over a recording read whole (for a format without ``open``, or a file
    that must be read whole: a ROS 2 bag whose stamps go back)."""

    t = None

    def __init__(self, rec: Recording):
        self.rec = rec
        self.name = rec.name
        self.meta = rec.meta
        self.n_rows = len(rec)
        self.columns = [str(c) for c in rec.data.columns]

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """The recording's table cut into blocks of ``rows`` rows (one empty block when it has
        no rows)."""
        data = self.rec.data if columns is None else self.rec.data[columns]
        for a in range(0, max(self.n_rows, 1), rows):
            yield data.iloc[a : a + rows].reset_index(drop=True)


def whole(rec: Recording) -> WholeTable:
    """A recording read whole as a :class:`Table`, its units checked as
    :func:`ditherlab.io.read` checks them (a DitherlabWarning for degrees, RobotError for an
    unknown robot)."""
    check_units(rec)
    return WholeTable(rec)


@dataclass(frozen=True)
class Format:
    """One recording file format (the module docstring says what to implement).

    Attributes
    ----------
    name : its name: ``write(..., format=name)``, :attr:`ditherlab.io.stream.Source.kind`
    title : what a file of it is, for messages (``"a Parquet file"``)
    read : ``read(path, **options) -> Recording``, the whole recording
    suffixes : the suffixes of its files (lower case, with the dot)
    magic : the first bytes of its files, for a file whose suffix no format has
    folder : a folder can be a recording of this format
    check : ``check(path) -> str | None`` for a path found by suffix, magic or folder: None when
        the content is of this format, else what the path holds (a phrase for the message)
    option : a reader option that chooses this format whatever the path (``mapping``)
    inputs : ``inputs(value) -> list[Path]``: the files that ``option``'s value names, which an
        output must not replace (the mapping file)
    open : ``open(path, **options) -> Table``, the file read in blocks of rows; None: read whole
    write : ``write(rec, path, **write_options) -> Path``; None: the format is read only
    output_suffixes : the suffixes for which :func:`ditherlab.io.write` picks it (``""``: a path
        without one, written as a folder)
    write_options : the options ``write`` takes besides the recording and the path
    write_stream : ``write_stream(blocks, meta, path, name) -> Path``, the file written from
        consecutive blocks of the table (``name`` for messages); None: written whole
    """

    name: str
    title: str
    read: Callable[..., Recording]
    suffixes: tuple[str, ...] = ()
    magic: tuple[bytes, ...] = ()
    folder: bool = False
    check: Callable[[Path], str | None] | None = None
    option: str | None = None
    inputs: Callable[[Any], list[Path]] | None = None
    open: Callable[..., Table] | None = None
    write: Callable[..., Path] | None = None
    output_suffixes: tuple[str, ...] = ()
    write_options: tuple[str, ...] = ()
    write_stream: Callable[[Iterable[pd.DataFrame], dict[str, Any], Path, str], Path] | None = None

"""``ditherlab info``: a recording's duration, sample rate and jitter, joints, optional columns
and time spent still, dithering and moving (:func:`ditherlab.analysis.overview.describe`), read
in pieces."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ditherlab.analysis.overview import describe, format_info
from ditherlab.app.workflow import ReadOptions
from ditherlab.io.stream import CHUNK_ROWS, open_source

__all__ = ["InfoOptions", "Info", "run"]


@dataclass(frozen=True)
class InfoOptions:
    """The options of ``ditherlab info``.

    Attributes
    ----------
    file : the recording (``.parquet``, ``.csv``, ``.mcap``, a ROS 2 bag)
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read at a time
    """

    file: Path
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS


@dataclass
class Info:
    """The recording's summary (:func:`ditherlab.analysis.overview.describe`)."""

    summary: dict[str, Any]

    def text(self) -> str:
        """The summary as lines (what the CLI prints)."""
        return format_info(self.summary)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output."""
        return self.summary


def run(options: InfoOptions) -> Info:
    """Read the recording in pieces and summarise it; nothing is written.

    Parameters
    ----------
    options : :class:`InfoOptions`

    Returns
    -------
    Info
    """
    src = open_source(options.file, **options.read.kwargs())
    return Info(describe(src, chunk_rows=options.chunk_rows))

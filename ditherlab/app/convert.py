"""``ditherlab convert``: read a recording in any readable format and write it in another,
atomically and never over the input (:func:`ditherlab.app.workflow.guard_recording`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ditherlab.analysis.known_load import KNOWN_LOAD, parse_known_load
from ditherlab.app.workflow import Progress, ReadOptions, guard_recording
from ditherlab.io.stream import CHUNK_ROWS, open_source, write_stream

__all__ = ["ConvertOptions", "Converted", "run"]


@dataclass(frozen=True)
class ConvertOptions:
    """The options of ``ditherlab convert``.

    Attributes
    ----------
    src : the input recording (any readable format)
    dst : the output: ``.parquet``, ``.csv`` (with its sidecar ``.json``), ``.mcap``, or a path
        without a suffix for a ROS 2 bag folder
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read and written at a time
    force : replace an existing output file or bag folder
    known_load : ``MASS[@X,Y,Z]``: a known load at the tool [kg; m, tool frame], written into the
        output's metadata as ``known_load`` (:mod:`ditherlab.analysis.known_load`); None: keep
        the input's
    """

    src: Path
    dst: str | Path
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS
    force: bool = False
    known_load: str | None = None


@dataclass
class Converted:
    """The file (or bag folder) written."""

    path: Path

    def text(self) -> str:
        """What the CLI prints."""
        return f"wrote {self.path}"


def run(options: ConvertOptions, progress: Progress | None = None) -> Converted:
    """Refuse an output that is, lies inside or holds the input (or a CSV input's sidecar, or
    the mapping file), an unwritable place, an existing output without ``force``, and a
    non-empty folder that is not a bag; then read ``src`` and write ``dst``. Parquet, CSV and
    ditherlab MCAP are read and written ``chunk_rows`` at a time
    (:func:`ditherlab.io.stream.write_stream`); a failure leaves no partial file.

    Parameters
    ----------
    options : :class:`ConvertOptions`
    progress : ``progress(done, total)`` over the samples written, optional

    Returns
    -------
    Converted
    """
    o = options
    load = None if o.known_load is None else parse_known_load(o.known_load)
    dst = guard_recording(o.dst, [o.src], read=o.read, force=o.force)
    src = open_source(o.src, **o.read.kwargs())
    if load is not None:
        src.meta = {**src.meta, KNOWN_LOAD: load}
    return Converted(write_stream(src, dst, rows=o.chunk_rows, progress=progress))

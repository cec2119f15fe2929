"""Reading and writing recordings: ``read(path, **options) -> Recording`` and
``write(rec, path) -> Path``, one module per format, found through one registry.

The built-in formats (:mod:`ditherlab.io.format` says what a format is and how to add one):

===============================  =================================================================
``.parquet``, ``.pq``            :mod:`ditherlab.io.parquet` (metadata under key ``ditherlab``)
``.csv``                         :mod:`ditherlab.io.csv` (metadata in the sidecar ``<stem>.json``)
``.mcap``                        ditherlab's own MCAP (:mod:`ditherlab.io.mcap`, profile
                                 ``ditherlab``) or a ROS 2 bag in MCAP storage
                                 (:mod:`ditherlab.io.rosbag`, profile ``ros2`` / ROS schemas)
``.db3``, a bag folder           a ROS 2 bag (:mod:`ditherlab.io.rosbag`)
any file with ``mapping=M``      a foreign log described by the TOML mapping file ``M``
                                 (:mod:`ditherlab.io.mapping`; read only)
===============================  =================================================================

A path is recognised by its suffix first, then by the file's content
(:func:`ditherlab.io.registry.input_format`); :func:`read`, :func:`write`, :func:`detect_format`,
:func:`open_source` (:mod:`ditherlab.io.stream`: the file read in pieces), :func:`write_stream`
and :func:`convert` dispatch through the registry. Every writer is atomic (a temporary file
beside the target, renamed on success). ``write`` to a path without a suffix (or
``format="rosbag"``) writes a ROS 2 bag folder (``storage="mcap"`` or ``"sqlite3"``).

Every ``read`` checks the units against the robot's joint limits (a DitherlabWarning when
``|q|`` lies far beyond them, as if logged in degrees) and so also raises RobotError for an
unknown robot or a URDF that does not parse.

This module registers the built-in formats. Parquet, ditherlab MCAP and ROS 2 bags are imported
when a path first needs them: importing all three up front (pyarrow's Parquet, mcap, rosbags)
costs every process that reads or writes one format about 0.1-0.3 s of CPU (``python -c "import
ditherlab.analysis.estimation"``: 1.8-1.9 s of CPU, with ditherlab.io.mcap and ditherlab.io.rosbag
too 2.1-2.2 s, the least of 6 runs each; ``-X importtime`` on an idle machine: rosbag 50-65 ms,
mcap 30-40 ms, parquet 14-21 ms). CSV and mapped logs are light and imported here
(tests/test_io.py checks that reading CSV and Parquet imports neither mcap nor rosbags).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ditherlab.core.files import check_output
from ditherlab.io import csv, mapping
from ditherlab.io.format import Format
from ditherlab.io.registry import (
    detect_format,
    extra_inputs,
    read,
    register,
    unregister,
    write,
)
from ditherlab.io.stream import open_source, write_stream

__all__ = [
    "Format",
    "check_recording_output",
    "convert",
    "detect_format",
    "open_source",
    "read",
    "register",
    "unregister",
    "write",
    "write_stream",
]


def _parquet() -> Format:
    from ditherlab.io import parquet

    return parquet.FORMAT


def _mcap() -> Format:
    from ditherlab.io import mcap

    return mcap.FORMAT


def _rosbag() -> Format:
    from ditherlab.io import rosbag

    return rosbag.FORMAT


# asked in this order for a path: CSV and Parquet by suffix; a .mcap file is ditherlab's own
# MCAP or else a ROS 2 bag (each checks the header's profile); mapped logs by their option
for _fmt in (csv.FORMAT, _parquet, _mcap, _rosbag, mapping.FORMAT):
    register(_fmt)


def check_recording_output(
    dst: str | Path, inputs: Sequence[str | Path | None] = (), *, force: bool = False
) -> Path:
    """:func:`ditherlab.core.files.check_output` for a recording written by :func:`write`: a
    path without a suffix is a ROS 2 bag folder, replaced as a whole (an existing non-empty one
    only with ``force``, and only when it is a bag); a CSV file brings its sidecar."""
    p = Path(dst)
    bag = p.suffix == ""
    return check_output(p, inputs, folder=bag, replace=bag, force=force)


def convert(
    src: str | Path,
    dst: str | Path,
    *,
    rows: int | None = None,
    force: bool = False,
    **options: Any,
) -> Path:
    """Read ``src`` (with reader ``options``, e.g. ``mapping=``, ``robot=``) and write ``dst``.

    Refuses an output that is, lies inside or contains the input (or a CSV input's sidecar, or
    the mapping file), an unwritable location, and an existing non-empty bag folder unless
    ``force`` (:func:`check_recording_output`); the output is written atomically, so a failure
    leaves no partial file. Parquet, CSV and ditherlab MCAP are read and written ``rows`` at a
    time (:func:`ditherlab.io.stream.write_stream`; default
    :data:`ditherlab.io.stream.CHUNK_ROWS`). Returns the path written.
    """
    src, dst = Path(src), Path(dst)
    inputs = [src, *extra_inputs(options)]
    check_recording_output(dst, inputs, force=force)
    return write_stream(open_source(src, **options), dst, **({"rows": rows} if rows else {}))

"""Reading and writing recordings: ``read(path, **options) -> Recording`` and
``write(rec, path) -> Path``, one module per format.

Dispatch (suffix first, then the file's content):

===============================  =================================================================
``.parquet``                     :mod:`ditherlab.io.parquet` (metadata under key ``ditherlab``)
``.csv``                         :mod:`ditherlab.io.csv` (metadata in the sidecar ``<stem>.json``)
``.mcap``                        ditherlab's own MCAP (:mod:`ditherlab.io.mcap`, profile
                                 ``ditherlab``) or a ROS 2 bag in MCAP storage
                                 (:mod:`ditherlab.io.rosbag`, profile ``ros2`` / ROS schemas)
``.db3``, a bag folder           a ROS 2 bag (:mod:`ditherlab.io.rosbag`)
any file with ``mapping=M``      a foreign log described by the TOML mapping file ``M``
                                 (:mod:`ditherlab.io.mapping`)
===============================  =================================================================

Every writer is atomic (a temporary file beside the target, renamed on success). ``write`` to a
path without a suffix (or ``format="rosbag"``) writes a ROS 2 bag folder (``storage="mcap"`` or
``"sqlite3"``).

Every ``read`` checks the units against the robot's joint limits (a DitherlabWarning when
``|q|`` lies far beyond them, as if logged in degrees) and so also raises RobotError for an
unknown robot or a URDF that does not parse.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ditherlab.core.errors import ConfigError, FormatError
from ditherlab.core.files import check_output
from ditherlab.data.recording import Recording
from ditherlab.io import csv, mapping
from ditherlab.io.common import check_units

__all__ = ["read", "write", "check_recording_output", "detect_format", "FORMATS"]

#: Formats ``write`` can produce, by name.
FORMATS = ("parquet", "csv", "mcap", "rosbag")

_MAGIC = {b"PAR1": "parquet", b"\x89MCAP": "mcap", b"SQLite format 3\x00": "rosbag"}


def detect_format(path: str | Path) -> str:
    """The format of an existing file or folder: ``parquet``, ``csv``, ``mcap`` or ``rosbag``.

    ``.mcap`` files are told apart by their header profile and schema encodings (ROS 2 bags
    have profile ``ros2`` and ``ros2msg``/``ros2idl`` schemas). Raises FormatError when the path
    does not exist or its format is unknown.
    """
    p = Path(path)
    if not p.exists():
        raise FormatError(f"{p}: no such file or folder")
    if p.is_dir():
        if (p / "metadata.yaml").is_file() or any(p.glob("*.mcap")) or any(p.glob("*.db3")):
            return "rosbag"
        raise FormatError(
            f"{p}: a folder that is not a ROS 2 bag (no metadata.yaml, .mcap or .db3 inside)"
        )
    suffix = p.suffix.lower()
    kind = {
        ".parquet": "parquet",
        ".pq": "parquet",
        ".csv": "csv",
        ".db3": "rosbag",
        ".mcap": "mcap",
    }.get(suffix)
    if kind is None:
        with open(p, "rb") as f:
            head = f.read(16)
        kind = next((k for m, k in _MAGIC.items() if head.startswith(m)), None)
        if kind is None:
            raise FormatError(
                f"{p}: unknown file format (suffix {suffix or 'none'!r}; expected .parquet, "
                ".csv, .mcap, .db3 or a ROS 2 bag folder, or a mapping file for a foreign log)"
            )
    if kind == "mcap":
        mcap = _module("mcap")
        profile, encodings = mcap.header_profile(p)
        if profile == mcap.PROFILE:
            return "mcap"
        if profile == "ros2" or encodings & {"ros2msg", "ros2idl"}:
            return "rosbag"
        raise FormatError(
            f"{p}: MCAP profile {profile!r} with schema encodings "
            f"{sorted(encodings) or 'none'} is neither a ditherlab MCAP (profile 'ditherlab') "
            "nor a ROS 2 bag (profile 'ros2')"
        )
    return kind


def read(path: str | Path, **options: Any) -> Recording:
    """Read a recording from any supported file.

    Parameters
    ----------
    path : file or ROS 2 bag folder
    **options : format options. Every format: ``robot`` (built-in name or URDF path),
        ``tool_frame``, ``tool_offset`` [m], ``payload``, ``source``, ``notes`` (fill in or
        override the metadata). ``mapping`` (a TOML file) reads a foreign log. ROS 2 bags:
        ``joint_topic``, ``wrench_topic``, ``wrench_tolerance`` [s]. Unknown options raise
        ConfigError.

    Returns
    -------
    Recording (its ``name`` is the path)
    """
    p = Path(path)
    mapping_file = options.pop("mapping", None)
    if mapping_file is not None:
        if not p.exists():
            raise FormatError(f"{p}: no such file")
        rec = mapping.read(p, mapping_file, **options)
    else:
        kind = detect_format(p)
        rec = _module(kind).read(p, **options)
    check_units(rec)
    return rec


def write(rec: Recording, path: str | Path, *, format: str | None = None, **options: Any) -> Path:
    """Write ``rec`` atomically; the format follows the suffix (or ``format=``).

    ``.parquet``, ``.csv`` (+ sidecar ``.json``), ``.mcap`` (ditherlab MCAP); a path without a
    suffix or ``format="rosbag"`` writes a ROS 2 bag folder (option ``storage="mcap"`` or
    ``"sqlite3"``). Returns the path written.
    """
    p = Path(path)
    if format is None:
        format = {
            ".parquet": "parquet",
            ".pq": "parquet",
            ".csv": "csv",
            ".mcap": "mcap",
            "": "rosbag",
        }.get(p.suffix.lower())
        if format is None:
            raise ConfigError(
                f"{p}: cannot tell the output format from the suffix {p.suffix!r} (expected "
                ".parquet, .csv, .mcap, or no suffix for a ROS 2 bag folder)"
            )
    if format not in FORMATS:
        raise ConfigError(
            f"{p}: unknown output format {format!r} (expected one of {', '.join(FORMATS)})"
        )
    if options and format != "rosbag":
        raise ConfigError(f"{p}: unknown option {next(iter(options))!r} for {format} output")
    try:
        return _module(format).write(rec, p, **options)
    except OSError as exc:  # a folder in the way, no permission, disk full: nothing is left
        raise FormatError(f"{p}: cannot write the {format} file ({exc.strerror or exc})") from None


def check_recording_output(
    dst: str | Path, inputs: Sequence[str | Path | None] = (), *, force: bool = False
) -> Path:
    """:func:`ditherlab.core.files.check_output` for a recording written by :func:`write`: a
    path without a suffix is a ROS 2 bag folder, replaced as a whole (an existing non-empty one
    only with ``force``, and only when it is a bag); a CSV file brings its sidecar."""
    p = Path(dst)
    bag = p.suffix == ""
    return check_output(p, inputs, folder=bag, replace=bag, force=force)


def _module(kind: str) -> Any:
    """The module that reads and writes format ``kind``.

    parquet, mcap and rosbag are imported here, on first use: importing all three up front
    (pyarrow, mcap, rosbags) costs every process that reads or writes one format about 0.1-0.2 s
    of CPU (``python -c "import ditherlab.io, ditherlab.io.parquet"``: median 0.79-0.82 s CPU,
    with mcap and rosbag too 0.91-1.01 s, 15 runs each; ``-X importtime``: rosbag 50-65 ms, mcap
    30-40 ms, parquet 14-21 ms). csv and mapping are light and imported at the top.
    """
    if kind == "parquet":
        from ditherlab.io import parquet as m
    elif kind == "csv":
        m = csv
    elif kind == "mcap":
        from ditherlab.io import mcap as m
    else:
        from ditherlab.io import rosbag as m
    return m

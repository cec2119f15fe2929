"""The recording formats by name, suffix and content: one registry (:mod:`ditherlab.io.format`).

``ditherlab/io/__init__.py`` registers the built-in formats (Python runs it before any module of
``ditherlab.io``): CSV, Parquet, ditherlab MCAP and ROS 2 bags, asked in that order for a path,
and foreign logs read through a mapping file (chosen by the reader option ``mapping``). A
format whose module imports a heavy library (pyarrow's Parquet, mcap, rosbags: 0.1-0.3 s of CPU
together) is registered as a function that imports it, called when a path or a name first
reaches that format in the order above: a process that reads CSV or Parquet does not import
mcap or rosbags.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from ditherlab.core.errors import ConfigError, FormatError
from ditherlab.data.recording import Recording
from ditherlab.io.common import check_units
from ditherlab.io.format import Format, Table, whole

__all__ = [
    "detect_format",
    "extra_inputs",
    "format_named",
    "formats",
    "input_format",
    "open_table",
    "output_format",
    "read",
    "register",
    "unregister",
    "write",
]

#: formats chosen by a reader option, asked first, whatever the path
_BY_OPTION: list[Format] = []
#: formats recognised by their path, in the order they are asked; a function stands for a format
#: not imported yet
_BY_PATH: list[Format | Callable[[], Format]] = []


def register(fmt: Format | Callable[[], Format]) -> None:
    """Add a format: a :class:`~ditherlab.io.format.Format`, or a function that imports and
    returns one (a format recognised by its path, imported when a path first reaches it).

    A format with a reader ``option`` is asked before every format recognised by its path; the
    others are asked in the order registered. ConfigError when a registered format (imported)
    has the same name.
    """
    if isinstance(fmt, Format):
        if any(f.name == fmt.name for f in _imported()):
            raise ConfigError(f"a format called {fmt.name!r} is registered already")
        if fmt.option is not None:
            _BY_OPTION.append(fmt)
            return
    _BY_PATH.append(fmt)


def unregister(name: str) -> None:
    """Remove the format called ``name`` (a format registered at run time, in a test)."""
    _BY_OPTION[:] = [f for f in _BY_OPTION if f.name != name]
    _BY_PATH[:] = [f for f in _BY_PATH if not (isinstance(f, Format) and f.name == name)]


def _imported() -> list[Format]:
    """The registered formats imported so far."""
    return [*_BY_OPTION, *(f for f in _BY_PATH if isinstance(f, Format))]


def _by_path() -> Iterator[Format]:
    """The formats recognised by their path, in order, each imported when the walk reaches it."""
    for k in range(len(_BY_PATH)):
        entry = _BY_PATH[k]
        if not isinstance(entry, Format):
            entry = _BY_PATH[k] = entry()
        yield entry


def formats() -> list[Format]:
    """Every registered format (all imported): those chosen by an option, then the others in the
    order they are asked."""
    return [*_BY_OPTION, *_by_path()]


def format_named(name: str) -> Format | None:
    """The format called ``name``, or None."""
    return next((f for f in formats() if f.name == name), None)


def input_format(path: Path, options: Mapping[str, Any]) -> Format:
    """The format that reads ``path`` with reader ``options``: the one an option chooses, else
    the first by suffix (or folder), then by the file's first bytes, whose ``check`` accepts the
    content.

    Raises FormatError when the path does not exist, no format has its suffix (or magic), or
    every format that has it refuses the content.
    """
    chosen = next((f for f in _BY_OPTION if options.get(f.option or "") is not None), None)
    if chosen is not None:
        return chosen
    p = Path(path)
    if not p.exists():
        raise FormatError(f"{p}: no such file or folder")
    found = _first_accepting(p, _by_suffix(p))
    if found is None and not p.is_dir():
        found = _first_accepting(p, _by_magic(p))
    if found is None:
        raise FormatError(
            f"{p}: unknown file format (suffix {p.suffix.lower() or 'none'!r}; expected "
            f"{_expected_inputs()})"
        )
    return found


def _by_suffix(p: Path) -> Iterator[Format]:
    """The formats that a folder, or a file's suffix, may be, in order."""
    suffix = p.suffix.lower()
    for f in _by_path():
        if (f.folder and p.is_dir()) or (not p.is_dir() and suffix in f.suffixes):
            yield f


def _by_magic(p: Path) -> Iterator[Format]:
    """The formats whose magic bytes begin the file, in order."""
    with open(p, "rb") as fh:
        head = fh.read(16)
    for f in _by_path():
        if any(head.startswith(m) for m in f.magic):
            yield f


def _first_accepting(p: Path, candidates: Iterator[Format]) -> Format | None:
    """The first candidate whose ``check`` accepts ``p``; None when there is none; FormatError
    naming what ``p`` holds when every candidate refuses it."""
    refused: list[Format] = []
    holds: list[str] = []
    for f in candidates:
        why = f.check(p) if f.check is not None else None
        if why is None:
            return f
        refused.append(f)
        holds.append(why)
    if not refused:
        return None
    raise FormatError(
        f"{p}: {'; '.join(dict.fromkeys(holds))}; expected {' or '.join(f.title for f in refused)}"
    )


def _expected_inputs() -> str:
    """What a readable path is, for the message on an unknown one."""
    fmts = list(_by_path())
    suffixes = list(dict.fromkeys(s for f in fmts for s in f.suffixes))
    text = ", ".join(suffixes)
    folders = [f.title for f in fmts if f.folder]
    if folders:
        text += f" or a folder ({' or '.join(folders)})"
    for f in _BY_OPTION:
        text += f", or the option {f.option}= ({f.title})"
    return text


def detect_format(path: str | Path) -> str:
    """The name of the format of an existing file or folder (``parquet``, ``csv``, ``mcap``,
    ``rosbag``, or a format registered at run time).

    ``.mcap`` files are told apart by their header profile and schema encodings (ROS 2 bags
    have profile ``ros2`` and ``ros2msg``/``ros2idl`` schemas). Raises FormatError when the path
    does not exist or its format is unknown.
    """
    return input_format(Path(path), {}).name


def read(path: str | Path, **options: Any) -> Recording:
    """Read a recording from any registered format (:func:`input_format`).

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
    Recording (its ``name`` is the path), its units checked against the robot's joint limits
    (:func:`ditherlab.io.common.check_units`)
    """
    p = Path(path)
    options = _given(options)
    rec = input_format(p, options).read(p, **options)
    check_units(rec)
    return rec


def open_table(path: str | Path, **options: Any) -> tuple[Format, Table]:
    """The format of ``path`` and the file opened in blocks of rows (read whole, its units
    checked, for a format without ``open``)."""
    p = Path(path)
    options = _given(options)
    fmt = input_format(p, options)
    if fmt.open is None:
        return fmt, whole(fmt.read(p, **options))
    return fmt, fmt.open(p, **options)


def _given(options: dict[str, Any]) -> dict[str, Any]:
    """The reader options without a format's choosing option left at None (``mapping=None``
    chooses no format, and no reader takes it)."""
    unset = {f.option for f in _BY_OPTION if options.get(f.option or "", 0) is None}
    return {k: v for k, v in options.items() if k not in unset}


def extra_inputs(options: Mapping[str, Any]) -> list[Path]:
    """The files besides the recording that a read with ``options`` takes (the mapping file of
    ``mapping=``), which an output must not replace."""
    out: list[Path] = []
    for f in _BY_OPTION:
        value = options.get(f.option or "")
        if value is not None and f.inputs is not None:
            out += f.inputs(value)
    return out


def output_format(path: Path, format: str | None = None) -> Format | None:
    """The format that :func:`write` writes ``path`` in: the one called ``format``, else the
    first whose ``output_suffixes`` hold the path's suffix; None when there is none (or it is
    read only)."""
    if format is not None:
        f = format_named(format)
        return f if f is not None and f.write is not None else None
    suffix = Path(path).suffix.lower()
    return next(
        (f for f in _by_path() if suffix in f.output_suffixes and f.write is not None), None
    )


def write(rec: Recording, path: str | Path, *, format: str | None = None, **options: Any) -> Path:
    """Write ``rec`` atomically; the format follows the suffix (or ``format=``).

    ``.parquet``, ``.csv`` (+ sidecar ``.json``), ``.mcap`` (ditherlab MCAP); a path without a
    suffix or ``format="rosbag"`` writes a ROS 2 bag folder (option ``storage="mcap"`` or
    ``"sqlite3"``). Returns the path written. ConfigError for an unknown suffix or format name,
    a read-only format, or an option the format's ``write`` does not take; FormatError when the
    file cannot be written (nothing is left).
    """
    p = Path(path)
    fmt = output_format(p, format)
    if fmt is None:
        raise _no_output_format(p, format)
    assert fmt.write is not None  # output_format returns writable formats only
    for key in options:
        if key not in fmt.write_options:
            raise ConfigError(f"{p}: unknown option {key!r} for {fmt.name} output")
    try:
        return fmt.write(rec, p, **options)
    except OSError as exc:  # a folder in the way, no permission, disk full: nothing is left
        raise FormatError(
            f"{p}: cannot write the {fmt.name} file ({exc.strerror or exc})"
        ) from None


def _no_output_format(p: Path, format: str | None) -> ConfigError:
    """The one-line error for a path (or format name) that no registered format writes."""
    writable = [f for f in formats() if f.write is not None]
    if format is not None:
        read_only = format_named(format) is not None
        return ConfigError(
            f"{p}: {'read-only' if read_only else 'unknown'} output format {format!r} "
            f"(expected one of {', '.join(f.name for f in writable)})"
        )
    suffixes = [s for f in writable for s in f.output_suffixes if s]
    folders = [f.title for f in writable if "" in f.output_suffixes]
    bare = f", or no suffix for {' or '.join(folders)} folder" if folders else ""
    return ConfigError(
        f"{p}: cannot tell the output format from the suffix {p.suffix!r} (expected "
        f"{', '.join(suffixes)}{bare})"
    )

"""Atomic output: write to a temporary file beside the target, then rename over it.

A crash never leaves half a file, and no command may write over one of its inputs.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import stat
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError, DitherlabError, FormatError

#: the files a path brings along: a CSV file's metadata sidecar ``<stem>.json``
#: (:func:`ditherlab.io.csv.sidecar_path`, which this layer cannot import)
_COMPANION_SUFFIX = {".csv": ".json"}


def companions(path: str | Path) -> list[Path]:
    """``path`` and the files read or written with it (a CSV file's sidecar ``<stem>.json``)."""
    p = Path(path)
    side = _COMPANION_SUFFIX.get(p.suffix.lower())
    return [p] + ([p.with_suffix(side)] if side else [])


def _is_bag(folder: Path) -> bool:
    """True when ``folder`` is a ROS 2 bag folder (it holds ``metadata.yaml``)."""
    return (folder / "metadata.yaml").is_file()


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    if a.exists() and b.exists():
        with contextlib.suppress(OSError):
            return os.path.samefile(a, b)
    return False


def check_not_input(out: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Raise ConfigError when ``out`` (or a CSV output's sidecar) is, lies inside or
    contains one of ``inputs`` (files or folders; a CSV input brings its sidecar, a ROS 2 bag's
    storage file its bag folder). The input part of :func:`check_output`."""
    for o in companions(out):
        ro = o.resolve()
        for given in inputs:
            if given is None:
                continue
            for p in companions(given):
                note = "" if p == Path(given) else f" (the sidecar of {given})"
                if p.is_file() and _is_bag(p.parent):  # a bag's storage file: the bag folder
                    p, note = p.parent, f" (the ROS 2 bag of {given})"
                what = f"{'folder' if p.is_dir() else 'file'} {p}{note}"
                rp = p.resolve()
                if _same(o, p):
                    raise ConfigError(f"{o}: refusing to write over the input {what}")
                if p.is_dir() and ro.is_relative_to(rp):
                    raise ConfigError(f"{o}: refusing to write inside the input {what}")
                if rp.is_relative_to(ro):
                    raise ConfigError(
                        f"{o}: refusing to write a folder that holds the input {what}"
                    )


def _writable_ancestor(path: Path) -> None:
    """Raise ConfigError unless the nearest existing ancestor of ``path`` is a folder this
    process may create files in (``path`` named in the message)."""
    a = path.parent
    while not a.exists() and a != a.parent:
        a = a.parent
    if not a.is_dir():
        raise ConfigError(f"{path}: cannot write there: {a} is a file, not a folder")
    if not os.access(a, os.W_OK | os.X_OK):
        why = "permission denied"
        with contextlib.suppress(OSError):
            if os.statvfs(a).f_flag & os.ST_RDONLY:
                why = "read-only file system"
        raise ConfigError(f"{path}: cannot write in the folder {a} ({why})")


@dataclass(frozen=True)
class FileKind:
    """What a file output holds and how it is named: the refusals of :func:`check_output` say
    it (``model.json: expected a file name ending in .toml (a torque model), not .json``).

    Attributes
    ----------
    what : what the file holds, with its article (``"a torque model"``)
    suffixes : the suffixes its writer takes, the usual one first (``(".toml",)``)
    default : a file name to suggest inside a folder (``"model.toml"``)
    """

    what: str
    suffixes: tuple[str, ...]
    default: str

    def names(self) -> str:
        """The suffixes as words: ``.csv or .parquet``, ``.parquet, .pq, .csv or .mcap``."""
        s = list(self.suffixes)
        return s[0] if len(s) == 1 else f"{', '.join(s[:-1])} or {s[-1]}"


def _names_a_folder(out: str | Path) -> bool:
    """True when ``out`` is written as a folder: text ending in a path separator (``Path``
    drops it, so only text shows it)."""
    return isinstance(out, str) and out.endswith(("/", os.sep))


def _check_not_folder(out: str | Path, kind: FileKind | None) -> None:
    """Refuse a file output named as a folder (``DIR/``, an existing folder), saying what file
    name is expected."""
    o = Path(out)
    if _names_a_folder(out) or o.is_dir():
        said = "is a folder" if o.is_dir() else "ends in a separator, a folder name"
        hint = f" such as {o / kind.default}" if kind else ""
        raise ConfigError(f"{out}: {said}; expected a file name{hint}")


def _check_suffix(o: Path, kind: FileKind) -> None:
    """Refuse a file output whose suffix ``kind``'s writer does not take."""
    if o.suffix.lower() not in kind.suffixes:
        raise ConfigError(
            f"{o}: expected a file name ending in {kind.names()} ({kind.what}), "
            f"not {o.suffix or 'no suffix'}"
        )


def check_output(
    out: str | Path,
    inputs: Iterable[str | Path | None] = (),
    *,
    kind: FileKind | None = None,
    folder: bool = False,
    replace: bool = False,
    force: bool = False,
) -> Path:
    """The one guard of every output, called before any work: refuse (DitherlabError, one
    sentence naming the path) what would lose data or fail late.

    Refused, in this order: a file output named as a folder (``DIR/``, an existing folder);
    ``out`` equal to, inside or containing one of ``inputs`` (:func:`check_not_input`); a
    location that cannot be written (under a regular file, in a folder without write permission,
    on a read-only file system); a file output whose suffix is not one of ``kind``'s; an
    existing file output (or a CSV output's existing sidecar) unless ``force``; a file where a
    folder is written; an existing non-empty output folder unless ``force``.

    Parameters
    ----------
    out : the output file or folder; as text, a trailing ``/`` names a folder
    inputs : the files and folders the command reads (None entries are skipped)
    kind : what a file output holds (its suffixes and a default name), for its checks and
        messages; None: any name
    folder : ``out`` is a folder (a report folder; a ROS 2 bag folder with ``replace``)
    replace : the writer replaces the whole folder (a ROS 2 bag): with ``force`` only an
        existing bag folder may be replaced, never another non-empty folder
    force : allow an existing output file (replaced, atomically) or non-empty output folder

    Returns
    -------
    ``Path(out)``
    """
    o = Path(out)
    if not folder:
        _check_not_folder(out, kind)
    check_not_input(o, inputs)
    for p in companions(o):
        _writable_ancestor(p)
    if not folder:
        if kind is not None:
            _check_suffix(o, kind)
        for p in companions(o):
            if p.exists() and not force:
                whose = "" if p == o else f" (the sidecar of {o})"
                raise ConfigError(f"{p}: exists{whose}; use --force to replace it")
        return o
    if o.exists() and not o.is_dir():
        raise ConfigError(f"{o}: exists and is not a folder")
    if o.is_dir():
        if not os.access(o, os.W_OK | os.X_OK):
            raise ConfigError(f"{o}: cannot write in the folder (permission denied)")
        if any(o.iterdir()):
            if not force:
                raise ConfigError(f"{o}: the folder is not empty; use --force to write into it")
            if replace and not _is_bag(o):
                raise ConfigError(
                    f"{o}: the folder is not empty and not a ROS 2 bag (no metadata.yaml); "
                    "refusing to replace it, even with --force"
                )
    return o


def current_umask() -> int:
    """The process umask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: the temporary file of :func:`atomic_path` for a target ``NAME.SUF``: ``.NAME.SUF.XXXXXXXX.SUF``
#: (mkstemp's eight characters)
_TEMP_NAME = re.compile(r"^\.(?P<name>.+(?P<suffix>\.[A-Za-z0-9]+))\.[a-z0-9_]{8}(?P=suffix)$")


def try_lock(fd: int) -> bool:
    """Take the exclusive lock of the open file ``fd`` without waiting; False when another
    process holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def clear_stale_temporaries(folder: str | Path) -> list[Path]:
    """Remove the temporary files that :func:`atomic_path` left in ``folder`` when its process
    died before renaming them (``kill -9``, a power cut); returns the paths removed.

    Only names of :func:`atomic_path`'s pattern (``.NAME.SUF.XXXXXXXX.SUF``) are considered,
    and only those whose lock no process holds: a writer holds its temporary file's lock from
    its creation to its rename, and the system releases it when the process ends, however it
    ends. Each is removed while holding its lock, so no writer can take it meanwhile.
    """
    removed: list[Path] = []
    try:
        names = [n for n in os.listdir(folder) if _TEMP_NAME.match(n)]
    except OSError:
        return removed
    for n in names:
        p = Path(folder) / n
        try:
            fd = os.open(p, os.O_RDONLY | os.O_NOFOLLOW)
        except OSError:
            continue  # gone meanwhile, or not ours to open
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode) and try_lock(fd):
                p.unlink()
                removed.append(p)
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


def _locked_temp(target: Path, suffix: str) -> tuple[int, Path]:
    """A new temporary file beside ``target`` (:data:`_TEMP_NAME`), open and locked; made again
    when a :func:`clear_stale_temporaries` removed it between its creation and its lock."""
    while True:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix, dir=target.parent)
        with contextlib.suppress(OSError):  # no locks on this file system: none clears it either
            fcntl.flock(fd, fcntl.LOCK_EX)
        if os.fstat(fd).st_nlink > 0:
            return fd, Path(tmp)
        os.close(fd)


def locked_temp_dir(parent: Path, prefix: str) -> tuple[int, Path]:
    """A new temporary folder in ``parent`` (``PREFIX`` and eight characters), with an open
    descriptor of it holding its lock while the caller writes it (closing the descriptor, or
    the process ending, releases it): a clearing of stale folders leaves it alone. Made again
    when such a clearing removed it between its creation and its lock."""
    while True:
        tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
        fd = os.open(tmp, os.O_RDONLY)
        with contextlib.suppress(OSError):  # no locks on this file system: none clears it either
            fcntl.flock(fd, fcntl.LOCK_EX)
        if os.fstat(fd).st_nlink > 0:
            return fd, tmp
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it to ``path``.

    The temporary file keeps the target's suffix (writers dispatch on it) and stays locked
    while it is written; the temporary files that a killed process left in the folder are
    removed first (:func:`clear_stale_temporaries`). On an exception the temporary file is
    removed and ``path`` is untouched.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        clear_stale_temporaries(target.parent)
        fd, tmp_path = _locked_temp(target, suffix if suffix is not None else target.suffix)
    except OSError as exc:  # a file in the way, no permission, read-only: one line
        raise DitherlabError(f"{target}: cannot write ({exc.strerror or exc})") from None
    try:
        os.chmod(tmp_path, 0o666 & ~current_umask())  # mkstemp makes 0600: the usual mode
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise
    finally:
        os.close(fd)  # the lock goes with it


@contextlib.contextmanager
def all_or_nothing(folder: str | Path) -> Iterator[Path]:
    """A block that writes files into ``folder``: if it raises, the files and folders it
    created there are removed (and ``folder`` itself when the block created it), so a command
    that fails half-way leaves no partial output. Files it replaced stay replaced (each was
    written atomically: whole, old or new)."""
    out = Path(folder)
    existed = out.exists()
    before = set(out.rglob("*")) if existed else set()
    try:
        yield out
    except BaseException:
        if out.is_dir():
            for p in sorted(set(out.rglob("*")) - before, key=lambda p: len(p.parts), reverse=True):
                with contextlib.suppress(OSError):
                    p.rmdir() if p.is_dir() and not p.is_symlink() else p.unlink()
            if not existed:
                with contextlib.suppress(OSError):
                    out.rmdir()
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def plain(x: Any) -> Any:
    """numpy values -> plain Python, recursively (for TOML and JSON): arrays and tuples as lists,
    numpy scalars as numbers, dict keys as strings. The one numpy -> JSON/TOML conversion."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def json_default(x: Any) -> Any:
    """``json.dumps(..., default=json_default)``: numpy scalars as Python numbers, arrays as
    (nested) lists (:func:`plain`); anything else is not JSON (TypeError)."""
    if isinstance(x, np.generic | np.ndarray):
        return plain(x)
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def atomic_write_json(path: str | Path, obj: Any, indent: int = 1) -> Path:
    """Write ``obj`` as JSON (numpy values converted, :func:`json_default`) atomically."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, default=json_default))


def damaged(path: Path | str, exc: BaseException) -> FormatError:
    """The error for a Parquet file pyarrow cannot read: one line, whatever pyarrow's message
    (a corrupt page's runs over several lines: only its first, trimmed, is kept)."""
    lines = [x.strip() for x in str(exc).splitlines() if x.strip()]
    why = lines[0].rstrip(":") if lines else type(exc).__name__
    return FormatError(f"{path}: not a readable Parquet file, truncated or corrupt ({why})")

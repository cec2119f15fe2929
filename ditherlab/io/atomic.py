"""Atomic output: write to a temporary file beside the target, then rename over it.

A crash never leaves half a file, and no command may write over one of its inputs.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.errors import DitherlabError


def check_not_input(out: str | Path, inputs: Iterable[str | Path]) -> None:
    """Raise DitherlabError when ``out`` is one of ``inputs`` (same file on disk)."""
    o = Path(out)
    for i in inputs:
        p = Path(i)
        same = o.resolve() == p.resolve()
        if not same and o.exists() and p.exists():
            with contextlib.suppress(OSError):
                same = os.path.samefile(o, p)
        if same:
            raise DitherlabError(f"{o}: refusing to write over the input file {p}")


def current_umask() -> int:
    """The process umask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it to ``path``.

    The temporary file keeps the target's suffix (writers dispatch on it). On an exception the
    temporary file is removed and ``path`` is untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{target.name}.",
        suffix=suffix if suffix is not None else target.suffix,
        dir=target.parent,
    )
    os.close(fd)
    os.chmod(tmp, 0o666 & ~current_umask())  # mkstemp makes 0600; give the file the usual mode
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
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

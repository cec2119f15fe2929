"""Arrays gathered per key, in memory up to a budget, then on disk: ``Spill``.

Identification of a long log keeps, per joint and regime, every friction-residual sample (the
maximum-likelihood fits and their block bootstrap need them all, in time order). Ten hours at
250 Hz is 9 M samples per joint: held in memory for every joint and regime at once that is
several GB. A :class:`Spill` holds the appended arrays in memory up to ``budget`` bytes, then
appends them to one temporary file per key (raw bytes, in order) and starts again;
:meth:`Spill.load` returns one key's array whole — what is on disk, then what is held — so only
one key's samples are in memory while it is fitted. The files live in a
temporary folder (``TMPDIR``, default ``/tmp``) removed by :meth:`Spill.close` (or ``with``).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Hashable, Iterator
from pathlib import Path
from types import TracebackType

import numpy as np

__all__ = ["SPILL_BYTES", "Spill"]

#: bytes held in memory before the arrays go to disk (256 MB)
SPILL_BYTES = 256 * 2**20


class Spill:
    """Append-only arrays per key, spilled to temporary files past ``budget`` bytes.

    Parameters
    ----------
    budget : bytes held in memory before everything held is written out (0: write every
        append)

    Every key holds one 1-D array of one dtype (the first append's); appends must keep it.
    """

    def __init__(self, budget: int = SPILL_BYTES):
        self.budget = int(budget)
        self._held: dict[Hashable, list[np.ndarray]] = {}
        self._dtype: dict[Hashable, np.dtype] = {}
        self._count: dict[Hashable, int] = {}
        self._files: dict[Hashable, Path] = {}
        self._bytes = 0
        self._dir: Path | None = None
        #: bytes written to disk so far
        self.spilled = 0

    def append(self, key: Hashable, a: np.ndarray) -> None:
        """Append the array ``a`` (flattened to 1-D, any unit) to ``key``'s array."""
        a = np.ascontiguousarray(a).reshape(-1)
        dt = self._dtype.setdefault(key, a.dtype)
        if a.dtype != dt:
            raise TypeError(f"spill key {key!r} holds {dt}, got {a.dtype}")
        self._held.setdefault(key, []).append(a)
        self._count[key] = self._count.get(key, 0) + len(a)
        self._bytes += a.nbytes
        if self._bytes > self.budget:
            self._flush()

    def flush(self) -> None:
        """Write what is held to disk, if anything is on disk already (then only one key's
        array is in memory at a time from here on, as :meth:`load` reads it)."""
        if self._files:
            self._flush()

    def _flush(self) -> None:
        if self._dir is None:
            self._dir = Path(tempfile.mkdtemp(prefix="ditherlab-spill-"))
        for key, parts in self._held.items():
            if not parts:
                continue
            path = self._files.get(key)
            if path is None:
                path = self._files[key] = self._dir / f"{len(self._files)}.bin"
            with open(path, "ab") as f:
                for p in parts:
                    p.tofile(f)
                    self.spilled += p.nbytes
            parts.clear()
        self._bytes = 0

    def count(self, key: Hashable) -> int:
        """Elements appended to ``key`` (0 for a key never seen)."""
        return self._count.get(key, 0)

    def keys(self) -> Iterator[Hashable]:
        """The keys in first-append order."""
        return iter(self._count)

    def load(self, key: Hashable) -> np.ndarray:
        """``key``'s whole array, (count,), in append order."""
        dt = self._dtype[key]
        parts = []
        path = self._files.get(key)
        if path is not None:
            parts.append(np.fromfile(path, dtype=dt))
        parts.extend(self._held.get(key, ()))
        if not parts:
            return np.zeros(0, dt)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def close(self) -> None:
        """Remove the temporary files (the Spill is empty afterwards)."""
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
        self._dir = None
        self._files.clear()
        self._held.clear()
        self._count.clear()
        self._dtype.clear()
        self._bytes = 0

    def __enter__(self) -> Spill:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

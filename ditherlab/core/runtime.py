"""Process-wide settings of the command-line program (not applied when ditherlab is imported as
a library: they are the embedding program's choice).

:func:`reuse_freed_memory`: the commands work piece by piece (``io.stream``), and every piece
allocates arrays of a few to 20 MB. With glibc's mmap threshold fixed at its 64-bit maximum
(32 MB) and the heap trimmed only above 1 GB, a freed piece's memory is reused by the next piece
instead of being unmapped and faulted in again; the peak memory stays the same. The reasoning is
in ``docs/design/core-freed-memory.md``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: mallopt(3) parameter numbers (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: glibc's upper limit of M_MMAP_THRESHOLD on 64-bit: 4 * 1024 * 1024 * sizeof(long)
MMAP_THRESHOLD = 32 * 1024 * 1024
TRIM_THRESHOLD = 1024 * 1024 * 1024


def reuse_freed_memory() -> bool:
    """Let glibc's malloc keep and reuse freed blocks up to 32 MB instead of unmapping them.

    Returns True if both settings were accepted (glibc on Linux), False elsewhere (nothing
    changed: other allocators and platforms keep their defaults).
    """
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )


__all__ = ["reuse_freed_memory"]

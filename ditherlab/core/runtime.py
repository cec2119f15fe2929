"""Process-wide settings of the command-line program (not applied when ditherlab is imported as
a library: they are the embedding program's choice).

:func:`reuse_freed_memory`: the commands work piece by piece (``io.stream``), and every piece
allocates arrays of a few to 20 MB (``(N, 6, 6)`` Jacobians, ``(N, 6)`` columns). glibc's malloc
hands allocations above its mmap threshold (128 KB, raised adaptively up to 32 MB) to fresh
``mmap`` pages and returns them on ``free``, and trims the heap's free top above twice that
threshold: pieces then page-fault their memory in again (replay of the one-hour log spent ~1 s
of system time so, and cache misses in user time). With the threshold fixed at 32 MB (glibc's
maximum on 64-bit) and trimming above 1 GB, freed pieces are reused from the heap: replay of the
hour 5 % less CPU (farm-bench, 3 alternating runs), the same peak (10 h: 999 MB).
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

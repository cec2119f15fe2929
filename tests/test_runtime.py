"""The CLI's process settings (ditherlab.core.runtime)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ditherlab.core.runtime import MMAP_THRESHOLD

CODE = """
import resource, sys
import numpy as np
from ditherlab.core.runtime import reuse_freed_memory
ok = reuse_freed_memory() if sys.argv[1] == "1" else True
n = 20 * 1024 * 1024 // 8  # 20 MB arrays
a = np.ones(n); del a  # glibc's dynamic threshold rises to 20 MB: later ones come from the heap
for _ in range(3):
    xs = [np.ones(n) for _ in range(4)]  # 80 MB of heap
    del xs  # 80 MB free at the top of the heap: above the default trim threshold (2 x 20 MB)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
xs = [np.ones(n) for _ in range(4)]
print(ok, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_memory_is_reused_without_page_faults():
    """With the CLI's setting, 80 MB of arrays allocated after the same were freed reuse the heap's
    pages (no page faults); glibc's default trims the freed top of the heap (above twice its
    adaptive threshold) and faults the next pieces in again, page by page."""
    out = {}
    for flag in ("0", "1"):
        res = subprocess.run([sys.executable, "-c", CODE, flag], capture_output=True, text=True,
                             check=True)  # fmt: skip
        ok, faults = res.stdout.split()
        out[flag] = (ok == "True", int(faults))
    assert 20 * 1024 * 1024 <= MMAP_THRESHOLD
    assert out["1"][0] and out["1"][1] < 50, out
    assert out["0"][1] > 500, out

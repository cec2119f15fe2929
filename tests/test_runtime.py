"""The CLI's process settings (ditherlab.runtime)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ditherlab.runtime import MMAP_THRESHOLD

CODE = """
import resource, sys
import numpy as np
from ditherlab.runtime import reuse_freed_memory
ok = reuse_freed_memory() if sys.argv[1] == "1" else True
a = np.ones(2 * 1024 * 1024)  # 16 MB
del a
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
b = np.ones(2 * 1024 * 1024)
print(ok, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_memory_is_reused_without_page_faults():
    """With the CLI's setting, a 16 MB array allocated after another was freed reuses its heap
    pages (no page faults); glibc's default unmaps the first and faults the second in again
    (4096 pages of 4 KB, or fewer with huge pages: far more than a handful)."""
    out = {}
    for flag in ("0", "1"):
        res = subprocess.run([sys.executable, "-c", CODE, flag], capture_output=True, text=True,
                             check=True)  # fmt: skip
        ok, faults = res.stdout.split()
        out[flag] = (ok == "True", int(faults))
    assert 16 * 1024 * 1024 <= MMAP_THRESHOLD
    assert out["1"][0] and out["1"][1] < 20, out
    assert out["0"][1] > 200, out

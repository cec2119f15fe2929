"""Recording I/O rate per format: write and read a 250 Hz IRB140 log with every column family.

Rows: samples per second for write and for read (write includes the atomic rename), and the
file size per sample. Parquet, CSV and MCAP are exact round trips; the ROS 2 bag (MCAP storage)
keeps t, q, dq, tau and the wrench. There is no slow reference here: these are rates to watch.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

import ditherlab.io as dio
from ditherlab.data.recording import Recording, RecordingArrays


def log(seconds: float, seed: int = 0) -> Recording:
    """A synthetic 250 Hz log: q, dq, tau, tau_ffw, temp, wrench, dither."""
    rng = np.random.default_rng(seed)
    n_rows = int(seconds * 250)
    t = np.arange(n_rows) / 250.0 + rng.normal(0, 1e-5, n_rows)  # [s] with jitter
    q = np.cumsum(rng.normal(0, 1e-4, (n_rows, 6)), axis=0)
    return Recording.from_arrays(
        RecordingArrays(
            t,
            q,
            rng.normal(0, 20, (n_rows, 6)),
            dq=rng.normal(0, 0.01, (n_rows, 6)),
            tau_ffw=rng.normal(0, 2, (n_rows, 6)),
            temp=30 + rng.random((n_rows, 6)),
            wrench=rng.normal(0, 5, (n_rows, 6)),
            dither=rng.random(n_rows) > 0.5,
        ),
        {"robot": "irb140"},
    )


def size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def run(quick: bool = False) -> list[dict]:
    seconds = 30.0 if quick else 600.0
    rec = log(seconds)
    rows: list[dict] = []
    tmp = Path(tempfile.mkdtemp(prefix="ditherlab-bench-io-"))
    try:
        for name, target in (
            ("parquet", "r.parquet"),
            ("csv", "r.csv"),
            ("mcap", "r.mcap"),
            ("ROS 2 bag (mcap)", "bag"),
        ):
            p = tmp / target
            t0 = time.perf_counter()
            dio.write(rec, p)
            t1 = time.perf_counter()
            dio.read(p)
            t2 = time.perf_counter()
            label = f"io {name}, {seconds:.0f} s at 250 Hz"
            rows += [
                {"name": f"{label}: write", "value": len(rec) / (t1 - t0), "unit": "samples/s"},
                {"name": f"{label}: read", "value": len(rec) / (t2 - t1), "unit": "samples/s"},
                {"name": f"{label}: size", "value": size(p) / len(rec), "unit": "bytes/sample"},
            ]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows

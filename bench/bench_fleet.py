"""`ditherlab fleet` over many simulated robots: the LocalCluster against the serial loop.

N robots (100; 8 with ``--quick``), each a short excitation run (1 pose block, 2 pushes, no
dither) with its own seed, friction level (0.8-1.3x) and, for every third robot, a hidden
effect. Both paths run the same tasks (identify from a base model with ``inertia``, diagnose;
no thresholds) and must give identical tables; the row reports the wall-clock speed-up of the
LocalCluster (one worker per core) over the serial loop in the same run. On this 2-core machine
the ceiling is 2x.

Standalone: ``python -m bench.bench_fleet --n 20``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from ditherlab.analysis.identification import identify
from ditherlab.app.fleet import FleetOptions
from ditherlab.app.fleet import run as run_fleet
from ditherlab.app.identify import add_effect
from ditherlab.io import write
from ditherlab.sim import simulate

OPTS = {"blocks": 1, "pushes_per_block": 2}
HIDDEN = ["load_friction", "drive_gain", "payload", "position_ripple", "stribeck"]
STATIC = np.array([10.0, 9.5, 8.4, 2.5, 2.5, 1.5])
VISCOUS = np.array([3.0, 2.85, 2.52, 0.75, 0.75, 0.45])


def make_fleet(folder: Path, n: int, seed: int = 20261124) -> tuple[Path, Path]:
    """``n`` robots' recordings, a manifest and a base model (inertia from a clean robot)."""
    rng = np.random.default_rng(seed)
    ref = simulate("excitation", seed=int(rng.integers(1 << 30)), dither=False, **OPTS)
    m = identify([ref], n_boot=0)
    base = add_effect([ref], m, "inertia", joints=list(range(1, 7)), refit=False)
    base_path = folder / "base.toml"
    identify([ref], base=base, n_boot=0).save(base_path)
    rows = []
    for i in range(n):
        scale = float(rng.uniform(0.8, 1.3))
        hidden = [HIDDEN[(i // 3) % len(HIDDEN)]] if i % 3 == 0 else []
        rec = simulate(
            "excitation",
            seed=int(rng.integers(1 << 30)),
            dither=False,
            hidden=hidden,
            config={"friction": {"static": list(STATIC * scale), "viscous": list(VISCOUS * scale)}},
            **OPTS,
        )
        f = folder / f"robot{i:03d}.parquet"
        write(rec, f)
        rows.append(
            {
                "file": f.name,
                "robot": f"robot{i:03d}",
                "date": "2026-11-24",
                "notes": ",".join(hidden) or "clean",
            }
        )
        print(f"\r   simulated {i + 1}/{n}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    manifest = folder / "manifest.csv"
    pd.DataFrame(rows).to_csv(manifest, index=False)
    return manifest, base_path


def run(quick: bool = False, n: int | None = None) -> list[dict]:
    n = n or (8 if quick else 100)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        manifest, base = make_fleet(d, n)
        t0 = time.perf_counter()
        run_fleet(
            FleetOptions(
                out=d / "serial",
                manifest=manifest,
                model=base,
                scheduler="serial",
                thresholds=False,
            )
        )
        t_serial = time.perf_counter() - t0
        t0 = time.perf_counter()
        run_fleet(FleetOptions(out=d / "cluster", manifest=manifest, model=base, thresholds=False))
        t_cluster = time.perf_counter() - t0
        a = pd.read_parquet(d / "serial" / "fleet.parquet")
        b = pd.read_parquet(d / "cluster" / "fleet.parquet")
        same = a.equals(b)
        found = b.drop_duplicates("file")
    if not same:
        raise AssertionError("the LocalCluster's table differs from the serial loop's")
    return [
        {
            "name": f"fleet: {n} robots, LocalCluster ({os.cpu_count()} workers) vs serial loop",
            "value": t_cluster,
            "unit": "s",
            "reference": t_serial,
            "ratio": t_serial / t_cluster,
            "target": f"identical tables (yes); speed-up up to {os.cpu_count()}x",
        },
        {
            "name": f"fleet: recordings per second on the cluster ({len(found)} done)",
            "value": n / t_cluster,
            "unit": "rec/s",
        },
    ]


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=20)
    for row in run(n=ap.parse_args().n):
        print(row)

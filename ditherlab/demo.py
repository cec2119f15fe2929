"""The demo run by ``make demo``: ``python -m ditherlab.demo --out DIR``.

For now it runs the real flow that exists: take the sample recording from ``recordings/``,
write it in every supported format into DIR (Parquet, CSV + JSON sidecar, ditherlab MCAP, ROS 2
bags in MCAP and SQLite 3 storage), read each back, check that it equals the original, and print
``ditherlab info`` for it. Each step is a small function so the pipeline can grow here.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import ditherlab.io as dio
from ditherlab.errors import DitherlabError
from ditherlab.io.info import describe, format_info
from ditherlab.recording import WRENCH_COLUMNS, Recording

RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
SAMPLE = RECORDINGS / "ur10e-static.parquet"

#: Output name per format; the bags are folders.
TARGETS = (
    ("parquet", "sample.parquet", {}),
    ("csv", "sample.csv", {}),
    ("mcap", "sample.mcap", {}),
    ("rosbag (mcap storage)", "sample_bag_mcap", {"storage": "mcap"}),
    ("rosbag (sqlite3 storage)", "sample_bag_sqlite3", {"storage": "sqlite3"}),
)


@dataclass
class RoundTrip:
    """Result of writing one format and reading it back."""

    fmt: str
    path: Path
    size_bytes: int
    seconds: float
    exact: bool
    max_error: float  # largest |difference| over t, q, dq, tau and the wrench [SI]


def folder_size(path: Path) -> int:
    """Size of a file, or of all files in a folder [bytes]."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def max_difference(a: Recording, b: Recording) -> float:
    """Largest absolute difference of the columns a ROS 2 bag keeps (t, q, dq, tau, wrench)."""
    if len(a) != len(b):
        return float("inf")
    cols = ["t"] + [f"{p}_{j + 1}" for p in ("q", "dq", "tau") for j in range(a.n)]
    cols = [c for c in cols if c in a.data.columns]
    if a.has_wrench:
        cols += list(WRENCH_COLUMNS)
    missing = [c for c in cols if c not in b.data.columns]
    if missing:
        return float("inf")
    return float(np.max(np.abs(a.data[cols].to_numpy() - b.data[cols].to_numpy())))


def round_trip(rec: Recording, out: Path, fmt: str, name: str, options: dict) -> RoundTrip:
    """Write ``rec`` to ``out/name``, read it back and compare."""
    path = out / name
    t0 = time.perf_counter()
    kind = "rosbag" if fmt.startswith("rosbag") else None
    dio.write(rec, path, format=kind, **options)
    back = dio.read(path)
    seconds = time.perf_counter() - t0
    exact = rec.equals(back)
    return RoundTrip(fmt, path, folder_size(path), seconds, exact, max_difference(rec, back))


def report(results: list[RoundTrip]) -> str:
    """One line per format."""
    lines = [f"{'format':<26} {'size':>10}  {'write+read':>10}  result"]
    for r in results:
        verdict = "identical" if r.exact else f"max |diff| {r.max_error:.2e}"
        lines.append(
            f"{r.fmt:<26} {r.size_bytes / 1024:>8.0f} kB  {r.seconds:>8.2f} s  {verdict}"
            f"  ({r.path.name})"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the demo; returns the exit status (0 when every round trip holds)."""
    parser = argparse.ArgumentParser(prog="python -m ditherlab.demo", description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("demo-out"), help="output folder")
    parser.add_argument("--recording", type=Path, default=SAMPLE, help="sample recording")
    args = parser.parse_args(argv)
    try:
        rec = dio.read(args.recording)
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"== ditherlab info {args.recording}")
        print(format_info(describe(rec)))
        print(f"\n== round trips through every format, in {args.out}/")
        results = [round_trip(rec, args.out, *target) for target in TARGETS]
    except DitherlabError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(report(results))
    # Parquet, CSV and MCAP are exact; a ROS 2 bag keeps t (ns stamps), q, dq, tau, wrench.
    ok = all(r.exact if not r.fmt.startswith("rosbag") else r.max_error < 1e-6 for r in results)
    print("\nall round trips hold" if ok else "\nA ROUND TRIP FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

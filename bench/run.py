"""`make bench`: run every bench/bench_*.py and print one table.

Each module defines ``run(quick: bool = False) -> list[dict]``; a row has ``name`` (what was
measured), ``value`` and ``unit`` (the fast path), and optionally ``reference`` (the slow, obviously
right path measured in the same run) and ``ratio`` (reference time / fast time), and ``target``
(text). Timings are wall-clock on this machine: compare ratios, not absolute numbers.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--only", help="run only bench modules whose name contains this")
    ap.add_argument("--quick", action="store_true", help="smaller problems (smoke test)")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = ap.parse_args()
    here = Path(__file__).parent
    rows: list[dict] = []
    for mod in sorted(
        m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_")
    ):
        if args.only and args.only not in mod:
            continue
        t0 = time.perf_counter()
        module = importlib.import_module(f"bench.{mod}")
        print(f"== {mod}", file=sys.stderr, flush=True)
        for row in module.run(quick=args.quick):
            row.setdefault("module", mod)
            rows.append(row)
            _print_row(row)
        print(f"   ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


def _print_row(r: dict) -> None:
    ratio = f"{r['ratio']:.1f}x vs reference" if r.get("ratio") is not None else ""
    ref = (
        f" (reference {r['reference']:.4g} {r.get('unit', '')})"
        if r.get("reference") is not None
        else ""
    )
    target = f"  [target: {r['target']}]" if r.get("target") else ""
    print(
        f"{r['name']:<58} {r['value']:>12.4g} {r.get('unit', ''):<12}{ref} {ratio}{target}",
        flush=True,
    )


if __name__ == "__main__":
    main()

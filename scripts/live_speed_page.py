"""Write the live update's timing table of docs/live.md from a run of ``bench/bench_live.py``.

The table sits between :data:`START` and :data:`END` in docs/live.md; the text around it is
hand-written and kept. Run from the repository's root::

    python scripts/live_speed_page.py          # about 5 minutes on 2 cores

The figures are CPU time of the timing thread (on a shared machine the wall time's p99 is the
scheduler's time slice), one sample per update, profile intervals.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PAGE = ROOT / "docs" / "live.md"
START = "<!-- measured by bench/bench_live.py: scripts/live_speed_page.py writes below -->"
END = "<!-- end of the measured table -->"


def table(rows: list[dict]) -> str:
    """The Markdown table of bench_live's compute rows (``bench.bench_live._compute``)."""
    by = {r["name"].strip(): r for r in rows}

    def us(name: str, key: str = "value") -> str:
        return f"{by[name][key]:.0f} µs"

    four = "live update, 1 sample, 4 variants, profile, CPU p{}"
    paced = "live update paced at 1 kHz (sleeping between), CPU p{}"
    lines = [
        "| update of one sample | CPU p50 | CPU p99 | the general update, CPU p50 |",
        "|---|---|---|---|",
        f"| all four variants, back to back | {us(four.format(50))} | {us(four.format(99))} | "
        f"{us(four.format(50), 'reference')} ({by[four.format(50)]['ratio']:.0f}× slower) |",
        f"| all four variants, paced at 1 kHz (sleeping between updates) | "
        f"{us(paced.format(50))} | {us(paced.format(99))} | "
        f"{us(paced.format(50), 'reference')} ({by[paced.format(50)]['ratio']:.0f}× slower) |",
    ]
    for v in ("nodither_band", "nodither_noband", "dither_band", "dither_noband"):
        one = f"--variants {v} alone, CPU p{{}}"
        lines.append(f"| `--variants {v}` | {us(one.format(50))} | {us(one.format(99))} | |")
    sm = "set_membership intervals (general update), CPU p50"
    lines.append(f"| set-membership intervals, four variants (general update) | {us(sm)} | | |")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += [
        "",
        f"Measured on {os.cpu_count()} cores ({platform.processor() or platform.machine()}), "
        f"load average {load:.1f} at the end of the run.",
    ]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s of updates (a smoke run)")
    args = ap.parse_args()
    from bench.bench_live import _compute

    text = PAGE.read_text()
    if START not in text or END not in text:
        sys.exit(f"{PAGE}: the markers {START!r} and {END!r} are missing")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    PAGE.write_text(f"{head}{START}\n{table(_compute(args.quick))}\n{END}{tail}")
    print(f"wrote {PAGE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

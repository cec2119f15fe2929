"""Write the lead-through in closed loop over DDS (``ditherlab leadthrough --live``) beside the
same runs in one process into docs/lead-through.md, after its marker line.

Usage (from the repository root; needs the ``live`` extra)::

    python scripts/lead_live_page.py

Through the CLI, as a user runs it, with Cyclone DDS on the loopback interface alone: the model
is identified on the simulator's push campaigns shipped in ``recordings/``; then, on seed 1 with
dither, both laws: ``leadthrough --model --live`` (a ``ditherlab live`` process, lock-step; the
command checks it against the same runs in one process) and ``leadthrough`` (the controller's
own eq. (3)). In this process: the same estimate applied one controller update (20 ms) late, what
a transport delay of one update would do (:func:`ditherlab.app.leadthrough_live.causal_source`
with ``lag=1``). Everything above the marker line of docs/lead-through.md is hand-written and
kept.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "lead-through.md"
MARKER = "<!-- generated below by scripts/lead_live_page.py -->"
SEED = 1


def _cli(*args: str) -> tuple[str, float]:
    """``ditherlab ARGS`` in its own process: stdout and the wall time [s]."""
    sys.path.insert(0, str(ROOT))
    from ditherlab.io.dds import LOOPBACK_URI

    env = dict(os.environ, CYCLONEDDS_URI=LOOPBACK_URI, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "ditherlab", *args, "-q"], env=env, capture_output=True, text=True
    )
    if r.returncode:
        raise SystemExit(f"ditherlab {' '.join(args)} failed: {r.stderr.strip()}")
    return r.stdout, time.perf_counter() - t0


def _late_means(model_path: Path) -> list[dict]:
    """The means of the runs with ``live``'s estimate applied one update late."""
    sys.path.insert(0, str(ROOT))
    from contextlib import nullcontext

    from ditherlab.app.leadthrough import compare_laws
    from ditherlab.app.leadthrough_live import causal_source, link_settings
    from ditherlab.data.torque_model import TorqueModel

    model = TorqueModel.load(model_path)

    def late(law: str, dither: bool):
        return nullcontext(causal_source(model, link_settings(model, law, dither), lag=1))

    return compare_laws([SEED], [True], sources=late)["means"]


def _rows(label: str, means: list[dict]) -> list[str]:
    from ditherlab.analysis.lead_metrics import COMPARED

    rows = []
    for m in means:
        cells = [label, m["law"], *(fmt.format(m[key]) for key, _, fmt, _ in COMPARED)]
        rows.append("| " + " | ".join(cells + [str(m["missed_pushes"])]) + " |")
    return rows


def measure(d: Path) -> tuple[list[str], list[str]]:
    """The table's rows and the lines on how they were made."""
    model = d / "model.toml"
    sims = [str(ROOT / "recordings" / f"sim-push-{k}.parquet") for k in ("no-dither", "dither")]
    _cli("identify", *sims, "-o", str(model))
    base = ["--seed", str(SEED), "--repeats", "1", "--dither", "on"]
    out_live, s_live = _cli("leadthrough", *base, "--model", str(model), "--live", "-o", f"{d}/l")
    _, s_own = _cli("leadthrough", *base, "-o", f"{d}/own")
    live = json.loads((d / "l" / "leadthrough.json").read_text())
    own = json.loads((d / "own" / "leadthrough.json").read_text())
    loop = next(ln for ln in out_live.splitlines() if ln.startswith("closed loop"))
    rows = _rows("live over DDS, lock-step", live["means"])
    rows += _rows("live, one update late", _late_means(model))
    rows += _rows("controller's eq. (3)", own["means"])
    how = [
        f"Written by `scripts/lead_live_page.py`: seed {SEED}, dither on, both laws; the model "
        "identified on `recordings/sim-push-*.parquet`. `leadthrough --model --live` took "
        f"{s_live:.0f} s (the runs over DDS and the same runs in one process), `leadthrough` "
        f"{s_own:.0f} s. The `--live` command printed:",
        "",
        f"    {loop}",
    ]
    return rows, how


def main() -> None:
    from ditherlab.analysis.lead_metrics import COMPARED

    text = PAGE.read_text()
    head = text.split(MARKER)[0]
    with tempfile.TemporaryDirectory() as tmp:
        rows, how = measure(Path(tmp))
    heads = ["estimate", "law", *(h for _, h, _, _ in COMPARED), "missed"]
    table = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads), *rows]
    PAGE.write_text(head + MARKER + "\n\n" + "\n".join(how) + "\n\n" + "\n".join(table) + "\n")
    print(f"wrote {PAGE}")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    main()

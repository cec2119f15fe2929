"""Write the difference between the causal estimate (``replay --causal``, ``live``) and the
offline one (``replay``) into docs/live.md, after its marker line.

Usage (from the repository root)::

    python scripts/causal_page.py

On the simulator's paired push campaigns shipped in ``recordings/`` (``sim-push-no-dither`` and
``sim-push-dither``: 41.5 s at 250 Hz each, the simulator of ``make demo``), the model is
identified on both (no bootstrap), then every variant is replayed offline and causally on each.
Per variant and force axis the table gives the RMS of causal minus offline over every sample, the
lag of the causal estimate behind the offline one (the shift in 4 ms steps, up to 0.3 s, that
best aligns the two over the pushes), and the force error RMS against the F/T sensor of both.
Everything above the marker line of docs/live.md is hand-written and kept.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "live.md"
MARKER = "<!-- generated below by scripts/causal_page.py -->"
AXES = ("f_x", "f_y", "f_z")


def lag_samples(causal: np.ndarray, offline: np.ndarray, mask: np.ndarray, most: int) -> int:
    """The shift ``L`` in samples (0..most) minimising the mean squared difference of
    ``causal[i]`` and ``offline[i - L]`` over the rows ``i`` of ``mask``; arrays (N, k)."""
    best, arg = np.inf, 0
    idx = np.flatnonzero(mask)
    idx = idx[idx >= most]
    for L in range(most + 1):
        d = causal[idx] - offline[idx - L]
        m = float(np.mean(d**2))
        if m < best:
            best, arg = m, L
    return arg


def measure() -> tuple[list[str], str]:
    """The table's rows (Markdown) and a line on how they were made."""
    sys.path.insert(0, str(ROOT))
    from ditherlab.analysis.causal import CausalEstimator, block_of, settings_for
    from ditherlab.analysis.estimation import replay
    from ditherlab.analysis.identification import identify
    from ditherlab.io import read

    recs = [read(ROOT / "recordings" / f"sim-push-{k}.parquet") for k in ("no-dither", "dither")]
    t0 = time.perf_counter()
    model = identify(recs, n_boot=0)
    rows = []
    for rec in recs:
        off = replay(rec, model).data
        est = CausalEstimator(model, rec.meta, settings_for(rec))
        cau = est.update(block_of(rec))
        sensor = rec.wrench[:, :3]
        pushes = np.linalg.norm(sensor, axis=1) > 5.0
        most = int(round(0.3 / rec.dt))
        for v in est.settings.variants:
            Fo = np.column_stack([off[f"{v}/{c}"].to_numpy() for c in AXES])
            Fc = np.column_stack([cau[f"{v}/{c}"] for c in AXES])
            diff = np.sqrt(np.mean((Fc - Fo) ** 2, axis=0))
            lag = lag_samples(Fc, Fo, pushes, most) * rec.dt * 1e3
            err_o = np.sqrt(np.mean((Fo - sensor) ** 2, axis=0))
            err_c = np.sqrt(np.mean((Fc - sensor) ** 2, axis=0))
            rows.append(
                f"| {Path(rec.name).stem} | {v} | {_xyz(diff, 2)} | {lag:.0f} | "
                f"{_xyz(err_o, 1)} | {_xyz(err_c, 1)} |"
            )
    how = (
        f"Written by `scripts/causal_page.py` in {time.perf_counter() - t0:.0f} s "
        f"({len(recs[0])} and {len(recs[1])} samples; model identified on both recordings)."
    )
    return rows, how


def _xyz(v: np.ndarray, digits: int) -> str:
    return "/".join(f"{x:.{digits}f}" for x in v)


def main() -> None:
    text = PAGE.read_text()
    head = text.split(MARKER)[0]
    rows, how = measure()
    table = [
        "| recording | variant | causal − offline RMS x/y/z [N] | lag [ms] | "
        "error offline x/y/z [N] | error causal x/y/z [N] |",
        "|---|---|---|---|---|---|",
        *rows,
    ]
    PAGE.write_text(head + MARKER + "\n\n" + how + "\n\n" + "\n".join(table) + "\n")
    print(f"wrote {PAGE}")


if __name__ == "__main__":
    main()

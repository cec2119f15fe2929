"""End-to-end replay of a one-hour 250 Hz recording (900k samples), all four variants.

The recording is the built-in simulator's dithered push campaign, long enough for one hour
(``--quick``: six minutes). Timed: :func:`ditherlab.replay.replay` with the default profile
intervals — gravity and Jacobian (pinocchio), the dither extraction, ``estimate`` and
``intervals`` for each of the four variants — and then writing the estimates Parquet. The
model is identified beforehand (not timed) on a short campaign.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path


def _recording(seconds: float):
    from ditherlab.sim import simulate

    # a push takes 0.5-2 s plus 1-2 s of rest: about 2.8 s each, 6 axis-sign pairs
    per = max(int(seconds / (2.8 * 6)), 2)
    rec = simulate("push-campaign", seed=11, dither=True, pushes_per_direction=per)
    return rec.slice(None, rec.t[0] + seconds) if rec.duration > seconds else rec


def run(quick: bool = False) -> list[dict]:
    from ditherlab.identify import identify
    from ditherlab.replay import replay
    from ditherlab.sim import simulate

    seconds = 360.0 if quick else 3600.0
    t0 = time.perf_counter()
    rec = _recording(seconds)
    t_sim = time.perf_counter() - t0
    ident = [
        simulate("push-campaign", seed=12, dither=d, pushes_per_direction=4) for d in (False, True)
    ]
    model = identify(ident, n_boot=0)
    # warm the compiled kernels on a short piece so that compilation is not timed
    replay(rec.slice(None, rec.t[0] + 5.0), model)

    phases: dict[str, float] = {}

    def progress(done: int, total: int) -> None:
        phases[f"step {done}/{total}"] = time.perf_counter()

    t0 = time.perf_counter()
    est = replay(rec, model, progress=progress)
    t_replay = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as d:
        t1 = time.perf_counter()
        est.save(Path(d) / "estimates.parquet")
        t_save = time.perf_counter() - t1
    total = t_replay + t_save
    n = len(rec)
    steps = sorted(phases.items(), key=lambda kv: kv[1])
    prev = t0
    step_rows = []
    for name, tt in steps:
        step_rows.append(
            {
                "name": f"replay {name} (geometry+extraction, then estimate/intervals per variant)",
                "value": tt - prev,
                "unit": "s",
            }
        )
        prev = tt
    return [
        {
            "name": f"simulate {rec.duration:.0f} s dithered push campaign (setup, not timed)",
            "value": t_sim,
            "unit": "s",
        },
        {
            "name": f"replay {n} samples x {len(est.variants)} variants + save",
            "value": total,
            "unit": "s",
            "target": "< 60 s for 900k samples" if not quick else None,
        },
        {
            "name": "replay throughput (samples of the recording per second)",
            "value": n / total,
            "unit": "samples/s",
        },
        {"name": "save estimates Parquet", "value": t_save, "unit": "s"},
        *step_rows,
    ]


if __name__ == "__main__":
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(f"{row['name']:<90} {row['value']:>12.4g} {row['unit']}")

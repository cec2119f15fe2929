"""End-to-end replay of a one-hour 250 Hz recording (900k samples), all four variants.

The recording is the built-in simulator's dithered push campaign, long enough for one hour
(``--quick``: six minutes). Timed: :func:`ditherlab.analysis.estimation.replay` with the default profile
intervals — gravity and Jacobian (pinocchio), the dither extraction, ``estimate`` and
``intervals`` for each of the four variants — and then writing the estimates Parquet, with the
time of each phase. The model is identified beforehand (not timed) on a short campaign. The
whole span's process CPU time is printed beside the wall time: the numba kernels run on one
thread (no ``prange``); Parquet writing may use pyarrow's threads.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

#: runs of each kind (fast, reference) whose median times give the ratio
REPEATS = 3


def _reference(profile_reference):
    """The profile-interval function of the reference kernel, in the fast one's signature."""
    return lambda prob, Fm, level, progress=None: profile_reference(prob, Fm, level)


def _recording(seconds: float):
    from ditherlab.sim import simulate

    # a push takes 0.5-2 s plus 1-2 s of rest: about 2.8 s each, 6 axis-sign pairs
    per = max(int(seconds / (2.8 * 6)), 2)
    rec = simulate("push-campaign", seed=11, dither=True, pushes_per_direction=per)
    return rec.slice(None, rec.t[0] + seconds) if rec.duration > seconds else rec


def run(quick: bool = False) -> list[dict]:
    from ditherlab.analysis.estimation import replay
    from ditherlab.analysis.identification import identify
    from ditherlab.estimator.interval_methods.profile import profile_reference
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

    marks: list[tuple[float, float]] = []

    def progress(done: int, total: int) -> None:
        marks.append((time.perf_counter(), time.process_time()))

    t0, c0 = time.perf_counter(), time.process_time()
    est = replay(rec, model, progress=progress)
    t_replay = time.perf_counter() - t0
    c_replay = time.process_time() - c0
    with tempfile.TemporaryDirectory() as d:
        t1 = time.perf_counter()
        est.save(Path(d) / "estimates.parquet")
        t_save = time.perf_counter() - t1
    total = t_replay + t_save
    cpu = time.process_time() - c0
    n = len(rec)
    # the reference in the same run: the same replay with the profile intervals of the reference
    # kernel (a refactorisation per path segment). Fast and reference runs alternate, REPEATS of
    # each, and the ratio is of the medians: one run of each swings the ratio by a third on a
    # shared machine (the first long replay after the warm-up pays allocations the others reuse).
    ivl = sys.modules["ditherlab.estimator.interval_methods"]
    fast = ivl._profile
    walls, cpus = {"fast": [t_replay], "ref": []}, {"fast": [c_replay], "ref": []}
    try:
        for i in range(2 * REPEATS - 1):
            kind = "ref" if i % 2 == 0 else "fast"
            ivl._profile = fast if kind == "fast" else _reference(profile_reference)
            t2, c2 = time.perf_counter(), time.process_time()
            replay(rec, model)
            walls[kind].append(time.perf_counter() - t2)
            cpus[kind].append(time.process_time() - c2)
    finally:
        ivl._profile = fast
    t_fast, t_ref = statistics.median(walls["fast"]), statistics.median(walls["ref"])
    c_fast, c_ref = statistics.median(cpus["fast"]), statistics.median(cpus["ref"])
    # replay's progress steps: geometry (gravity, Jacobian, effects, bands), the dither
    # extraction, then per variant the estimate and its intervals
    names = ["gravity + Jacobian + effects + bands", "dither extraction"]
    for v in est.variants:
        names += [f"estimate {v}", f"intervals {v}"]
    step_rows = []
    prev = t0
    for name, (tt, _) in zip(names, marks, strict=False):
        step_rows.append({"name": f"  replay phase: {name}", "value": tt - prev, "unit": "s"})
        prev = tt
    return [
        {
            "name": f"simulate {rec.duration:.0f} s dithered push campaign (setup, not timed)",
            "value": t_sim,
            "unit": "s",
        },
        {
            "name": f"replay {n} samples x {len(est.variants)} variants, profile intervals + save",
            "value": total,
            "unit": "s",
            "target": "<= 10 s for one hour on one core" if not quick else None,
        },
        {
            "name": f"  replay alone (no save), fast profile vs reference kernel, median of {REPEATS}",
            "value": t_fast,
            "unit": "s",
            "reference": t_ref,
            "ratio": t_ref / t_fast,
        },
        {
            # CPU time: the ratio holds when other processes share the cores
            "name": "  the same, CPU time of the process",
            "value": c_fast,
            "unit": "s",
            "reference": c_ref,
            "ratio": c_ref / c_fast,
        },
        {
            "name": "  CPU time of replay + save (numba kernels single-threaded)",
            "value": cpu,
            "unit": "s",
        },
        {
            "name": "replay throughput (samples of the recording per second)",
            "value": n / total,
            "unit": "samples/s",
        },
        *step_rows,
        {"name": "  save estimates Parquet", "value": t_save, "unit": "s"},
    ]


if __name__ == "__main__":
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(f"{row['name']:<90} {row['value']:>12.4g} {row['unit']}")

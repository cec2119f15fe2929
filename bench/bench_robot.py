"""Robot model rate: gravity + tool-point Jacobian over a log, fast path vs the per-sample loop.

Two synthetic IRB140 logs at 250 Hz: a mostly-still one (95 % of the samples held at a few poses
with one-count encoder flicker, 5 % moving between them) and a moving one (every sample
distinct). The reference is the plain per-sample pinocchio loop (``evaluate(reference=True)``);
the fast paths are the compiled kernels (:mod:`ditherlab.robot.tree`) on every sample, and with
the exact or quantised deduplication and the result cache.
"""

from __future__ import annotations

import time

import numpy as np

from ditherlab.robot import RobotModel, unique_configurations

COUNT = 2 * np.pi / 2**20  # [rad] one count of a 20-bit encoder


def still_log(robot: RobotModel, N: int, seed: int = 0) -> np.ndarray:
    """(N, n) [rad]: 95 % still at 10 poses (5 % per-joint flicker of one count), 5 % moving."""
    rng = np.random.default_rng(seed)
    poses = rng.uniform(robot.q_lower / 2, robot.q_upper / 2, size=(10, robot.n))
    seg = N // 10
    parts = []
    for k in range(10):
        n_move = seg // 20  # 5 %: a smooth move from the previous pose
        a = poses[k - 1]
        s = (1 - np.cos(np.linspace(0, np.pi, n_move))) / 2
        parts.append(a + s[:, None] * (poses[k] - a))
        n_still = seg - n_move
        flick = (rng.random((n_still, robot.n)) < 0.05) * rng.choice([-1, 1], (n_still, robot.n))
        parts.append(poses[k] + COUNT * flick)
    q = np.concatenate(parts)
    return np.round(q / COUNT) * COUNT  # what a position encoder reports


def moving_log(robot: RobotModel, N: int, seed: int = 1) -> np.ndarray:
    """(N, n) [rad]: slow sinusoids on every joint, every sample distinct."""
    t = np.arange(N) / 250.0
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.05, 0.3, robot.n)
    amp = 0.4 * (robot.q_upper - robot.q_lower) / 2
    mid = (robot.q_upper + robot.q_lower) / 2
    return mid + amp * np.sin(2 * np.pi * f * t[:, None])


def _time(fn, robot: RobotModel, repeat: int) -> float:
    """Best wall-clock time of ``fn()`` [s] over ``repeat`` runs, each with an empty cache."""
    best = np.inf
    for _ in range(repeat):
        robot.clear_cache()
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _row(name: str, N: int, t_fast: float, t_ref: float, target: str | None = None) -> dict:
    return {
        "name": name,
        "value": N / t_fast,
        "unit": "samples/s",
        "reference": N / t_ref,
        "ratio": t_ref / t_fast,
        "target": target,
    }


def run(quick: bool = False) -> list[dict]:
    robot = RobotModel.from_spec("irb140", tool_offset=[0, 0, 0.1])
    N = 10_000 if quick else 100_000
    repeat = 1 if quick else 3
    rows = []
    for label, q in (("mostly still", still_log(robot, N)), ("moving", moving_log(robot, N))):

        def ref(q=q):
            # the plain per-sample pinocchio loop
            robot.evaluate(q, ["gravity", "jacobian"], reference=True)

        def compiled(q=q):
            robot.gravity_jacobian(q, dedup=False)  # every sample, compiled (robot/fast.py)

        def fast(q=q):
            robot.gravity_jacobian(q)

        def fast_tol(q=q):
            robot.gravity_jacobian(q, tol=4 * COUNT)

        t_ref = _time(ref, robot, repeat)
        t_fast = _time(fast, robot, repeat)
        t_tol = _time(fast_tol, robot, repeat)
        t_compiled = _time(compiled, robot, repeat)
        robot.clear_cache()
        fast()
        t0 = time.perf_counter()
        fast()  # a second consumer asking for the same recording's gravity and Jacobian
        t_cached = time.perf_counter() - t0
        n_unique = len(unique_configurations(q).q)
        rows.append(
            _row(f"gravity+jacobian, {label}, compiled, every sample", N, t_compiled, t_ref)
        )
        rows.append(
            _row(f"gravity+jacobian, {label} ({n_unique} distinct q), exact", N, t_fast, t_ref)
        )
        rows.append(_row(f"gravity+jacobian, {label}, tol = 4 encoder counts", N, t_tol, t_ref))
        rows.append(_row(f"gravity+jacobian, {label}, repeated call (cache)", N, t_cached, t_ref))
    return rows


if __name__ == "__main__":
    for r in run(quick=True):
        print(r)

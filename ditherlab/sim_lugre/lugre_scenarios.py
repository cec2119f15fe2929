"""The LuGre plant's scenarios: the joint reference, the pushes by a person, the dither timeline.

- ``excitation``: minimum-jerk strokes between poses drawn about the home pose (joints 1-3
  ±0.5 rad, the wrist ±0.8 rad, inside the joint limits), at durations of 1.5..5 s (slow and fast
  sliding), holds of 1.5..3 s between them; raised-cosine pushes of 10..30 N, 0.6..1.2 s, in
  drawn directions, in the middle of a third of the strokes and in half of the holds. About 90 s.
- ``push-campaign``: standing at the home pose; pushes along ±x, ±y, ±z of the base frame
  (``pushes_per_direction`` each, default 3) of 10..40 N and 0.5..2 s, in drawn order, rests of
  3..5 s between them. The dither (with ``--dither``) is on from 1 s to the end.
- ``standing``: standing at the home pose, pushed by hand in drawn directions (5..30 N,
  0.5..2 s, rests of 3..6 s) for 60 s; no F/T sensor is logged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.robot import RobotModel

__all__ = ["SCENARIOS", "Scenario", "build_scenario", "raised_cosine"]

SCENARIOS = ("excitation", "push-campaign", "standing")
AXES = "xyz"


@dataclass
class Scenario:
    """A scenario's inputs at the logged samples (N) and at the substeps (N * nsub).

    Attributes
    ----------
    name : the scenario
    dt_log : [s] logged sample step; nsub : substeps per sample
    q_ref, dq_ref : (N * nsub, n) [rad], [rad/s] the joint reference
    still : (N,) bool, the reference stands still (the dither may be on)
    push : (N, 6) [N, N·m] the wrench a person applies to the tool, base axes
    pushes : the push plan (t0 [s], duration [s], direction (3,), magnitude [N])
    sensor : an F/T sensor is logged
    """

    name: str
    dt_log: float
    nsub: int
    q_ref: np.ndarray
    dq_ref: np.ndarray
    still: np.ndarray
    push: np.ndarray
    pushes: list[dict[str, Any]] = field(default_factory=list)
    sensor: bool = True

    @property
    def n_samples(self) -> int:
        """N, the logged samples."""
        return len(self.still)


def raised_cosine(t: np.ndarray, t0: float, duration: float) -> np.ndarray:
    """(N,) [-]: a raised-cosine pulse of height 1 from t0 over duration [s] at times t (N,)."""
    x = np.clip((t - t0) / duration, 0.0, 1.0)
    return 0.5 * (1 - np.cos(2 * np.pi * x))


def _min_jerk(t: np.ndarray, segments: list[tuple[float, float, np.ndarray, np.ndarray]]):
    """q (N, n) and dq (N, n) of minimum-jerk moves (t0, t1, qa, qb), holding in between."""
    q = np.tile(segments[0][2], (len(t), 1))
    dq = np.zeros_like(q)
    for t0, t1, qa, qb in segments:
        T = t1 - t0
        x = np.clip((t - t0) / T, 0.0, 1.0)[:, None]
        inside = ((t >= t0) & (t < t1))[:, None]
        s = 10 * x**3 - 15 * x**4 + 6 * x**5
        ds = (30 * x**2 - 60 * x**3 + 30 * x**4) / T
        q = np.where(t[:, None] >= t0, qa + s * (qb - qa), q)
        dq = np.where(inside, ds * (qb - qa), dq)
    return q, dq


def _direction(rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=3)
    return d / np.sqrt(d @ d)


def _push_wrench(t: np.ndarray, pushes: list[dict[str, Any]]) -> np.ndarray:
    out = np.zeros((len(t), 6))
    for p in pushes:
        out[:, :3] += np.outer(raised_cosine(t, p["t0"], p["duration"]), p["magnitude"] * p["dir"])
    return out


def _strokes(robot: RobotModel, home: np.ndarray, rng: np.random.Generator):
    """The excitation's moves and the push plan (module docstring)."""
    n = robot.n
    amp = np.where(np.arange(n) < 3, 0.5, 0.8)
    lo = np.nan_to_num(robot.q_lower, nan=-np.inf) + 0.05
    hi = np.nan_to_num(robot.q_upper, nan=np.inf) - 0.05
    t, q, segments, pushes = 1.0, home.copy(), [], []
    while t < 88.0:
        target = np.clip(home + amp * rng.uniform(-1, 1, n), lo, hi)
        move, hold = rng.uniform(1.5, 5.0), rng.uniform(1.5, 3.0)
        segments.append((t, t + move, q, target))
        if rng.uniform() < 1 / 3:
            pushes.append(_one_push(rng, t + 0.5 * move - 0.4, 10.0, 30.0, (0.6, 1.2)))
        if rng.uniform() < 0.5:
            pushes.append(_one_push(rng, t + move + 0.2, 10.0, 30.0, (0.6, 1.2)))
        t, q = t + move + hold, target
    segments.append((t, t + 3.0, q, home))
    return segments, pushes, t + 4.0


def _one_push(rng, t0: float, lo: float, hi: float, span: tuple[float, float]) -> dict[str, Any]:
    d = _direction(rng)
    return {"t0": float(t0), "duration": float(rng.uniform(*span)), "dir": d,
            "magnitude": float(rng.uniform(lo, hi))}  # fmt: skip


def _campaign(rng: np.random.Generator, per_direction: int) -> tuple[list, float]:
    plan = [(a, s) for a in range(3) for s in (1, -1) for _ in range(per_direction)]
    plan = [plan[i] for i in rng.permutation(len(plan))]
    t, pushes = 4.0, []
    for axis, sign in plan:
        d = np.zeros(3)
        d[axis] = sign
        p = {"t0": t, "duration": float(rng.uniform(0.5, 2.0)), "dir": d,
             "magnitude": float(rng.uniform(10.0, 40.0)), "axis": AXES[axis], "sign": sign}  # fmt: skip
        pushes.append(p)
        t += p["duration"] + rng.uniform(3.0, 5.0)
    return pushes, t + 2.0


def _by_hand(rng: np.random.Generator) -> tuple[list, float]:
    t, pushes = 3.0, []
    while t < 56.0:
        p = _one_push(rng, t, 5.0, 30.0, (0.5, 2.0))
        pushes.append(p)
        t += p["duration"] + rng.uniform(3.0, 6.0)
    return pushes, 60.0


def build_scenario(name: str, robot: RobotModel, home: np.ndarray, rng, options) -> Scenario:
    """The scenario ``name`` for ``robot`` about the pose ``home`` (n,) [rad], drawn from
    ``rng``; ``options``: ``dt_log`` [s], ``nsub``, ``pushes_per_direction``, ``duration`` [s]
    (None: the scenario's own; shorter: its first part)."""
    if name not in SCENARIOS:
        raise ConfigError(f"scenario '{name}' is unknown for --plant lugre; expected one of "
                          f"{', '.join(SCENARIOS)}")  # fmt: skip
    segments: list = [(0.0, 1.0, home, home)]
    if name == "excitation":
        segments, pushes, duration = _strokes(robot, home, rng)
    elif name == "push-campaign":
        pushes, duration = _campaign(rng, int(options.get("pushes_per_direction") or 3))
    else:
        pushes, duration = _by_hand(rng)
    dt, nsub = options["dt_log"], options["nsub"]
    duration = min(duration, options.get("duration") or duration)
    pushes = [p for p in pushes if p["t0"] < duration]
    n_log = int(round(duration / dt))
    t_sub = np.arange(n_log * nsub) * (dt / nsub)
    q_ref, dq_ref = _min_jerk(t_sub, segments)
    moving = np.abs(dq_ref).reshape(n_log, nsub, -1).max(axis=(1, 2)) > 0
    t_log = (np.arange(n_log) + 1) * dt
    still = ~moving & (t_log > 1.0)
    for p in pushes:
        p["dir"] = [float(v) for v in p["dir"]]
    push = _push_wrench(t_log, [{**p, "dir": np.asarray(p["dir"])} for p in pushes])
    return Scenario(name, dt, nsub, q_ref, dq_ref, still, push, pushes, name != "standing")

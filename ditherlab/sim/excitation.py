"""Excitation: a recording made for identification and diagnosis of the torque model.

The push campaign stands in one pose, so a gravity error (``payload``), an F/T offset
(``ft_bias``) and anything that depends on load, speed or position cannot be told apart from the
stick band there. This scenario visits ``poses`` (cycled when ``blocks`` exceeds their number);
in each block the robot

1. moves smoothly to the block's pose (minimum-jerk, ``move_s``),
2. sweeps every joint back and forth about it: ``sweeps`` minimum-jerk strokes to
   ``±sweep_amplitude`` (wrist joints ``wrist_amplitude``) with durations drawn from
   [``stroke_min_s``, ``stroke_max_s``], so speeds spread from rest up to about
   1.9 amplitude / duration (Stribeck, viscous, ripple over several periods, load-dependent
   friction as gravity changes along the stroke); ``moving_pushes`` of these strokes get a
   raised-cosine push in their middle, while the joints slide (the one place where a push reaches
   the logged torque whole without dither, so an error in how it reaches the arm —
   ``attenuation_lag`` — shows),
3. stands still, ramps the dither on (when ``dither``), receives ``pushes_per_block`` raised-cosine
   pushes along random base axes and signs (magnitudes in [``magnitude_min``,
   ``magnitude_max``]), each followed by a rest, and ramps the dither off.

Every reference is a minimum-jerk profile: position, velocity and acceleration are continuous, as
from a real path planner, so the servo is never asked for a velocity step (a step rings the gear
springs, a transient no rigid-body model has). The recording is long enough (about
``blocks`` × 30 s) for a temperature drift of the hidden ``temperature_friction`` to show.
The plan depends only on the seed and the options, never on ``dither``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ditherlab.data.recording import RecordingArrays
from ditherlab.sim.engine import Engine
from ditherlab.sim.hidden import HiddenSpec
from ditherlab.sim.scenarios import (
    AXES,
    Plan,
    cable_force,
    drive,
    scenario_columns,
    scenario_rngs,
)


def _min_jerk(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk profile of progress ``s`` in [0, 1]: (position, d/ds, d²/ds²)."""
    p = s**3 * (10 - 15 * s + 6 * s**2)
    dp = 30 * s**2 * (1 - s) ** 2
    ddp = 60 * s * (1 - s) * (1 - 2 * s)
    return p, dp, ddp


def _plan(ex: dict[str, Any], n: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Segments ``{"kind": "move"|"hold"|"push", "t": duration, ...}`` of the whole run."""
    poses = np.asarray(ex["poses"], dtype=float)[:, :n]
    amp = np.full(n, float(ex["sweep_amplitude"]))
    amp[3:] = float(ex["wrist_amplitude"])
    segs: list[dict[str, Any]] = []
    here = poses[0].copy()
    for b in range(int(ex["blocks"])):
        pose = poses[b % len(poses)]
        if b > 0:
            segs.append({"kind": "move", "t": float(ex["move_s"]), "a": here, "b": pose.copy()})
            here = pose.copy()
        strokes = []
        for _ in range(int(ex["sweeps"])):
            for sign in (1.0, -1.0):
                # each joint its own amplitude share, so joints do not move in lock-step
                target = pose + sign * amp * rng.uniform(0.6, 1.0, n)
                dur = float(rng.uniform(ex["stroke_min_s"], ex["stroke_max_s"]))
                strokes.append({"kind": "move", "t": dur, "a": here, "b": target})
                here = target
        k = min(int(ex["moving_pushes"]), len(strokes))
        for i in sorted(rng.choice(len(strokes), size=k, replace=False)):
            st = strokes[int(i)]
            # a push in the middle of the stroke, while every joint slides
            d = float(min(rng.uniform(ex["duration_min"], ex["duration_max"]), 0.4 * st["t"]))
            st["push"] = {
                "start": float(rng.uniform(0.25 * st["t"], 0.75 * st["t"] - d)),
                "t": d,
                "axis": AXES[int(rng.integers(3))],
                "sign": float(rng.choice([-1.0, 1.0])),
                "magnitude": float(rng.uniform(ex["magnitude_min"], ex["magnitude_max"])),
            }
        segs.extend(strokes)
        dur = float(rng.uniform(ex["stroke_min_s"], ex["stroke_max_s"]))
        segs.append({"kind": "move", "t": dur, "a": here, "b": pose.copy()})
        here = pose.copy()
        segs.append({"kind": "hold", "t": float(ex["settle_s"]), "dither": False})
        segs.append({"kind": "ramp", "t": float(ex["ramp_s"]), "dither": True})
        for _ in range(int(ex["pushes_per_block"])):
            segs.append(
                {
                    "kind": "push",
                    "t": float(rng.uniform(ex["duration_min"], ex["duration_max"])),
                    "rest": float(rng.uniform(ex["rest_min"], ex["rest_max"])),
                    "axis": AXES[int(rng.integers(3))],
                    "sign": float(rng.choice([-1.0, 1.0])),
                    "magnitude": float(rng.uniform(ex["magnitude_min"], ex["magnitude_max"])),
                }
            )
        segs.append({"kind": "ramp", "t": float(ex["ramp_s"]), "dither": False})
    return segs


def _add_push(
    push: np.ndarray,
    push_id: np.ndarray,
    pushes: list[dict[str, Any]],
    tt: np.ndarray,
    t0: float,
    p: dict[str, Any],
    rest: float,
    moving: bool,
) -> None:
    """Add a raised-cosine push ``p`` (``t``, ``axis``, ``sign``, ``magnitude``) starting at
    ``t0`` [s] to ``push`` (N, 6) [N], mark its samples in ``push_id`` and list it."""
    mp = (tt >= t0) & (tt < t0 + p["t"])
    shape = 0.5 * (1 - np.cos(2 * np.pi * (tt[mp] - t0) / p["t"]))
    push[mp, AXES.index(p["axis"])] += p["sign"] * p["magnitude"] * shape
    push_id[mp] = len(pushes)
    pushes.append(
        {
            "t0": t0,
            "duration": p["t"],
            "rest": rest,
            "axis": p["axis"],
            "sign": int(p["sign"]),
            "magnitude": p["magnitude"],
            "moving": moving,
        }
    )


def excitation(
    engine_for: Callable[[Any], Engine],
    params: dict[str, Any],
    *,
    seed: int,
    dither: bool,
    hidden: list[HiddenSpec],
    progress: Callable[[int, int], None] | None,
    robot: Any,
) -> tuple[RecordingArrays, dict[str, Any]]:
    """Simulate the excitation scenario; returns (the recording's arrays, meta["sim"] part).

    Same parameters as :func:`ditherlab.sim.scenarios.push_campaign`. Arrays as there
    (``q, dq, tau, tau_ffw (N, n)``, ``wrench (N, 6)``, ``dither (N,)``, ``temp``), plus the
    extra integer column ``push`` (index of the push, -1 outside pushes).
    """
    ex = params["excitation"]
    plan_rng, noise_rng, hidden_rng = scenario_rngs(seed)
    segs = _plan(ex, robot.n, plan_rng)
    plan, push_id, pushes = _follow(params, robot.n, segs, dither)
    run = drive(plan, engine_for, params, hidden, (noise_rng, hidden_rng), robot, progress)
    arrays = scenario_columns(plan.t, run.out, run.wrench, run.hp, {"push": push_id})
    poses = np.asarray(ex["poses"], dtype=float)[:, : robot.n]
    sim_meta = {
        "pushes": pushes,
        "poses": [[float(v) for v in p] for p in poses],
        "timeline": {"end": float(plan.t[-1])},
        "hidden": run.hp.truth,
    }
    return arrays, sim_meta


def _follow(
    params: Mapping[str, Any], n: int, segs: list[dict[str, Any]], dither: bool
) -> tuple[Plan, np.ndarray, list[dict[str, Any]]]:
    """The segments ``segs`` (:func:`_plan`) one after another, sampled: the :class:`Plan`
    (minimum-jerk moves, holds, pushes; the cable's force on the tool throughout), the push
    index of each sample (N,) (-1 outside pushes) and the pushes as they were placed."""
    ex = params["excitation"]
    fs_hz = float(params["timing"]["sample_rate_hz"])
    t_total = sum(s["t"] + s.get("rest", 0.0) for s in segs) + float(ex["settle_s"])
    N = int(np.ceil(t_total * fs_hz))
    tt = np.arange(N) * (1.0 / fs_hz)
    poses = np.asarray(ex["poses"], dtype=float)[:, :n]
    q_ref = np.tile(poses[0], (N, 1))
    dq_ref = np.zeros((N, n))
    push = np.zeros((N, 6))
    push_id = np.full(N, -1, dtype=np.int64)
    dcmd = np.zeros(N)
    pushes: list[dict[str, Any]] = []
    t0, here, dith = 0.0, poses[0].copy(), False
    for s in segs:
        length = s["t"] + s.get("rest", 0.0)
        m = (tt >= t0) & (tt < t0 + length)
        if s["kind"] == "move":
            u = (tt[m] - t0) / s["t"]
            p, dp, _ = _min_jerk(u)
            q_ref[m] = s["a"] + p[:, None] * (s["b"] - s["a"])
            dq_ref[m] = (dp / s["t"])[:, None] * (s["b"] - s["a"])
            here = s["b"]
            if "push" in s:
                _add_push(push, push_id, pushes, tt, t0 + s["push"]["start"], s["push"], 0.0, True)
        else:
            q_ref[m] = here
            if s["kind"] == "ramp":
                dith = bool(s["dither"]) and dither
            dcmd[m] = 1.0 if dith and s["kind"] != "hold" else 0.0
            if s["kind"] == "push":
                _add_push(push, push_id, pushes, tt, t0, s, s["rest"], False)
        t0 += length
    q_ref[tt >= t0] = here
    push[:, :3] += cable_force(params)
    return Plan(tt, poses[0], q_ref, dq_ref, push, dcmd), push_id, pushes

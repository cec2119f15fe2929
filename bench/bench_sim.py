"""Simulator speed: real-time factor of a 6-joint push campaign (compiled kernel), and the kernel
against the plain numpy reference step on a short run (same numbers to tolerance)."""

from __future__ import annotations

import time

import numpy as np

from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim import simulate
from ditherlab.sim.engine import Engine, Inputs
from ditherlab.sim.params import load_params


def _campaign(per: int, dither: bool) -> tuple[float, float]:
    t0 = time.perf_counter()
    rec = simulate("push-campaign", seed=0, dither=dither, pushes_per_direction=per)
    return rec.duration, time.perf_counter() - t0


def _short(reference: bool, n_samples: int) -> tuple[np.ndarray, float]:
    eng = Engine(load_params(), RobotModel.from_spec("irb140"))
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(n_samples, q0)
    inp.dither_cmd[5:] = 1.0
    inp.tau_ext[n_samples // 2 :, 1] = 3.0
    state = eng.initial_state(q0)
    t0 = time.perf_counter()
    out = eng.run(inp, state, reference=reference)
    return out.tau, time.perf_counter() - t0


def run(quick: bool = False) -> list[dict]:
    """Rows: real-time factor with and without dither; kernel vs reference per simulated second."""
    simulate("push-campaign", seed=0, pushes_per_direction=1)  # compile / load the numba cache
    per = 5 if quick else 50
    rows = []
    for dither in (False, True):
        dur, wall = _campaign(per, dither)
        rows.append(
            {
                "name": f"push campaign {6 * per} pushes, dither={'on' if dither else 'off'}"
                f" ({dur:.0f} s simulated)",
                "value": dur / wall,
                "unit": "x real time",
                "target": ">= 15x (aim 100x); 300 pushes <= 60 s",
            }
        )
    n = 25 if quick else 75
    fast, t_fast = _short(False, n)
    ref, t_ref = _short(True, n)
    err = float(np.max(np.abs(fast - ref)))
    sim_s = n / 250.0
    rows.append(
        {
            "name": f"kernel step vs numpy reference ({n} samples, max |dtau| {err:.1e} N·m)",
            "value": t_fast / sim_s,
            "unit": "s per sim s",
            "reference": t_ref / sim_s,
            "ratio": t_ref / t_fast,
            "target": "same torques to 1e-6 N·m",
        }
    )
    return rows

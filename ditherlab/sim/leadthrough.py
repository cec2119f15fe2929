"""Lead-through (paper §V): an operator guides the tool; the robot follows the *estimated* force.

The operator pushes the tool along z, then y, then x, then several directions at once (like the
paper's Fig. 7), each push a smooth profile with a flat top, released between pushes. Every
``timing.dynamics_update_samples`` samples the controller estimates the push from the logged
torques with eq. (3) (:func:`ditherlab.estimator.estimate`, forces only):

- still and dithering: the dither signal extracted over the last period (mean of the upper and
  lower means), band shrunk by the measured dither amplitude;
- moving: Coulomb + viscous friction subtracted (known when moving), no band;
- still without dither: the full band.

Zero-stiffness impedance (admittance) control in task space, linear motions only: the commanded
tool velocity is ``admittance * (|P| - dead_zone) * P/|P|`` beyond the 10 N dead zone (limited to
``max_speed``), mapped to joint velocities through the pseudo-inverse of the Jacobian with zero
angular velocity. The dither is ramped off as soon as the commanded speed exceeds
``dither_off_speed``, and back on after ``still_s`` without motion.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ditherlab.estimator import estimate
from ditherlab.sim import plant as K
from ditherlab.sim.engine import Engine, Inputs
from ditherlab.sim.hidden import HiddenSpec, build_hidden
from ditherlab.sim.scenarios import scenario_columns, scenario_rngs, wrench_noise

#: (direction in base axes, magnitude [N], flat-top duration [s]); release 2.5 s after each.
OPERATOR_PLAN = (
    ((0.0, 0.0, -1.0), 30.0, 2.5),
    ((0.0, 1.0, 0.0), 28.0, 2.5),
    ((1.0, 0.0, 0.0), 32.0, 2.5),
    ((-1.0, -1.0, 1.0), 35.0, 3.0),
)
EDGE_S, RELEASE_S, START_S = 0.4, 2.5, 4.0


def lead_through(
    engine_for: Callable[[Any], Engine],
    params: dict[str, Any],
    *,
    seed: int,
    dither: bool,
    hidden: list[HiddenSpec],
    progress: Callable[[int, int], None] | None,
    robot: Any,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Simulate lead-through; returns (columns for Recording.from_arrays, meta["sim"] part).

    Same parameters as :func:`ditherlab.sim.scenarios.push_campaign`. Extra columns
    ``fhat_x, fhat_y, fhat_z`` [N] hold the push the controller estimated (on the tool).
    """
    lt = params["lead_through"]
    fs_hz = float(params["timing"]["sample_rate_hz"])
    dt = 1.0 / fs_hz
    n = robot.n
    plan_rng, noise_rng, hidden_rng = scenario_rngs(seed)

    segments = []
    t = START_S
    for direction, mag, flat in OPERATOR_PLAN:
        d = np.asarray(direction) / np.linalg.norm(direction)
        m = mag * plan_rng.uniform(0.9, 1.1)
        segments.append(
            {"t0": t, "direction": [float(v) for v in d], "magnitude": float(m), "flat": flat}
        )
        t += 2 * EDGE_S + flat + RELEASE_S
    N = int(np.ceil(t * fs_hz))
    tt = np.arange(N) * dt
    push = np.zeros((N, 6))
    for s in segments:
        u = tt - s["t0"]
        total = 2 * EDGE_S + s["flat"]
        rise = 0.5 * (1 - np.cos(np.pi * np.clip(u / EDGE_S, 0, 1)))
        fall = 0.5 * (1 - np.cos(np.pi * np.clip((total - u) / EDGE_S, 0, 1)))
        shape = np.where((u >= 0) & (u <= total), np.minimum(rise, fall), 0.0)
        push[:, :3] += s["magnitude"] * shape[:, None] * np.asarray(s["direction"])

    hp = build_hidden(hidden, params, tt, n, hidden_rng)
    eng = engine_for(hp)
    fs = eng.fs
    sigma = params["noise"]["tau_sigma_fraction"] * fs
    noise = noise_rng.normal(size=(N, n)) * sigma
    ft_noise = wrench_noise(params, noise_rng, N)
    q0 = np.asarray(params["pose"]["q0"], dtype=float)[:n]
    inputs = Inputs(
        push=np.ascontiguousarray(hp.arm_push(push, dt)),
        tau_ext=np.zeros((N, n)),
        q_ref=np.tile(q0, (N, 1)),
        dq_ref=np.zeros((N, n)),
        kp_on=np.ones(N),
        dither_cmd=np.zeros(N),
        fscale=np.ascontiguousarray(hp.fscale),
        noise=noise,
    )
    period = max(1, round(2 * np.pi / params["dither"]["frequency"] * fs_hz))
    still_after = int(lt["still_s"] * fs_hz)
    fhat = np.zeros((N, 3))
    ctl = {
        "v": np.zeros(3),
        "q_ref": q0.copy(),
        "still": still_after if dither else 0,
        "dither": False,
    }
    if dither:
        inputs.dither_cmd[: int(1.0 * fs_hz)] = 0.0  # first second: settle without dither

    def control(k0: int, k1: int, state: dict[str, np.ndarray], out: np.ndarray) -> None:
        k = k1 - 1
        q, dq = out[K.O_QM, k], out[K.O_VM, k]
        lo = max(0, k - period + 1)
        if out[K.O_DITHER, k, 0] > 0.5 and k - lo + 1 == period:
            w = out[K.O_TAU, lo : k + 1]
            c = w.mean(axis=0)
            up = np.where(w > c, w, 0).sum(0) / np.maximum((w > c).sum(0), 1)
            low = np.where(w < c, w, 0).sum(0) / np.maximum((w < c).sum(0), 1)
            tau = 0.5 * (up + low)
            half = np.clip(fs - out[K.O_AMEAS, k], 0.05 * fs, fs)
        else:
            tau = out[K.O_TAU, k]
            half = fs.copy()
        # moving: the mean velocity over the last dither period (the dither's vibration averages
        # out) or the commanded velocity
        moving = (np.abs(out[K.O_VM, lo : k + 1].mean(axis=0)) > 0.005) | (
            np.abs(inputs.dq_ref[k]) > 0.002
        )
        dq = np.where(moving, dq, 0.0)
        geo = robot.evaluate(q, ["gravity", "jacobian"], reference=True)  # as the plant's
        tau_bar = tau - geo["gravity"][0]
        tau_bar = tau_bar - np.where(moving, eng.fc * np.sign(dq) + eng.fv * dq, 0.0)
        half = np.where(moving, 0.0, half)
        J = geo["jacobian"]
        sol = estimate(
            tau_bar[None],
            J,
            -half,
            half,
            sigma,
            np.zeros(6),
            np.r_[np.full(3, 100.0), np.full(3, 10.0)],
            components=("f_x", "f_y", "f_z"),
        )
        p_hat = -sol.F[0, :3]  # the push on the tool
        fhat[k0:k1] = p_hat
        mag = np.linalg.norm(p_hat)
        v = np.zeros(3)
        if mag > lt["dead_zone"]:
            v = lt["admittance"] * (mag - lt["dead_zone"]) * p_hat / mag
            speed = np.linalg.norm(v)
            if speed > lt["max_speed"]:
                v *= lt["max_speed"] / speed
        # the impedance's own first-order smoothing (time constant `smoothing_s`) keeps the
        # accelerations, which the static estimator reads as force, small
        a = min(1.0, (k1 - k0) * dt / max(lt["smoothing_s"], 1e-9))
        ctl["v"] = ctl["v"] + a * (v - ctl["v"])
        v = ctl["v"]
        dq_ref = np.linalg.pinv(J[0]) @ np.r_[v, 0.0, 0.0, 0.0]
        # the next chunk follows this velocity
        k2 = min(N, k1 + (k1 - k0))
        for kk in range(k1, k2):
            inputs.q_ref[kk] = ctl["q_ref"] + dq_ref * dt * (kk - k1)
            inputs.dq_ref[kk] = dq_ref
        ctl["q_ref"] = ctl["q_ref"] + dq_ref * dt * (k2 - k1)
        if k2 < N:
            inputs.q_ref[k2:] = ctl["q_ref"]
        if dither:
            if np.linalg.norm(v) > lt["dither_off_speed"]:
                ctl["still"] = 0
            else:
                ctl["still"] += k1 - k0
            on = ctl["still"] >= still_after
            inputs.dither_cmd[k1:] = 1.0 if on else 0.0

    state = eng.initial_state(q0)
    if dither:
        inputs.dither_cmd[int(1.0 * fs_hz) :] = 1.0
    out = eng.run(inputs, state, progress=progress, chunk_callback=control)

    wrench = hp.logged_wrench(-push, robot, out.q_link) + ft_noise
    extra = {"fhat_x": fhat[:, 0], "fhat_y": fhat[:, 1], "fhat_z": fhat[:, 2]}
    cols = scenario_columns(tt, out, wrench, hp, extra)
    sim_meta = {
        "operator": segments,
        "timeline": {"end": float(tt[-1])},
        "lead_through": dict(lt),
        "dither_amplitudes": {
            "set_point": [float(v) for v in eng.jp[K.AMP_SP]],
            "unit": "N·m (amplitude of the logged torque)",
        },
        "hidden": hp.truth,
    }
    return cols, sim_meta

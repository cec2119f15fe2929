"""Scenarios: what the simulated robot is asked to do, and the Recording that comes out.

``push-campaign``: standing in the paper's pose; a short excitation (every joint moves slowly
back and forth, one sine cycle per entry of ``excitation_periods``) so that Coulomb and viscous
friction can be identified from moving data; a still settle; the dither ramp (in the dithered
run; the undithered run stands still for the same time); then smooth raised-cosine pushes along
±x, ±y, ±z of the base frame in shuffled order, magnitudes stratified over
[magnitude_min, magnitude_max], each followed by a rest; finally the dither is ramped off. The push
plan and every noise sample depend only on the seed and the options, never on ``dither``, so a
dithered and an undithered run with the same seed are paired. Friction state is carried from push
to push.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ditherlab.core.names import FORCE_AXES
from ditherlab.data.recording import Recording
from ditherlab.sim.engine import Engine, Inputs, PlantExtras
from ditherlab.sim.hidden import HiddenSpec, build_hidden
from ditherlab.sim.params import joint_array

AXES = FORCE_AXES


def scenario_rngs(
    seed: int,
) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator]:
    """The three independent streams of a scenario: (plan, noise, hidden effects)."""
    seeds = np.random.SeedSequence(seed).spawn(3)
    plan_rng, noise_rng, hidden_rng = (np.random.default_rng(s) for s in seeds)
    return plan_rng, noise_rng, hidden_rng


def cable_force(params: Mapping[str, Any]) -> np.ndarray:
    """The environment's constant force on the tool point (3,) [N, base axes]
    (``environment.cable_force``): carried by the arm and measured by the F/T sensor."""
    return np.asarray(params["environment"]["cable_force"], dtype=float)


def wrench_noise(params: Mapping[str, Any], rng: np.random.Generator, N: int) -> np.ndarray:
    """F/T sensor noise (N, 6): forces [N] with ``noise.force_sigma``, moments [N·m] with
    ``noise.moment_sigma``."""
    sigma = np.r_[
        np.full(3, params["noise"]["force_sigma"]), np.full(3, params["noise"]["moment_sigma"])
    ]
    return rng.normal(size=(N, 6)) * sigma


def scenario_columns(
    tt: np.ndarray, out: Any, wrench: np.ndarray, hp: Any, extra: dict[str, np.ndarray]
) -> dict[str, Any]:
    """The columns for :func:`to_recording` from the engine's outputs.

    Parameters
    ----------
    tt : (N,) [s]
    out : the Engine's outputs (motor-side q, dq, logged tau, tau_ffw, dither flag)
    wrench : (N, 6) [N, N·m] the F/T sensor
    hp : the HiddenPlant (its temperature)
    extra : further columns, each (N,)
    """
    q, tau = hp.logged(out.q_motor, out.tau)  # encoder offsets, drive torque scales
    return {
        "t": tt,
        "q": q,
        "dq": out.dq_motor,
        "tau": tau,
        "tau_ffw": out.tau_ffw,
        "wrench": wrench,
        "dither": out.dither,
        "temp": hp.temp,
        "extra": extra,
    }


def _plan_pushes(pc: Mapping[str, Any], rng: np.random.Generator) -> list[dict[str, Any]]:
    per = int(pc["pushes_per_direction"])
    pushes = []
    for axis in range(3):
        for sign in (1, -1):
            # stratified magnitudes: one draw in each of `per` equal bins
            edges = np.linspace(pc["magnitude_min"], pc["magnitude_max"], per + 1)
            mags = edges[:-1] + rng.random(per) * np.diff(edges)
            for m in mags:
                pushes.append({"axis": AXES[axis], "sign": sign, "magnitude": float(m)})
    order = rng.permutation(len(pushes))
    pushes = [pushes[i] for i in order]
    how = pc.get("order", "shuffled")
    if how != "shuffled":  # the shuffled order within each experiment; experiments in turn
        key = (lambda p: p["axis"]) if how == "per-axis" else (lambda p: (p["axis"], -p["sign"]))
        pushes.sort(key=key)  # stable: keeps the shuffle inside an experiment
    for p in pushes:
        p["duration"] = float(rng.uniform(pc["duration_min"], pc["duration_max"]))
        p["rest"] = float(rng.uniform(pc["rest_min"], pc["rest_max"]))
    return pushes


def push_shape(tau: np.ndarray, duration: float, release_fraction: float = 0.5) -> np.ndarray:
    """The operator's push profile, unit peak: a raised-cosine rise over ``(1 -
    release_fraction) duration`` and a raised-cosine fall over the rest.

    Parameters
    ----------
    tau : (K,) [s] time since the push began, in ``[0, duration)``
    duration : [s] the push's length
    release_fraction : [-] share of the duration spent letting go; 0.5 is the symmetric
        ``(1 - cos(2 pi tau / duration)) / 2`` (computed by that formula)

    Returns
    -------
    (K,) [-] the profile in [0, 1]
    """
    if release_fraction == 0.5:
        return 0.5 * (1 - np.cos(2 * np.pi * tau / duration))
    rise = (1.0 - release_fraction) * duration
    fall = duration - rise
    up = 0.5 * (1 - np.cos(np.pi * tau / max(rise, 1e-12)))
    down = 0.5 * (1 + np.cos(np.pi * (tau - rise) / max(fall, 1e-12)))
    return np.where(tau < rise, up, down)


def push_campaign(
    engine_for: Callable[[Any], Engine],
    params: dict[str, Any],
    *,
    seed: int,
    dither: bool,
    hidden: list[HiddenSpec],
    progress: Callable[[int, int], None] | None,
    robot: Any,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Simulate the push campaign; returns (columns for Recording.from_arrays, meta["sim"] part).

    Parameters
    ----------
    engine_for : builds the Engine for a HiddenPlant
    params : merged parameters
    seed : random seed (push plan, noise, hidden-effect draws)
    dither : dither on after the excitation
    hidden : hidden effects to inject
    progress : ``progress(done, total)``
    robot : the controller's RobotModel
    """
    pc = params["push_campaign"]
    fs_hz = float(params["timing"]["sample_rate_hz"])
    dt = 1.0 / fs_hz
    n = robot.n
    plan_rng, noise_rng, hidden_rng = scenario_rngs(seed)
    pushes = _plan_pushes(pc, plan_rng)

    amp = float(pc["excitation_amplitude"])
    periods = [float(T) for T in pc["excitation_periods"]]
    if any(h.name == "position_ripple" for h in hidden):
        # ripple shows only in motion: sweep several ripple periods at the same speeds
        scale = max(amp, 0.35) / amp if amp > 0 else 1.0
        amp, periods = amp * scale, [T * scale for T in periods]
    t_exc = float(sum(periods))
    ramp = float(params["dither"]["ramp_s"])
    settle = float(pc["settle_s"])
    t_dither_on = t_exc + settle
    t = t_dither_on + ramp + settle
    for p in pushes:
        p["t0"] = t
        t += p["duration"] + p["rest"]
    t_dither_off = t
    t_end = t + ramp + 0.5
    N = int(np.ceil(t_end * fs_hz))
    tt = np.arange(N) * dt

    q0 = np.asarray(params["pose"]["q0"], dtype=float)[:n]
    q_ref = np.tile(q0, (N, 1))
    dq_ref = np.zeros((N, n))
    t0 = 0.0
    for T in periods:
        m = (tt >= t0) & (tt < t0 + T)
        ph = 2 * np.pi * (tt[m] - t0) / T
        q_ref[m] += amp * np.sin(ph)[:, None]
        dq_ref[m] += (amp * 2 * np.pi / T * np.cos(ph))[:, None]
        t0 += T

    push = np.zeros((N, 6))
    push_id = np.full(N, -1, dtype=np.int64)
    for i, p in enumerate(pushes):
        m = (tt >= p["t0"]) & (tt < p["t0"] + p["duration"])
        shape = push_shape(tt[m] - p["t0"], p["duration"], pc["release_fraction"])
        push[m, AXES.index(p["axis"])] += p["sign"] * p["magnitude"] * shape
        push_id[m] = i

    push[:, :3] += cable_force(params)
    hp = build_hidden(hidden, params, tt, n, hidden_rng)
    engine = engine_for(hp)
    fs = engine.fs
    noise = noise_rng.normal(size=(N, n)) * params["noise"]["tau_sigma_fraction"] * fs
    ft_noise = wrench_noise(params, noise_rng, N)

    dcmd = np.zeros(N)
    if dither:
        dcmd[(tt >= t_dither_on) & (tt < t_dither_off)] = 1.0
    inputs = Inputs(
        push=hp.arm_push(push, dt),
        tau_ext=np.zeros((N, n)),
        q_ref=q_ref,
        dq_ref=dq_ref,
        kp_on=np.ones(N),
        dither_cmd=dcmd,
        fscale=hp.fscale,
        noise=noise,
    )
    state = engine.initial_state(q0)
    out = engine.run(inputs, state, progress=progress)

    # F = wrench the robot exerts = -push
    wrench = hp.logged_wrench(-push, robot, out.q_link) + ft_noise
    extra = {"push": push_id}
    if pc["log_link_angle"]:  # the arm's angle behind the gear spring: ground truth (sweeps)
        extra.update({f"q_link_{j + 1}": out.q_link[:, j] for j in range(n)})
    cols = scenario_columns(tt, out, wrench, hp, extra)
    on = out.dither & (tt >= t_dither_on + ramp + settle)
    dsp = joint_array(params, "dither.amplitude_fraction", n) * fs
    mask = np.asarray(params["dither"]["joints"][:n], dtype=bool)
    sim_meta = {
        "pushes": [
            {k: p[k] for k in ("t0", "duration", "rest", "axis", "sign", "magnitude")}
            for p in pushes
        ],
        "timeline": {
            "excitation_end": t_exc,
            "dither_on": t_dither_on if dither else None,
            "first_push": pushes[0]["t0"] if pushes else None,
            "dither_off": t_dither_off if dither else None,
            "end": float(tt[-1]),
        },
        "excitation": {"amplitude": amp, "periods": periods},
        "dither_amplitudes": {
            "set_point": [float(v) if mk else 0.0 for v, mk in zip(dsp, mask, strict=True)],
            "feedforward_mean": [
                float(out.amp_ffw[on, j].mean()) if on.any() and mask[j] else 0.0 for j in range(n)
            ],
            "measured_mean": [
                float(out.amp_meas[on, j].mean()) if on.any() and mask[j] else 0.0 for j in range(n)
            ],
            "unit": "N·m (peak amplitude of the dither in the logged torque; feedforward = "
            "the waveform's peak amplitude)",
        },
        "hidden": hp.truth,
    }
    return cols, sim_meta


def to_recording(cols: dict[str, Any], meta: dict[str, Any]) -> Recording:
    """Build the Recording from scenario columns."""
    return Recording.from_arrays(
        cols["t"],
        cols["q"],
        cols["tau"],
        meta,
        dq=cols["dq"],
        tau_ffw=cols["tau_ffw"],
        wrench=cols["wrench"],
        temp=cols["temp"],
        dither=cols["dither"],
        extra=cols["extra"],
        name="sim",
    )


def plant_extras(hp: Any) -> PlantExtras:
    """Hidden plant terms for the Engine."""
    return PlantExtras(
        load=hp.load,
        stribeck=hp.stribeck,
        stribeck_v=hp.stribeck_v,
        ripple_amp=hp.ripple_amp,
        ripple_freq=hp.ripple_freq,
    )

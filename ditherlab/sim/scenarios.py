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
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.names import FORCE_AXES
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.sim.engine import Engine, Inputs, Outputs, PlantExtras
from ditherlab.sim.hidden import HiddenPlant, HiddenSpec, build_hidden
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


@dataclass(frozen=True, eq=False)
class Plan:
    """What an open-loop scenario asks of the robot, sample by sample.

    Attributes
    ----------
    t : (N,) [s] sample times
    q0 : (n,) [rad] the pose the run starts in, standing still
    q_ref, dq_ref : (N, n) [rad], [rad/s] motor-angle reference and its rate
    push : (N, 6) [N, N·m] wrench on the tool point from the environment (base axes), before the
        hidden effects
    dither_cmd : (N,) [-] 1 while the dither is requested
    """

    t: np.ndarray
    q0: np.ndarray
    q_ref: np.ndarray
    dq_ref: np.ndarray
    push: np.ndarray
    dither_cmd: np.ndarray


@dataclass(frozen=True, eq=False)
class Driven:
    """What the plant did with a :class:`Plan`: the engine's outputs, the hidden plant, the
    engine, and the F/T sensor's columns (N, 6) [N, N·m] (the robot's wrench, noise included)."""

    out: Outputs
    hp: HiddenPlant
    engine: Engine
    wrench: np.ndarray


def drive(
    plan: Plan,
    engine_for: Callable[[Any], Engine],
    params: Mapping[str, Any],
    hidden: list[HiddenSpec],
    rngs: tuple[np.random.Generator, np.random.Generator],
    robot: Any,
    progress: Callable[[int, int], None] | None,
) -> Driven:
    """Run ``plan`` on the plant with the ``hidden`` effects: the logged torque's noise
    (N, n) [N·m] and the F/T noise (N, 6) [N, N·m] from the first of ``rngs``, the hidden
    effects' draws from the second (:func:`scenario_rngs`); ``robot`` is the controller's
    RobotModel (the F/T sensor's tool axes)."""
    noise_rng, hidden_rng = rngs
    tt, n = plan.t, len(plan.q0)
    N, dt = len(tt), 1.0 / float(params["timing"]["sample_rate_hz"])
    hp = build_hidden(hidden, params, tt, n, hidden_rng)
    engine = engine_for(hp)
    noise = noise_rng.normal(size=(N, n)) * params["noise"]["tau_sigma_fraction"] * engine.fs
    ft_noise = wrench_noise(params, noise_rng, N)
    inputs = Inputs(
        push=hp.arm_push(plan.push, dt),
        tau_ext=np.zeros((N, n)),
        q_ref=plan.q_ref,
        dq_ref=plan.dq_ref,
        kp_on=np.ones(N),
        dither_cmd=plan.dither_cmd,
        fscale=hp.fscale,
        noise=noise,
    )
    out = engine.run(inputs, engine.initial_state(plan.q0), progress=progress)
    # F = the wrench the robot exerts = -push
    wrench = hp.logged_wrench(-plan.push, robot, out.q_link) + ft_noise
    return Driven(out, hp, engine, wrench)


def scenario_columns(
    tt: np.ndarray,
    out: Outputs,
    wrench: np.ndarray,
    hp: HiddenPlant,
    extra: dict[str, np.ndarray],
) -> RecordingArrays:
    """The recording's arrays from the engine's outputs.

    Parameters
    ----------
    tt : (N,) [s]
    out : the Engine's outputs (motor-side q, dq, logged tau, tau_ffw, dither flag)
    wrench : (N, 6) [N, N·m] the F/T sensor
    hp : the HiddenPlant (its encoder offsets, drive scales and temperature)
    extra : further columns, each (N,)
    """
    q, tau = hp.logged(out.q_motor, out.tau)  # encoder offsets, drive torque scales
    return RecordingArrays(
        t=tt,
        q=q,
        dq=out.dq_motor,
        tau=tau,
        tau_ffw=out.tau_ffw,
        wrench=wrench,
        dither=out.dither,
        temp=hp.temp,
        extra=extra,
    )


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


@dataclass(frozen=True)
class _Timeline:
    """When the push campaign's phases begin [s]: the excitation ends, the dither is requested
    on and off, the last sample's time; the pushes' onsets are in the plan (``t0``)."""

    excitation_end: float
    dither_on: float
    dither_off: float
    end: float


def push_campaign(
    engine_for: Callable[[Any], Engine],
    params: dict[str, Any],
    *,
    seed: int,
    dither: bool,
    hidden: list[HiddenSpec],
    progress: Callable[[int, int], None] | None,
    robot: Any,
) -> tuple[RecordingArrays, dict[str, Any]]:
    """Simulate the push campaign; returns (the recording's arrays, meta["sim"] part).

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
    plan_rng, noise_rng, hidden_rng = scenario_rngs(seed)
    pushes = _plan_pushes(pc, plan_rng)
    amp, periods = _excitation_strokes(pc, hidden)
    times = _schedule(params, periods, pushes)
    plan, push_id = _campaign_plan(params, robot.n, amp, periods, pushes, times, dither)
    run = drive(plan, engine_for, params, hidden, (noise_rng, hidden_rng), robot, progress)
    extra = {"push": push_id}
    if pc["log_link_angle"]:  # the arm's angle behind the gear spring: ground truth (sweeps)
        extra.update({f"q_link_{j + 1}": run.out.q_link[:, j] for j in range(robot.n)})
    arrays = scenario_columns(plan.t, run.out, run.wrench, run.hp, extra)
    sim_meta = {
        "pushes": [
            {k: p[k] for k in ("t0", "duration", "rest", "axis", "sign", "magnitude")}
            for p in pushes
        ],
        "timeline": {
            "excitation_end": times.excitation_end,
            "dither_on": times.dither_on if dither else None,
            "first_push": pushes[0]["t0"] if pushes else None,
            "dither_off": times.dither_off if dither else None,
            "end": float(plan.t[-1]),
        },
        "excitation": {"amplitude": amp, "periods": periods},
        "dither_amplitudes": _campaign_amplitudes(params, run, plan.t, times),
        "hidden": run.hp.truth,
    }
    return arrays, sim_meta


def _excitation_strokes(pc: Mapping[str, Any], hidden: list[HiddenSpec]) -> tuple[float, list]:
    """The opening excitation: amplitude [rad] and the period [s] of each sine cycle; with a
    hidden ``position_ripple`` stretched so that the strokes sweep several ripple periods at the
    same speeds (the ripple shows only in motion)."""
    amp = float(pc["excitation_amplitude"])
    periods = [float(T) for T in pc["excitation_periods"]]
    if any(h.name == "position_ripple" for h in hidden):
        scale = max(amp, 0.35) / amp if amp > 0 else 1.0
        amp, periods = amp * scale, [T * scale for T in periods]
    return amp, periods


def _schedule(
    params: Mapping[str, Any], periods: list[float], pushes: list[dict[str, Any]]
) -> _Timeline:
    """The campaign's timeline: excitation, settle, dither ramp, settle, the pushes each with
    its rest (their onsets written to ``t0``), the dither ramped off, half a second more."""
    ramp = float(params["dither"]["ramp_s"])
    settle = float(params["push_campaign"]["settle_s"])
    t_exc = float(sum(periods))
    t_dither_on = t_exc + settle
    t = t_dither_on + ramp + settle
    for p in pushes:
        p["t0"] = t
        t += p["duration"] + p["rest"]
    return _Timeline(t_exc, t_dither_on, t, t + ramp + 0.5)


def _campaign_plan(
    params: Mapping[str, Any],
    n: int,
    amp: float,
    periods: list[float],
    pushes: list[dict[str, Any]],
    times: _Timeline,
    dither: bool,
) -> tuple[Plan, np.ndarray]:
    """The campaign's :class:`Plan` and the push index of each sample (N,) (-1 outside)."""
    pc = params["push_campaign"]
    fs_hz = float(params["timing"]["sample_rate_hz"])
    N = int(np.ceil(times.end * fs_hz))
    tt = np.arange(N) * (1.0 / fs_hz)
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
    dcmd = np.zeros(N)
    if dither:
        dcmd[(tt >= times.dither_on) & (tt < times.dither_off)] = 1.0
    return Plan(tt, q0, q_ref, dq_ref, push, dcmd), push_id


def _campaign_amplitudes(
    params: Mapping[str, Any], run: Driven, tt: np.ndarray, times: _Timeline
) -> dict[str, Any]:
    """The dither's peak amplitudes [N·m] per joint: the set-point, and the mean feedforward
    and measured amplitude once the ramp has settled."""
    n = run.engine.n
    ramp = float(params["dither"]["ramp_s"])
    settle = float(params["push_campaign"]["settle_s"])
    out = run.out
    on = out.dither & (tt >= times.dither_on + ramp + settle)
    dsp = joint_array(params, "dither.amplitude_fraction", n) * run.engine.fs
    mask = np.asarray(params["dither"]["joints"][:n], dtype=bool)
    return {
        "set_point": [float(v) if mk else 0.0 for v, mk in zip(dsp, mask, strict=True)],
        "feedforward_mean": [
            float(out.amp_ffw[on, j].mean()) if on.any() and mask[j] else 0.0 for j in range(n)
        ],
        "measured_mean": [
            float(out.amp_meas[on, j].mean()) if on.any() and mask[j] else 0.0 for j in range(n)
        ],
        "unit": "N·m (peak amplitude of the dither in the logged torque; feedforward = "
        "the waveform's peak amplitude)",
    }


def to_recording(arrays: RecordingArrays, meta: dict[str, Any]) -> Recording:
    """The simulated Recording (named ``sim``) of a scenario's arrays and metadata."""
    return Recording.from_arrays(arrays, meta, name="sim")


def plant_extras(hp: HiddenPlant) -> PlantExtras:
    """The hidden plant's terms the Engine's compiled step takes."""
    return PlantExtras(
        load=hp.load,
        stribeck=hp.stribeck,
        stribeck_v=hp.stribeck_v,
        ripple_amp=hp.ripple_amp,
        ripple_freq=hp.ripple_freq,
    )

"""A second simulated plant, written from the physics and independent of :mod:`ditherlab.sim`:
LuGre friction per joint, a PID servo with the controller's gravity feedforward, reflected
motor inertia, a coupled arm (pinocchio), a current-measuring drive (coloured noise, an LSB,
time-stamp jitter), an F/T sensor with its own dynamics and drift, slow external loads, and the
effect library's effects planted as their physical causes.

Entry point: :func:`simulate_lugre` (``ditherlab simulate SCENARIO --plant lugre``). It imports
nothing from :mod:`ditherlab.sim` or :mod:`ditherlab.physics` (a test checks it), so that a
diagnosis tuned on one plant can be checked on the other.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.robot import RobotModel
from ditherlab.sim_lugre.lugre_effects import EFFECTS, parse_planted, plant
from ditherlab.sim_lugre.lugre_loads import LOADS, build_loads
from ditherlab.sim_lugre.lugre_log import (
    LogStreams,
    friction_scale,
    noise_floor,
    temperatures,
    to_arrays,
)
from ditherlab.sim_lugre.lugre_params import OMEGA, SAMPLE_RATE, SUBSTEPS, draw_params, home_pose
from ditherlab.sim_lugre.lugre_run import RunInputs, run_plant
from ditherlab.sim_lugre.lugre_scenarios import SCENARIOS, build_scenario

__all__ = ["simulate_lugre", "SCENARIOS", "EFFECTS", "LOADS", "LugreOptions"]

#: the random streams of a seed, by purpose: each a function of the seed alone
_STREAMS = ("params", "scenario", "loads", "torque", "sensor", "stamps")


@dataclass(frozen=True)
class LugreOptions:
    """What a LuGre run is made of (see :func:`simulate_lugre`)."""

    scenario: str
    seed: int
    dither: bool
    hidden: tuple[str, ...]
    loads: tuple[str, ...]
    log_temperature: bool
    pushes_per_direction: int | None
    duration: float | None = None


def _streams(seed: int) -> dict[str, np.random.Generator]:
    children = np.random.SeedSequence(int(seed)).spawn(len(_STREAMS))
    return {k: np.random.default_rng(s) for k, s in zip(_STREAMS, children, strict=True)}


@dataclass
class _Setup:
    robot: RobotModel
    params: Any
    scenario: Any
    loads: Any


def _setup(o: LugreOptions, robot: RobotModel) -> _Setup:
    rng = _streams(o.seed)
    params = draw_params(robot, rng["params"])
    home = home_pose(robot)
    sc = build_scenario(o.scenario, robot, home, rng["scenario"], {
        "dt_log": 1 / SAMPLE_RATE, "nsub": SUBSTEPS,
        "pushes_per_direction": o.pushes_per_direction, "duration": o.duration})  # fmt: skip
    t = (np.arange(sc.n_samples) + 1) * sc.dt_log
    p_home = robot.tool_pose(home[None])[0, :3, 3]
    return _Setup(robot, params, sc, build_loads(o.loads, t, p_home, rng["loads"]))


def _run(o: LugreOptions, s: _Setup, hidden: list, progress) -> tuple[RecordingArrays, Any]:
    """One run with the planted ``hidden`` specs: its arrays and its Planted."""
    planted = plant(hidden, s.robot.n, o.seed)
    t = (np.arange(s.scenario.n_samples) + 1) * s.scenario.dt_log
    scale = friction_scale(temperatures(t, planted), planted)
    inputs = RunInputs(s.params, planted, s.scenario, s.loads, o.dither, scale)
    true = run_plant(s.robot, inputs, progress)
    rng = _streams(o.seed)
    streams = LogStreams(rng["torque"], rng["sensor"], rng["stamps"])
    return to_arrays(true, inputs, streams, o.log_temperature), planted


def _rms(a: np.ndarray | None, b: np.ndarray | None) -> list[float] | None:
    if a is None or b is None:
        return None
    return [float(v) for v in np.sqrt(np.mean((a - b) ** 2, axis=0))]


def _effect_sizes(o: LugreOptions, s: _Setup, specs: list, arrays: RecordingArrays) -> list:
    """Per planted effect: the RMS per joint of what it adds to the logged torque [N·m] (and to
    the F/T columns [N, N·m]): the run against the same seed's run without that effect."""
    sizes = []
    for spec in specs:
        other, _ = _run(o, s, [x for x in specs if x is not spec], None)
        sizes.append({"tau_rms": _rms(arrays.tau, other.tau),
                      "wrench_rms": _rms(arrays.wrench, other.wrench)})  # fmt: skip
    return sizes


def simulate_lugre(
    scenario: str,
    *,
    seed: int = 0,
    dither: bool = True,
    hidden: Iterable[str] = (),
    external_loads: Iterable[str] = (),
    robot: str | Mapping[str, Any] = "irb140",
    log_temperature: bool = True,
    pushes_per_direction: int | None = None,
    duration: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Recording:
    """Simulate ``scenario`` on the LuGre plant and return its Recording (250 Hz).

    Parameters
    ----------
    scenario : ``excitation``, ``push-campaign`` or ``standing`` (no F/T columns)
    seed : every drawn parameter, the scenario, the noise: the same seed, the same recording
    dither : the dither feedforward while standing still
    hidden : effects to plant, ``NAME[:SIZE][@J1,J2]`` (:data:`EFFECTS`)
    external_loads : slow loads the sensor measures: ``cable``, ``hose``, ``hand``
    robot : the arm: a built-in name, a URDF path or a resolved spec
    log_temperature : write ``temp_j`` when ``temperature_friction`` is planted
    pushes_per_direction : push-campaign's pushes per axis and sign (default 3)
    duration : [s] only the scenario's first ``duration`` seconds (None: all of it)
    progress : ``progress(done, total)`` over the logged samples

    Returns
    -------
    Recording
        ``t, q_j, dq_j, tau_j, tau_ffw_j, dither`` (+ ``f_x..m_z``, ``temp_j``); ``meta["sim"]``:
        ``plant = "lugre"``, the drawn parameters, the push plan, the loads, the planted effects
        (``hidden``: name, size, unit, joints, draws, ``tau_rms`` (n,) [N·m] and
        ``wrench_rms`` (6,)), and ``noise_std`` (n,) [N·m], the logged torque's noise.
    """
    if int(seed) < 0:
        raise ConfigError(f"--seed {seed}: negative; expected an integer >= 0")
    if duration is not None and not duration > 1.0:
        raise ConfigError(f"duration {duration}: expected more than 1 s")
    if pushes_per_direction is not None and pushes_per_direction < 1:
        raise ConfigError(
            f"--pushes-per-direction {pushes_per_direction}: expected an integer >= 1"
        )
    arm = RobotModel.from_spec(robot)
    o = LugreOptions(scenario, int(seed), bool(dither), tuple(hidden), tuple(external_loads),
                     bool(log_temperature), pushes_per_direction, duration)  # fmt: skip
    specs = parse_planted(o.hidden, arm.n)
    s = _setup(o, arm)
    arrays, planted = _run(o, s, specs, progress)
    for truth, size in zip(planted.truth, _effect_sizes(o, s, specs, arrays), strict=True):
        truth.update(size)
    return Recording.from_arrays(arrays, _meta(o, s, planted, robot), name="sim")


def _meta(o: LugreOptions, s: _Setup, planted: Any, robot_spec: Any) -> dict[str, Any]:
    sim = {
        "plant": "lugre",
        "scenario": o.scenario,
        "seed": o.seed,
        "dither": o.dither,
        "friction_model": "LuGre (Canudas de Wit et al. 1995), exact bristle update at 5 kHz",
        "params": s.params.as_meta(),
        "hidden": planted.truth,
        "noise_std": [float(v) for v in noise_floor(s.params, planted)],
        "pushes": s.scenario.pushes,
        "external_loads": s.loads.truth,
        "home": [float(v) for v in home_pose(s.robot)],
    }
    meta: dict[str, Any] = {
        "robot": _robot_meta(robot_spec, s.robot),
        "sample_rate_hz": SAMPLE_RATE,
        "source": "sim",
        "notes": f"ditherlab simulate {o.scenario} --plant lugre seed={o.seed}",
        "sim": sim,
    }
    if o.dither:
        meta["dither"] = {"waveform": "square", "omega": float(OMEGA)}
    return meta


def _robot_meta(spec: Any, arm: RobotModel) -> Any:
    """The recording's ``robot``: a built-in by its name, a resolved spec as it is, any other
    arm by its URDF text."""
    if isinstance(spec, Mapping):
        return dict(spec)
    if spec == arm.name:
        return spec
    return {"urdf": arm.urdf, "tool_frame": arm.tool_frame, "name": arm.name}

"""The built-in simulator: an IRB140-like robot with gear springs, stick-slip friction, the
paper's cascaded servo and its dither loops, producing ordinary Recordings.

Entry point: :func:`simulate`. Parameters live in ``irb140.toml`` (:mod:`ditherlab.sim.params`);
the compiled joint loop in :mod:`ditherlab.sim.plant`; scenarios in
:mod:`ditherlab.sim.scenarios`; hidden effects in :mod:`ditherlab.sim.hidden`.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording
from ditherlab.robot import RobotModel
from ditherlab.sim import scenarios as sc
from ditherlab.sim.engine import Engine
from ditherlab.sim.excitation import excitation
from ditherlab.sim.guidance import lead_through
from ditherlab.sim.hidden import EFFECTS, parse_hidden
from ditherlab.sim.params import joint_array, load_params

__all__ = ["simulate", "SCENARIOS", "EFFECTS"]

SCENARIOS = ("push-campaign", "lead-through", "excitation")


def simulate(
    scenario: str,
    *,
    seed: int = 0,
    dither: bool = True,
    config: str | Path | Mapping[str, Any] | None = None,
    hidden: Iterable[Any] = (),
    progress: Callable[[int, int], None] | None = None,
    robot: str | Mapping[str, Any] = "irb140",
    estimate: Callable[..., Any] | None = None,
    **options: Any,
) -> Recording:
    """Simulate a scenario and return its Recording (250 Hz, 6 joints of the built-in IRB140).

    Parameters
    ----------
    scenario : ``"push-campaign"``, ``"lead-through"`` or ``"excitation"`` (smooth strokes
        through several poses and pushes in each, for identification and diagnosis)
    seed : random seed; the same seed and options give identical output
    dither : dither while standing still
    config : user parameter file (TOML) or dict overriding ``irb140.toml``
    hidden : effects to inject, ``"NAME[:SIZE]"`` strings or ``(name, size)`` pairs
        (names: :data:`EFFECTS`)
    progress : ``progress(done, total)`` callback
    robot : the simulated arm: a built-in name, a URDF path or a resolved ``{"urdf",
        "tool_frame", "name"}`` (:func:`ditherlab.robot.resolve_spec`), with as many joints as the
        parameters' per-joint lists (6 in ``irb140.toml``); the IRB140's drive, friction and
        servo parameters apply to it unless ``config`` sets its own
    estimate : lead-through only: an external estimate of the push that drives the admittance
        (:data:`ditherlab.sim.guidance.EstimateSource`; None: the controller's own eq. (3))
    options : any key of the scenario's table in ``irb140.toml`` (e.g.
        ``pushes_per_direction=10``), and ``log_temperature=False`` for ``temperature_friction``

    Returns
    -------
    Recording
        Columns ``t, q_j, dq_j, tau_j, tau_ffw_j, f_x..m_z, dither`` (+ ``temp_j``, ``push``);
        ``meta["sim"]`` holds every parameter used and the truth (bands, hidden effects,
        dither amplitudes, the push plan).

    Raises
    ------
    ConfigError
        Unknown scenario, effect, option or config key; negative sizes or magnitudes.
    """
    if scenario not in SCENARIOS:
        raise ConfigError(
            f"scenario '{scenario}' is unknown; expected one of {', '.join(SCENARIOS)}"
        )
    if estimate is not None and scenario != "lead-through":
        raise ConfigError(f"scenario {scenario} takes no external estimate; lead-through does")
    specs = parse_hidden(hidden)
    params = load_params(config, _overrides(scenario, options))
    if int(seed) < 0:
        raise ConfigError(f"seed {seed} is negative; expected an integer >= 0")
    robot_spec, robot = robot, _robot(robot, params)

    def engine_for(hp: Any) -> Engine:
        return Engine(params, robot, hp.plant_robot(robot), sc.plant_extras(hp))

    arrays, sim_meta = _RUNS[scenario](
        engine_for,
        params,
        seed=int(seed),
        dither=bool(dither),
        hidden=specs,
        progress=progress,
        robot=robot,
        **({} if estimate is None else {"estimate": estimate}),
    )
    meta = _meta(scenario, seed, dither, options, params, robot.n, sim_meta)
    if isinstance(robot_spec, Mapping):  # resolved: kept as it is (its source path too)
        meta["robot"] = dict(robot_spec)
    elif robot_spec != "irb140":  # a built-in by its name, any other arm by its URDF text
        builtin = robot.name == robot_spec
        meta["robot"] = (
            robot_spec
            if builtin
            else {"urdf": robot.urdf, "tool_frame": robot.tool_frame, "name": robot.name}
        )
    return sc.to_recording(arrays, meta)


#: The function that runs each scenario.
_RUNS: dict[str, Callable[..., tuple[Any, dict[str, Any]]]] = {
    "push-campaign": sc.push_campaign,
    "lead-through": lead_through,
    "excitation": excitation,
}


def _overrides(scenario: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The parameter overrides of ``simulate``'s options: each a key of the scenario's table
    (None: not given), ``log_temperature`` one of ``hidden.temperature_friction``'s."""
    table = scenario.replace("-", "_")
    overrides: dict[str, Any] = {}
    for key, value in options.items():
        if value is None:
            continue
        if key == "log_temperature":
            overrides.setdefault("hidden", {})["temperature_friction"] = {"log_temperature": value}
            continue
        if key not in load_params()[table]:
            raise ConfigError(f"option '{key}' is unknown for scenario {scenario}")
        if isinstance(value, int | float) and not isinstance(value, bool) and value < 0:
            raise ConfigError(f"option '{key}' = {value!r} is negative; expected a value >= 0")
        overrides.setdefault(table, {})[key] = value
    return overrides


def _robot(spec: str | Mapping[str, Any], params: Mapping[str, Any]) -> RobotModel:
    """The simulated arm ``spec``; ConfigError when its joints are not as many as the
    parameters' per-joint lists."""
    robot = RobotModel.from_spec(spec)
    n = len(params["friction"]["static"])
    if robot.n != n:
        label = spec if isinstance(spec, str) else robot.name
        raise ConfigError(
            f"--robot {label}: {robot.n} joints, the simulator's parameters give {n} per joint; "
            f"expected a robot with {n} joints"
        )
    return robot


def _meta(
    scenario: str,
    seed: int,
    dither: bool,
    options: Mapping[str, Any],
    params: dict[str, Any],
    n: int,
    sim_meta: dict[str, Any],
) -> dict[str, Any]:
    """The recording's metadata: the robot, the rate, and under ``sim`` every parameter used,
    the ``n`` joints' true friction and the scenario's truth (``sim_meta``)."""
    sim_meta_all = {
        "scenario": scenario,
        "seed": int(seed),
        "dither": bool(dither),
        "options": {k: v for k, v in options.items() if v is not None},
        "params": copy.deepcopy(params),
        "friction_model": "rigid stick-slip, implicit at velocity level",
        "bands": _bands(params, n),
        **sim_meta,
    }
    meta = {
        "robot": "irb140",
        "sample_rate_hz": float(params["timing"]["sample_rate_hz"]),
        "source": "sim",
        "notes": f"ditherlab simulate {scenario} seed={seed} dither={'on' if dither else 'off'}",
        "sim": sim_meta_all,
    }
    if dither:
        # the dither's waveform and angular frequency (docs/recording-format.md): the period is
        # read from omega before it is measured from tau_ffw, whose zero crossings are unreliable
        # at few samples a half period; stated only when dithering, since a recording that
        # states a period counts as dithered
        meta["dither"] = {
            "waveform": params["dither"]["waveform"],
            "omega": float(params["dither"]["frequency"]),
        }
    return meta


def _bands(params: Mapping[str, Any], n: int) -> dict[str, Any]:
    """The true friction of the ``n`` joints [N·m, N·m·s/rad] for ``meta["sim"]["bands"]``."""
    fs = joint_array(params, "friction.static", n)
    return {
        "static": [float(v) for v in fs],
        "tau_min_offset": [float(-v) for v in fs],
        "tau_max_offset": [float(v) for v in fs],
        "coulomb": [float(v) for v in fs * params["friction"]["coulomb_ratio"]],
        "viscous": [float(v) for v in joint_array(params, "friction.viscous", n)],
        "motor_share": float(params["friction"]["motor_share"]),
        "unit": "N·m, N·m·s/rad; the still band is gravity ± static",
    }

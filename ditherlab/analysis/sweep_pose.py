"""The pose as a sweep axis (:mod:`ditherlab.app.sweep`): the start pose's limits, the
dithered campaign without its ramp-down, and the per-direction and predicted F50 columns
(:func:`ditherlab.analysis.sensitivity.predict` at each point's pose, beside the measured)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ditherlab.analysis.detection import fit_logistic
from ditherlab.analysis.sensitivity import condition_bands, predict
from ditherlab.analysis.sensitivity_map import report_noise_level
from ditherlab.core.errors import ConfigError
from ditherlab.core.names import FORCE_AXES
from ditherlab.data.recording import Recording
from ditherlab.robot import RobotModel
from ditherlab.robot.poses import outside_limits
from ditherlab.sim.params import load_params

__all__ = ["DIRECTION_NAMES", "check_pose", "direction_f50", "predicted", "without_ramp_down"]

#: the robot the simulator simulates
SIM_ROBOT = "irb140"
#: push directions of the per-direction columns: axis and sign of the applied force
DIRECTION_NAMES = ("+x", "-x", "+y", "-y", "+z", "-z")


def check_pose(config: Mapping[str, Any], label: str) -> None:
    """ConfigError when a point's start pose ``pose.q0`` [rad] leaves the simulated robot's
    joint limits (the URDF's)."""
    q0 = np.asarray(load_params(config)["pose"]["q0"], dtype=float)
    robot = RobotModel.from_spec(SIM_ROBOT)
    j = outside_limits(q0, robot.q_lower, robot.q_upper)
    if j is not None:
        raise ConfigError(
            f"sweep: --grid point {label}: pose.q0 joint {j + 1} is {q0[j]:g} rad, outside its "
            f"limits [{robot.q_lower[j]:.4g}, {robot.q_upper[j]:.4g}] rad"
        )


def without_ramp_down(rec: Recording) -> Recording:
    """A dithered campaign without the dither's final ramp-down (``meta["sim"]["timeline"]
    ["dither_off"]`` on): while the amplitude ramps to zero the dither flag is still on, so the
    report would count those samples as rest with dither, where the extracted signal moves by
    the centre's feedforward (up to ~8 N·m) and sets the noise level (measured at the paper's
    pose: 10.6 N in x instead of 1 N; where rest with dither ends: ``docs/method.md``, "The
    paper's detection statistics")."""
    off = ((rec.meta.get("sim") or {}).get("timeline") or {}).get("dither_off")
    return rec.slice(t1=float(off)) if off is not None else rec


def direction_f50(cond: Mapping[str, Any]) -> dict[str, float]:
    """F50 [N] per push direction (``+x`` ..) from one condition of
    :func:`ditherlab.analysis.detection.analyse`: the logistic fit to the pushes of one sign (no
    bootstrap); the smallest (largest) force when every (no) push was seen; NaN without
    pushes."""
    pushes = cond.get("pushes") or []
    out = {}
    for d in DIRECTION_NAMES:
        sel = [p for p in pushes if p["axis"] == d[1] and p["sign"] == (1 if d[0] == "+" else -1)]
        c = fit_logistic(
            np.array([p["peak"] for p in sel]), np.array([p["detected"] for p in sel]), n_boot=0
        )
        out[d] = float(c["bound_force"]) if c.get("bound") else float(c["F50"])
    return out


def _f50_columns(pr: Mapping[str, Any], head: str) -> dict[str, float]:
    """``{head}f50_x`` .. (per axis the report's logistic fit, else the smaller direction's
    crossing) and ``{head}f50_+x`` .. (per direction the crossing of one half) [N] of one
    :func:`ditherlab.analysis.sensitivity.predict` result."""
    out: dict[str, float] = {}
    for a in FORCE_AXES:
        f = pr["axes"][a]["f50"]
        if not np.isfinite(f):
            f = min(pr["directions"][f"+{a}"]["f50"], pr["directions"][f"-{a}"]["f50"])
        out[f"{head}f50_{a}"] = float(f)
    for dn in DIRECTION_NAMES:
        out[f"{head}f50_{dn}"] = float(pr["directions"][dn]["f50"])
    return out


def predicted(
    rec: Recording,
    model: Any,
    config: Mapping[str, Any],
    seed: int,
    analysis: Mapping[str, Any] | None = None,
) -> dict[str, float]:
    """The ``pred_*`` columns: :func:`ditherlab.analysis.sensitivity.predict` at the point's pose
    (``pose.q0``) from the identified ``model``, with and without dither, fitted over the
    campaign's push magnitudes: ``pred_[nodither_]f50_*`` from the model alone (its predicted
    noise level ``pred_[nodither_]noise_x`` .. [N]); with the point's ``analysis``
    (:func:`ditherlab.analysis.detection.analyse` of its evaluation campaigns) also
    ``predm_[nodither_]f50_*``, the same prediction given the noise level the analysis measured
    at rest in the matching condition (``dither_band`` / ``nodither_band``, read, not
    recomputed; NaN where it has none)."""
    p = load_params(config)
    pc = p["push_campaign"]
    fr = (float(pc["magnitude_min"]), float(pc["magnitude_max"]))
    robot = rec.robot()
    out: dict[str, float] = {}
    for prefix, d in (("", True), ("nodither_", False)):
        bands = condition_bands(robot.n, model, dither=d, params=p, robot_name=robot.name)
        pr = predict(robot, p["pose"]["q0"], bands, force_range=fr, seed=seed)
        out.update(_f50_columns(pr, f"pred_{prefix}"))
        out.update({f"pred_{prefix}noise_{a}": float(pr["noise_level"][a]) for a in FORCE_AXES})
        if analysis is None:
            continue
        try:
            nl = report_noise_level(analysis, d, where="sweep")
        except ConfigError:  # no rest (or no pushes) in that condition: nothing measured
            out.update(
                {f"predm_{prefix}f50_{k}": math.nan for k in (*FORCE_AXES, *DIRECTION_NAMES)}
            )
            continue
        pm = predict(
            robot, p["pose"]["q0"], bands, force_range=fr, seed=seed, noise_level=nl,
            noise_source="measured",
        )  # fmt: skip
        out.update(_f50_columns(pm, f"predm_{prefix}"))
    return out

"""``ditherlab leadthrough --live``: the lead-through of ``leadthrough`` in closed loop across
processes. The simulated arm publishes its joint states (and the dither's state) over DDS as a
ROS 2 robot would; a ``ditherlab live`` process, started by the command, estimates the push and
publishes it (``geometry_msgs/WrenchStamped``, with its interval's bounds); the arm subscribes
to that estimate and moves by the admittance law with it.

Lock-step: the arm publishes the samples of one controller update, waits for the estimate of
the update's last sample, and only then steps on; so the run is deterministic and reproducible
from the seed, and equals the same lead-through with the same estimator in one process
(:func:`causal_source`, ``ditherlab leadthrough --model``) float for float. The process and the
link over DDS: :mod:`ditherlab.app.leadthrough_dds` (needs the ``live`` extra). The estimator is
``live``'s (:class:`ditherlab.analysis.causal.CausalEstimator` with a torque model): variant
``dither_band`` with dither, ``nodither_band`` without, forces only; the interval the law's
(``lead_through.interval`` at ``lead_through.level``) with the interval law, ``profile`` with the
dead zone (whose law reads no interval).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.analysis.causal import CausalBlock, CausalEstimator, CausalSettings
from ditherlab.analysis.lead_metrics import COMPARED
from ditherlab.core.errors import ConfigError
from ditherlab.core.stamps import wire_time
from ditherlab.data.torque_model import TorqueModel
from ditherlab.robot import RobotModel
from ditherlab.sim.guidance import EstimateSource, LoggedChunk
from ditherlab.sim.params import load_params

__all__ = [
    "LinkSettings",
    "causal_source",
    "closed_loop_difference",
    "closed_loop_line",
    "push_of",
    "link_settings",
]


@dataclass(frozen=True)
class LinkSettings:
    """What the estimate of one lead-through run is computed with (:func:`link_settings`).

    Attributes
    ----------
    variant : the estimator variant that drives the arm ; interval : ``profile`` or
        ``set_membership`` ; level : the interval's confidence level in (0, 1)
    period : [s] the dither period (None: the run has no dither) ; names : the joints, in order
    """

    variant: str
    interval: str
    level: float
    period: float | None
    names: tuple[str, ...]


def link_settings(model: TorqueModel, law: str, dither: bool, config: Any = None) -> LinkSettings:
    """The estimate's settings of a run with ``law`` and ``dither`` (module docstring), from the
    simulator's parameters (``config``: a TOML path or dict); ConfigError when the model's robot
    is not the simulated one (the built-in IRB140)."""
    params = load_params(config, {"lead_through": {"law": law}})
    lt = params["lead_through"]
    sim_names = RobotModel.from_spec("irb140").joint_names
    if not model.same_robot("irb140"):
        raise ConfigError(
            f"--model: its robot {_robot_name(model.robot)!r} is not the simulated arm; "
            "expected a model of the simulator's IRB140 (ditherlab identify on its recordings)"
        )
    interval = str(lt["interval"]) if law == "interval" else "profile"
    period = 2 * np.pi / float(params["dither"]["frequency"]) if dither else None
    variant = "dither_band" if dither else "nodither_band"
    return LinkSettings(variant, interval, float(lt["level"]), period, tuple(sim_names))


def _robot_name(spec: Any) -> str:
    """A model's robot, named: the built-in's name or the URDF's robot."""
    return spec if isinstance(spec, str) else str(spec.get("name") or spec.get("urdf", "")[:40])


def push_of(est: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """The push on the tool (3,) [N] and its interval from the estimated wrench of the arm on
    its surroundings (the sensor's sign) ``est``, ``lo``, ``hi`` (6,) or (3,) [N, N·m]."""
    return -np.asarray(est[:3], float), -np.asarray(hi[:3], float), -np.asarray(lo[:3], float)


def causal_source(model: TorqueModel, link: LinkSettings, lag: int = 0) -> EstimateSource:
    """The estimate of ``ditherlab live`` computed in this process: the samples of every update
    as they arrive over DDS (stamps in whole nanoseconds, the dither's flag), the settings as
    ``live`` takes them from its first samples; ``lag`` updates late (0: the estimate of the
    update's last sample; 1: the previous update's, as a transport delay of one update would
    give)."""
    state: dict[str, Any] = {"est": None, "past": []}

    def source(chunk: LoggedChunk) -> tuple[np.ndarray, ...]:
        t = wire_time(chunk.t)
        if state["est"] is None:
            dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
            s = CausalSettings(dt, link.period, (link.variant,), link.level, link.interval, "fxyz")
            state["est"] = CausalEstimator(model, {"robot": model.robot}, s)
        dither = chunk.dither.copy() if link.period is not None else None
        rows = state["est"].update(CausalBlock(t, chunk.q, chunk.tau, chunk.dq, dither))
        v = link.variant
        got = [np.array([rows[f"{v}/f_{a}{s}"][-1] for a in "xyz"]) for s in ("", "_lo", "_hi")]
        state["past"].append(push_of(*got))
        if len(state["past"]) <= lag:
            return np.zeros(3), np.full(3, np.nan), np.full(3, np.nan)
        return state["past"].pop(0)

    return source


def closed_loop_difference(live: Mapping[str, Any], here: Mapping[str, Any]) -> dict[str, Any]:
    """The live runs against the same runs in one process (two :func:`compare_laws` results
    of the same seeds, laws and dither settings): per compared metric the largest difference
    over the runs (NaN in both counts as equal), and the largest difference of the tool's path
    [mm] over the first seed's traces."""
    diff: dict[str, float] = {}
    for a, b in zip(live["runs"], here["runs"], strict=True):
        for key, *_ in COMPARED:
            x, y = float(a["summary"][key]), float(b["summary"][key])
            d = 0.0 if (np.isnan(x) and np.isnan(y)) or x == y else abs(x - y)
            diff[key] = max(diff.get(key, 0.0), d)
    path = max(
        float(np.max(np.abs(np.asarray(p["x"]) - np.asarray(here["paths"][k]["x"]))))
        for k, p in live["paths"].items()
    )
    return {"metrics_max_abs": diff, "path_max_mm": path, "runs": len(live["runs"])}


def closed_loop_line(loop: Mapping[str, Any]) -> str:
    """One line: how far the live runs are from the same runs in one process."""
    worst = max(loop["metrics_max_abs"].items(), key=lambda kv: kv[1])
    return (
        f"closed loop over DDS against the same estimate in one process ({loop['runs']} runs): "
        f"tool path max |difference| {loop['path_max_mm']:.3g} mm, metrics max |difference| "
        f"{worst[1]:.3g} ({worst[0]})"
    )

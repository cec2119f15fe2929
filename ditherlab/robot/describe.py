"""A robot's summary: :func:`describe_robot` (JSON-ready) and :func:`format_description` (text)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["describe_robot", "format_description"]


def describe_robot(robot: Any, q: np.ndarray | None = None) -> dict[str, Any]:
    """A JSON-ready summary: joints and limits, masses, and at pose ``q`` the tool pose,
    gravity and lever arms.

    Parameters
    ----------
    robot : RobotModel (:class:`ditherlab.robot.RobotModel`; not imported here, which imports
        this module)
    q : (n,) [rad], optional
        Pose for the pose-dependent part (default: zeros).

    Returns
    -------
    dict
        ``name, n, tool_frame, tool_offset [m], payload, moving_mass [kg], joints`` (name,
        lower/upper [rad], velocity [rad/s], effort [N·m]) and ``pose``: ``q [rad]``,
        ``tool_position [m]``, ``tool_rotation`` (3×3, columns = tool axes in base axes),
        ``gravity [N·m]``, ``lever_arms [m]`` (3 × n: |∂tau_j/∂F_axis| for F along base
        x, y, z at the tool point).
    """
    q = np.zeros(robot.n) if q is None else np.asarray(q, dtype=float).reshape(robot.n)
    r = robot.evaluate(q, ["gravity", "jacobian", "tool_pose"], dedup=False)
    T = r["tool_pose"][0]

    def finite(x: float) -> float | None:
        return float(x) if np.isfinite(x) else None

    return {
        "name": robot.name,
        "n": robot.n,
        "tool_frame": robot.tool_frame,
        "tool_offset": robot.tool_offset.tolist(),
        "payload": robot.payload,
        "moving_mass": float(sum(robot.model.inertias[j].mass for j in range(1, robot.n + 1))),
        "joints": [
            {
                "name": name,
                "lower": finite(robot.q_lower[j]),
                "upper": finite(robot.q_upper[j]),
                "velocity": finite(robot.velocity_limit[j]),
                "effort": finite(robot.effort_limit[j]),
            }
            for j, name in enumerate(robot.joint_names)
        ],
        "pose": {
            "q": q.tolist(),
            "tool_position": T[:3, 3].tolist(),
            "tool_rotation": T[:3, :3].tolist(),
            "gravity": r["gravity"][0].tolist(),
            "lever_arms": np.abs(r["jacobian"][0][:3]).tolist(),
        },
    }


def format_description(d: Mapping[str, Any]) -> str:
    """Plain-text table of :meth:`RobotModel.describe` (angles in degrees for reading)."""

    def deg(x: float | None) -> str:
        return "-" if x is None else f"{np.degrees(x):.1f}"

    pay = d["payload"]
    lines = [
        f"robot {d['name']}: {d['n']} joints, tool frame {d['tool_frame']}, tool offset "
        f"{d['tool_offset']} m, payload "
        + (f"{pay['mass']:g} kg at {pay['com']} m" if pay else "none")
        + f", moving mass {d['moving_mass']:.1f} kg",
        f"{'joint':<22}{'lower [deg]':>12}{'upper [deg]':>12}{'vel [deg/s]':>12}"
        f"{'effort [N·m]':>13}",
    ]
    for j in d["joints"]:
        eff = "-" if j["effort"] is None else f"{j['effort']:.0f}"
        lines.append(
            f"{j['name']:<22}{deg(j['lower']):>12}{deg(j['upper']):>12}"
            f"{deg(j['velocity']):>12}{eff:>13}"
        )
    pose = d["pose"]
    qd = ", ".join(f"{np.degrees(x):.1f}" for x in pose["q"])
    px = ", ".join(_fixed(x, 3) for x in pose["tool_position"])
    z = ", ".join(_fixed(row[2], 3) for row in pose["tool_rotation"])
    lines += [
        f"at q = ({qd}) deg: tool point ({px}) m, tool z axis ({z})",
        f"{'joint':<22}{'gravity [N·m]':>14}{'lever Fx [m]':>14}{'lever Fy [m]':>14}"
        f"{'lever Fz [m]':>14}",
    ]
    lev = pose["lever_arms"]
    for k, j in enumerate(d["joints"]):
        lines.append(
            f"{j['name']:<22}{_fixed(pose['gravity'][k], 2):>14}{_fixed(lev[0][k], 3):>14}"
            f"{_fixed(lev[1][k], 3):>14}{_fixed(lev[2][k], 3):>14}"
        )
    return "\n".join(lines)


def _fixed(x: float, digits: int) -> str:
    """``x`` with ``digits`` decimals, never "-0.00"."""
    return f"{round(float(x), digits) + 0.0:.{digits}f}"

"""The robots ``--robot`` takes by name (``ditherlab robot --list``): the built-ins and, when
example-robot-data is installed, its arms, each with its joint count and tool frame."""

from __future__ import annotations

from typing import Any

from ditherlab.robot.example_robots import (
    ERD_PREFIX,
    EXAMPLE_ARMS,
    INSTALL_HINT,
    example_urdf_path,
    installed,
)
from ditherlab.robot.model import RobotModel
from ditherlab.robot.urdf import BUILTIN, builtin_robots

__all__ = ["available_robots", "format_catalog"]


def _entry(name: str, source: str, robot: RobotModel) -> dict[str, Any]:
    return {
        "name": name,
        "source": source,
        "joints": robot.n,
        "tool_frame": robot.tool_frame,
        "robot_name": robot.name,
    }


def available_robots() -> dict[str, Any]:
    """``{"robots": [{name, source, joints, tool_frame, robot_name}], "example_robot_data":
    installed?, "missing": [names needing example-robot-data]}``: each robot built once (its
    joint count is its model's)."""
    rows = [
        _entry(name, "built-in", RobotModel.from_spec(name, where=name))
        for name in builtin_robots()
    ]
    if not installed():
        return {"robots": rows, "example_robot_data": False, "missing": sorted(EXAMPLE_ARMS)}
    for name in sorted(EXAMPLE_ARMS):
        key = ERD_PREFIX + name if name in BUILTIN else name
        path, tool = example_urdf_path(key)
        robot = RobotModel(path.read_text(encoding="utf-8"), tool, name=name, where=str(path))
        rows.append(_entry(key, "example-robot-data", robot))
    return {"robots": rows, "example_robot_data": True, "missing": []}


def format_catalog(catalog: dict[str, Any]) -> str:
    """The table of :func:`available_robots` as text."""
    rows = catalog["robots"]
    width = max(len(r["name"]) for r in rows) + 2
    lines = [f"{'robot':<{width}}joints  {'tool frame':<26}source"]
    for r in rows:
        lines.append(f"{r['name']:<{width}}{r['joints']:>6}  {r['tool_frame']:<26}{r['source']}")
    if catalog["missing"]:
        lines.append(
            f"example-robot-data is not installed; {INSTALL_HINT} adds "
            f"{len(catalog['missing'])} arms: {', '.join(catalog['missing'])}"
        )
    lines.append(
        "Any other arm: --robot PATH.urdf, or PATH.xacro with --robot-arg NAME:=VALUE; "
        "--tool-frame LINK where the tool is not the description's own."
    )
    return "\n".join(lines)

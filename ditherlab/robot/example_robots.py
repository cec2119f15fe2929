"""The arms of example-robot-data (an optional install: ``pip install 'ditherlab[robots]'``),
by name.

example-robot-data (PyPI ``example-robot-data``, BSD-3-Clause) ships URDFs and meshes of many
robots under ``cmeel.prefix/share/example-robot-data/robots``; its URDFs name their meshes
``package://example-robot-data/robots/...``. :data:`EXAMPLE_ARMS` names the arms among them with
their tool frames. A name that is also a built-in robot (``panda``) means the built-in; the
example-robot-data one is then ``erd:panda`` (``erd:`` works for every name).
"""

from __future__ import annotations

import importlib.metadata
from functools import cache
from pathlib import Path

from ditherlab.core.errors import RobotError

__all__ = [
    "EXAMPLE_ARMS",
    "ERD_PREFIX",
    "INSTALL_HINT",
    "example_urdf_path",
    "installed",
    "share_root",
]

#: name -> (URDF path under example-robot-data's ``robots`` folder, tool frame)
EXAMPLE_ARMS: dict[str, tuple[str, str]] = {
    "baxter": ("baxter_description/urdf/baxter.urdf", "right_hand_link"),
    "double_pendulum": ("double_pendulum_description/urdf/double_pendulum.urdf", "link2"),
    "finger_edu": ("finger_edu_description/robots/finger_edu.urdf", "finger_tip_link"),
    "kinova": ("kinova_description/robots/kinova.urdf", "j2s6s200_end_effector"),
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand_tcp"),
    "so100": ("so_arm_description/urdf/so100.urdf", "gripper"),
    "so101": ("so_arm_description/urdf/so101.urdf", "gripper_frame_link"),
    "talos_arm": ("talos_data/robots/talos_left_arm.urdf", "wrist_left_ft_tool_link"),
    "tiago": ("tiago_description/robots/tiago.urdf", "arm_tool_link"),
    "tiago_no_hand": ("tiago_description/robots/tiago_no_hand.urdf", "arm_tool_link"),
    "ur3": ("ur_description/urdf/ur3_robot.urdf", "tool0"),
    "ur3_gripper": ("ur_description/urdf/ur3_gripper.urdf", "tool0"),
    "ur3_limited": ("ur_description/urdf/ur3_joint_limited_robot.urdf", "tool0"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0"),
    "ur5_gripper": ("ur_description/urdf/ur5_gripper.urdf", "tool0"),
    "ur5_limited": ("ur_description/urdf/ur5_joint_limited_robot.urdf", "tool0"),
    "ur10": ("ur_description/urdf/ur10_robot.urdf", "tool0"),
    "ur10_limited": ("ur_description/urdf/ur10_joint_limited_robot.urdf", "tool0"),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", "link_eef"),
    "z1": ("z1_description/urdf/z1.urdf", "gripperStator"),
}

#: The prefix that names an example-robot-data arm whatever the built-ins are (``erd:panda``).
ERD_PREFIX = "erd:"

#: What to run when example-robot-data is missing.
INSTALL_HINT = "pip install 'ditherlab[robots]'"

_DIST = "example-robot-data"


@cache
def share_root() -> Path | None:
    """The ``share`` folder holding ``example-robot-data/robots`` (None when not installed)."""
    try:
        dist = importlib.metadata.distribution(_DIST)
    except importlib.metadata.PackageNotFoundError:
        return None
    for f in dist.files or ():
        parts = Path(str(f)).parts
        if "example-robot-data" in parts and "robots" in parts:
            i = parts.index("example-robot-data")
            root = Path(str(dist.locate_file(Path(*parts[:i]))))
            return root if (root / "example-robot-data" / "robots").is_dir() else None
    return None


def installed() -> bool:
    """Whether example-robot-data is installed."""
    return share_root() is not None


def example_urdf_path(name: str, where: str = "") -> tuple[Path, str]:
    """The URDF file and tool frame of the example-robot-data arm ``name`` (with or without
    ``erd:``); RobotError naming the install command when example-robot-data is missing.

    Parameters
    ----------
    name : a key of :data:`EXAMPLE_ARMS`, optionally prefixed ``erd:``
    where : prefix of error messages (``"--robot: "``)
    """
    key = name[len(ERD_PREFIX) :] if name.startswith(ERD_PREFIX) else name
    rel, tool = EXAMPLE_ARMS[key]
    root = share_root()
    if root is None:
        raise RobotError(
            f"{where}robot {name!r} is an arm of example-robot-data, which is not installed "
            f"(expected it installed: {INSTALL_HINT})"
        )
    path = root / "example-robot-data" / "robots" / rel
    if not path.is_file():
        raise RobotError(
            f"{where}robot {name!r}: example-robot-data has no file {path} (expected "
            f"example-robot-data 6.0.0 as {INSTALL_HINT} installs it)"
        )
    return path, tool

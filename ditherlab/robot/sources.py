"""Where a robot description comes from: a ``--robot`` value that is not a built-in name, read
into URDF text.

A value is one of: an arm of example-robot-data by name (``ur5``, ``erd:panda``; see
:mod:`~ditherlab.robot.example_robots`), a xacro file (``.xacro``, expanded with its
arguments, :mod:`~ditherlab.robot.xacro_file`) or a URDF file. Anything else is an unknown
name, reported with the close known names.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

from ditherlab.core.errors import RobotError
from ditherlab.robot.example_robots import ERD_PREFIX, EXAMPLE_ARMS, example_urdf_path
from ditherlab.robot.urdf import builtin_robots, short_repr
from ditherlab.robot.xacro_file import expand_xacro, is_xacro

__all__ = ["Description", "known_names", "read_description", "unknown_name"]


class Description(NamedTuple):
    """A robot description read from its source.

    Attributes
    ----------
    urdf : the URDF text (a xacro file's expansion)
    tool_frame : the source's own tool frame (an example-robot-data arm's), or None (guess)
    name : the robot's short name (the example-robot-data name), or None (the URDF's)
    path : the file it was read from, absolute (``view`` finds meshes from it), or None
    """

    urdf: str
    tool_frame: str | None
    name: str | None
    path: str | None


def known_names() -> list[str]:
    """Every robot name ``--robot`` takes: built-ins, then example-robot-data's arms (installed
    or not) and their ``erd:`` forms."""
    erd = sorted(EXAMPLE_ARMS)
    return list(dict.fromkeys(builtin_robots() + erd + [ERD_PREFIX + k for k in erd]))


def unknown_name(spec: Any, where: str) -> str:
    """The error message for a ``--robot`` value that names nothing known (``where`` its
    prefix): the close names, and what was expected."""
    close = difflib.get_close_matches(str(spec).lower(), known_names(), n=5, cutoff=0.6)
    hint = f" (close names: {', '.join(close)})" if close else ""
    return (
        f"{where}robot {short_repr(spec)} is not a built-in robot or an example-robot-data arm"
        f"{hint}; expected one of: {', '.join(builtin_robots())}, a name of `ditherlab robot "
        "--list`, a .urdf or .xacro file, or an object {'urdf': <URDF text>, 'tool_frame': "
        "<frame name>}"
    )


def _read_text(path: Path, where: str) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RobotError(f"{where}robot URDF file '{path}' does not exist") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RobotError(f"{where}robot URDF file '{path}' cannot be read ({e})") from None


def read_description(
    spec: str | os.PathLike,
    robot_args: Iterable[str] | Mapping[str, str] | None = None,
    where: str = "",
) -> Description:
    """The description ``spec`` names (not a built-in name): an example-robot-data arm, a xacro
    file expanded with ``robot_args`` (``NAME:=VALUE`` texts), or a URDF file; RobotError
    (prefixed ``where``) for anything else, naming the close known names.

    ``robot_args`` only serve a xacro file; given with another source they are an error (they
    would silently do nothing)."""
    text = str(spec)
    key = text[len(ERD_PREFIX) :] if text.startswith(ERD_PREFIX) else text
    is_file = Path(text).expanduser().is_file()
    if robot_args and not is_xacro(text):
        raise RobotError(
            f"{where}--robot-arg {', '.join(map(str, robot_args))}: robot {short_repr(text)} "
            "is not a xacro file (expected --robot-arg only with a .xacro robot)"
        )
    if key in EXAMPLE_ARMS and not is_file:
        path, tool = example_urdf_path(text, where)
        return Description(_read_text(path, where), tool, key, str(path))
    if is_xacro(text):
        path = Path(text).expanduser()
        return Description(expand_xacro(path, robot_args, where), None, None, str(path.resolve()))
    if text.lower().endswith(".urdf") or is_file:
        path = Path(text).expanduser()
        return Description(_read_text(path, where), None, None, str(path.resolve()))
    raise RobotError(unknown_name(spec, where))

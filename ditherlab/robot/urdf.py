"""URDF robots: the built-in ones, parsing URDF text into a pinocchio model, guessing the tool
frame, and checking a payload.

The built-in robots' URDF files live in the data folder ``ditherlab/robot/descriptions`` (package data).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from ditherlab.core.errors import RobotError

__all__ = [
    "BUILTIN",
    "build_model",
    "builtin_robots",
    "builtin_urdf",
    "frame_id",
    "guess_tool_frame",
    "parse_payload",
    "robot_name",
    "short_repr",
    "unknown_robot",
]

#: Built-in robots: name -> (URDF file in ditherlab/robot/descriptions, tool frame).
BUILTIN: dict[str, tuple[str, str]] = {
    "irb140": ("irb140.urdf", "tool0"),
    "panda": ("panda.urdf", "panda_hand_tcp"),
    "ur10e": ("ur10e.urdf", "tool0"),
}

#: Link names tried, in order, when a URDF is given without a tool frame.
_TOOL_FRAME_GUESSES = ("tool0", "flange", "ee_link", "tool", "end_effector")


def builtin_robots() -> list[str]:
    """Names of the built-in robots, sorted (``["irb140", "panda", "ur10e"]``)."""
    return sorted(BUILTIN)


def builtin_urdf(name: str) -> str:
    """The URDF text of the built-in robot ``name``; RobotError when there is none."""
    if name not in BUILTIN:
        raise RobotError(unknown_robot(name, ""))
    fname = BUILTIN[name][0]
    return (Path(__file__).parent / "descriptions" / fname).read_text(encoding="utf-8")


def unknown_robot(name: Any, where: str) -> str:
    """The error message for a robot ``name`` that is not built in (``where`` its prefix)."""
    return (
        f"{where}robot {short_repr(name)} is not a built-in robot (expected one of: "
        f"{', '.join(builtin_robots())}, a path to a .urdf file, or an object "
        "{'urdf': <URDF text>, 'tool_frame': <frame name>})"
    )


@contextlib.contextmanager
def _captured_stderr_fd():
    """Capture what C++ code (urdfdom) writes to file descriptor 2, yielding a getter."""
    buf: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded interpreters): nothing to capture
        yield lambda: ""
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        try:
            os.dup2(tmp.fileno(), 2)
            yield lambda: "".join(buf)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            buf.append(tmp.read().decode("utf-8", "replace"))


def _urdfdom_reason(text: str) -> str:
    """The first 'Error: ...' line urdfdom printed, without its source location."""
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("Error:"):
            return " ".join(line[len("Error:") :].split())
    return ""


def build_model(urdf: str, where: str) -> pin.Model:
    """The pinocchio model of URDF text (lengths [m], masses [kg], inertias [kg m²]); RobotError,
    prefixed with ``where``, when it does not parse, has an implausible inertial, no movable
    joint or a joint of several degrees of freedom."""
    if not isinstance(urdf, str) or not urdf.strip():
        raise RobotError(f"{where}robot URDF is empty (expected URDF XML text)")
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as e:
        raise RobotError(f"{where}robot URDF does not parse as XML ({e})") from None
    if root.tag != "robot":
        raise RobotError(
            f"{where}robot URDF has root element <{root.tag}>, expected <robot name=...>"
        )
    _check_inertials(root, where)
    got: Callable[[], str]
    try:
        with _captured_stderr_fd() as got:
            model = pin.buildModelFromXML(urdf)
    except (ValueError, RuntimeError) as e:
        reason = _urdfdom_reason(got()) or str(e).strip()
        raise RobotError(f"{where}robot URDF does not parse: {reason}") from None
    if model.njoints <= 1:
        raise RobotError(f"{where}robot URDF has no movable joints (expected at least one)")
    bad = [
        f"{model.names[j]} ({model.joints[j].shortname()})"
        for j in range(1, model.njoints)
        if not (model.joints[j].nv == 1 and model.joints[j].nq in (1, 2))
    ]
    if bad:
        raise RobotError(
            f"{where}robot URDF has joints {', '.join(bad)} with several degrees of freedom; "
            "expected revolute, continuous or prismatic joints"
        )
    return model


#: Heaviest link [kg] and largest principal moment [kg m²] accepted: beyond any robot arm, and
#: small enough that gravity torques and mass matrices stay finite.
MAX_LINK_MASS, MAX_LINK_INERTIA = 1e5, 1e5


def _check_inertials(root: ET.Element, where: str) -> None:
    """RobotError for a link whose mass [kg] or principal moment (ixx, iyy, izz) [kg m²] is
    negative, not a number or huge, or whose product of inertia is not a number or huge."""
    moments, products = ("ixx", "iyy", "izz"), ("ixy", "ixz", "iyz")
    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass, inertia = inertial.find("mass"), inertial.find("inertia")
        values = [("mass", None if mass is None else mass.get("value"), 0.0, MAX_LINK_MASS, "kg")]
        if inertia is not None:
            for k in moments + products:
                lo = -MAX_LINK_INERTIA if k in products else 0.0
                values.append((f"inertia {k}", inertia.get(k), lo, MAX_LINK_INERTIA, "kg m²"))
        for key, text, lo, hi, unit in values:
            if text is None:
                continue
            try:
                v = float(text)
            except ValueError:
                v = float("nan")
            if not lo <= v <= hi:  # NaN fails too
                raise RobotError(
                    f"{where}robot URDF link {link.get('name', '?')!r} {key}: got "
                    f"{short_repr(text)}; expected a number in [{lo:g}, {hi:g}] [{unit}]"
                )


def frame_id(model: pin.Model, name: str) -> int:
    """The id of the frame ``name``: its link (BODY frame) when it is a link, else the first
    frame of that name. A URDF may name a link and a joint alike (pinocchio then has two frames
    of that name)."""
    for i, f in enumerate(model.frames):
        if f.name == name and f.type == pin.FrameType.BODY:
            return i
    return int(model.getFrameId(name))


def guess_tool_frame(model: pin.Model) -> str:
    """The tool frame of a URDF given without one: the first of ``tool0``, ``flange``,
    ``ee_link``, ``tool``, ``end_effector`` that exists, else the last link of the chain."""
    for name in _TOOL_FRAME_GUESSES:
        if model.existFrame(name):
            return name
    last_joint = model.njoints - 1
    bodies = [
        f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == last_joint
    ]
    return bodies[-1] if bodies else model.frames[-1].name


def parse_payload(payload: Mapping[str, Any], w: str) -> tuple[float, np.ndarray]:
    """``(mass [kg], com (3,) [m])`` of a payload ``{"mass": kg, "com": [x, y, z] m}`` (tool
    frame; ``com`` defaults to the origin); RobotError, prefixed with ``w``, otherwise."""
    if not isinstance(payload, Mapping) or "mass" not in payload:
        raise RobotError(f"{w}payload is {payload!r}, expected {{'mass': kg, 'com': [x, y, z] m}}")
    try:
        mass = float(payload["mass"])
    except (TypeError, ValueError):
        mass = float("nan")
    if not np.isfinite(mass) or mass < 0:
        raise RobotError(f"{w}payload mass is {payload['mass']!r}, expected a number >= 0 [kg]")
    try:
        com = np.asarray(payload.get("com", (0.0, 0.0, 0.0)), dtype=float)
    except (TypeError, ValueError):
        com = np.full(1, np.nan)
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise RobotError(
            f"{w}payload com is {payload.get('com')!r}, expected [x, y, z] in m (tool frame)"
        )
    return mass, com


def robot_name(urdf: str) -> str | None:
    """The ``<robot name=...>`` of URDF text, or None."""
    try:
        return ET.fromstring(urdf).get("name")
    except ET.ParseError:
        return None


def short_repr(value: Any) -> str:
    """``repr`` of a value cut to 40 characters, for messages (a URDF text can be 100 kB)."""
    r = repr(value)
    return r if len(r) <= 40 else r[:37] + "..."

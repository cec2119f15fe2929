"""Helpers shared by the format modules: metadata from options, robot specs, unit and time
checks."""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.core.errors import ConfigError, FormatError, RecordingError
from ditherlab.core.schema import ListOf, MapOf, Table, Text, check
from ditherlab.data.recording import (
    PAYLOAD_NODE,
    SCHEMA,
    STORED_META_SCHEMA,
    TOOL_OFFSET_NODE,
    Recording,
)
from ditherlab.data.recording import _check_increasing as check_increasing
from ditherlab.io.units import degrees_evidence
from ditherlab.robot import RobotModel, resolve_spec

#: the recording columns that hold numbers (besides the wrench)
NUMERIC = re.compile(r"^(t|(q|dq|tau|tau_ffw|temp|tau_ext_vendor)_\d+)$")
#: Options every reader accepts: they fill in or override the recording's metadata.
META_OPTIONS = (
    "robot",
    "tool_frame",
    "robot_args",
    "tool_offset",
    "payload",
    "source",
    "notes",
)
#: Their values (``robot`` is checked where it is resolved); other options are the readers'.
_OPTIONS_SCHEMA = Table(
    keys={
        "tool_frame": Text(nonempty=True, what="the name of a URDF link"),
        "robot_args": ListOf(item=Text(nonempty=True, what="NAME:=VALUE")),
        "tool_offset": TOOL_OFFSET_NODE,
        "payload": PAYLOAD_NODE,
        "source": Text(),
        "notes": Text(),
        "meta": MapOf(what="a dict of metadata"),
    },
    open=True,
)


def robot_spec(
    value: Any,
    *,
    base_dir: Path | None = None,
    tool_frame: str | None = None,
    where: str = "robot",
    robot_args: Sequence[str] | None = None,
) -> str | dict[str, str]:
    """The metadata ``robot`` entry for a ``robot=`` option
    (:func:`ditherlab.robot.resolve_spec`, with relative URDF paths taken from ``base_dir``).

    Parameters
    ----------
    value : str | Path | dict
        A built-in robot name (``"irb140"``), an example-robot-data arm (``"ur5"``), a path to
        a URDF or xacro file, or an already formed ``{"urdf": ..., "tool_frame": ...}``.
    base_dir : folder that relative URDF paths are relative to (e.g. the mapping file's).
    tool_frame : frame of the tool for a URDF file; default: the robot model's guess
        (``tool0``, ``flange``, ... else the last link).
    where : the file or option named in error messages.
    robot_args : a xacro file's ``NAME:=VALUE`` arguments (:func:`ditherlab.robot.resolve_spec`).

    Returns
    -------
    str (built-in name) or dict with ``urdf`` (text), ``tool_frame`` and ``name``.
    """
    if isinstance(value, Mapping):
        return resolve_spec(value, tool_frame=tool_frame, where=where)
    p = Path(str(value)).expanduser()
    if base_dir is not None and not p.is_absolute() and (base_dir / p).is_file():
        p = base_dir / p
    return resolve_spec(
        str(p) if p.is_file() else str(value),
        tool_frame=tool_frame,
        where=where,
        robot_args=robot_args,
    )


def urdf_spec(urdf: str, tool_frame: str | None = None, where: str = "URDF") -> dict[str, str]:
    """The metadata ``robot`` entry for URDF text (e.g. a bag's ``/robot_description``)."""
    robot = RobotModel(urdf, tool_frame, where=where)
    return {"urdf": urdf, "tool_frame": robot.tool_frame, "name": robot.name}


def meta_from_options(
    meta: Mapping[str, Any] | None,
    options: Mapping[str, Any],
    *,
    base_dir: Path | None = None,
    where: str = "",
) -> dict[str, Any]:
    """Metadata from a file's own metadata (may be None) updated by reader options.

    ``robot``, ``tool_offset``, ``payload``, ``source``, ``notes`` override the file's values;
    ``schema`` is filled in when absent. ConfigError when an option's value is of the wrong
    kind or out of range (``tool_offset`` [m] of 3 numbers, ``payload`` {mass [kg], com [m]}).
    """
    given = {k: v.tolist() if hasattr(v, "tolist") else v for k, v in options.items()}
    given = {k: v for k, v in given.items() if v is not None}
    check(given, _OPTIONS_SCHEMA, where or "options", ConfigError, label="option ")
    out = copy.deepcopy(dict(meta)) if meta else {}
    out.setdefault("schema", SCHEMA)
    if options.get("robot") is not None:
        out["robot"] = robot_spec(
            options["robot"],
            base_dir=base_dir,
            tool_frame=options.get("tool_frame"),
            where=where or "robot",
            robot_args=options.get("robot_args"),
        )
    elif options.get("robot_args"):
        raise ConfigError(
            f"{where or 'options'}: --robot-arg {', '.join(options['robot_args'])} needs --robot "
            "with a .xacro file (the arguments expand it)"
        )
    elif options.get("tool_frame") and out.get("robot") is not None:
        out["robot"] = robot_spec(
            out["robot"], tool_frame=options["tool_frame"], where=where or "robot"
        )
    if options.get("tool_offset") is not None:
        out["tool_offset"] = [float(x) for x in options["tool_offset"]]
    for key in ("payload", "source", "notes"):
        if options.get(key) is not None:
            out[key] = options[key]
    if "robot" not in out:
        raise FormatError(
            f"{where}: no robot given (the file has no metadata 'robot'); expected --robot with "
            "a built-in name (irb140) or the path of a URDF file, or --mapping for a vendor log "
            f"(built in: {', '.join(builtin_mappings())})"
        )
    return out


#: the reader options that only ROS 2 bags take (:mod:`ditherlab.io.rosbag`)
BAG_OPTIONS = ("joint_topic", "wrench_topic")


def check_options(
    options: Mapping[str, Any], allowed: tuple[str, ...], fmt: str, where: str
) -> None:
    """Raise ConfigError for an option the reader of ``fmt`` does not know (a bag's topic
    option given for another format is named as the CLI spells it)."""
    for key in options:
        if key in BAG_OPTIONS and key not in allowed:
            raise ConfigError(
                f"{where}: --{key.replace('_', '-')} ({key}=) chooses a topic of a ROS 2 bag, "
                f"and this is a {fmt} file; expected no topic option for it"
            )
        if key not in allowed:
            raise ConfigError(
                f"{where}: unknown option {key!r} for {fmt} files (expected one of "
                f"{', '.join(sorted(allowed))})"
            )


def check_units(rec: Recording) -> None:
    """Refuse (RecordingError) a joint log in degrees (:func:`ditherlab.io.units.degrees_evidence`:
    its range against the robot's limits, its derivative against the logged velocity); warn
    (DitherlabWarning) when joint positions lie far beyond the robot's limits for another reason
    (:meth:`ditherlab.robot.RobotModel.check_units`).

    Raises RobotError for an unknown robot, a URDF that does not parse, or a joint count that
    does not match the recording's.
    """
    evidence = degrees_evidence(rec)
    if evidence is not None:
        raise RecordingError(
            f"{rec.name}: the joint log looks like degrees: {evidence}; expected q in rad and dq "
            'in rad/s (a mapping\'s unit = "deg" or "deg/s" converts them, or convert the log)'
        )
    rec.robot().check_units(rec.q, rec.name)


def dumps_meta(meta: Mapping[str, Any]) -> str:
    """The metadata as one JSON string (sorted keys; exact floats)."""
    return json.dumps(meta, sort_keys=True)


def loads_meta(text: str | bytes, where: str) -> dict[str, Any]:
    """Parse a metadata JSON string and check it against the recording's metadata schema
    (:data:`ditherlab.data.recording.STORED_META_SCHEMA`: ``schema`` and ``robot`` may come from
    reader options); FormatError naming ``where`` and the key at the first problem."""
    try:
        meta = json.loads(text)
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(f"{where}: the ditherlab metadata is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise FormatError(
            f"{where}: the ditherlab metadata is {type(meta).__name__}, expected a JSON object"
        )
    check(meta, STORED_META_SCHEMA, where, FormatError, label="metadata key ")
    return meta


def check_times(t: np.ndarray, name: str) -> None:
    """RecordingError, in the Recording's words, for a time stamp that is not a finite number
    or ``t`` (N,) [s] that does not strictly increase."""
    bad = ~np.isfinite(t)
    if bad.any():
        kind = "NaN" if np.isnan(t[bad]).all() else "NaN or infinite"
        first = int(np.flatnonzero(bad)[0]) + 1
        raise RecordingError(f"{name}: t has {int(bad.sum())} {kind} values in rows {first}..")
    check_increasing(t, f"{name}: ")


def checked_times(t: np.ndarray, name: str) -> np.ndarray:
    """A ``t`` column as read, (N,), as float [s] (a cell that is not a number becomes NaN),
    checked by :func:`check_times`."""
    out = pd.to_numeric(pd.Series(t), errors="coerce").to_numpy(float)
    check_times(out, name)
    return out


def looks_numeric(text: str) -> bool:
    """Whether a header field is a number (a line of data where names were expected)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


#: the mapping files shipped with ditherlab (``--mapping NAME``)
MAPPINGS_DIR = Path(__file__).parent / "mappings"


def builtin_mappings() -> list[str]:
    """Names of the mapping files shipped with ditherlab (``ditherlab/io/mappings/*.toml``)."""
    return sorted(p.stem for p in MAPPINGS_DIR.glob("*.toml"))

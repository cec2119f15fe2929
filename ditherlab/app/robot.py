"""``ditherlab robot``: a robot's joints, limits and masses and its tool point, gravity and lever
arms at a pose; with ``sensitivity`` the predicted detection thresholds per push direction
(:func:`ditherlab.analysis.sensitivity.predict`) at the pose, or over a grid of poses written as a
table and a PNG heat map (``--map``, :mod:`ditherlab.analysis.sensitivity_map`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.analysis.sensitivity import Bands, condition_bands, predict
from ditherlab.analysis.sensitivity_map import (
    REPORT_CONDITIONS,
    check_pose,
    format_map,
    format_prediction,
    parse_force_range,
    parse_map_grid,
    parse_noise_level,
    plot_map,
    read_report_noise_level,
    sensitivity_map,
)
from ditherlab.app.workflow import Progress, guard
from ditherlab.core.errors import ConfigError, ModelError
from ditherlab.core.files import FileKind, atomic_path, plain
from ditherlab.data.torque_model import TorqueModel
from ditherlab.robot import RobotModel, format_description, resolve_spec
from ditherlab.robot.catalog import available_robots, format_catalog

__all__ = ["MAP_FILE", "RobotOptions", "RobotResult", "run"]

#: the table that ``robot --sensitivity --map`` writes (a PNG beside it)
MAP_FILE = FileKind("a sensitivity map table", (".csv", ".parquet"), "map.csv")


@dataclass(frozen=True)
class RobotOptions:
    """The options of ``ditherlab robot``.

    Attributes
    ----------
    spec : a built-in robot name (``irb140``, ``panda``, ``ur10e``), an example-robot-data arm
        (``ur5``), or a URDF or xacro path; None: list the robots
    list_robots : list the robots by name with their joint counts (``--list``)
    robot_args : a xacro robot's ``NAME:=VALUE`` arguments
    q : the pose: ``zero``, ``paper`` (IRB140) or n angles [rad], comma-separated; None: zero
    tool_frame : the tool frame of a URDF (default: ``tool0``, ``flange``, ... or the last link)
    sensitivity : predict the detection thresholds F50 / F90 per push direction
    model : a model file from ``identify`` for the bands (None: the simulator's)
    dither : one condition (with / without dither); None: both
    map_out : the map's table over ``grid`` (``.csv`` or ``.parquet``; the PNG beside it)
    grid : the map's poses, ``qJ=START:STOP:COUNT[,qK=...]`` [rad]
    force_range : the pushes' magnitudes ``MIN:MAX`` [N]
    noise_level : a measured noise level ``X,Y,Z`` [N] of one condition, for the predicted
    report : a ``report.json`` of ``ditherlab report``: its measured noise level instead
    seed : the draws' seed
    force : replace an existing map table and PNG
    """

    spec: str | None = None
    list_robots: bool = False
    robot_args: tuple[str, ...] = ()
    q: str | None = None
    tool_frame: str | None = None
    sensitivity: bool = False
    model: Path | None = None
    dither: bool | None = None
    map_out: str | Path | None = None
    grid: str | None = None
    force_range: str = "10:60"
    noise_level: str | None = None
    report: Path | None = None
    seed: int = 0
    force: bool = False


@dataclass
class RobotResult:
    """The description (or prediction, or map summary) as text and as JSON-ready data."""

    lines: str
    data: dict[str, Any]

    def text(self) -> str:
        """What the CLI prints."""
        return self.lines

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output."""
        return plain(self.data)


def run(options: RobotOptions, progress: Progress | None = None) -> RobotResult:
    """Describe the robot at the pose, or (``sensitivity``) predict its thresholds there or
    write the map over the grid (atomically; both outputs checked before any work).

    Parameters
    ----------
    options : :class:`RobotOptions`
    progress : ``progress(done, total)`` over the map's poses, optional

    Returns
    -------
    RobotResult

    Raises
    ------
    ConfigError, ModelError, RobotError
        A bad option (one line naming it), a model of another robot, a pose outside the limits.
    """
    o = options
    extra = (o.map_out, o.grid, o.model, o.noise_level, o.report)
    if not o.sensitivity and (any(x is not None for x in extra) or o.dither is not None):
        raise ConfigError(
            "robot: --map, --grid, --model, --dither, --noise-level and --report need --sensitivity"
        )
    if o.spec is None or o.list_robots:
        return _list(o)
    spec = resolve_spec(o.spec, o.tool_frame, robot_args=o.robot_args)
    if not o.sensitivity:
        rm = RobotModel.from_spec(spec)
        summary = rm.describe(rm.parse_pose(o.q))
        return RobotResult(format_description(summary), summary)
    if o.map_out is not None:
        guard(o.map_out, [o.model, o.report], kind=MAP_FILE, force=o.force)
        guard(Path(o.map_out).with_suffix(".png"), [o.model, o.report, o.map_out], force=o.force)
    tm = _load_model(o.model, spec)
    rm = RobotModel.from_spec(
        spec, tool_offset=tm.tool_offset if tm else None, payload=tm.payload if tm else None
    )
    pose = rm.parse_pose(o.q)
    check_pose(rm, pose)
    fr = parse_force_range(o.force_range)
    conds = [o.dither] if o.dither is not None else [False, True]
    given = _given_noise(o, conds)
    bands = {d: condition_bands(rm.n, tm, dither=d, robot_name=rm.name) for d in conds}
    if o.map_out is None:
        if o.grid is not None:
            raise ConfigError("--grid needs --map FILE (the table to write)")
        return _predict_at_pose(o, rm, pose, bands, given, fr)
    if o.grid is None:
        raise ConfigError("--map needs --grid qJ=START:STOP:COUNT[,qK=...] (the poses)")
    return _write_map(o, rm, pose, bands, fr, progress)


def _list(o: RobotOptions) -> RobotResult:
    """The robots by name (:func:`ditherlab.robot.catalog.available_robots`); ConfigError for
    a robot or pose option given with it."""
    given = [
        opt
        for opt, v in (("ROBOT", o.spec if o.list_robots else None), ("--q", o.q),
                       ("--tool-frame", o.tool_frame), ("--robot-arg", o.robot_args),
                       ("--sensitivity", o.sensitivity))
        if v
    ]  # fmt: skip
    if given:
        raise ConfigError(f"robot --list lists every robot; expected no {', '.join(given)} with it")
    catalog = available_robots()
    return RobotResult(format_catalog(catalog), catalog)


def _load_model(path: Path | None, spec: str | dict) -> TorqueModel | None:
    """The model of ``path`` (None for None); ModelError when it is for another robot."""
    if path is None:
        return None
    tm = TorqueModel.load(path)
    if not tm.same_robot(spec):
        label = spec if isinstance(spec, str) else spec.get("name", "urdf")
        mlabel = tm.robot if isinstance(tm.robot, str) else tm.robot.get("name", "urdf")
        raise ModelError(
            f"{path}: the model is for robot {mlabel}, not {label}; expected a model "
            "identified on this robot"
        )
    return tm


def _given_noise(o: RobotOptions, conds: list[bool]) -> dict[bool, tuple[np.ndarray, str]]:
    """Per condition, a measured noise level (3,) [N] and where it comes from
    (``--noise-level``, ``--report``); ConfigError for options that do not go together."""
    given: dict[bool, tuple[np.ndarray, str]] = {}
    if o.noise_level is not None and o.report is not None:
        raise ConfigError("--noise-level and --report both give the noise level; expected one")
    if (o.noise_level is not None or o.report is not None) and o.map_out is not None:
        opt = "--noise-level" if o.noise_level is not None else "--report"
        raise ConfigError(
            f"{opt} gives the noise level measured at one pose; expected no --map (the map "
            "predicts each pose's own)"
        )
    if o.noise_level is not None:
        if o.dither is None:
            raise ConfigError(
                f"--noise-level {o.noise_level} is one condition's noise level; expected "
                "--dither or --no-dither with it"
            )
        given[o.dither] = (parse_noise_level(o.noise_level), "given (--noise-level)")
    if o.report is not None:
        for d in conds:
            lv = read_report_noise_level(o.report, d)
            given[d] = (lv, f"measured (--report {o.report}, {REPORT_CONDITIONS[d]})")
    return given


def _predict_at_pose(
    o: RobotOptions,
    rm: RobotModel,
    pose: np.ndarray,
    bands: dict[bool, Bands],
    given: dict[bool, tuple[np.ndarray, str]],
    fr: tuple[float, float],
) -> RobotResult:
    """The prediction of each condition at ``pose`` (n,) [rad] for pushes of ``fr`` [N]."""
    preds = [
        predict(
            rm,
            pose,
            bands[d],
            force_range=fr,
            seed=o.seed,
            noise_level=given[d][0] if d in given else None,
            noise_source=given[d][1] if d in given else None,
        )
        for d in bands
    ]
    text = "\n\n".join(format_prediction(p) for p in preds)
    return RobotResult(text, {"robot": rm.name, "predictions": preds})


def _write_map(
    o: RobotOptions,
    rm: RobotModel,
    pose: np.ndarray,
    bands: dict[bool, Bands],
    fr: tuple[float, float],
    progress: Progress | None,
) -> RobotResult:
    """The prediction at every pose of the grid for pushes of ``fr`` [N], written as a table
    and a PNG beside it."""
    assert o.map_out is not None and o.grid is not None
    map_out = Path(o.map_out)
    g = parse_map_grid(o.grid, rm)
    conds = list(bands)
    total = len(conds) * int(np.prod([len(v) for v in g.values()]))
    frames = []
    for i, d in enumerate(conds):
        done = i * total // len(conds)

        def tick(k: int, _n: int, done: int = done) -> None:
            if progress:
                progress(done + k, total)

        df = pd.DataFrame(
            sensitivity_map(rm, pose, g, bands[d], progress=tick, force_range=fr, seed=o.seed)
        )
        df.insert(0, "dither", d)
        frames.append(df)
    table = pd.concat(frames, ignore_index=True)
    png = map_out.with_suffix(".png")
    with atomic_path(map_out) as tmp:
        if map_out.suffix.lower() == ".csv":
            table.to_csv(tmp, index=False)
        else:
            table.to_parquet(tmp, index=False)
    with atomic_path(png) as tmp:
        plot_map(table, list(g), tmp, conds, rm.name, bands)
    src = bands[conds[0]].source
    text = format_map(table, list(g), conds)
    text += f"\nwrote {map_out} ({len(table)} rows) and {png}; bands from {src}"
    summary = {
        "table": str(map_out),
        "figure": str(png),
        "rows": len(table),
        "conditions": ["dither" if d else "no dither" for d in conds],
        "source": src,
    }
    return RobotResult(text, summary)

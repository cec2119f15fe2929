"""``ditherlab robot --sensitivity`` over a grid of poses (``--map``): the grid's parsing, one
row per pose, the text summary, the PNG heat map, a measured noise level (``--noise-level``,
``--report``: :func:`parse_noise_level`, :func:`report_noise_level`) and the prediction as text
(:func:`format_prediction`). The prediction is :mod:`ditherlab.analysis.sensitivity`; the
command's workflow :mod:`ditherlab.app.robot`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.sensitivity import (
    AXES,
    DIRECTIONS,
    MAP_OPTIONS,
    Bands,
    predict,
)
from ditherlab.core.errors import ConfigError, RobotError
from ditherlab.robot.model import RobotModel
from ditherlab.robot.poses import outside_limits

__all__ = [
    "REPORT_CONDITIONS",
    "check_pose",
    "format_map",
    "format_prediction",
    "map_columns",
    "parse_force_range",
    "parse_map_grid",
    "parse_noise_level",
    "plot_map",
    "prediction_row",
    "read_report_noise_level",
    "report_noise_level",
    "sensitivity_map",
]


#: the report's condition (``replay`` variant) whose noise level a prediction can take: the
#: estimator of eq. (3) with the band term, which :func:`predict` models (dithered: True)
REPORT_CONDITIONS = {True: "dither_band", False: "nodither_band"}


# ------------------------------------------------------------------ a grid of poses
def parse_map_grid(text: str, robot: RobotModel, where: str = "--grid") -> dict[int, np.ndarray]:
    """``"q2=-0.5:0.5:11,q3=-1:0.2:6"`` -> ``{1: values (11,), 2: values (6,)}`` [rad]:
    per joint (1-based ``qJ``) ``start:stop:count`` evenly spaced, inclusive, within the joint's
    limits; one or two joints.

    Raises
    ------
    ConfigError
        A malformed entry, an unknown joint, a joint given twice, a count below 2, ``start >=
        stop``, values outside the joint's limits, more than two joints.
    """
    grid: dict[int, np.ndarray] = {}
    parts = [p for p in str(text).split(",") if p.strip()]
    if not parts:
        raise ConfigError(f"{where} is empty; expected qJ=START:STOP:COUNT[,qK=...]")
    for part in parts:
        key, eq, rng = part.partition("=")
        key = key.strip().lower()
        if not eq or not key.startswith("q") or not key[1:].isdigit():
            raise ConfigError(
                f"{where} entry {part.strip()!r} is not qJ=START:STOP:COUNT (e.g. q2=-0.5:0.5:11)"
            )
        j = int(key[1:])
        if not 1 <= j <= robot.n:
            raise ConfigError(
                f"{where} joint {key!r} is unknown; expected q1..q{robot.n} ({robot.name})"
            )
        if j - 1 in grid:
            raise ConfigError(f"{where} joint {key!r} is given twice; expected it once")
        bits = rng.split(":")
        try:
            a, b, c = float(bits[0]), float(bits[1]), int(bits[2])
            ok = len(bits) == 3 and math.isfinite(a) and math.isfinite(b)
        except (ValueError, IndexError):
            ok = False
        if not ok:
            raise ConfigError(
                f"{where} {key}={rng!r} is not START:STOP:COUNT (rad, rad, an integer)"
            )
        if c < 2 or not a < b:
            raise ConfigError(
                f"{where} {key}={rng}: expected START < STOP and COUNT >= 2 (got {a:g}, {b:g}, {c})"
            )
        lo, hi = robot.q_lower[j - 1], robot.q_upper[j - 1]
        if a < lo or b > hi:
            raise ConfigError(
                f"{where} {key}={rng}: [{a:g}, {b:g}] rad leaves joint {j}'s limits "
                f"[{lo:.4g}, {hi:.4g}] rad"
            )
        grid[j - 1] = np.round(np.linspace(a, b, c), 12) + 0.0  # no -1e-16 for 0
    if len(grid) > 2:
        raise ConfigError(f"{where} varies {len(grid)} joints; expected one or two")
    return grid


def check_pose(robot: RobotModel, q: np.ndarray, where: str = "--q") -> None:
    """RobotError when a joint of ``q`` (n,) [rad] lies outside its limits."""
    j = outside_limits(q, robot.q_lower, robot.q_upper)
    if j is not None:
        raise RobotError(
            f"{where}: q{j + 1} = {q[j]:.4g} rad is outside joint {j + 1}'s limits "
            f"[{robot.q_lower[j]:.4g}, {robot.q_upper[j]:.4g}] rad"
        )


def map_columns() -> list[str]:
    """The columns of a map row after the joint angles ``q1..qn``."""
    cols = []
    for name, _, _ in DIRECTIONS:
        cols += [f"f50_{name}", f"f90_{name}"]
    cols += [f"f50_{a}" for a in AXES] + [f"f90_{a}" for a in AXES]
    cols += [f"noise_{a}" for a in AXES]
    return cols


def prediction_row(pred: Mapping[str, Any]) -> dict[str, float]:
    """One map row (:func:`map_columns`) from :func:`predict`'s result."""
    row: dict[str, float] = {}
    for name, _, _ in DIRECTIONS:
        d = pred["directions"][name]
        row[f"f50_{name}"], row[f"f90_{name}"] = d["f50"], d["f90"]
    for a in AXES:
        row[f"f50_{a}"] = pred["axes"][a]["f50"]
        row[f"f90_{a}"] = pred["axes"][a]["f90"]
        row[f"noise_{a}"] = pred["noise_level"][a]
    return row


def sensitivity_map(
    robot: RobotModel,
    q: np.ndarray,
    grid: Mapping[int, np.ndarray],
    bands: Bands,
    *,
    progress: Callable[[int, int], None] | None = None,
    **options: Any,
) -> list[dict[str, float]]:
    """:func:`predict` at every pose of ``grid`` (joint index -> values [rad], the first joint
    varying slowest; the other joints at ``q`` (n,) [rad]): one row per pose, the angles
    ``q1..qn`` [rad] then :func:`map_columns`. ``options`` go to :func:`predict` (default
    :data:`MAP_OPTIONS`)."""
    keys = list(grid)
    mesh = np.meshgrid(*(grid[k] for k in keys), indexing="ij")
    poses = np.stack([m.ravel() for m in mesh], axis=1)
    rows = []
    options = {**MAP_OPTIONS, **options}
    for i, vals in enumerate(poses):
        qi = np.array(q, float)
        qi[keys] = vals
        pred = predict(robot, qi, bands, **options)
        rows.append({**{f"q{j + 1}": float(qi[j]) for j in range(robot.n)}, **prediction_row(pred)})
        if progress:
            progress(i + 1, len(poses))
    return rows


def parse_force_range(text: str, where: str = "--force-range") -> tuple[float, float]:
    """``"5:60"`` -> ``(5.0, 60.0)`` [N]: the campaign's push magnitudes, ``0 <= MIN < MAX``."""
    try:
        lo, hi = (float(x) for x in str(text).split(":"))
        ok = math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi
    except ValueError:
        ok = False
    if not ok:
        raise ConfigError(f"{where} is {text!r}; expected MIN:MAX in N with 0 <= MIN < MAX")
    return lo, hi


# ------------------------------------------------------------------ the noise level and the text
def parse_noise_level(text: str, where: str = "--noise-level") -> np.ndarray:
    """``"4.6,5.2,6.5"`` -> the noise level per axis x, y, z (3,) [N]: a measured level (the
    report's 99.9 % of ``|F̂|`` at rest) for :func:`predict` instead of the predicted one.

    Raises
    ------
    ConfigError
        Not three comma-separated numbers, or one negative or not finite.
    """
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = np.array([float(p) for p in parts], float)
    except ValueError:
        vals = np.array([math.nan])
    if len(parts) != 3 or not np.all(np.isfinite(vals)):
        raise ConfigError(
            f"{where} is {text!r}; expected three numbers X,Y,Z in N (the noise level per axis)"
        )
    if np.any(vals < 0):
        raise ConfigError(f"{where} is {text!r}; expected noise levels >= 0 N")
    return vals


def report_noise_level(
    report: Mapping[str, Any], dithered: bool, where: str = "report"
) -> np.ndarray:
    """The measured noise level per axis x, y, z (3,) [N] of the condition a prediction models
    (:data:`REPORT_CONDITIONS`: ``dither_band`` with dither, ``nodither_band`` without) from
    the analysis ``report`` (``report.json`` of ``ditherlab report``, or
    :func:`ditherlab.analysis.detection.analyse`'s dict): read, not recomputed.

    Raises
    ------
    ConfigError
        ``report`` has no such condition, or that condition has no noise level on an axis
        (no rest samples) or a negative one; ``where`` names the report in the message.
    """
    cond = REPORT_CONDITIONS[bool(dithered)]
    conds = report.get("conditions") if isinstance(report, Mapping) else None
    if not isinstance(conds, Mapping):
        raise ConfigError(f"{where}: no 'conditions'; expected the report.json of ditherlab report")
    if cond not in conds:
        have = ", ".join(sorted(conds)) or "none"
        raise ConfigError(
            f"{where}: no condition {cond} (it has {have}); expected a report of estimates "
            f"with the {cond} variant ({'with' if dithered else 'without'} dither)"
        )
    nl = (conds[cond] or {}).get("noise_level") or {}
    out = []
    for a in AXES:
        v = nl.get(a)
        ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or v < 0:
            raise ConfigError(
                f"{where}: condition {cond} has noise level {v!r} along {a}; expected a "
                "number >= 0 N (rest samples on every axis)"
            )
        out.append(float(v))
    return np.array(out)


def _num(x: float, width: int = 7) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return f"{'–':>{width}}"
    if math.isinf(x):
        return f"{'never':>{width}}"
    return f"{x:{width}.1f}"


def format_prediction(pred: Mapping[str, Any]) -> str:
    """The per-direction table of :func:`predict` as text."""
    qd = ", ".join(f"{math.degrees(x):.1f}" for x in pred["q"])
    nl = pred["noise_level"]
    lines = [
        f"pose sensitivity at q = ({qd}) deg, "
        f"{'with dither' if pred['dithered'] else 'without dither'}; bands from {pred['source']}",
        *(
            [
                "noise level (99.9 % of |F̂| at rest, >= 1 N): "
                + "  ".join(f"{a} {nl[a]:.2f} N" for a in AXES)
            ]
            if pred.get("noise_level_source", "predicted") == "predicted"
            else [
                f"noise level {pred['noise_level_source']}: "
                + "  ".join(f"{a} {nl[a]:.2f} N" for a in AXES)
                + "  (predicted from the bands: "
                + "  ".join(f"{a} {pred['noise_level_predicted'][a]:.2f}" for a in AXES)
                + " N)"
            ]
        ),
        *(
            [f"push transmission with dither: {pred['transmission']}"]
            if pred.get("transmission")
            else []
        ),  # fmt: skip
        f"{'direction':<10}{'F50 [N]':>9}{'F90 [N]':>9}{'curve F50':>11}{'curve F90':>11}  joints",
    ]
    for name, _, _ in DIRECTIONS:
        d = pred["directions"][name]
        lines.append(
            f"{name:<10}{_num(d['f50'], 9)}{_num(d['f90'], 9)}{_num(d['curve_f50'], 11)}"
            f"{_num(d['curve_f90'], 11)}  {', '.join(str(j) for j in d['joints']) or '-'}"
        )
    lo, hi = pred["force_range"]
    lines.append(
        f"per axis, both signs (the report's logistic fit to pushes of {lo:g}–{hi:g} N): "
        + "  ".join(
            f"{a} F50 {_num(pred['axes'][a]['f50'], 0).strip()} / F90 "
            f"{_num(pred['axes'][a]['f90'], 0).strip()} N"
            for a in AXES
        )
    )
    if pred.get("borrowed"):  # every line says what it takes from another robot
        tag = f"  [IRB140 simulator's {' and '.join(pred['borrowed'])}]"
        lines = [line + tag for line in lines]
    return "\n".join(lines)


def read_report_noise_level(path: str | Path, dithered: bool) -> np.ndarray:
    """The measured noise level per axis (3,) [N] of the matching condition
    (:data:`ditherlab.analysis.sensitivity.REPORT_CONDITIONS`) in a ``report.json`` written by
    ``ditherlab report`` (:func:`ditherlab.analysis.sensitivity.report_noise_level`).

    Raises
    ------
    ConfigError
        No such file, not JSON, or no noise level of that condition (one line naming the file).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(
            f"--report {p}: no such file; expected the report.json of ditherlab report"
        )
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        msg = " ".join(str(exc).split())
        raise ConfigError(
            f"--report {p}: not JSON ({msg}); expected the report.json of ditherlab report"
        ) from None
    return report_noise_level(d, dithered, where=f"--report {p}")


def format_map(table: Any, joints: Sequence[int], conditions: Sequence[bool]) -> str:
    """A short text summary of a map (a DataFrame of :func:`sensitivity_map` rows with a
    ``dither`` column): per condition and axis the smallest and largest F50 and their poses."""
    lines = []
    names = [f"q{j + 1}" for j in joints]
    for d in conditions:
        t = table[table["dither"] == d]
        lines.append(
            f"{'with dither' if d else 'without dither'}: F50 per axis over {len(t)} poses"
        )
        for a in AXES:
            col = t[f"f50_{a}"].to_numpy(float)
            if not np.isfinite(col).any():
                lines.append(f"  {a}: no transition in the force range at any pose")
                continue
            i, k = int(np.nanargmin(col)), int(np.nanargmax(col))
            at_i, at_k = (", ".join(f"{n}={t.iloc[r][n]:.3g}" for n in names) for r in (i, k))
            lines.append(f"  {a}: {col[i]:.1f} N ({at_i}) .. {col[k]:.1f} N ({at_k})")
    return "\n".join(lines)


def plot_map(
    table: Any,
    joints: Sequence[int],
    path: Any,
    conditions: Sequence[bool],
    robot_name: str,
    bands: Mapping[bool, Bands],
) -> None:
    """A PNG of F50 per push direction over the grid: a heat map per direction and condition
    for two varied joints, curves for one.

    Parameters
    ----------
    table : DataFrame of :func:`sensitivity_map` rows with a ``dither`` column
    joints : the varied joints (0-based), in grid order
    path : the PNG to write
    conditions : the conditions in the table (False: no dither, True: dither)
    robot_name, bands : for the titles
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [f"q{j + 1}" for j in joints]
    nr = len(conditions)
    fig, axs = plt.subplots(nr, 6, figsize=(20, 3.4 * nr), constrained_layout=True, squeeze=False)
    for i, d in enumerate(conditions):
        t = table[table["dither"] == d]
        for k, (name, _, _) in enumerate(DIRECTIONS):
            ax = axs[i, k]
            z = t[f"f50_{name}"].to_numpy(float)
            z = np.where(np.isfinite(z), z, np.nan)
            if len(joints) == 1:
                ax.plot(t[names[0]].to_numpy(float), z, "o-")
                ax.set_xlabel(f"{names[0]} [rad]")
                ax.set_ylabel("F50 [N]")
            else:
                x = np.unique(t[names[0]].to_numpy(float))
                y = np.unique(t[names[1]].to_numpy(float))
                im = ax.pcolormesh(
                    y, x, z.reshape(len(x), len(y)), shading="nearest", cmap="viridis"
                )
                fig.colorbar(im, ax=ax, label="F50 [N]")
                ax.set_xlabel(f"{names[1]} [rad]")
                ax.set_ylabel(f"{names[0]} [rad]")
            ax.set_title(f"push {name}, {'dither' if d else 'no dither'}", fontsize=9)
    fig.suptitle(
        f"{robot_name}: predicted F50 per push direction; bands from {bands[conditions[0]].source}"
    )
    fig.savefig(path, dpi=80)
    plt.close(fig)

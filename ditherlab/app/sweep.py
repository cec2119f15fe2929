"""Simulator sweeps of the dither design (§VII left open): ``ditherlab sweep``.

A grid over any keys of the simulator's parameter file (``irb140.toml``), e.g.
``dither.waveform=square,sine`` × ``dither.frequency=40,80,160``: each point is one Dask task
(:func:`ditherlab.core.tasks.run_tasks`, a LocalCluster in this process by default) that runs
the paper's experiment in small, as ``make demo`` does (:mod:`ditherlab.app.demo`):

1. paired push campaigns without and with dither for **identification** (seed ``seed + 1``)
   and, separately, for **evaluation** (seed ``seed``): the same pushes with and without
   dither, and the same push plans at every grid point, so points differ only by their design;
2. ``identify`` on the identification pair (no bootstrap);
3. ``replay`` of the evaluation pair: ``nodither_band`` on the undithered campaign (the
   baseline), ``dither_band`` on the dithered one (force components only, as ``fleet``);
4. the detection statistics of :func:`ditherlab.analysis.detection.analyse`: per direction the F50 /
   F90 of the logistic detection curve, the 95 % interval's coverage during pushes and at
   rest; and the **vibration** of the dithered evaluation campaign (:func:`vibration`): of
   the arm (the link angle; the paper's limit, 1e-4 rad, applies to it) and of the motor angle
   in arm-side units (what the paper measured), each on the joint that vibrates most.

:func:`run` runs each point on ``repeats`` seeds (``seed, seed + 2, ...``: the design's
effect against the campaigns' own scatter) and writes, atomically, ``sweep.parquet`` (one row
per point, the mean over its runs, :data:`COLUMNS` after the grid's own columns),
``sweep_runs.parquet`` (one row per run, :data:`RUN_COLUMNS`), ``sweep.md`` (the printed
table), ``sweep.json`` (the best design under the vibration limit, overall and per waveform)
and two figures (:mod:`ditherlab.output.sweep_figures`). A run that fails is reported with its
error; the others go on. Grid mistakes (an unknown key, an empty grid, an unknown
waveform, a value of the wrong type, a value the simulator rejects) are a
:class:`~ditherlab.core.errors.ConfigError` before any task runs.
"""

from __future__ import annotations

import copy
import itertools
import math
import re
import time
import tomllib
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.analysis.detection import analyse
from ditherlab.analysis.estimation import replay
from ditherlab.analysis.identification import identify
from ditherlab.analysis.sweep_pose import (
    DIRECTION_NAMES,
    check_pose,
    direction_f50,
    predicted,
    without_ramp_down,
)
from ditherlab.app.workflow import guard
from ditherlab.core.errors import ConfigError
from ditherlab.core.files import atomic_path, atomic_write_json, atomic_write_text
from ditherlab.core.names import FORCE_AXES
from ditherlab.core.tasks import TaskResult, run_tasks
from ditherlab.data.recording import Recording
from ditherlab.output.sweep_figures import plot_points, plot_prediction, plot_tradeoff
from ditherlab.physics.dither import WAVEFORMS, dither_period
from ditherlab.sim import simulate
from ditherlab.sim.params import default_params, load_params

__all__ = [
    "COLUMNS",
    "RUN_COLUMNS",
    "VIBRATION_LIMIT",
    "aggregate",
    "parse_grid",
    "run_point",
    "SweepOptions",
    "Swept",
    "run",
    "vibration",
]

#: The paper's acceptable vibration (§III-B): "about one hundredth of a motor radian, which
#: would correspond to 0.0001 arm radians" [rad, arm side]
VIBRATION_LIMIT = 1e-4

#: What one run of a point measures. Units: N for forces, rad (arm side) for the vibration,
#: fractions for coverage, s for seconds. ``f50_*``, ``f90_*``: the dithered evaluation campaign
#: (``dither_band``), ``_bound`` ``below`` / ``above`` when every / no push was seen (then the
#: smallest / largest force), ``_lo`` / ``_hi`` F50's 90 % bootstrap interval over pushes;
#: ``nodither_*``: the undithered campaign (``nodither_band``); ``f50_+x`` ..: F50 of one push
#: direction (the pushes of one sign, no bootstrap; a bound's force when every / no push was
#: seen); ``noise_x`` ..: the noise level the report measured at rest (``dither_band``;
#: ``nodither_noise_*``: ``nodither_band``); ``pred_*``: F50 predicted at the point's pose from
#: the identified model alone (:func:`ditherlab.analysis.sensitivity.predict`; per axis the
#: report's logistic fit over the campaign's push magnitudes, else the smaller direction's
#: crossing; per direction the crossing of one half; ``pred_noise_*`` its predicted noise
#: level); ``predm_*``: the same prediction given the point's measured noise level.
METRICS = [
    *(f"f50_{a}" for a in FORCE_AXES),
    *(f"f90_{a}" for a in FORCE_AXES),
    *(f"f50_{a}_bound" for a in FORCE_AXES),
    *(f"f50_{a}_{e}" for a in FORCE_AXES for e in ("lo", "hi")),
    "f50_mean",
    *(f"nodither_f50_{a}" for a in FORCE_AXES),
    "vibration",
    "vibration_joint",
    "vibration_motor",
    "vibration_motor_joint",
    "within_limit",
    "coverage_push",
    "coverage_rest",
    "nodither_coverage_push",
    "amplitude_reached",
    "pushes",
    "seconds",
    *(f"{c}f50_{d}" for c in ("", "nodither_") for d in DIRECTION_NAMES),
    *(f"pred_{c}f50_{a}" for c in ("", "nodither_") for a in FORCE_AXES),
    *(f"pred_{c}f50_{d}" for c in ("", "nodither_") for d in DIRECTION_NAMES),
    *(f"{c}noise_{a}" for c in ("", "nodither_") for a in FORCE_AXES),
    *(f"pred_{c}noise_{a}" for c in ("", "nodither_") for a in FORCE_AXES),
    *(f"predm_{c}f50_{a}" for c in ("", "nodither_") for a in FORCE_AXES),
    *(f"predm_{c}f50_{d}" for c in ("", "nodither_") for d in DIRECTION_NAMES),
]
#: ``sweep_runs.parquet``'s columns after the grid's own: one row per point and seed.
RUN_COLUMNS = ["point", "seed", "ok", "error", *METRICS]
#: ``sweep.parquet``'s columns after the grid's own (one per grid key, named by the key): one
#: row per point, the mean over its runs that did not fail (``runs`` of them; a direction whose
#: pushes were all / none seen counts its bound's force; ``_bound`` is kept when every run had
#: it), ``f50_mean_sem`` the standard error of ``f50_mean`` over runs (NaN for one run).
COLUMNS = ["point", "runs", "ok", "error", *METRICS, "f50_mean_sem"]


# ------------------------------------------------------------------ the grid
def _leaf(params: Mapping[str, Any], key: str) -> Any:
    """The default of a dotted parameter key, or a ConfigError naming it."""
    node: Any = params
    parts = key.split(".")
    for i, part in enumerate(parts):
        if not isinstance(node, Mapping) or part not in node:
            where = ".".join(parts[:i]) or "the top level"
            known = ", ".join(sorted(node)) if isinstance(node, Mapping) else ""
            raise ConfigError(
                f"sweep: --grid key '{key}' does not exist; expected a key of the simulator's "
                f"parameters (irb140.toml; under {where}: {known})"
            )
        node = node[part]
    if isinstance(node, Mapping):
        raise ConfigError(
            f"sweep: --grid key '{key}' is a table; expected one of its keys "
            f"({', '.join(f'{key}.{k}' for k in sorted(node))})"
        )
    return node


def _scalar(default: Any, text: str, key: str) -> Any:
    """One grid value of the default's type (bool, int, float or text)."""
    s = text.strip()
    if isinstance(default, bool):
        if s.lower() in ("true", "false"):
            return s.lower() == "true"
        expected = "true or false"
    elif isinstance(default, int):
        try:
            return int(s)
        except ValueError:
            expected = f"an integer such as {default}"
    elif isinstance(default, float):
        try:
            v = float(s)
        except ValueError:
            v = math.nan
        if math.isfinite(v):
            return v
        expected = f"a finite number such as {default:g}"
    elif key == "dither.waveform":
        if s in WAVEFORMS:
            return s
        raise ConfigError(
            f"sweep: --grid dither.waveform value '{s}' is unknown; expected one of "
            f"{', '.join(WAVEFORMS)}"
        )
    else:
        return s
    raise ConfigError(f"sweep: --grid {key} value '{s}' is not {expected}")


def _value(default: Any, text: str, key: str) -> Any:
    """One grid value: a scalar, or for a per-joint list one value for all joints or
    ``v1:v2:...`` with one value per joint."""
    if not isinstance(default, list):
        return _scalar(default, text, key)
    if not default or isinstance(default[0], list):
        raise ConfigError(
            f"sweep: --grid key '{key}' holds a list of lists; it cannot be swept (give it in "
            "--config)"
        )
    parts = text.split(":")
    if len(parts) == 1:
        return _scalar(default[0], parts[0], key)
    if len(parts) != len(default):
        raise ConfigError(
            f"sweep: --grid {key} value '{text}' has {len(parts)} entries; expected one value "
            f"or {len(default)} separated by ':'"
        )
    return [_scalar(d, p, key) for d, p in zip(default, parts, strict=True)]


def parse_grid(specs: Sequence[str]) -> dict[str, list[Any]]:
    """``["dither.frequency=40,80", "dither.waveform=square,sine"]`` -> ``{key: values}``.

    Each spec is ``KEY=V1,V2,...`` with ``KEY`` a dotted key of ``irb140.toml``; the values take
    the default's type (numbers, ``true``/``false``, text; a waveform must be one of
    :data:`ditherlab.physics.dither.WAVEFORMS`); a per-joint list takes one value for all joints or one
    per joint separated by ``:`` (``0:0.3:0:0:1.5708:0``). Keys keep the order given.

    Raises
    ------
    ConfigError
        No spec, a spec without ``=`` or values, a key given twice, a key the parameters do
        not have, a value of the wrong type; one line naming the key and the value.
    """
    if not specs:
        raise ConfigError(
            "sweep: the grid is empty; expected at least one --grid KEY=V1,V2,... (e.g. "
            "--grid dither.frequency=40,80,160)"
        )
    defaults = default_params()
    grid: dict[str, list[Any]] = {}
    lists: dict[str, str] = {}  # a swept list's key -> the grid key that sweeps (part of) it
    for spec in specs:
        key, eq, values = str(spec).partition("=")
        key = key.strip()
        if not eq or not key:
            raise ConfigError(f"sweep: --grid '{spec}' is not KEY=V1,V2,...")
        base, index = _element(key)
        default = _leaf(defaults, base)
        if index is not None:
            default = _element_default(default, key, base, index)
        texts = [v for v in values.split(",") if v.strip()]
        if not texts:
            raise ConfigError(
                f"sweep: --grid {key} has no values (the grid is empty); expected {key}=V1,V2,..."
            )
        if key in grid:
            raise ConfigError(f"sweep: --grid key '{key}' is given twice; expected it once")
        other = lists.get(base)
        if other is not None and (index is None or _element(other)[1] is None):
            raise ConfigError(
                f"sweep: --grid keys '{other}' and '{key}' both set {base}; expected the whole "
                "list or single joints of it"
            )
        lists[base] = key
        grid[key] = [_value(default, t, key) for t in texts]
    return grid


#: ``pose.qJ`` (J = 1, 2, ...) is joint J of the start pose ``pose.q0`` [rad]
_POSE_JOINT = re.compile(r"^pose\.q([1-9][0-9]*)$")
_INDEXED = re.compile(r"^(.+)\[([0-9]+)\]$")


def _element(key: str) -> tuple[str, int | None]:
    """The parameter a grid key sets and the joint (0-based) of a per-joint list it sets alone:
    ``KEY[J]`` (J = 1, 2, ...) and ``pose.qJ`` (= ``pose.q0[J]``); ``(key, None)`` otherwise."""
    m = _POSE_JOINT.match(key)
    if m:
        return "pose.q0", int(m.group(1)) - 1
    m = _INDEXED.match(key)
    if m:
        return m.group(1), int(m.group(2)) - 1
    return key, None


def _element_default(default: Any, key: str, base: str, index: int) -> Any:
    """The default of joint ``index`` of the per-joint list ``base``, or a ConfigError."""
    if not isinstance(default, list) or not default or isinstance(default[0], list):
        raise ConfigError(
            f"sweep: --grid key '{key}': {base} is not a per-joint list; expected KEY[J] of a "
            "list such as dither.amplitude_fraction[1] or pose.q2"
        )
    if not 0 <= index < len(default):
        raise ConfigError(
            f"sweep: --grid key '{key}': joint {index + 1} does not exist; expected 1.."
            f"{len(default)}"
        )
    return default[index]


def _get(config: Mapping[str, Any], key: str, defaults: Mapping[str, Any]) -> Any:
    """The value of a dotted key in ``config``, else in ``defaults`` (a copy)."""
    node: Any = _merge(dict(defaults), config)
    for part in key.split("."):
        node = node[part]
    return copy.deepcopy(node)


def _nest(key: str, value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    node = out
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return out


def _merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` merged in, table by table (a new dict)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), dict) else v
    return out


def _label(value: Any) -> str:
    if isinstance(value, list):
        return ":".join(_label(v) for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value).lower() if isinstance(value, bool) else str(value)


@dataclass
class Point:
    """One grid point: its values per grid key, its label and its full simulator config."""

    values: dict[str, Any]
    label: str
    config: dict[str, Any]


def grid_points(
    grid: Mapping[str, Sequence[Any]], base: Mapping[str, Any] | None = None
) -> list[Point]:
    """Every combination of the grid's values (the first key varies slowest), each merged over
    ``base`` (a nested dict of simulator parameters) and checked by
    :func:`ditherlab.sim.params.load_params`; a value it rejects is a ConfigError naming the
    grid key and value."""
    points = []
    keys = list(grid)
    defaults = default_params()
    for combo in itertools.product(*(grid[k] for k in keys)):
        values = dict(zip(keys, combo, strict=True))
        config = dict(copy.deepcopy(base or {}))
        for k, v in values.items():
            target, index = _element(k)
            if index is not None:  # one joint of a per-joint list: the rest from the config
                whole = _get(config, target, defaults)
                n = len(_get({}, target, defaults))
                v = [
                    *(whole if isinstance(whole, list) else [whole] * n)[:index],
                    v,
                    *(whole if isinstance(whole, list) else [whole] * n)[index + 1 :],
                ]
            config = _merge(config, _nest(target, v))
        label = " ".join(f"{k}={_label(v)}" for k, v in values.items())
        try:
            load_params(config)
        except ConfigError as exc:
            msg = str(exc).removeprefix("config: ")
            raise ConfigError(f"sweep: --grid point {label}: {msg}") from None
        check_pose(config, label)
        points.append(Point(values, label, config))
    return points


# ------------------------------------------------------------------ one point
def vibration(rec: Recording, angle: str = "link", settle: float = 0.8) -> np.ndarray:
    """The dither's vibration per joint [rad, arm side], (n,): in windows of one dither period
    (at least 20 samples, as ``tests/test_sim_paper.py``) at rest with the dither on, half the
    peak-to-peak of the joint angle after removing each window's linear trend, averaged over
    the windows.

    ``angle``: ``"link"``, the arm's angle behind the gear spring (the simulator's ground truth,
    columns ``q_link_j``: ``push_campaign.log_link_angle``), the vibration of the arm itself;
    ``"motor"``, the logged angle ``q``, the motor's in arm-side units, which is what the paper
    measured ("about one hundredth of a motor radian, which would correspond to 0.0001 arm
    radians", §III-B) and vibrates more, by the gear spring's deflection. Rest: from the end of
    the dither's ramp to the first push, and between pushes from ``settle`` [s] after one ends
    to the next's start (the simulator's push plan, ``meta["sim"]``). NaN where no window fits.
    """
    sim = rec.meta.get("sim") or {}
    tl = sim.get("timeline") or {}
    pushes = sim.get("pushes") or []
    t = rec.t
    if angle == "motor":
        q = rec.q
    else:
        cols = [f"q_link_{j + 1}" for j in range(rec.n)]
        if not all(c in rec.data.columns for c in cols):
            raise ConfigError(
                f"{rec.name or 'recording'}: no q_link_j columns; expected a simulated push "
                "campaign with push_campaign.log_link_angle = true"
            )
        q = rec.data[cols].to_numpy()
    on = rec.dither if rec.dither is not None else np.zeros(len(t), bool)
    ramp = float(((sim.get("params") or {}).get("dither") or {}).get("ramp_s", 1.0))
    spans = []
    if tl.get("dither_on") is not None and pushes:
        spans.append((tl["dither_on"] + ramp, pushes[0]["t0"]))
    for p, nxt in zip(pushes, pushes[1:], strict=False):
        spans.append((p["t0"] + p["duration"] + settle, nxt["t0"]))
    W = max(20, int(round(dither_period(rec) / rec.dt))) if on.any() else 20
    x = np.arange(W) - (W - 1) / 2
    amps = []
    for a, b in spans:
        k0, k1 = np.searchsorted(t, [a, b])
        for k in range(int(k0), int(k1) - W + 1, W):
            if not on[k : k + W].all():
                continue
            seg = q[k : k + W]
            slope = x @ (seg - seg.mean(axis=0)) / (x @ x)
            amps.append(np.ptp(seg - np.outer(x, slope), axis=0) / 2)
    if not amps:
        return np.full(q.shape[1], np.nan)
    return np.mean(amps, axis=0)


def _f50(d: Mapping[str, Any] | None) -> tuple[float, float, str, float, float]:
    """(F50, F90, bound, F50's 90 % bootstrap interval lo, hi) of one direction's detection
    curve: when every push (none) was seen, F50 = F90 = the smallest (largest) force with bound
    ``below`` (``above``) and no interval."""
    if not d:
        return math.nan, math.nan, "", math.nan, math.nan
    c = d["curve"]
    if c.get("bound"):
        f = float(c["bound_force"])
        return f, f, str(c["bound"]), math.nan, math.nan
    lo, hi = (float(v) for v in c.get("F50_ci", [math.nan, math.nan]))
    return float(c["F50"]), float(c["F90"]), "", lo, hi


def run_point(config: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """One grid point on a worker: simulate, identify, replay and analyse (module docstring).

    Parameters
    ----------
    config : the point's simulator parameters (nested dict over ``irb140.toml``)
    options : ``seed``, ``curve_boot`` (bootstrap replicates of the detection curves),
        ``vibration_limit`` [rad], ``exclude_dither_ramp`` (default True)

    Returns
    -------
    The row's values for :data:`COLUMNS` (without ``point``, ``ok``, ``error``).
    """
    t0 = time.perf_counter()
    seed = int(options["seed"])
    recs = {}
    for role, s in (("identification", seed + 1), ("evaluation", seed)):
        for d in (False, True):
            recs[role, d] = simulate(
                "push-campaign", seed=s, dither=d, config=config, log_link_angle=True
            )
    model = identify([recs["identification", False], recs["identification", True]], n_boot=0)
    ev_dither = recs["evaluation", True]
    if options.get("exclude_dither_ramp", True):
        ev_dither = without_ramp_down(ev_dither)
    ests = [
        replay(recs["evaluation", False], model, variants=["nodither_band"], components="fxyz"),
        replay(ev_dither, model, variants=["dither_band"], components="fxyz"),
    ]
    ests[0].name, ests[1].name = "evaluation without dither", "evaluation with dither"
    with warnings.catch_warnings():  # a condition without rest samples: its width is NaN
        warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)
        a = analyse(ests, n_boot=int(options["curve_boot"]), seed=seed)
    dith = a["conditions"].get("dither_band") or {}
    plain = a["conditions"].get("nodither_band") or {}
    row: dict[str, Any] = {}
    for ax in FORCE_AXES:
        f50, f90, bound, lo, hi = _f50((dith.get("directions") or {}).get(ax))
        row[f"f50_{ax}"], row[f"f90_{ax}"], row[f"f50_{ax}_bound"] = f50, f90, bound
        row[f"f50_{ax}_lo"], row[f"f50_{ax}_hi"] = lo, hi
        row[f"nodither_f50_{ax}"] = _f50((plain.get("directions") or {}).get(ax))[0]
    row["f50_mean"] = float(np.mean([row[f"f50_{ax}"] for ax in FORCE_AXES]))
    ev = recs["evaluation", True]
    mask = np.asarray(load_params(config)["dither"]["joints"][: ev.n], dtype=bool)
    for col, angle in (("vibration", "link"), ("vibration_motor", "motor")):
        vib = vibration(ev, angle)
        v = np.where(mask & np.isfinite(vib), vib, -np.inf)
        j = int(np.argmax(v))
        row[col] = float(vib[j]) if np.isfinite(v[j]) else math.nan
        row[f"{col}_joint"] = j + 1
    row["within_limit"] = bool(row["vibration"] <= float(options["vibration_limit"]))

    def push_coverage(cond: Mapping[str, Any]) -> float:
        covs = [d["coverage"] for d in (cond.get("directions") or {}).values()]
        return float(np.mean(covs)) if covs else math.nan

    row["coverage_push"] = push_coverage(dith)
    row["coverage_rest"] = float(dith.get("coverage_rest", math.nan))
    row["nodither_coverage_push"] = push_coverage(plain)
    amps = ev.meta["sim"]["dither_amplitudes"]
    reached = [m / s for m, s in zip(amps["measured_mean"], amps["set_point"], strict=True) if s]
    row["amplitude_reached"] = float(min(reached)) if reached else math.nan
    row["pushes"] = len(ev.meta["sim"]["pushes"])
    for prefix, cond in (("", dith), ("nodither_", plain)):
        row.update({f"{prefix}f50_{d}": v for d, v in direction_f50(cond).items()})
    for prefix, cond in (("", dith), ("nodither_", plain)):
        nl = cond.get("noise_level") or {}
        row.update({f"{prefix}noise_{a}": _num(nl.get(a)) for a in FORCE_AXES})
    row.update(predicted(ev, model, config, seed, analysis=a))
    row["seconds"] = time.perf_counter() - t0
    return row


# ------------------------------------------------------------------ the sweep
def _read_config(path: str | Path | None) -> dict[str, Any]:
    """The user's simulator TOML as a nested dict, checked (errors name the file and key)."""
    if path is None:
        return {}
    load_params(path)
    return tomllib.loads(Path(path).read_text(encoding="utf-8"))


def best_points(table: pd.DataFrame, grid: Sequence[str]) -> dict[str, Any]:
    """The best design under the vibration limit (smallest mean dithered F50 over x, y, z; a
    direction whose pushes were all seen counts its smallest force), overall and per waveform
    when the waveform is swept; ``None`` where no point qualifies."""
    ok = table[table["ok"] & table["within_limit"] & np.isfinite(table["f50_mean"])]

    def pick(rows: pd.DataFrame) -> dict[str, Any] | None:
        if rows.empty:
            return None
        r = rows.loc[rows["f50_mean"].idxmin()]
        return {
            "point": r["point"],
            **{k: _plain(r[k]) for k in grid},
            "f50_mean": float(r["f50_mean"]),
            **{f"f50_{a}": float(r[f"f50_{a}"]) for a in FORCE_AXES},
            "vibration": float(r["vibration"]),
            "coverage_push": float(r["coverage_push"]),
        }

    out: dict[str, Any] = {"best": pick(ok)}
    if "dither.waveform" in grid:
        out["best_per_waveform"] = {
            w: pick(ok[ok["dither.waveform"] == w]) for w in table["dither.waveform"].unique()
        }
    return out


def _plain(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    return v


def _num(v: Any) -> float:
    """A number of the analysis as float [its unit], NaN for None."""
    return math.nan if v is None else float(v)


def _cell(v: float, bound: str = "") -> str:
    if not np.isfinite(v):
        return "–"
    return f"{'<' if bound == 'below' else '>' if bound == 'above' else ''}{v:.1f}"


def format_table(table: pd.DataFrame, grid: Sequence[str], limit: float = VIBRATION_LIMIT) -> str:
    """The sweep's table as Markdown: the grid's values, F50 per direction (``<`` every push
    seen, ``>`` none) and the predicted (:mod:`ditherlab.analysis.sensitivity`: from the model
    alone; given the point's measured noise level), the noise level measured at rest and the
    predicted, F50 without dither and the two predictions, F90, vibration, coverage, per
    point."""
    head = [
        *grid,
        "F50 x / y / z [N] (predicted: model; model + measured noise level)",
        "mean",
        "noise level x / y / z [N] (predicted)",
        "no dither F50 x / y / z (predicted: model; model + measured noise level)",
        "F90 x / y / z",
        "vibration arm / motor [1e-4 rad]",
        "coverage push / rest",
        "status",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in table.iterrows():
        vals = [_label(_plain(r[k])) for k in grid]
        if not r["ok"]:
            vals += ["–"] * (len(head) - len(grid) - 1) + [f"failed: {r['error']}"]
            lines.append("| " + " | ".join(vals) + " |")
            continue
        f50 = " / ".join(_cell(r[f"f50_{a}"], r[f"f50_{a}_bound"]) for a in FORCE_AXES)
        nd = " / ".join(_cell(r[f"nodither_f50_{a}"]) for a in FORCE_AXES)
        f90 = " / ".join(_cell(r[f"f90_{a}"], r[f"f50_{a}_bound"]) for a in FORCE_AXES)
        vib = (
            f"{r['vibration'] / 1e-4:.2f} (j{int(r['vibration_joint'])}) / "
            f"{r['vibration_motor'] / 1e-4:.2f} (j{int(r['vibration_motor_joint'])})"
        )
        cov = f"{r['coverage_push']:.0%} / {r['coverage_rest']:.0%}"
        status = "ok" if r["within_limit"] else f"vibrates > {limit:g} rad"
        mean = _cell(r["f50_mean"])
        if np.isfinite(r["f50_mean_sem"]):
            mean += f" ± {r['f50_mean_sem']:.1f}"
        for c in ("", "nodither_"):
            pred = " / ".join(_cell(r[f"pred_{c}f50_{a}"]) for a in FORCE_AXES)
            pred += "; " + " / ".join(_cell(r[f"predm_{c}f50_{a}"]) for a in FORCE_AXES)
            if c:
                nd += f" ({pred})"
            else:
                f50 += f" ({pred})"
        noise = " / ".join(_cell(r[f"noise_{a}"]) for a in FORCE_AXES)
        noise += " (" + " / ".join(_cell(r[f"pred_noise_{a}"]) for a in FORCE_AXES) + ")"
        vals += [f50, mean, noise, nd, f90, vib, cov, status]
        lines.append("| " + " | ".join(vals) + " |")
    return "\n".join(lines)


def summary_text(s: Mapping[str, Any]) -> str:
    """The printed result: the table, the best design under the limit (and per waveform)."""
    lines = [s["table_text"], ""]
    lim = s["vibration_limit"]
    b = s["best"]
    lines.append(
        f"best under the vibration limit ({lim:g} rad): "
        + (
            f"{b['point']}: F50 {b['f50_mean']:.1f} N (x/y/z mean), vibration "
            f"{b['vibration']:.2g} rad"
            if b
            else "no point within the limit"
        )
    )
    for w, p in (s.get("best_per_waveform") or {}).items():
        lines.append(
            f"  best {w}: "
            + (f"{p['point']}: F50 {p['f50_mean']:.1f} N" if p else "none within the limit")
        )
    n_fail = len(s["failures"])
    runs = f" × {len(s['seeds'])} seeds" if len(s["seeds"]) > 1 else ""
    lines.append(f"{s['points']} points{runs}, {n_fail} failed; {s['seconds']:.0f} s")
    for f in s["failures"]:
        lines.append(f"  failed: {f['point']}: {f['error']}")
    return "\n".join(lines)


def aggregate(runs: pd.DataFrame, grid: Sequence[str], limit: float) -> pd.DataFrame:
    """One row per point (:data:`COLUMNS`) from the runs' rows (:data:`RUN_COLUMNS`): means
    over the runs that did not fail, the vibration limit applied to the mean vibration."""
    rows = []
    for label, g in runs.groupby("point", sort=False):
        good = g[g["ok"]]
        n = len(good)
        row: dict[str, Any] = {k: g.iloc[0][k] for k in grid}
        errors = [(s, e) for s, e in zip(g["seed"], g["error"], strict=True) if e]
        row.update(
            point=label,
            runs=n,
            ok=n > 0,
            error="; ".join(e if len(g) == 1 else f"seed {s}: {e}" for s, e in errors),
        )
        for c in METRICS:
            if c.endswith("_bound"):
                b = set(good[c])
                row[c] = b.pop() if len(b) == 1 else ""
            elif c.endswith("_joint"):
                row[c] = int(good[c].mode().iloc[0]) if n else math.nan
            elif c == "seconds":
                row[c] = float(g[c].sum())
            elif c != "within_limit":
                row[c] = float(good[c].mean()) if n else math.nan
        row["within_limit"] = bool(row["vibration"] <= limit)
        row["f50_mean_sem"] = (
            float(good["f50_mean"].std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
        )
        rows.append(row)
    return pd.DataFrame(rows, columns=[*grid, *COLUMNS])


@dataclass(frozen=True)
class SweepOptions:
    """The options of ``ditherlab sweep``.

    Attributes
    ----------
    grid : ``KEY=V1,V2,...`` (:func:`parse_grid`): a key of the simulator's parameters
        (``irb140.toml``) and its values, one per entry
    out : the output folder (``sweep.parquet``, ``sweep_runs.parquet``, ``sweep.md``,
        ``sweep.json``, PNG figures)
    config : a simulator TOML every point starts from (the grid's values override it)
    pushes_per_direction : pushes per axis and sign in each of the four campaigns (None: the
        config's); a grid key ``push_campaign.pushes_per_direction`` overrides it
    seed : the evaluation campaigns' seed (identification: ``seed + 1``), the same at every point
    repeats : runs per point, on seeds ``seed, seed + 2, ...``; the point's row is their mean
    curve_boot : bootstrap replicates of each detection curve
    vibration_limit : [rad, arm side] the acceptable arm vibration (the paper's 1e-4)
    exclude_dither_ramp : evaluate the dithered campaign without its final ramp-down
        (:func:`without_ramp_down`)
    scheduler : None (a LocalCluster here), ``"serial"`` or ``tcp://HOST:PORT``
    workers : the LocalCluster's workers
    force : write into an existing non-empty folder
    """

    grid: tuple[str, ...] = ()
    out: str | Path = "sweep-out"
    config: Path | None = None
    pushes_per_direction: int | None = 6
    seed: int = 0
    repeats: int = 1
    curve_boot: int = 50
    vibration_limit: float = VIBRATION_LIMIT
    exclude_dither_ramp: bool = True
    scheduler: str | None = None
    workers: int | None = None
    force: bool = False


@dataclass
class Swept:
    """The sweep's summary (``sweep.json``'s content, with ``table``: the Parquet path, and
    ``table_text``: the Markdown table) and the output folder."""

    summary: dict[str, Any]
    out: Path

    def text(self) -> str:
        """:func:`summary_text` and the files written (what the CLI prints)."""
        s = self.summary
        wrote = f"wrote {s['table']}, {self.out / 'sweep.md'}, {self.out / 'sweep.json'}, figures"
        return f"{summary_text(s)}\n{wrote}"

    def to_dict(self) -> dict[str, Any]:
        """The summary."""
        return self.summary


def run(
    options: SweepOptions,
    *,
    progress: bool = False,
    on_result: Callable[[TaskResult], None] | None = None,
) -> Swept:
    """Run a grid of simulated paired campaigns as Dask tasks and write the results.

    Parameters
    ----------
    options : :class:`SweepOptions`
    progress : Dask's progress bar on stderr
    on_result : called as each run finishes (:func:`ditherlab.core.tasks.run_tasks`)

    Returns
    -------
    Swept
    """
    o = options
    grid = parse_grid(o.grid)
    if int(o.seed) < 0:
        raise ConfigError(f"sweep: --seed {o.seed} is negative; expected an integer >= 0")
    if int(o.repeats) < 1:
        raise ConfigError(f"sweep: --repeats {o.repeats}; expected an integer >= 1")
    ppd = o.pushes_per_direction
    if ppd is not None and ppd < 1:
        raise ConfigError(f"sweep: --pushes-per-direction {ppd}; expected an integer >= 1")
    base = _read_config(o.config)
    if ppd is not None:
        base = _merge(base, {"push_campaign": {"pushes_per_direction": int(ppd)}})
    points = grid_points(grid, base)
    out = guard(o.out, [o.config], folder=True, force=o.force)
    seeds = [int(o.seed) + 2 * r for r in range(int(o.repeats))]
    t0 = time.perf_counter()
    run_table = _run_points(o, grid, points, seeds, progress, on_result)
    table = aggregate(run_table, list(grid), o.vibration_limit)
    out.mkdir(parents=True, exist_ok=True)
    for name, t in (("sweep.parquet", table), ("sweep_runs.parquet", run_table)):
        with atomic_path(out / name) as tmp:
            t.to_parquet(tmp, index=False)
    text = format_table(table, list(grid), o.vibration_limit)
    atomic_write_text(out / "sweep.md", text + "\n")
    figures = [
        plot_tradeoff(table, list(grid), o.vibration_limit, out / "f50_vs_vibration.png"),
        plot_points(table, o.vibration_limit, out / "f50_per_point.png"),
        plot_prediction(table, out / "f50_predicted.png"),
    ]
    summary = {
        "grid": {k: [_label(v) for v in vs] for k, vs in grid.items()},
        "points": len(points),
        "seeds": seeds,
        "pushes_per_direction": ppd,
        "vibration_limit": o.vibration_limit,
        **best_points(table, list(grid)),
        "failures": [
            {"point": r["point"], "error": r["error"]} for _, r in table.iterrows() if not r["ok"]
        ],
        "seconds": time.perf_counter() - t0,
        "figures": [str(f) for f in figures],
        "table": str(out / "sweep.parquet"),
    }
    atomic_write_json(out / "sweep.json", summary)
    return Swept({**summary, "table_text": text}, out)


def _run_points(
    o: SweepOptions,
    grid: dict[str, list[Any]],
    points: list[Point],
    seeds: list[int],
    progress: bool,
    on_result: Callable[[TaskResult], None] | None,
) -> pd.DataFrame:
    """Every point on every seed as one Dask task (:func:`run_point`): one row per run
    (:data:`RUN_COLUMNS` after the grid's own columns), a failed run with its error."""
    options = {
        "curve_boot": int(o.curve_boot),
        "vibration_limit": o.vibration_limit,
        "exclude_dither_ramp": bool(o.exclude_dither_ramp),
    }
    runs = [(p, s) for p in points for s in seeds]
    results = run_tasks(
        run_point,
        [
            (p.label + (f" seed={s}" if len(seeds) > 1 else ""), (p.config, {**options, "seed": s}))
            for p, s in runs
        ],
        scheduler=o.scheduler,
        workers=o.workers,
        progress=progress,
        on_result=on_result,
    )
    rows = []
    for (p, s), r in zip(runs, results, strict=True):
        row: dict[str, Any] = {
            k: _label(v) if isinstance(v, list) else v for k, v in p.values.items()
        }
        row.update({"point": p.label, "seed": s, "ok": r.ok, "error": r.error or ""})
        values = r.value if r.ok else {}
        for c in METRICS:
            row[c] = values.get(c, "" if c.endswith("_bound") else math.nan)
        row["within_limit"] = bool(values.get("within_limit", False))
        rows.append(row)
    return pd.DataFrame(rows, columns=[*grid, *RUN_COLUMNS])

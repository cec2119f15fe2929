"""One recording of a fleet: identify, diagnose and (with pushes) the detection thresholds.

:func:`analyse_recording` runs on a Dask worker and returns plain data: the table rows (one per
regime and joint) and a per-recording summary. It reads nothing but the recording (and an
optional base model's text) and writes nothing: the client writes every output, so workers on
other machines need only the input files.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.detection import AXES, NoPushesError, analyse
from ditherlab.analysis.diagnosis import Diagnosis, diagnose
from ditherlab.analysis.estimation import available_variants, replay
from ditherlab.analysis.identification import identify
from ditherlab.core.errors import DitherlabError, one_line
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.io import read

__all__ = ["COLUMNS", "analyse_recording", "robot_identity"]

#: the fleet table's columns, in order (units in the names' suffixes: N·m, N, s)
COLUMNS = [
    "robot",
    "file",
    "date",
    "notes",
    "regime",
    "joint",
    "tau_min",
    "tau_max",
    "sigma",
    "coulomb",
    "viscous",
    "torque_rms",
    "noise_floor",
    "effect",
    "effect_on_joint",
    "effects",
    "joint_effects",
    "verdict",
    "force_rms_x",
    "force_rms_y",
    "force_rms_z",
    "f50_x",
    "f50_y",
    "f50_z",
    "f90_x",
    "f90_y",
    "f90_z",
    "samples",
    "duration_s",
]


def _thresholds(rec: Any, model: TorqueModel, n_boot: int, seed: int) -> dict[str, float]:
    """F50 / F90 [N] per force axis of the paper's estimator on this recording's pushes (the
    model's own band variant: ``dither_band`` on a dithered log, else ``nodither_band``);
    empty when the log has no sensor or no pushes."""
    if not rec.has_wrench:
        return {}
    variant = "dither_band" if "dither_band" in available_variants(rec) else "nodither_band"
    try:
        est = replay(rec, model, variants=[variant], components="fxyz")
        a = analyse([est], n_boot=n_boot, seed=seed)
    except NoPushesError:
        return {}
    out: dict[str, float] = {}
    for cond in a["conditions"].values():
        for axis, d in cond["directions"].items():
            if axis in AXES:
                out[f"f50_{axis}"] = float(d["curve"]["F50"])
                out[f"f90_{axis}"] = float(d["curve"]["F90"])
    return out


def analyse_recording(path: str, info: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """Identify a model on one recording, diagnose it, and tabulate the result.

    Parameters
    ----------
    path : the recording (any format :func:`ditherlab.io.read` knows)
    info : ``robot`` (id), ``date`` (ISO text or None), ``notes`` from the manifest, and the
        recording's own settings: ``read`` (reader options over the fleet's) and
        ``assume_no_force`` (None: the fleet's)
    options : ``read`` (read options), ``base`` (a model's TOML text or None),
        ``assume_no_force``, ``n_boot``, ``seed``, ``thresholds`` (bool), ``thresholds_boot``

    Returns
    -------
    ``{"rows": [dict per regime and joint, keys :data:`COLUMNS`], "model": TOML text,
    "suggested": [{"effect", "joints", "explained_fraction"}], "verdict": text or None,
    "robot_from": "manifest", "metadata" or "file name" (where the robot's identity came from),
    "skipped": [{"step", "error"}] (optional steps that failed: the rows hold NaN for them)}``
    """
    rec = read(path, **{**options.get("read", {}), **(info.get("read") or {})})
    own = info.get("assume_no_force")
    model = _identify(rec, {**options, **({} if own is None else {"assume_no_force": own})})
    d = diagnose([rec], model)
    suggested = [
        {"effect": c.effect, "joints": list(c.joints), "explained_fraction": c.explained_fraction}
        for c in d.suggested
    ]
    thr: dict[str, float] = {}
    skipped: list[dict[str, str]] = []
    if options.get("thresholds", True):
        try:
            boot = int(options.get("thresholds_boot", 50))
            thr = _thresholds(rec, model, boot, int(options.get("seed", 0)))
        except DitherlabError as exc:  # an optional step: the recording's rows stand without it
            skipped.append({"step": "thresholds", "error": one_line(exc)})
    robot, robot_from = robot_identity(path, info, rec.meta)
    common = _common_columns(path, {**info, "robot": robot}, rec, d, suggested, thr)
    rows = [
        {**common, **_joint_columns(model, d, suggested, regime, band, j)}
        for regime, band in model.regimes.items()
        for j in range(model.n)
    ]
    return {
        "rows": [{k: r[k] for k in COLUMNS} for r in rows],
        "model": model.dumps(),
        "suggested": suggested,
        "verdict": d.verdict["text"] if d.verdict else None,
        "robot_from": robot_from,
        "skipped": skipped,
    }


def robot_identity(path: str, info: dict[str, Any], meta: dict[str, Any]) -> tuple[str, str]:
    """Which robot a recording is of, and where that came from: the manifest's ``robot``, else
    the recording's metadata ``robot_id`` (a serial number, a cell name), else the file's stem
    (each such file its own robot)."""
    if info.get("robot"):
        return str(info["robot"]), "manifest"
    if meta.get("robot_id"):
        return str(meta["robot_id"]), "metadata"
    return Path(path).stem, "file name"


def _identify(rec: Any, options: dict[str, Any]) -> TorqueModel:
    """The model of one recording, from the fleet's base model (``options["base"]``, TOML
    text) when there is one."""
    base = (
        TorqueModel.from_dict(tomllib.loads(options["base"]), source=options.get("base_name"))
        if options.get("base")
        else None
    )
    return identify(
        [rec],
        base=base,
        assume_no_force=bool(options.get("assume_no_force")),
        n_boot=int(options.get("n_boot", 0)),
        seed=int(options.get("seed", 0)),
    )


def _common_columns(
    path: str,
    info: dict[str, Any],
    rec: Any,
    d: Diagnosis,
    suggested: list[dict[str, Any]],
    thr: dict[str, float],
) -> dict[str, Any]:
    """The columns every row of one recording shares: the robot and file, the diagnosis's
    suggestions and verdict, the force error RMS [N], the thresholds ``thr`` [N], the length."""
    force = d.force["rms"] if d.force is not None else [np.nan] * 6
    t = rec.t
    return {
        "robot": str(info["robot"]),
        "file": str(path),
        "date": info.get("date"),
        "notes": info.get("notes") or "",
        "effect": suggested[0]["effect"] if suggested else "",
        "effects": ",".join(s["effect"] for s in suggested),
        "verdict": (d.verdict["text"] if d.verdict else None) or "",
        "force_rms_x": float(force[0]),
        "force_rms_y": float(force[1]),
        "force_rms_z": float(force[2]),
        **{k: thr.get(k, np.nan) for k in COLUMNS if k.startswith(("f50_", "f90_"))},
        "samples": int(len(t)),
        "duration_s": float(t[-1] - t[0]) if len(t) > 1 else 0.0,
    }


def _joint_columns(
    model: TorqueModel,
    d: Diagnosis,
    suggested: list[dict[str, Any]],
    regime: str,
    band: Band,
    j: int,
) -> dict[str, Any]:
    """The columns of one regime and 0-based joint ``j``: the band [N·m], the residual against
    the noise floor [N·m], the suggested effects on the joint."""
    return {
        "regime": regime,
        "joint": j + 1,
        "tau_min": float(band.tau_min[j]),
        "tau_max": float(band.tau_max[j]),
        "sigma": float(band.sigma[j]),
        "coulomb": float(band.coulomb[j]) if band.coulomb is not None else np.nan,
        "viscous": float(band.viscous[j]) if band.viscous is not None else np.nan,
        "torque_rms": float(d.residual["torque_rms"][j]),
        "noise_floor": float(d.residual["noise_floor"][j]),
        "effect_on_joint": bool(suggested) and (j + 1) in suggested[0]["joints"],
        "joint_effects": ",".join(s["effect"] for s in suggested if (j + 1) in s["joints"]),
    }

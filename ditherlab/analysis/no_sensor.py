"""The report of estimates without a force sensor: what the estimator saw, on its own terms.

Without F/T columns there are no pushes of known size to score (the paper's §VI-C statistics,
:mod:`ditherlab.analysis.detection`). What a log without a sensor still shows, per estimator
variant (named for people by :func:`variant_label`):

- **events**: the stretches where the estimate's interval excludes zero on some force axis (the
  estimator states, at the interval's level, that a force acts), merged across gaps shorter than
  :data:`MERGE_GAP` s and kept when they last :data:`MIN_EVENT` s or more; each with its start,
  end and the largest force magnitude ``|F̂|`` [N] in it;
- **the noise level at rest**: the 99.9 % quantile of ``|F̂_axis|`` [N] per axis over the samples
  outside the events and away from motion (the file's ``moving_spans`` and 0.5 s around them);
- **predicted thresholds** at the recording's rest pose (:func:`predict_thresholds`), from the
  model's bands, the robot's Jacobian and the measured noise level: no value of another robot
  is used (the uniform friction states of the estimator's own model, ``states="independent"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ditherlab.analysis.sensitivity import condition_bands, predict
from ditherlab.data.estimates import EstimatesSource
from ditherlab.data.torque_model import TorqueModel
from ditherlab.robot.model import RobotModel

__all__ = [
    "MERGE_GAP",
    "MIN_EVENT",
    "no_sensor_analysis",
    "predict_thresholds",
    "variant_label",
]

#: events closer than this [s] are one event
MERGE_GAP = 0.5
#: events shorter than this [s] are not listed
MIN_EVENT = 0.1
#: the noise level's quantile of |F̂_axis| at rest
QUANTILE = 0.999
AXES = ("x", "y", "z")

_LABELS = {
    "nodither_band": "without dither",
    "nodither_noband": "without dither, noise term only (no friction band)",
    "dither_band": "with dither",
    "dither_noband": "with dither, noise term only (no friction band)",
}


def variant_label(variant: str, dithered: bool = False) -> str:
    """A variant's name for people: ``nodither_band`` -> ``without dither``; a no-dither
    variant on a dithered log says that the dither was on."""
    label = _LABELS.get(variant, variant)
    if variant.startswith("nodither") and dithered:
        label += " (estimator ignores the dither that was on)"
    return label


def no_sensor_analysis(
    ests: Sequence[EstimatesSource],
    *,
    robots: Sequence[tuple[RobotModel, np.ndarray] | None] = (),
) -> dict[str, Any]:
    """Events, noise level at rest and predicted thresholds of estimates without F/T columns.

    Parameters
    ----------
    ests : estimates files (their ``t``, ``V/f_*``, ``V/f_*_lo``, ``V/f_*_hi`` columns read
        whole: 8 bytes per sample and column)
    robots : per file, its robot and rest pose (n,) [rad] (from the recording behind it), or
        None: no thresholds predicted for that file

    Returns
    -------
    dict (JSON-ready): ``definitions``, ``files`` (per file: ``file``, ``duration`` [s],
    ``variants`` per variant: ``label``, ``events``, ``noise_level`` per axis [N],
    ``largest`` [N], and ``thresholds`` when predicted).
    """
    files = []
    for k, src in enumerate(ests):
        rp = robots[k] if k < len(robots) else None
        files.append(_file_analysis(src, rp))
    return {
        "definitions": {
            "event": "a stretch where the estimate's interval excludes zero on some force axis "
            f"(merged across gaps < {MERGE_GAP:g} s, at least {MIN_EVENT:g} s long); size: the "
            "largest |F_hat| in it",
            "noise_level": f"{QUANTILE:.1%} quantile of |F_hat| along the axis at rest (outside "
            "the events, 0.5 s or more from motion)",
            "thresholds": "F50 / F90 predicted at the rest pose from the model's bands, the "
            "robot's Jacobian and the measured noise level, friction states uniform in the band "
            "(ditherlab robot --sensitivity --states independent)",
        },
        "files": files,
    }


def _file_analysis(
    src: EstimatesSource, robot_pose: tuple[RobotModel, np.ndarray] | None
) -> dict[str, Any]:
    """One estimates file's events, noise levels and thresholds per variant."""
    t = src.column("t").astype(float)
    dithered = "dither" in src.columns and bool(src.column("dither").astype(bool).any())
    moving = np.zeros(len(t), bool)
    for a, b in src.meta.get("moving_spans", []):
        moving |= (t >= a - 0.5) & (t <= b + 0.5)
    out: dict[str, Any] = {
        "file": src.name or "<memory>",
        "duration": float(t[-1] - t[0]) if len(t) else 0.0,
        "dithered": dithered,
        "variants": {},
    }
    model = _model_of(src)
    for v in src.variants:
        F = np.stack([src.column(f"{v}/f_{a}").astype(float) for a in AXES], axis=1)
        lo = np.stack([src.column(f"{v}/f_{a}_lo").astype(float) for a in AXES], axis=1)
        hi = np.stack([src.column(f"{v}/f_{a}_hi").astype(float) for a in AXES], axis=1)
        events, inside = _events(t, F, (lo > 0) | (hi < 0))
        rest = ~inside & ~moving
        nl = {
            a: float(np.quantile(np.abs(F[rest, i]), QUANTILE)) if rest.any() else None
            for i, a in enumerate(AXES)
        }
        row: dict[str, Any] = {
            "label": variant_label(v, dithered),
            "events": events,
            "noise_level": nl,
            "largest": float(np.linalg.norm(F, axis=1).max()) if len(F) else 0.0,
            "rest_seconds": float(rest.sum() * np.median(np.diff(t))) if len(t) > 1 else 0.0,
        }
        if robot_pose is not None and model is not None and v == "nodither_band":
            row["thresholds"] = predict_thresholds(*robot_pose, model, nl)
        out["variants"][v] = row
    return out


def _model_of(src: EstimatesSource) -> TorqueModel | None:
    """The model the estimates were made with (the file's metadata), or None."""
    d = src.meta.get("model")
    if not isinstance(d, dict):
        return None
    try:
        return TorqueModel.from_dict(d, source=f"{src.name} (its model)")
    except Exception:  # noqa: BLE001 - an older file's model: no thresholds, said in the report
        return None


def _events(
    t: np.ndarray, F: np.ndarray, det: np.ndarray
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """The events of one variant (see the module docstring) and the (N,) mask of their rows;
    ``F`` (N, 3) [N], ``det`` (N, 3) bool: the interval excludes zero."""
    hit = det.any(axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, hit.astype(np.int8), 0]))
    runs: list[list[int]] = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if runs and t[a] - t[runs[-1][1] - 1] < MERGE_GAP:
            runs[-1][1] = int(b)
        else:
            runs.append([int(a), int(b)])
    mask = np.zeros(len(t), bool)
    out = []
    for a, b in runs:
        if t[b - 1] - t[a] < MIN_EVENT:
            continue
        mask[a:b] = True
        mag = np.linalg.norm(F[a:b], axis=1)
        k = int(np.argmax(mag))
        out.append(
            {
                "start": float(t[a]),
                "end": float(t[b - 1]),
                "peak": float(mag[k]),
                "at": float(t[a + k]),
                "peak_axes": {ax: float(F[a + k, i]) for i, ax in enumerate(AXES)},
            }
        )
    return out, mask


def predict_thresholds(
    robot: RobotModel, q: np.ndarray, model: TorqueModel, noise: dict[str, float | None]
) -> dict[str, Any]:
    """F50 / F90 per push direction [N] predicted at the pose ``q`` (n,) [rad] of ``robot``
    without dither: the model's ``still`` bands, the Jacobian, and the measured noise level per
    axis ``noise`` [N] (None: predicted from the bands); friction states uniform in the band
    (the estimator's own model; nothing is taken from the simulator's robot)."""
    bands = condition_bands(robot.n, model, dither=False, robot_name=robot.name)
    nl = None if any(noise[a] is None for a in AXES) else [max(float(noise[a]), 1e-6) for a in AXES]
    pred = predict(
        robot,
        q,
        bands,
        states="independent",
        noise_level=nl,
        noise_source="measured at rest",
        forces=80,
        draws=120,
        rest_samples=5000,
    )
    return {
        "q": pred["q"],
        "noise_level": pred["noise_level"],
        "directions": {
            k: {"f50": d["f50"], "f90": d["f90"], "joints": d["joints"]}
            for k, d in pred["directions"].items()
        },
    }

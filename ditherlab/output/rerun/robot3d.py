"""The robot in 3D: link transforms, the skeleton through the link origins, the links' meshes
where the robot's description has them on this machine, and force arrows and interval boxes at
the tool point (``robot/...``), at the 3D rate."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from ditherlab.core.names import FORCE_AXES
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording
from ditherlab.output.rerun.columns import SENSOR_COLOR, VARIANT_COLORS, ColumnLogger
from ditherlab.robot.visuals import MESH_TYPES, MeshVisual, mesh_visuals


def log_robot(
    log: ColumnLogger,
    rec: Recording,
    idx: np.ndarray,
    estimates: Estimates | None,
    est_idx: np.ndarray,
    caps: dict[str, float],
    force_scale: float,
) -> None:
    """The robot, the force arrows and the interval boxes at the samples ``idx`` (M,) of ``rec``
    (the 3D rate's samples among the rows a piece owns); the estimates' rows ``est_idx`` (M,) are
    the same samples. ``caps`` [N] per variant: where an unbounded interval side is drawn
    (:func:`interval_cap`, of the whole recording)."""
    log.static("robot", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
    robot = rec.robot()
    t3 = rec.t[idx]
    q3 = rec.q[idx]
    poses = robot.link_poses(q3)
    for name, T in poses.items():
        path = f"robot/links/{rr.escape_entity_path_part(name)}"
        log.static(path, rr.TransformAxes3D(0.06))
        log.send(
            path,
            t3,
            rr.Transform3D.columns(translation=T[:, :3, 3], quaternion=_quat_xyzw(T[:, :3, :3])),
        )
    _log_meshes(log, rec)
    # Skeleton through the link origins in kinematic order; coincident origins (wrist) collapse.
    origins = np.stack([T[:, :3, 3] for T in poses.values()], axis=1)  # (M, L, 3) [m]
    log.static("robot/skeleton", rr.LineStrips3D([], radii=0.02, colors=[160, 160, 170]))
    log.send(
        "robot/skeleton",
        t3,
        rr.LineStrips3D.columns(strips=list(origins)).partition(np.ones(len(t3), dtype=np.int32)),
    )
    tool = robot.tool_pose(q3)[:, :3, 3]  # (M, 3) [m]
    if rec.has_wrench:
        f = rec.wrench[idx, :3]
        _arrows(log, "robot/force/sensor", t3, tool, f * force_scale, SENSOR_COLOR, "sensor F")
    if estimates is not None:
        d = estimates.data
        for v in estimates.variants:
            fe = d[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)[est_idx]
            _arrows(log, f"robot/force/{v}", t3, tool, fe * force_scale, VARIANT_COLORS[v], v)
            if v in caps:
                lo_c, hi_c = _interval_columns(v)
                lo = d[lo_c].to_numpy(dtype=float)[est_idx]
                hi = d[hi_c].to_numpy(dtype=float)[est_idx]
                cap = caps[v]
                lo, hi = np.clip(lo, -cap, cap), np.clip(hi, -cap, cap)
                log.static(
                    f"robot/force/{v}/interval",
                    rr.Boxes3D(half_sizes=[[0, 0, 0]], colors=[VARIANT_COLORS[v]], radii=0.002),
                )
                log.send(
                    f"robot/force/{v}/interval",
                    t3,
                    rr.Boxes3D.columns(
                        centers=tool + force_scale * (lo + hi) / 2,
                        half_sizes=force_scale * (hi - lo) / 2,
                    ),
                )


@lru_cache(maxsize=8)
def _visuals(urdf: str, path: str | None) -> tuple[MeshVisual, ...]:
    """The meshes of a URDF (described at ``path``, or None) found here, parsed once."""
    return tuple(mesh_visuals(urdf, Path(path).parent if path else None))


def _log_meshes(log: ColumnLogger, rec: Recording) -> None:
    """Each link's meshes (:func:`ditherlab.robot.visuals.mesh_visuals`), static, under the
    link's entity: they move with its transform. Links without one keep their axes alone."""
    spec = rec.meta.get("robot")
    path = spec.get("path") if isinstance(spec, dict) else None
    counts: dict[str, int] = {}
    for v in _visuals(rec.robot().urdf, path):
        k = counts[v.link] = counts.get(v.link, -1) + 1
        entity = f"robot/links/{rr.escape_entity_path_part(v.link)}/mesh_{k}"
        rot = Rotation.from_euler("xyz", v.rpy).as_quat()  # URDF rpy: fixed axes x, y, z
        asset = rr.Asset3D(
            path=v.path,
            media_type=MESH_TYPES[v.path.suffix.lower()],
            albedo_factor=None if v.rgba is None else [float(c) for c in v.rgba],
        )
        log.static(entity, rr.Transform3D(translation=v.xyz, quaternion=rot, scale=v.scale))
        log.static(f"{entity}/asset", asset)


def _interval_columns(v: str) -> tuple[list[str], list[str]]:
    return [f"{v}/f_{a}_lo" for a in FORCE_AXES], [f"{v}/f_{a}_hi" for a in FORCE_AXES]


def interval_cap(lo: np.ndarray) -> float:
    """The largest finite ``|lo|`` [N] of interval lower bounds (M, 3) at the 3D rate (0 where
    none is finite): an unbounded side (a free component) is drawn at 4x it (at least 4 N)."""
    return float(np.max(np.abs(np.where(np.isfinite(lo), lo, 0)), initial=0.0))


def interval_caps(
    columns: list[str], variants: list[str], blocks: Any, idx: np.ndarray
) -> dict[str, float]:
    """Per variant with interval columns, the box cap [N] of :func:`log_robot`:
    ``4 * max(interval_cap over the whole recording's 3D samples, 1)``.

    ``blocks(cols)`` gives those columns of the estimates in consecutive blocks of rows; ``idx``
    (M,) the whole recording's 3D samples (increasing row indices)."""
    out: dict[str, float] = {}
    for v in variants:
        lo_c, hi_c = _interval_columns(v)
        if not all(c in columns for c in lo_c + hi_c):
            continue
        m, a = 0.0, 0
        for block in blocks(lo_c):
            b = a + len(block)
            sel = idx[(idx >= a) & (idx < b)] - a
            if len(sel):
                m = max(m, interval_cap(block.to_numpy(dtype=float)[sel]))
            a = b
        out[v] = 4 * max(m, 1.0)
    return out


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (M, 3, 3) -> unit quaternions (M, 4), scalar last (Rerun's order)."""
    return Rotation.from_matrix(R).as_quat()  # scipy returns (x, y, z, w)


def _arrows(
    log: ColumnLogger,
    path: str,
    t: np.ndarray,
    origins: np.ndarray,
    vectors: np.ndarray,
    color: Any,
    label: str,
) -> None:
    vec = np.where(np.isfinite(vectors), vectors, 0.0)
    log.static(
        path,
        rr.Arrows3D(
            vectors=[[0, 0, 0]], colors=[color], radii=0.006, labels=[label], show_labels=False
        ),
    )
    log.send(path, t, rr.Arrows3D.columns(vectors=vec, origins=origins))

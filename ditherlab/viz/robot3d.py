"""The robot in 3D: link transforms, the skeleton through the link origins, and force arrows and
interval boxes at the tool point (``robot/...``), at the 3D rate."""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from ditherlab.estimates import Estimates
from ditherlab.recording import FORCE_AXES, Recording
from ditherlab.robot import RobotModel
from ditherlab.viz.stream import SENSOR_COLOR, VARIANT_COLORS, ColumnLogger, decimate_index


def log_robot(
    log: ColumnLogger,
    rec: Recording,
    robot: RobotModel,
    estimates: Estimates | None,
    rate_3d: float | None,
    force_scale: float,
) -> None:
    s = log.stream
    s.log("robot", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    idx = decimate_index(rec.t, rate_3d)
    t3 = rec.t[idx]
    q3 = rec.q[idx]
    poses = robot.link_poses(q3)
    for name, T in poses.items():
        path = f"robot/links/{rr.escape_entity_path_part(name)}"
        s.log(path, rr.TransformAxes3D(0.06), static=True)
        log.send(
            path,
            t3,
            rr.Transform3D.columns(translation=T[:, :3, 3], quaternion=_quat_xyzw(T[:, :3, :3])),
        )
    # Skeleton through the link origins in kinematic order; coincident origins (wrist) collapse.
    origins = np.stack([T[:, :3, 3] for T in poses.values()], axis=1)  # (M, L, 3) [m]
    s.log("robot/skeleton", rr.LineStrips3D([], radii=0.02, colors=[160, 160, 170]), static=True)
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
            fe = d[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)[idx]
            _arrows(log, f"robot/force/{v}", t3, tool, fe * force_scale, VARIANT_COLORS[v], v)
            lo_c = [f"{v}/f_{a}_lo" for a in FORCE_AXES]
            hi_c = [f"{v}/f_{a}_hi" for a in FORCE_AXES]
            if all(c in d.columns for c in lo_c + hi_c):
                lo = d[lo_c].to_numpy(dtype=float)[idx]
                hi = d[hi_c].to_numpy(dtype=float)[idx]
                # An unbounded side (a free component) is drawn at 4x the largest finite one.
                cap = 4 * max(float(np.nanmax(np.abs(np.where(np.isfinite(lo), lo, 0)))), 1.0)
                lo, hi = np.clip(lo, -cap, cap), np.clip(hi, -cap, cap)
                s.log(
                    f"robot/force/{v}/interval",
                    rr.Boxes3D(half_sizes=[[0, 0, 0]], colors=[VARIANT_COLORS[v]], radii=0.002),
                    static=True,
                )
                log.send(
                    f"robot/force/{v}/interval",
                    t3,
                    rr.Boxes3D.columns(
                        centers=tool + force_scale * (lo + hi) / 2,
                        half_sizes=force_scale * (hi - lo) / 2,
                    ),
                )


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
    log.stream.log(
        path,
        rr.Arrows3D(
            vectors=[[0, 0, 0]], colors=[color], radii=0.006, labels=[label], show_labels=False
        ),
        static=True,
    )
    log.send(path, t, rr.Arrows3D.columns(vectors=vec, origins=origins))

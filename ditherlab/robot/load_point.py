"""The motion of a point fixed to the tool: where a known load's centre of mass is and how it
accelerates, for the wrench the arm exerts on that load
(:func:`ditherlab.analysis.known_load.known_wrench`).

pinocchio's forward kinematics at ``(q, dq, ddq)`` on a copy of the robot's model with one more
frame at the point; the classical acceleration (``a = J ddq + dJ dq``, base axes) of that frame.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin

from ditherlab.robot.dedup import unique_configurations
from ditherlab.robot.model import TOOL_POINT_FRAME
from ditherlab.robot.urdf import frame_id

__all__ = ["PointMotion", "tool_point_motion"]

#: the name of the frame added at the point
_POINT_FRAME = "ditherlab_load_point"


class PointMotion(NamedTuple):
    """A point fixed to the tool, over N samples.

    Attributes
    ----------
    lever : (N, 3) [m] from the tool point to the point, base axes
    acceleration : (N, 3) [m/s²] the point's classical acceleration, base axes
    gravity : (3,) [m/s²] the robot model's gravity vector, base axes
    """

    lever: np.ndarray
    acceleration: np.ndarray
    gravity: np.ndarray


def tool_point_motion(
    robot: Any, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, point: np.ndarray
) -> PointMotion:
    """Where a point fixed to the tool is and how it accelerates.

    Parameters
    ----------
    robot : :class:`ditherlab.robot.RobotModel`
    q, dq, ddq : (N, n) [rad, rad/s, rad/s²]
    point : (3,) [m] the point in the tool frame (the frame a payload's ``com`` is given in)

    Returns
    -------
    PointMotion
    """
    m = pin.Model(robot.model)
    tf_id = frame_id(m, robot.tool_frame)
    tf = m.frames[tf_id]
    placement = tf.placement * pin.SE3(np.eye(3), np.asarray(point, dtype=float))
    fid = m.addFrame(
        pin.Frame(_POINT_FRAME, tf.parentJoint, tf_id, placement, pin.FrameType.OP_FRAME)
    )
    tp_id = m.getFrameId(TOOL_POINT_FRAME)
    d = m.createData()
    n = robot.n
    x = np.concatenate([np.atleast_2d(q), np.atleast_2d(dq), np.atleast_2d(ddq)], axis=1)
    u = unique_configurations(x)
    qp = robot.pin_configuration(u.q[:, :n])
    lever = np.empty((len(u.q), 3))
    acc = np.empty((len(u.q), 3))
    for i in range(len(u.q)):
        pin.forwardKinematics(m, d, qp[i], u.q[i, n : 2 * n], u.q[i, 2 * n :])
        pin.updateFramePlacements(m, d)
        lever[i] = d.oMf[fid].translation - d.oMf[tp_id].translation
        acc[i] = pin.getFrameClassicalAcceleration(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear
    g = np.array(m.gravity.linear, dtype=float)
    if len(u.q) == len(x):
        return PointMotion(lever, acc, g)
    return PointMotion(lever[u.inverse], acc[u.inverse], g)

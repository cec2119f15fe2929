"""The pinocchio loops behind :meth:`RobotModel.evaluate <ditherlab.robot.RobotModel.evaluate>`:
one tight loop per quantity, and the map of a body's dynamic parameters from the tool frame to
the frame of the joint that carries it."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import pinocchio as pin

from ditherlab.robot.tree import gravity as tree_gravity
from ditherlab.robot.tree import jacobian as tree_jacobian
from ditherlab.robot.tree import tree_of

__all__ = ["compiled_kernels", "quantity_kernels", "tool_to_joint_params"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def quantity_kernels(
    m: pin.Model,
    d: pin.Data,
    fid: int,
    parent: int,
    link_names: Sequence[str],
    T_params: np.ndarray,
) -> dict[str, tuple[Callable[[np.ndarray, np.ndarray], None], tuple]]:
    """Per-quantity loops over pinocchio: name -> (fill(qs (U, n), out (U, ...)), shape).

    ``m``, ``d``: the model (with the payload and tool-point frame) and its scratch data; ``fid``:
    the tool-point frame; ``parent``: the joint that carries the tool frame; ``link_names``: the
    URDF links of ``link_poses``; ``T_params``: :func:`tool_to_joint_params`.

    Each ``fill`` is a tight loop with its pinocchio function and arguments bound to local
    names: the per-sample Python overhead is then about that of one pinocchio call.
    """
    n = int(m.nv)
    tool_placement = m.frames[fid].placement
    z = np.zeros(n)
    cols = slice(10 * (parent - 1), 10 * parent)
    link_ids = [m.getFrameId(name, pin.FrameType.BODY) for name in link_names]
    oMi, oMf = d.oMi, d.oMf

    def gravity(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.computeGeneralizedGravity
        for i in range(len(qs)):
            out[i] = f(m, d, qs[i])

    def jacobian(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.computeFrameJacobian
        for i in range(len(qs)):
            out[i] = f(m, d, qs[i], fid, _LWA)

    def mass(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.crba
        for i in range(len(qs)):
            out[i] = f(m, d, qs[i])
        # pinocchio fills the upper triangle only
        iu = np.tril_indices(n, -1)
        out[:, iu[0], iu[1]] = out[:, iu[1], iu[0]]

    def tool(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.forwardKinematics
        for i in range(len(qs)):
            f(m, d, qs[i])
            out[i] = (oMi[parent] * tool_placement).homogeneous

    def links(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.framesForwardKinematics
        for i in range(len(qs)):
            f(m, d, qs[i])
            for k, j in enumerate(link_ids):
                out[i, k] = oMf[j].homogeneous

    def regressor(qs: np.ndarray, out: np.ndarray) -> None:
        f = pin.computeJointTorqueRegressor
        for i in range(len(qs)):
            out[i] = f(m, d, qs[i], z, z)[:, cols] @ T_params

    return {
        "gravity": (gravity, (n,)),
        "jacobian": (jacobian, (6, n)),
        "mass_matrix": (mass, (n, n)),
        "tool_pose": (tool, (4, 4)),
        "link_poses": (links, (len(link_ids), 4, 4)),
        "gravity_regressor": (regressor, (n, 10)),
    }


def compiled_kernels(
    m: pin.Model,
    point_id: int,
    reference: dict[str, tuple[Callable[[np.ndarray, np.ndarray], None], tuple]],
) -> dict[str, tuple[Callable[[np.ndarray, np.ndarray], None], tuple]]:
    """``reference`` (:func:`quantity_kernels`) with gravity and the Jacobian at the frame
    ``point_id`` compiled (:mod:`ditherlab.robot.tree`) when every joint of ``m`` is a one-axis
    revolute or prismatic joint; the other quantities (and those otherwise) stay pinocchio's."""
    kernels = dict(reference)
    tree = tree_of(m, point_id)
    if tree is not None:
        n = int(m.nv)
        kernels["gravity"] = (partial(tree_gravity, tree), (n,))
        kernels["jacobian"] = (partial(tree_jacobian, tree), (6, n))
    return kernels


def tool_to_joint_params(model: pin.Model, tool_frame_id: int) -> np.ndarray:
    """(10, 10) linear map: dynamic parameters in the tool frame -> parent joint frame."""
    X = model.frames[tool_frame_id].placement
    base = np.array([1.0, 0, 0, 0, 1.0, 0, 1.0, 0, 0, 1.0])  # a valid reference body

    def act(theta: np.ndarray) -> np.ndarray:
        return X.act(pin.Inertia.FromDynamicParameters(theta)).toDynamicParameters()

    ref = act(base)
    T = np.empty((10, 10))
    for k in range(10):
        e = np.zeros(10)
        e[k] = 1.0
        T[:, k] = act(base + e) - ref
    return T

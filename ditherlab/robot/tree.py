"""Gravity torque and tool-point Jacobian of a kinematic tree of one-axis joints, compiled.

The same quantities as pinocchio's ``computeGeneralizedGravity`` and ``computeFrameJacobian``
(LOCAL_WORLD_ALIGNED) at the tool point, from the pinocchio model's own joint placements, axes
and inertias (with the payload), without a Python call per sample: a long log's gravity and
Jacobian are most of what ``replay`` and ``diagnose`` compute per sample. The pinocchio loops of
:mod:`ditherlab.robot.batch` stay the reference (``tests/test_robot.py`` compares them on every
built-in robot); :func:`tree_of` returns None for a model with any other joint (a continuous
joint's two coordinates, a free flyer), which then keeps the pinocchio loops.

Per sample, in world axes: ``R_i = R_parent R0_i Rot(a_i, q_i)``, ``p_i = p_parent +
R_parent (p0_i + [prismatic] a_i q_i)``; the world axis ``w_i = R_i a_i``. With ``M_i`` the mass
of the subtree of joint ``i`` and ``S_i`` the sum of its masses times their centres of mass,
the gravity torque (the torque that holds the pose, pinocchio's sign) is
``g_i = -gvec · (w_i × (S_i - M_i p_i))`` for a revolute joint and ``-M_i gvec · w_i`` for a
prismatic one; the Jacobian's column of a joint that carries the tool point ``x`` is
``(w_i × (x - p_i), w_i)`` (revolute) or ``(w_i, 0)`` (prismatic), zero for the others.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pinocchio as pin
from numba import njit

__all__ = ["Tree", "gravity", "jacobian", "tree_of"]

#: fused multiply-adds and reordered sums (faster; the results stay within rounding of
#: pinocchio's, ``tests/test_robot.py``); not "nnan"/"ninf": a NaN stays
_FAST = {"contract", "reassoc", "nsz", "arcp"}
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


class Tree(NamedTuple):
    """A pinocchio model's joints as arrays (joint 0, the universe, has no motion); a NamedTuple,
    so that the compiled kernels take it as one argument.

    Attributes
    ----------
    parent : (J,) int
        Each joint's parent joint.
    R0 : (J, 3, 3)
        The joint's placement in its parent's frame: rotation.
    p0 : (J, 3) [m]
        The joint's placement in its parent's frame: origin.
    prismatic : (J,) bool
        Prismatic (else revolute).
    axis : (J, 3)
        The joint's unit axis, in its own frame.
    iq : (J,) int
        The joint's coordinate (column of ``q`` and of the outputs).
    mass : (J,) [kg]
        The mass of the joint's link (with the payload).
    com : (J, 3) [m]
        The link's centre of mass, in the joint's frame.
    g : (3,) [m/s²]
        Gravity.
    tool_joint : int
        The joint that carries the tool point.
    pf : (3,) [m]
        The tool point in that joint's frame.
    carries : (J,) bool
        The joints between the universe and the tool point.
    nv : int
        Joint velocities (columns of the outputs).
    """

    parent: np.ndarray
    R0: np.ndarray
    p0: np.ndarray
    prismatic: np.ndarray
    axis: np.ndarray
    iq: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    g: np.ndarray
    tool_joint: int
    pf: np.ndarray
    carries: np.ndarray
    nv: int


def _kind(joint: object) -> tuple[bool, tuple[float, float, float]] | None:
    """(prismatic, axis) of a one-axis joint with one coordinate, else None."""
    name = joint.shortname()  # type: ignore[attr-defined]
    if joint.nq != 1 or joint.nv != 1:  # type: ignore[attr-defined]
        return None
    for prefix, prismatic in (("JointModelR", False), ("JointModelP", True)):
        rest = name[len(prefix) :] if name.startswith(prefix) else None
        if rest in _AXES:
            return prismatic, _AXES[rest]
        if rest in ("evoluteUnaligned", "rismaticUnaligned"):
            a = np.asarray(joint.extract().axis, dtype=float)  # type: ignore[attr-defined]
            return prismatic, (float(a[0]), float(a[1]), float(a[2]))
    return None


def tree_of(model: pin.Model, frame_id: int) -> Tree | None:
    """The arrays of ``model`` for :func:`gravity` and :func:`jacobian` at the frame
    ``frame_id``, or None when a joint is not one of pinocchio's one-axis revolute or
    prismatic joints (aligned or not)."""
    J = int(model.njoints)
    parent = np.zeros(J, dtype=np.int64)
    R0 = np.zeros((J, 3, 3))
    p0 = np.zeros((J, 3))
    prismatic = np.zeros(J, dtype=np.bool_)
    axis = np.zeros((J, 3))
    iq = np.zeros(J, dtype=np.int64)
    mass = np.zeros(J)
    com = np.zeros((J, 3))
    R0[0] = np.eye(3)
    for i in range(1, J):
        kind = _kind(model.joints[i])
        if kind is None:
            return None
        parent[i] = int(model.parents[i])
        if parent[i] >= i:
            return None
        pl = model.jointPlacements[i]
        R0[i], p0[i] = pl.rotation, pl.translation
        prismatic[i], axis[i] = kind
        iq[i] = int(model.joints[i].idx_q)
        mass[i] = float(model.inertias[i].mass)
        com[i] = model.inertias[i].lever
    f = model.frames[frame_id]
    tool_joint = int(f.parentJoint)
    carries = np.zeros(J, dtype=np.bool_)
    k = tool_joint
    while k > 0:
        carries[k] = True
        k = int(parent[k])
    return Tree(
        parent,
        R0,
        p0,
        prismatic,
        axis,
        iq,
        mass,
        com,
        np.asarray(model.gravity.linear, dtype=float).copy(),
        tool_joint,
        np.asarray(f.placement.translation, dtype=float).copy(),
        carries,
        int(model.nv),
    )


@njit(cache=True, fastmath=_FAST, error_model="numpy")
def _pose(tree, q, R, p, w):
    """World rotation ``R (J, 3, 3)``, origin ``p (J, 3)`` [m] and axis ``w (J, 3)`` of every
    joint of ``tree`` at the configuration ``q (nq,)`` [rad, m]."""
    parent, R0, p0, prismatic, axis, iq = (
        tree.parent, tree.R0, tree.p0, tree.prismatic, tree.axis, tree.iq
    )  # fmt: skip
    J = len(parent)
    for i in range(1, J):
        k = parent[i]
        x = q[iq[i]]
        ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
        # B = R_parent R0_i: the joint frame before its motion
        for r in range(3):
            for c in range(3):
                R[i, r, c] = (
                    R[k, r, 0] * R0[i, 0, c] + R[k, r, 1] * R0[i, 1, c] + R[k, r, 2] * R0[i, 2, c]
                )
        for r in range(3):
            p[i, r] = (
                p[k, r] + R[k, r, 0] * p0[i, 0] + R[k, r, 1] * p0[i, 1] + R[k, r, 2] * p0[i, 2]
            )
            w[i, r] = R[i, r, 0] * ax + R[i, r, 1] * ay + R[i, r, 2] * az
        if prismatic[i]:
            for r in range(3):
                p[i, r] += w[i, r] * x
            continue
        # R_i = B Rot(a, x) (Rodrigues): B Rot = cos B + sin B[a]x + (1 - cos) (B a) a^T
        cs, sn = np.cos(x), np.sin(x)
        for r in range(3):
            b0, b1, b2 = R[i, r, 0], R[i, r, 1], R[i, r, 2]
            R[i, r, 0] = cs * b0 + sn * (b1 * az - b2 * ay) + (1.0 - cs) * w[i, r] * ax
            R[i, r, 1] = cs * b1 + sn * (b2 * ax - b0 * az) + (1.0 - cs) * w[i, r] * ay
            R[i, r, 2] = cs * b2 + sn * (b0 * ay - b1 * ax) + (1.0 - cs) * w[i, r] * az


@njit(cache=True)
def _scratch(J):
    """:func:`_pose`'s outputs for ``J`` joints, the universe (joint 0) at the origin."""
    R = np.zeros((J, 3, 3))
    R[0, 0, 0] = R[0, 1, 1] = R[0, 2, 2] = 1.0
    return R, np.zeros((J, 3)), np.zeros((J, 3))


@njit(cache=True, fastmath=_FAST, error_model="numpy")
def _gravity_kernel(tree, qs, out):
    """``out (U, nv)`` [N·m]: the gravity torque of ``tree`` at each configuration ``qs (U, nq)``
    [rad, m] (module docstring)."""
    parent, prismatic, iq, mass, com, g = (
        tree.parent, tree.prismatic, tree.iq, tree.mass, tree.com, tree.g
    )  # fmt: skip
    J = len(parent)
    R, p, w = _scratch(J)
    M = np.empty(J)
    S = np.empty((J, 3))
    for s in range(qs.shape[0]):
        _pose(tree, qs[s], R, p, w)
        for i in range(J):
            M[i] = mass[i]
            for r in range(3):
                S[i, r] = mass[i] * (
                    p[i, r]
                    + R[i, r, 0] * com[i, 0]
                    + R[i, r, 1] * com[i, 1]
                    + R[i, r, 2] * com[i, 2]
                )
        for i in range(J - 1, 0, -1):
            k = parent[i]
            M[k] += M[i]
            for r in range(3):
                S[k, r] += S[i, r]
        for i in range(1, J):
            v = iq[i]
            if prismatic[i]:
                out[s, v] = -M[i] * (g[0] * w[i, 0] + g[1] * w[i, 1] + g[2] * w[i, 2])
                continue
            dx = S[i, 0] - M[i] * p[i, 0]
            dy = S[i, 1] - M[i] * p[i, 1]
            dz = S[i, 2] - M[i] * p[i, 2]
            cx = w[i, 1] * dz - w[i, 2] * dy
            cy = w[i, 2] * dx - w[i, 0] * dz
            cz = w[i, 0] * dy - w[i, 1] * dx
            out[s, v] = -(g[0] * cx + g[1] * cy + g[2] * cz)


@njit(cache=True, fastmath=_FAST, error_model="numpy")
def _jacobian_kernel(tree, qs, out):
    """``out (U, 6, nv)``: the tool point's Jacobian of ``tree`` at each configuration
    ``qs (U, nq)`` [rad, m] (module docstring)."""
    parent, prismatic, iq, tool_joint, pf, carries = (
        tree.parent, tree.prismatic, tree.iq, tree.tool_joint, tree.pf, tree.carries
    )  # fmt: skip
    J = len(parent)
    R, p, w = _scratch(J)
    x = np.empty(3)
    for s in range(qs.shape[0]):
        _pose(tree, qs[s], R, p, w)
        f = tool_joint
        for r in range(3):
            x[r] = p[f, r] + R[f, r, 0] * pf[0] + R[f, r, 1] * pf[1] + R[f, r, 2] * pf[2]
        for i in range(1, J):
            v = iq[i]
            if not carries[i]:
                for r in range(6):
                    out[s, r, v] = 0.0
            elif prismatic[i]:
                for r in range(3):
                    out[s, r, v] = w[i, r]
                    out[s, 3 + r, v] = 0.0
            else:
                dx, dy, dz = x[0] - p[i, 0], x[1] - p[i, 1], x[2] - p[i, 2]
                out[s, 0, v] = w[i, 1] * dz - w[i, 2] * dy
                out[s, 1, v] = w[i, 2] * dx - w[i, 0] * dz
                out[s, 2, v] = w[i, 0] * dy - w[i, 1] * dx
                for r in range(3):
                    out[s, 3 + r, v] = w[i, r]


def gravity(tree: Tree, qs: np.ndarray, out: np.ndarray) -> None:
    """out (U, nv) [N·m] = the gravity torque at each configuration qs (U, nq) [rad, m]."""
    _gravity_kernel(tree, qs, out)


def jacobian(tree: Tree, qs: np.ndarray, out: np.ndarray) -> None:
    """out (U, 6, nv) = the tool point's Jacobian (linear [m/rad] over angular rows, world
    axes) at each configuration qs (U, nq) [rad, m]."""
    _jacobian_kernel(tree, qs, out)

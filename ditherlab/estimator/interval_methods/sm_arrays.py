"""The arrays of the set-membership kernels, grouped by what they are: the problem of a run of
samples, the bounds the kernels write, the warm-start state, and the scratch of the torque
coordinates' LPs (:mod:`.sm_square`, :mod:`.sm_lockstep`).

Each group is a ``typing.NamedTuple`` of arrays and scalars, which numba takes as one argument;
the allocators are compiled, so that a kernel can allocate its scratch itself. Names and units
are stated once here; the kernels unpack the fields into short local names.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit


class SMProblem(NamedTuple):
    """The set-membership LPs of a run of ``N`` samples: ``m`` estimated components, ``n`` joints.

    The polytope of a sample is every ``F`` with ``tau_min - k sigma <= tau_bar - J^T F <=
    tau_max + k sigma`` on every joint and ``|F_i - prior_mean_i| <= half_i`` on every component
    with a prior; a component without one (``ridge``) gets the artificial box ``+- big``.

    Attributes
    ----------
    tau_bar : (N, n) [N·m]
        Gravity-compensated torque, the held components' torque removed.
    J : (N, m, n) [m, 1]
        The estimated components' rows of the tool-point Jacobian.
    tau_min, tau_max : (N, n) [N·m]
        Band edges (``+-inf`` allowed).
    sigma : (N, n) [N·m]
        Noise standard deviation.
    k : float
        Half-width multiplier of the slabs and the prior box (:func:`.set_membership.interval_k`).
    prior_mean : (m,) [N, N·m]
        Centre of the prior box.
    half : (m,) [N, N·m]
        Half-width of the prior box, ``k prior_sigma`` (not read where ``ridge``).
    ridge : (m,) bool
        Components without a prior.
    big : float [N, N·m]
        Half-width of the artificial box (:data:`.set_membership.BIG_BOX`).
    """

    tau_bar: np.ndarray
    J: np.ndarray
    tau_min: np.ndarray
    tau_max: np.ndarray
    sigma: np.ndarray
    k: float
    prior_mean: np.ndarray
    half: np.ndarray
    ridge: np.ndarray
    big: float


class Bounds(NamedTuple):
    """What the set-membership kernels write per sample.

    Attributes
    ----------
    lo, hi : (N, m) [N, N·m]
        ``min F_i`` and ``max F_i`` over the sample's polytope.
    status : (N,) int64
        How the sample was solved (:func:`.set_membership._set_membership` lists the codes).
    """

    lo: np.ndarray
    hi: np.ndarray
    status: np.ndarray


class SquareState(NamedTuple):
    """The working set of each of the ``2m`` LPs of the torque coordinates, kept from sample to
    sample (LP ``o`` minimises ``F_i`` for ``o = 2i`` and maximises it for ``o = 2i + 1``).

    Attributes
    ----------
    var_side : (2m, m) int8
        Variable ``tau_j`` at its lower bound (-1), its upper bound (+1) or free (0).
    row_side : (2m, m) int8
        Prior-box row ``g`` held at its lower side (-1), its upper side (+1) or not held (0).
    warm : (2m,) bool
        The working set is the previous sample's optimum.
    """

    var_side: np.ndarray
    row_side: np.ndarray
    warm: np.ndarray


class PriorBox(NamedTuple):
    """The prior box as rows ``lo_g <= F_g <= hi_g`` of the torque coordinates' LPs.

    Attributes
    ----------
    lo, hi : (m,) [N, N·m]
        ``prior_mean -+ half``.
    has : (m,) bool
        Component ``g`` has a prior (else its row is not a row of the LPs).
    """

    lo: np.ndarray
    hi: np.ndarray
    has: np.ndarray


class SampleLP(NamedTuple):
    """One sample's LPs in torque coordinates ``tau = J^T F`` (``F = B tau``).

    Attributes
    ----------
    B : (m, m) [1/m, 1]
        ``J^-T``: row ``g`` gives component ``g`` of ``F`` from the joint torques.
    rn : (m,)
        1-norms of the rows of ``B`` (the violation of a box row in force units).
    L, U : (m,) [N·m]
        Bounds of ``tau``: ``tau_bar - tau_max - k sigma`` and ``tau_bar - tau_min + k sigma``.
    """

    B: np.ndarray
    rn: np.ndarray
    L: np.ndarray
    U: np.ndarray


class LPWork(NamedTuple):
    """Scratch of one torque-coordinate LP (:func:`.sm_square._lp`) and of ``J^-T``.

    Attributes
    ----------
    M : (m, m)
        Gauss-Jordan elimination of ``J^T``.
    K : (m, m)
        LU factors of the held rows restricted to the free variables.
    perm, free, held : (m,) int64
        The LU's row order, the free variables, the held rows.
    tau : (m,) [N·m]
        The working set's vertex.
    nu : (m,)
        The held rows' multipliers.
    ua, rhs, w : (m,)
        Solves and their right-hand sides.
    """

    M: np.ndarray
    K: np.ndarray
    perm: np.ndarray
    free: np.ndarray
    held: np.ndarray
    tau: np.ndarray
    nu: np.ndarray
    ua: np.ndarray
    rhs: np.ndarray
    w: np.ndarray


class BlockWork(NamedTuple):
    """Scratch of a block of ``W`` samples in lockstep, samples innermost (``q`` indexes the
    block).

    Attributes
    ----------
    Bs : (m, m, W) [1/m, 1]
        ``J^-T`` per sample.
    Ls, Us : (m, W) [N·m]
        The torque bounds per sample.
    rns : (m, W)
        The 1-norms of the rows of ``Bs``.
    ok : (W,) bool
        The sample is one the torque coordinates take.
    bad, empty : (W,) bool
        An LP of the sample gave up; the polytope is empty with the prior box.
    todo, done : (W,) bool
        The current LP: the sample is to be solved; it is solved.
    vals : (2m, W) [N, N·m]
        The LPs' values.
    K : (m, m, W)
        LU factors (:func:`.sm_lockstep.lockstep_verify`) or the elimination of ``J^T``
        (:func:`.sm_lockstep.lockstep_inverse`).
    rh, tau, nu : (m, W)
        Right-hand sides, vertices [N·m], multipliers.
    okv : (W,)
        1.0 where the lockstep step holds at the sample, else 0.0.
    cnv, fq : (W,)
        Scratch per sample (norms, sums).
    """

    Bs: np.ndarray
    Ls: np.ndarray
    Us: np.ndarray
    rns: np.ndarray
    ok: np.ndarray
    bad: np.ndarray
    empty: np.ndarray
    todo: np.ndarray
    done: np.ndarray
    vals: np.ndarray
    K: np.ndarray
    rh: np.ndarray
    tau: np.ndarray
    nu: np.ndarray
    okv: np.ndarray
    cnv: np.ndarray
    fq: np.ndarray


def square_state(m: int) -> SquareState:
    """The warm-start state of the torque coordinates for ``m`` components: every LP cold."""
    return SquareState(
        np.zeros((2 * m, m), np.int8), np.zeros((2 * m, m), np.int8), np.zeros(2 * m, np.bool_)
    )


@njit(cache=True)
def sample_lp(m):
    """A :class:`SampleLP` of ``m`` components (uninitialised)."""
    return SampleLP(np.empty((m, m)), np.empty(m), np.empty(m), np.empty(m))


@njit(cache=True)
def prior_box(m):
    """A :class:`PriorBox` of ``m`` components (uninitialised)."""
    return PriorBox(np.empty(m), np.empty(m), np.empty(m, np.bool_))


@njit(cache=True)
def lp_work(m):
    """An :class:`LPWork` of ``m`` components (uninitialised)."""
    return LPWork(
        np.empty((m, m)), np.empty((m, m)), np.empty(m, np.int64), np.empty(m, np.int64),
        np.empty(m, np.int64), np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m),
    )  # fmt: skip


@njit(cache=True)
def block_work(m, W):
    """A :class:`BlockWork` of ``m`` components and ``W`` samples (uninitialised)."""
    return BlockWork(
        np.empty((m, m, W)), np.empty((m, W)), np.empty((m, W)), np.empty((m, W)),
        np.empty(W, np.bool_), np.empty(W, np.bool_), np.empty(W, np.bool_),
        np.empty(W, np.bool_), np.empty(W, np.bool_), np.empty((2 * m, W)),
        np.empty((m, m, W)), np.empty((m, W)), np.empty((m, W)), np.empty((m, W)),
        np.empty(W), np.empty(W), np.empty(W),
    )  # fmt: skip


__all__ = [
    "BlockWork",
    "Bounds",
    "LPWork",
    "PriorBox",
    "SMProblem",
    "SampleLP",
    "SquareState",
    "block_work",
    "lp_work",
    "prior_box",
    "sample_lp",
    "square_state",
]

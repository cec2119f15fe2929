"""Profile-likelihood intervals in closed form for zero-width bands (a model whose friction is
all noise): one Cholesky factorisation per sample (numba) instead of the general path search.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ditherlab.estimator.backends.exact import PieceWork, _newton_piece, _solve_exact, piece_work
from ditherlab.estimator.formulation import Problem, chi2_1_quantile, complete
from ditherlab.estimator.interval_methods import intervals
from ditherlab.estimator.piecewise import Sample

#: A Cholesky pivot below this fraction of its diagonal entry (``H`` near singular in that
#: direction: the normal equations' relative error grows as 1 / pivot) sends the sample to the
#: QR of the stacked least-squares matrix instead (the exact backend's :func:`_newton_piece`).
MIN_PIVOT = 1e-5


class GaussWork(NamedTuple):
    """Scratch of :func:`_gaussian_kernel` for ``m`` components and ``n`` joints.

    Attributes
    ----------
    H : (m, m)
        ``H = J W J^T + diag(p)``, then its Cholesky factor ``L`` (lower, in place).
    Li : (m, m)
        ``L^-1``.
    piece : PieceWork
        The QR of the stacked matrix (:func:`_newton_piece`).
    x, y : (m,)
        The estimate [N, N·m]; a triangular solve.
    s : (n,) int8
        Every joint on its (zero-width) band's edge: the active set of the QR.
    """

    H: np.ndarray
    Li: np.ndarray
    piece: PieceWork
    x: np.ndarray
    y: np.ndarray
    s: np.ndarray


@njit(cache=True, inline="always", _nrt=False)
def _same_factor(S, k):
    """Whether sample ``k``'s ``(J, w, p)`` equals sample ``k - 1``'s (the same numbers: its
    factor is exact here)."""
    J, w, p = S.J, S.w, S.p
    m, n = J.shape[1], J.shape[2]
    for j in range(n):
        if w[k, j] != w[k - 1, j]:
            return False
    for i in range(m):
        if p[k, i] != p[k - 1, i]:
            return False
    for i in range(m):
        for j in range(n):
            if J[k, i, j] != J[k - 1, i, j]:
                return False
    return True


@njit(cache=True, inline="always", _nrt=False)
def _cholesky(S, k, H):
    """``H = J_k W_k J_k^T + diag(p_k)`` (lower triangle) factored in place, ``H = L L^T``.
    False when a pivot cancels below :data:`MIN_PIVOT` of its diagonal."""
    J, w, p = S.J, S.w, S.p
    m, n = J.shape[1], J.shape[2]
    for i in range(m):
        for q in range(i + 1):
            v = 0.0
            for j in range(n):
                v += J[k, i, j] * w[k, j] * J[k, q, j]
            H[i, q] = v
        H[i, i] += p[k, i]
    for i in range(m):  # Cholesky, lower, in place
        for q in range(i + 1):
            v = H[i, q]
            for t in range(q):
                v -= H[i, t] * H[q, t]
            if i == q:
                if not v > MIN_PIVOT * H[i, i]:
                    return False
                H[i, i] = math.sqrt(v)
            else:
                H[i, q] = v / H[q, q]
    return True


@njit(cache=True, inline="always", _nrt=False)
def _factor_by_qr(S, k, ws):
    """Ill-conditioned ``H``: the QR of ``[diag(sqrt p); sqrt(w_j) J_j^T]`` (the exact backend's
    solve of the same piece), ``L = R^T`` (``R^T R = H``) and the estimate into ``ws.x``."""
    m = S.J.shape[1]
    smp = Sample(S.tau_bar[k], S.J[k], S.tau_min[k], S.tau_min[k], S.w[k], S.p[k], S.prior_mean)
    _newton_piece(smp, ws.s, ws.piece, ws.x)
    R = ws.piece.R
    for i in range(m):
        for q in range(i + 1):
            ws.H[i, q] = R[q, i]


@njit(cache=True, inline="always", _nrt=False)
def _inverse_lower(H, Li, m):
    """``Li = L^-1`` column by column (``L`` the lower triangle of ``H``)."""
    for c in range(m):
        for i in range(c):
            Li[i, c] = 0.0
        Li[c, c] = 1.0 / H[c, c]
        for i in range(c + 1, m):
            v = 0.0
            for t in range(c, i):
                v -= H[i, t] * Li[t, c]
            Li[i, c] = v / H[i, i]


@njit(cache=True, inline="always", _nrt=False)
def _gaussian_mean(S, k, ws):
    """``x = fb + H^-1 J W (tb - a - J^T fb) = fb + Li^T (Li (J W d))``."""
    tb, J, a, w, fb = S.tau_bar, S.J, S.tau_min, S.w, S.prior_mean
    m, n = J.shape[1], J.shape[2]
    Li, z, y, x = ws.Li, ws.piece.z, ws.y, ws.x
    for i in range(m):
        z[i] = 0.0
    for j in range(n):
        d = tb[k, j] - a[k, j]
        for i in range(m):
            d -= J[k, i, j] * fb[i]
        d *= w[k, j]
        for i in range(m):
            z[i] += J[k, i, j] * d
    for i in range(m):
        v = 0.0
        for t in range(i + 1):
            v += Li[i, t] * z[t]
        y[i] = v
    for i in range(m):
        v = 0.0
        for t in range(i, m):
            v += Li[t, i] * y[t]
        x[i] = fb[i] + v


@njit(cache=True, _nrt=False)
def _gaussian_loop(S, thr, solve, F_out, half, active, ws):
    """:func:`_gaussian_kernel` on its scratch ``ws`` (:class:`GaussWork`), compiled without
    reference counts."""
    N, m, n = S.J.shape
    tb, J, a = S.tau_bar, S.J, S.tau_min
    x = ws.x
    fresh = False
    for k in range(N):
        if not (k > 0 and fresh and _same_factor(S, k)):
            fresh = _cholesky(S, k, ws.H)
            if not fresh:  # ill-conditioned: the QR of the stacked matrix
                _factor_by_qr(S, k, ws)
            _inverse_lower(ws.H, ws.Li, m)
        for c in range(m):
            v = 0.0
            for i in range(c, m):
                v += ws.Li[i, c] * ws.Li[i, c]
            half[k, c] = math.sqrt(thr * v)
        if not solve:
            continue
        if fresh:
            _gaussian_mean(S, k, ws)
        for i in range(m):
            F_out[k, i] = x[i]
        for j in range(n):
            r = tb[k, j] - a[k, j]
            for i in range(m):
                r -= J[k, i, j] * x[i]
            active[k, j] = r != 0.0


@njit(cache=True)
def _gaussian_kernel(S, thr, solve, F_out, half, active):
    """Zero-width bands (``a = tau_min = tau_max``) of the run ``S``
    (:class:`~ditherlab.estimator.formulation.Samples`): ``half[k, i] = sqrt(thr (H_k^-1)_ii)``,
    ``H_k = J_k W_k J_k^T + diag(p_k)``, and with ``solve`` the minimiser
    ``F_out[k] = fb + H_k^-1 J_k W_k (tb_k - a_k - J_k^T fb)`` of the quadratic eq. (3) and
    ``active[k, j]`` (the residual is not exactly on the zero-width band).

    One Cholesky ``H = L L^T`` per sample: ``(H^-1)_ii`` is the squared norm of column ``i`` of
    ``L^-1`` and ``F`` two triangular solves. A sample whose ``(J, w, p)`` equals the previous
    one's reuses its factor (exact: the same numbers). A pivot that cancels below
    :data:`MIN_PIVOT` of its diagonal takes the QR of ``[diag(sqrt p); sqrt(w_j) J_j^T]``
    (:func:`_newton_piece`, the exact backend's solve of the same piece) for both.
    """
    N, m, n = S.J.shape
    ws = GaussWork(
        np.empty((m, m)), np.empty((m, m)), piece_work(m, n), np.empty(m), np.empty(m),
        np.ones(n, np.int8),
    )  # fmt: skip
    _gaussian_loop(S, thr, solve, F_out, half, active, ws)


#: Placeholders of the kernel's outputs when it computes the half-widths alone.
_NO_F = np.empty((0, 0))
_NO_ACTIVE = np.empty((0, 0), np.bool_)


def gaussian_profile_intervals(
    prob: Problem, F_hat: np.ndarray, level: float = 0.95, chunk: int = 65536
) -> tuple[np.ndarray, np.ndarray]:
    """Profile-likelihood intervals in closed form when every band has zero width.

    Without the uniform term (``tau_min == tau_max``) the cost of eq. (3) is the quadratic
    ``(F - F̂)^T H (F - F̂) + c`` with ``H = J W J^T + P`` (``W = diag(1/sigma^2)``,
    ``P = diag(1/prior_sigma^2)``) over the estimated components, so the profile interval of
    component ``i`` is ``F̂_i ± sqrt(chi2_1(level) · (H^-1)_ii)`` — what
    :func:`ditherlab.estimator.intervals` (``method="profile"``) computes by its general
    piecewise search, here by one Cholesky factorisation per sample in numba (the tests compare
    the two, and with ``numpy.linalg.inv``).
    Falls back to the general routine when a band has width or an estimated component has no
    prior (``prior_sigma = inf``).

    Parameters
    ----------
    prob : Problem
        Eq. (3) for N samples (:func:`~ditherlab.estimator.problem`).
    F_hat : (N, 6) [N, N·m]
        The estimate.
    level : float
        Confidence level in (0, 1).
    chunk : int
        Samples per kernel call.

    Returns
    -------
    lo, hi : (N, 6) [N, N·m]
    """
    if not np.array_equal(prob.tau_min, prob.tau_max) or np.any(prob.p_true <= 0):
        return intervals(prob, F_hat, method="profile", level=level)
    N, m = prob.N, prob.m
    lo = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    hi = lo.copy()
    if m == 0 or N == 0:
        return lo, hi
    thr = chi2_1_quantile(level)
    half = np.empty((N, m))
    for a in range(0, N, chunk):
        sl = slice(a, min(a + chunk, N))
        _gaussian_kernel(prob.samples(sl), thr, False, _NO_F, half[sl], _NO_ACTIVE)
    Fm = np.asarray(F_hat, dtype=float)[:, prob.free]
    lo[:, prob.free] = Fm - half
    hi[:, prob.free] = Fm + half
    return lo, hi


def gaussian_problem_estimate(
    prob: Problem, level: float = 0.95, chunk: int = 65536
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The estimate of a zero-width-band :class:`Problem` and its profile intervals from one
    factorisation per sample (:func:`_gaussian_kernel`): what ``solve(prob, "exact")`` and
    :func:`gaussian_profile_intervals` give, in one pass (the tests compare them).

    Falls back to the exact backend and the general intervals when a band has width or an
    estimated component has no prior.

    Returns
    -------
    F : (N, 6) [N, N·m] the estimate (held components at ``prior_mean``)
    active : (N, n) bool the joints whose residual is off their (zero-width) band
    lo, hi : (N, 6) [N, N·m] the profile interval at ``level``
    """
    if not np.array_equal(prob.tau_min, prob.tau_max) or np.any(prob.p_true <= 0):
        sol = complete(prob, *_solve_exact(prob))
        lo, hi = intervals(prob, sol.F, method="profile", level=level)
        return sol.F, sol.active, lo, hi
    N, m, n = prob.N, prob.m, prob.n
    F = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    lo, hi = F.copy(), F.copy()
    active = np.zeros((N, n), np.bool_)
    if m == 0 or N == 0:
        return F, active, lo, hi
    thr = chi2_1_quantile(level)
    Fm = np.empty((N, m))
    half = np.empty((N, m))
    for a in range(0, N, chunk):
        sl = slice(a, min(a + chunk, N))
        _gaussian_kernel(prob.samples(sl), thr, True, Fm[sl], half[sl], active[sl])
    F[:, prob.free] = Fm
    lo[:, prob.free] = Fm - half
    hi[:, prob.free] = Fm + half
    return F, active, lo, hi

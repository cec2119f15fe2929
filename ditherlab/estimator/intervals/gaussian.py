"""Profile-likelihood intervals in closed form for zero-width bands (the no-band variants of
:mod:`ditherlab.analysis.estimation`): one Cholesky factorisation per sample (numba) instead of the general
path search.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from ditherlab.estimator.backends.exact import _newton_piece, _solve_exact
from ditherlab.estimator.intervals import problem_intervals
from ditherlab.estimator.problem import Problem, chi2_1_quantile, complete, problem

#: A Cholesky pivot below this fraction of its diagonal entry (``H`` near singular in that
#: direction: the normal equations' relative error grows as 1 / pivot) sends the sample to the
#: QR of the stacked least-squares matrix instead (the exact backend's :func:`_newton_piece`).
MIN_PIVOT = 1e-5


@njit(cache=True)
def _gaussian_kernel(tb, J, a, w, p, fb, thr, solve, F_out, half, active):
    """Zero-width bands (``a = tau_min = tau_max``): ``half[k, i] = sqrt(thr (H_k^-1)_ii)``,
    ``H_k = J_k W_k J_k^T + diag(p_k)``, and with ``solve`` the minimiser
    ``F_out[k] = fb + H_k^-1 J_k W_k (tb_k - a_k - J_k^T fb)`` of the quadratic eq. (3) and
    ``active[k, j]`` (the residual is not exactly on the zero-width band).

    One Cholesky ``H = L L^T`` per sample: ``(H^-1)_ii`` is the squared norm of column ``i`` of
    ``L^-1`` and ``F`` two triangular solves. A sample whose ``(J, w, p)`` equals the previous
    one's reuses its factor (exact: the same numbers). A pivot that cancels below
    :data:`MIN_PIVOT` of its diagonal takes the QR of ``[diag(sqrt p); sqrt(w_j) J_j^T]``
    (:func:`_newton_piece`, the exact backend's solve of the same piece) for both.
    """
    N, m, n = J.shape
    H = np.empty((m, m))
    Li = np.empty((m, m))
    R = np.empty((m, m))
    z = np.empty(m)
    Bm = np.empty((n, m))
    bb = np.empty(n)
    x = np.empty(m)
    y = np.empty(m)
    s = np.ones(n, np.int8)
    fresh = False
    for k in range(N):
        same = k > 0 and fresh
        if same:
            for j in range(n):
                if w[k, j] != w[k - 1, j]:
                    same = False
                    break
        if same:
            for i in range(m):
                if p[k, i] != p[k - 1, i]:
                    same = False
                    break
        if same:
            for i in range(m):
                for j in range(n):
                    if J[k, i, j] != J[k - 1, i, j]:
                        same = False
                        break
                if not same:
                    break
        if not same:
            for i in range(m):
                for q in range(i + 1):
                    v = 0.0
                    for j in range(n):
                        v += J[k, i, j] * w[k, j] * J[k, q, j]
                    H[i, q] = v
                H[i, i] += p[k, i]
            fresh = True
            for i in range(m):  # Cholesky, lower, in place
                for q in range(i + 1):
                    v = H[i, q]
                    for t in range(q):
                        v -= H[i, t] * H[q, t]
                    if i == q:
                        if not v > MIN_PIVOT * H[i, i]:
                            fresh = False
                            break
                        H[i, i] = math.sqrt(v)
                    else:
                        H[i, q] = v / H[q, q]
                if not fresh:
                    break
            if not fresh:  # ill-conditioned: the QR of the stacked matrix, L = R^T (R^T R = H)
                _newton_piece(tb[k], J[k], a[k], a[k], w[k], p[k], fb, s, m, n, R, z, Bm, bb, x)
                for i in range(m):
                    for q in range(i + 1):
                        H[i, q] = R[q, i]
            for c in range(m):  # L^-1, column by column
                for i in range(c):
                    Li[i, c] = 0.0
                Li[c, c] = 1.0 / H[c, c]
                for i in range(c + 1, m):
                    v = 0.0
                    for t in range(c, i):
                        v -= H[i, t] * Li[t, c]
                    Li[i, c] = v / H[i, i]
        for c in range(m):
            v = 0.0
            for i in range(c, m):
                v += Li[i, c] * Li[i, c]
            half[k, c] = math.sqrt(thr * v)
        if not solve:
            continue
        if fresh:
            # F - fb = H^-1 J W (tb - a - J^T fb) = Li^T (Li (J W d))
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
        for i in range(m):
            F_out[k, i] = x[i]
        for j in range(n):
            r = tb[k, j] - a[k, j]
            for i in range(m):
                r -= J[k, i, j] * x[i]
            active[k, j] = r != 0.0


#: Placeholders of the kernel's outputs when it computes the half-widths alone.
_NO_F = np.empty((0, 0))
_NO_ACTIVE = np.empty((0, 0), np.bool_)


def gaussian_profile_intervals(
    tau_bar: np.ndarray,
    J: np.ndarray,
    tau_min: np.ndarray,
    tau_max: np.ndarray,
    sigma: np.ndarray,
    prior_mean: np.ndarray,
    prior_sigma: np.ndarray,
    *,
    F_hat: np.ndarray,
    level: float = 0.95,
    components: Sequence[str] | None = None,
    chunk: int = 65536,
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
    tau_bar : (N, n) [N·m]; J : (N, 6, n); tau_min, tau_max, sigma : (n,) or (N, n) [N·m]
    prior_mean, prior_sigma : (6,) [N, N·m]
    F_hat : (N, 6) the estimate [N, N·m]
    level : confidence level; components : as for the estimator

    Returns
    -------
    lo, hi : (N, 6) [N, N·m]
    """
    prob = problem(tau_bar, J, tau_min, tau_max, sigma, prior_mean, prior_sigma, components)
    return gaussian_problem_intervals(prob, F_hat, level, chunk)


def gaussian_problem_intervals(
    prob: Problem, F_hat: np.ndarray, level: float = 0.95, chunk: int = 65536
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gaussian_profile_intervals` of a prepared :class:`Problem` (falls back to
    :func:`~ditherlab.estimator.intervals.problem_intervals` as it does)."""

    if not np.array_equal(prob.tau_min, prob.tau_max) or np.any(prob.p_true <= 0):
        return problem_intervals(prob, F_hat, method="profile", level=level)
    N, m = prob.N, prob.m
    lo = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    hi = lo.copy()
    if m == 0 or N == 0:
        return lo, hi
    thr = chi2_1_quantile(level)
    half = np.empty((N, m))
    for a in range(0, N, chunk):
        sl = slice(a, min(a + chunk, N))
        _gaussian_kernel(
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.w[sl], prob.p[sl],
            prob.prior_mean, thr, False, _NO_F, half[sl], _NO_ACTIVE,
        )  # fmt: skip
    Fm = np.asarray(F_hat, dtype=float)[:, prob.free]
    lo[:, prob.free] = Fm - half
    hi[:, prob.free] = Fm + half
    return lo, hi


def gaussian_problem_estimate(
    prob: Problem, level: float = 0.95, chunk: int = 65536
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The estimate of a zero-width-band :class:`Problem` and its profile intervals from one
    factorisation per sample (:func:`_gaussian_kernel`): what ``solve(prob, "exact")`` and
    :func:`gaussian_problem_intervals` give, in one pass (the tests compare them).

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
        lo, hi = problem_intervals(prob, sol.F, method="profile", level=level)
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
        _gaussian_kernel(
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.w[sl], prob.p[sl],
            prob.prior_mean, thr, True, Fm[sl], half[sl], active[sl],
        )  # fmt: skip
    F[:, prob.free] = Fm
    lo[:, prob.free] = Fm - half
    hi[:, prob.free] = Fm + half
    return F, active, lo, hi

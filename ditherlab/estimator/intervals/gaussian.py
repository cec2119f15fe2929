"""Profile-likelihood intervals in closed form for zero-width bands (the no-band variants of
:mod:`ditherlab.replay`): one Cholesky factorisation per sample (numba) instead of the general
path search.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from ditherlab.estimator.core import Problem, chi2_1_quantile, problem
from ditherlab.estimator.intervals import problem_intervals


@njit(cache=True)
def _gaussian_half_kernel(J, w, p, thr, half):
    """``half[k, i] = sqrt(thr (H_k^-1)_ii)``, ``H_k = J_k W_k J_k^T + diag(p_k)``: Cholesky
    ``H = L L^T``, then ``(H^-1)_ii`` is the squared norm of column ``i`` of ``L^-1``. A sample
    whose ``(J, w, p)`` equals the previous one's reuses its result (exact: the same numbers)."""
    N, m, n = J.shape
    H = np.empty((m, m))
    Li = np.empty((m, m))
    for k in range(N):
        if k > 0:
            same = True
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
            if same:
                for i in range(m):
                    half[k, i] = half[k - 1, i]
                continue
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
                    H[i, i] = math.sqrt(v)
                else:
                    H[i, q] = v / H[q, q]
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
        _gaussian_half_kernel(prob.J[sl], prob.w[sl], prob.p[sl], thr, half[sl])
    Fm = np.asarray(F_hat, dtype=float)[:, prob.free]
    lo[:, prob.free] = Fm - half
    hi[:, prob.free] = Fm + half
    return lo, hi

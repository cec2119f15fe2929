"""The profile-likelihood interval: ``{t : min_{F: F_i = t} f(F) - min_F f(F) <= chi2_1(level)}``
followed exactly along the path of constrained minimisers (see :mod:`ditherlab.estimator.intervals`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.estimator.core import Problem, _chunks
from ditherlab.estimator.kernels import _cost, _dist, _givens_row, _sides

#: Intervals whose half-width exceeds this many "information units" are reported as infinite.
UNOBSERVABLE = 1e5


@njit(cache=True)
def _qr_factor(J, w, p, s, m, n, R, u):
    """Upper-triangular R with R^T R = diag(p) + sum_{s_j != 0} w_j J_j J_j^T (Givens rows)."""
    for i in range(m):
        for k in range(m):
            R[i, k] = 0.0
        R[i, i] = math.sqrt(p[i])
    for j in range(n):
        if s[j] == 0:
            continue
        sw = math.sqrt(w[j])
        for i in range(m):
            u[i] = sw * J[i, j]
        _givens_row(R, u, m, u, 0.0, False)


@njit(cache=True)
def _hinv_col(R, i, m, y, x):
    """x = H^{-1} e_i with H = R^T R (two triangular solves)."""
    for q in range(m):
        v = 1.0 if q == i else 0.0
        for k in range(q):
            v -= R[k, q] * y[k]
        y[q] = v / R[q, q]
    for q in range(m - 1, -1, -1):
        v = y[q]
        for k in range(q + 1, m):
            v -= R[q, k] * x[k]
        x[q] = v / R[q, q]


@njit(cache=True)
def _profile_kernel(tb, J, a, b, w, p, fb, Fh, thr, ridge, unobs, lo_out, hi_out, seg_out):
    N, m, n = J.shape
    R = np.empty((m, m))
    R0 = np.empty((m, m))
    u = np.empty(m)
    y = np.empty(m)
    v = np.empty(m)
    F = np.empty(m)
    r = np.empty(n)
    s = np.zeros(n, np.int8)
    s0 = np.zeros(n, np.int8)
    maxseg = 4 * n + 8
    for k in range(N):
        tbk, Jk, ak, bk, wk, pk = tb[k], J[k], a[k], b[k], w[k], p[k]
        f0 = _cost(tbk, Jk, ak, bk, wk, pk, fb, Fh[k], m, n)
        target = f0 + thr
        scale = 0.0
        for i in range(m):
            for j in range(n):
                scale += wk[j] * Jk[i, j] ** 2
        scale = scale / m if scale > 0.0 else 1.0
        far = unobs * math.sqrt(thr / scale)
        # every path starts at F_hat with the same active set: factor it once per sample
        _sides(tbk, Jk, ak, bk, Fh[k], m, n, s0)
        _qr_factor(Jk, wk, pk, s0, m, n, R0, u)
        for i in range(m):
            for sg in (1.0, -1.0):
                for q in range(m):
                    F[q] = Fh[k, q]
                for j in range(n):
                    s[j] = s0[j]
                pcur = f0
                end = np.nan
                nseg = 0
                while nseg < maxseg:
                    nseg += 1
                    if nseg == 1:
                        _hinv_col(R0, i, m, y, v)
                    else:
                        _qr_factor(Jk, wk, pk, s, m, n, R, u)
                        _hinv_col(R, i, m, y, v)
                    h = v[i]
                    for q in range(m):
                        v[q] /= h
                    # slope of the profile along the path: grad f . v (grad f = mu e_i on it)
                    dp = 0.0
                    for q in range(m):
                        dp += 2.0 * pk[q] * (F[q] - fb[q]) * v[q]
                    db = np.inf
                    jb = -1
                    for j in range(n):
                        rj = tbk[j]
                        cj = 0.0
                        for q in range(m):
                            rj -= Jk[q, j] * F[q]
                            cj += Jk[q, j] * v[q]
                        r[j] = rj
                        dp -= 2.0 * wk[j] * cj * _dist(rj, ak[j], bk[j])
                        cj *= sg  # r_j(D) = r_j - D cj
                        dj = np.inf
                        if s[j] == 0:
                            if cj < 0.0:
                                dj = (bk[j] - rj) / (-cj)
                            elif cj > 0.0:
                                dj = (rj - ak[j]) / cj
                        elif s[j] > 0:
                            if cj > 0.0:
                                dj = (rj - bk[j]) / cj
                        elif cj < 0.0:
                            dj = (ak[j] - rj) / (-cj)
                        if dj < 0.0:
                            dj = 0.0
                        if dj < db:
                            db = dj
                            jb = j
                    dp *= sg
                    rem = target - pcur
                    if rem <= 0.0:
                        dstar = 0.0
                    else:
                        qq = 1.0 / h  # p(D) = pcur + dp D + D^2 / h on this piece
                        dstar = 2.0 * rem / (dp + math.sqrt(dp * dp + 4.0 * qq * rem))
                    if dstar <= db:
                        end = F[i] + sg * dstar - Fh[k, i]
                        break
                    for q in range(m):
                        F[q] += sg * db * v[q]
                    if s[jb] == 0:
                        cj = 0.0
                        for q in range(m):
                            cj += Jk[q, jb] * v[q]
                        s[jb] = 1 if sg * cj < 0.0 else -1
                    else:
                        s[jb] = 0
                    pcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
                seg_out[k] = max(seg_out[k], nseg)
                if ridge[i] and abs(end) > far:
                    end = sg * np.inf
                if sg > 0:
                    hi_out[k, i] = Fh[k, i] + end
                else:
                    lo_out[k, i] = Fh[k, i] + end


def _profile(
    prob: Problem, Fm: np.ndarray, level: float, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    """The profile bounds ``lo, hi (N, m)`` of the estimated components around ``Fm (N, m)``
    (the estimate: the path starts at the minimiser)."""
    from scipy.stats import chi2

    N, m = prob.N, prob.m
    lo_m, hi_m = np.empty((N, m)), np.empty((N, m))
    ridge = prob.p_true == 0.0
    thr = float(chi2.ppf(level, 1))
    seg = np.zeros(N, np.int64)
    Fm = np.ascontiguousarray(Fm)
    for sl in _chunks(N, progress):
        _profile_kernel(
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], prob.w[sl],
            prob.p[sl], prob.prior_mean, Fm[sl], thr, ridge, UNOBSERVABLE, lo_m[sl],
            hi_m[sl], seg[sl],
        )  # fmt: skip
        if progress is not None:
            progress(sl.stop, N)
    return lo_m, hi_m

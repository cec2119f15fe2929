"""The ``exact`` backend: semi-smooth Newton / active-set iteration on ``f``, compiled with
numba, all samples in one call (see :mod:`ditherlab.estimator` for the method and its limits).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.estimator.piecewise import _cost, _dist, _sides
from ditherlab.estimator.problem import Problem, _chunks


@njit(cache=True)
def _newton_piece(tb, J, a, b, w, p, fb, s, m, n, R, z, Bm, bb, x):
    """Minimiser x of the quadratic piece of f with active set s (joint j outside on side s_j).

    The piece is the least-squares problem ``|sqrt(p) (F - F_bar)|^2 + sum_{j active}
    w_j (tau_bar_j - e_j - J_j^T F)^2``; it is solved by QR, not by the normal equations: with
    tiny noise the normal equations square a condition number of ~1e5 and lose 1e-4 N in the
    prior-held directions. The QR is by Householder reflections on the stacked matrix
    ``[diag(sqrt(p)); sqrt(w_j) J_j^T for the active joints]`` (``Bm``, ``bb``: the active rows
    and their right-hand side): the top block stays triangular, so column ``c`` reflects its
    diagonal entry and the active rows only — one square root per column instead of one per
    column and active joint by Givens rotations.
    """
    na = 0
    for j in range(n):
        if s[j] == 0:
            continue
        e = b[j] if s[j] > 0 else a[j]
        sw = math.sqrt(w[j])
        beta = tb[j] - e
        for i in range(m):
            beta -= J[i, j] * fb[i]
            Bm[na, i] = sw * J[i, j]
        bb[na] = beta * sw
        na += 1
    for i in range(m):
        for k in range(m):
            R[i, k] = 0.0
        R[i, i] = math.sqrt(p[i])
        z[i] = 0.0  # unknown: dF = F - F_bar
    if na:
        for c in range(m):
            sig = 0.0
            for r in range(na):
                sig += Bm[r, c] * Bm[r, c]
            if sig == 0.0:
                continue
            alpha = R[c, c]  # > 0, untouched by the earlier columns' reflections
            nrm = math.sqrt(alpha * alpha + sig)
            v0 = alpha + nrm
            f2 = 2.0 / (v0 * v0 + sig)
            R[c, c] = -nrm
            for k in range(c + 1, m):
                t = v0 * R[c, k]
                for r in range(na):
                    t += Bm[r, c] * Bm[r, k]
                t *= f2
                R[c, k] -= t * v0
                for r in range(na):
                    Bm[r, k] -= t * Bm[r, c]
            t = v0 * z[c]
            for r in range(na):
                t += Bm[r, c] * bb[r]
            t *= f2
            z[c] -= t * v0
            for r in range(na):
                bb[r] -= t * Bm[r, c]
    for i in range(m - 1, -1, -1):
        v = z[i]
        for k in range(i + 1, m):
            v -= R[i, k] * x[k]
        x[i] = v / R[i, i]
    for i in range(m):
        x[i] += fb[i]


@njit(cache=True)
def _line_search(tb, J, a, b, w, p, fb, F, d, m, n):
    """Exact minimiser t in [0, 1] of the convex piecewise quadratic phi(t) = f(F + t d)."""
    r0 = np.empty(n)
    c = np.empty(n)
    bps = np.empty(2 * n + 1)
    nb = 0
    for j in range(n):
        r = tb[j]
        cj = 0.0
        for i in range(m):
            r -= J[i, j] * F[i]
            cj += J[i, j] * d[i]
        r0[j] = r
        c[j] = cj
        if cj != 0.0:
            for e in (a[j], b[j]):
                t = (r - e) / cj
                if 0.0 < t < 1.0:
                    bps[nb] = t
                    nb += 1
    bps[nb] = 1.0
    nb += 1
    bps[:nb].sort()

    def dphi(t):
        v = 0.0
        for i in range(m):
            v += p[i] * d[i] * (F[i] + t * d[i] - fb[i])
        for j in range(n):
            v -= w[j] * c[j] * _dist(r0[j] - t * c[j], a[j], b[j])
        return v

    t0 = 0.0
    g0 = dphi(0.0)
    if g0 >= 0.0:
        return 0.0
    for q in range(nb):
        t1 = bps[q]
        g1 = dphi(t1)
        if g1 >= 0.0:
            # phi' is linear on [t0, t1]: its root
            return t0 - g0 * (t1 - t0) / (g1 - g0)
        t0, g0 = t1, g1
    return 1.0


@njit(cache=True)
def _solve_exact_kernel(tb, J, a, b, w, p, fb, max_iter, warm, F_out, it_out):
    N, m, n = J.shape
    R = np.empty((m, m))
    z = np.empty(m)
    Bm = np.empty((n, m))
    bb = np.empty(n)
    x = np.empty(m)
    d = np.empty(m)
    F = fb.copy()
    s = np.zeros(n, np.int8)
    sn = np.zeros(n, np.int8)
    sa = np.zeros(n, np.int8)
    for k in range(N):
        tbk, Jk, ak, bk, wk, pk = tb[k], J[k], a[k], b[k], w[k], p[k]
        # warm start from the previous sample's solution (time series are smooth)
        if not warm:
            for i in range(m):
                F[i] = fb[i]
        _sides(tbk, Jk, ak, bk, F, m, n, s)
        # the cost at F, computed when first needed (most samples stop at the first piece)
        fcur = 0.0
        have_fcur = False
        it = 0
        n_amb_tries = 0
        while it < max_iter:
            it += 1
            _newton_piece(tbk, Jk, ak, bk, wk, pk, fb, s, m, n, R, z, Bm, bb, x)
            _sides(tbk, Jk, ak, bk, x, m, n, sn)
            same = True
            for j in range(n):
                # a joint of zero-width band is on the same piece on either side of it (the
                # edge is the same number): a sign change there is not a new active set
                if sn[j] != s[j] and not (ak[j] == bk[j] and sn[j] != 0 and s[j] != 0):
                    same = False
                    break
            if same:
                # Joints held active at a distance within rounding of their edge: with a huge
                # w_j (tiny noise) and a weak prior the sign of that distance is noise, and the
                # piece without them may be the true optimum (13 N away in a fuzzed case).
                improved = False
                if n_amb_tries < 8:
                    fbest = np.nan  # computed at the first joint near its edge
                    for j in range(n):
                        if s[j] == 0:
                            continue
                        e = bk[j] if s[j] > 0 else ak[j]
                        r = tbk[j]
                        size = abs(tbk[j]) + abs(e)
                        for i in range(m):
                            r -= Jk[i, j] * x[i]
                            size += abs(Jk[i, j] * x[i])
                        if abs(r - e) > 1e-9 * size:
                            continue
                        if fbest != fbest:
                            f1 = _cost(tbk, Jk, ak, bk, wk, pk, fb, x, m, n)
                            fbest = f1 - 1e-12 * (1.0 + f1)
                        for q in range(n):
                            sa[q] = s[q]
                        sa[j] = 0
                        _newton_piece(tbk, Jk, ak, bk, wk, pk, fb, sa, m, n, R, z, Bm, bb, d)
                        f2 = _cost(tbk, Jk, ak, bk, wk, pk, fb, d, m, n)
                        if f2 < fbest:
                            fbest = f2
                            improved = True
                            for i in range(m):
                                F[i] = d[i]
                if improved:
                    n_amb_tries += 1
                    fcur = fbest
                    have_fcur = True
                    _sides(tbk, Jk, ak, bk, F, m, n, s)
                    continue
                for i in range(m):
                    F[i] = x[i]
                break
            fnew = _cost(tbk, Jk, ak, bk, wk, pk, fb, x, m, n)
            if not have_fcur:
                fcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
                have_fcur = True
            if fnew < fcur:
                for i in range(m):
                    F[i] = x[i]
                fcur = fnew
                for j in range(n):
                    s[j] = sn[j]
            else:
                step = 0.0
                for i in range(m):
                    d[i] = x[i] - F[i]
                    step = max(step, abs(d[i]) / (1.0 + abs(F[i])))
                if step < 1e-15:
                    break  # the piece's minimiser is the current point: ties at a band edge
                t = _line_search(tbk, Jk, ak, bk, wk, pk, fb, F, d, m, n)
                if t <= 0.0:
                    break
                for i in range(m):
                    F[i] += t * d[i]
                fcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
                _sides(tbk, Jk, ak, bk, F, m, n, s)
        for i in range(m):
            F_out[k, i] = F[i]
        it_out[k] = it


def _solve_exact(
    prob: Problem, max_iter: int = 100, warm: bool = True, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    F = np.empty((prob.N, prob.m))
    it = np.zeros(prob.N, np.int64)
    if prob.N and prob.m:
        for sl in _chunks(prob.N, progress):
            _solve_exact_kernel(
                prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], prob.w[sl],
                prob.p[sl], prob.prior_mean, max_iter, warm, F[sl], it[sl],
            )  # fmt: skip
            if progress is not None:
                progress(sl.stop, prob.N)
    return F, it

"""The set-membership interval: ``[min F_i, max F_i]`` over the polytope of every ``F`` consistent
with the bands widened by ``k sigma`` and the prior box (see :mod:`ditherlab.estimator.intervals`):
a numba LP fast path and the HiGHS (``scipy.optimize.linprog``) reference.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.core.errors import ConfigError
from ditherlab.estimator.intervals.sm_square import square_block, square_state
from ditherlab.estimator.problem import Problem, _chunks, normal_quantile

#: Half-width [N, N·m] of the artificial box of the set-membership LP for prior-less components.
BIG_BOX = 1e9


@njit(cache=True)
def _gram_solve(G, nW, y):
    """Cholesky of the Gram matrix ``G[:nW, :nW]`` (lower triangle filled) in place, then
    ``y[:nW] = G^-1 y[:nW]``. A pivot that is not positive becomes 1e-300 (the rows are
    numerically dependent); False then, True otherwise."""
    ok = True
    for a1 in range(nW):
        for a2 in range(a1 + 1):
            v = G[a1, a2]
            for q in range(a2):
                v -= G[a1, q] * G[a2, q]
            if a1 == a2:
                if v > 0.0:
                    G[a1, a1] = math.sqrt(v)
                else:
                    G[a1, a1] = 1e-300
                    ok = False
            else:
                G[a1, a2] = v / G[a2, a2]
    for a1 in range(nW):
        v = y[a1]
        for q in range(a1):
            v -= G[a1, q] * y[q]
        y[a1] = v / G[a1, a1]
    for a1 in range(nW - 1, -1, -1):
        v = y[a1]
        for q in range(a1 + 1, nW):
            v -= G[q, a1] * y[q]
        y[a1] = v / G[a1, a1]
    return ok


@njit(cache=True)
def _lp_active_set(A, bv, nr, d, c, x, W, nW, G, lam, dirn, maxit):
    """Minimise c^T x subject to A[:nr, :d] x <= bv[:nr] from the feasible point x.

    Primal active-set method: W[:nW] are tight, linearly independent rows; move along the
    steepest descent direction projected on their null space until a row blocks (added); at a
    point where the projection vanishes, drop the row with the most negative multiplier; stop
    when all multipliers are >= 0 (optimal). Returns (status, nW): 0 optimal, 1 unbounded,
    2 iteration limit.
    """
    cn = 0.0
    for q in range(d):
        cn += c[q] * c[q]
    cn = math.sqrt(cn)
    for _it in range(maxit):
        # lam = -(A_W A_W^T)^{-1} A_W c ; dirn = -c - A_W^T lam
        for a1 in range(nW):
            r1 = W[a1]
            for a2 in range(a1 + 1):
                r2 = W[a2]
                v = 0.0
                for q in range(d):
                    v += A[r1, q] * A[r2, q]
                G[a1, a2] = v
            v = 0.0
            for q in range(d):
                v += A[r1, q] * c[q]
            lam[a1] = -v
        _gram_solve(G, nW, lam)
        dn = 0.0
        for q in range(d):
            v = -c[q]
            for a1 in range(nW):
                v -= A[W[a1], q] * lam[a1]
            dirn[q] = v
            dn += v * v
        dn = math.sqrt(dn)
        if nW == d or dn <= 1e-10 * cn:  # a vertex: the projected direction is zero
            worst = -1
            wl = -1e-10 * cn
            for a1 in range(nW):
                if lam[a1] < wl:
                    wl = lam[a1]
                    worst = a1
            if worst < 0:
                return 0, nW
            W[worst] = W[nW - 1]
            nW -= 1
            continue
        alpha = np.inf
        kb = -1
        for k in range(nr):
            inw = False
            for a1 in range(nW):
                if W[a1] == k:
                    inw = True
                    break
            if inw:
                continue
            ad = 0.0
            ax = 0.0
            an = 0.0
            for q in range(d):
                ad += A[k, q] * dirn[q]
                ax += A[k, q] * x[q]
                an += A[k, q] * A[k, q]
            if ad <= 1e-10 * math.sqrt(an) * dn:
                continue
            sl = bv[k] - ax
            al = (sl if sl > 0.0 else 0.0) / ad
            if al < alpha:
                alpha = al
                kb = k
        if kb < 0:
            return 1, nW
        for q in range(d):
            x[q] += alpha * dirn[q]
        W[nW] = kb
        nW += 1
    return 2, nW


@njit(cache=True)
def _sm_rows(tbk, Jk, ak, bk, sk, fb, halfbox, kk, ridge, attempt, A, bv, m, n):
    """The LP rows of one sample: joint slabs, the (prior or artificial) box, and z >= 0."""
    d1 = m + 1
    # rows: J_j^T F <= tb_j - a_j + k sig_j ; -J_j^T F <= -(tb_j - b_j - k sig_j) ; box rows
    nrow = 0
    for j in range(n):
        for side in (1.0, -1.0):
            edge = ak[j] if side > 0 else bk[j]
            if not math.isfinite(edge):
                continue
            for i in range(m):
                A[nrow, i] = side * Jk[i, j]
            A[nrow, m] = -1.0  # phase-1 slack z
            bv[nrow] = side * (tbk[j] - edge) + kk * sk[j]
            nrow += 1
    nj = nrow
    for i in range(m):
        # an artificial box far beyond any force keeps the LP bounded; an optimum held by it
        # (positive multiplier) is reported as unbounded
        hb = halfbox[i] if not ridge[i] and attempt == 0 else BIG_BOX
        for side in (1.0, -1.0):
            for q in range(d1):
                A[nrow, q] = 0.0
            A[nrow, i] = side
            bv[nrow] = side * fb[i] + hb
            nrow += 1
    for q in range(d1):
        A[nrow, q] = 0.0
    A[nrow, m] = -1.0
    bv[nrow] = 0.0
    nrow += 1
    return nrow, nj


@njit(cache=True)
def _lu_rows(A, Wo, m, M, piv, tmp):
    """LU with partial pivoting of the m x m matrix of rows A[Wo]; Wo is reordered to the pivot
    order (so L U = A[Wo] afterwards). False if (numerically) singular."""
    big = 0.0
    for a1 in range(m):
        for q in range(m):
            M[a1, q] = A[Wo[a1], q]
            big = max(big, abs(M[a1, q]))
        piv[a1] = a1
    for col in range(m):
        pr = col
        for r in range(col + 1, m):
            if abs(M[r, col]) > abs(M[pr, col]):
                pr = r
        if abs(M[pr, col]) <= 1e-12 * big:
            return False
        if pr != col:
            for q in range(m):
                t = M[col, q]
                M[col, q] = M[pr, q]
                M[pr, q] = t
            t2 = piv[col]
            piv[col] = piv[pr]
            piv[pr] = t2
        for r in range(col + 1, m):
            f = M[r, col] / M[col, col]
            M[r, col] = f
            for q in range(col + 1, m):
                M[r, q] -= f * M[col, q]
    for a1 in range(m):
        tmp[a1] = Wo[piv[a1]]
    for a1 in range(m):
        Wo[a1] = tmp[a1]
    return True


@njit(cache=True)
def _lu_solve(M, m, rhs, out):
    """out = (L U)^{-1} rhs."""
    for a1 in range(m):
        v = rhs[a1]
        for q in range(a1):
            v -= M[a1, q] * out[q]
        out[a1] = v
    for a1 in range(m - 1, -1, -1):
        v = out[a1]
        for q in range(a1 + 1, m):
            v -= M[a1, q] * out[q]
        out[a1] = v / M[a1, a1]


@njit(cache=True)
def _lu_solve_t(M, m, rhs, out):
    """out = (L U)^{-T} rhs."""
    for a1 in range(m):
        v = rhs[a1]
        for q in range(a1):
            v -= M[q, a1] * out[q]
        out[a1] = v / M[a1, a1]
    for a1 in range(m - 1, -1, -1):
        v = out[a1]
        for q in range(a1 + 1, m):
            v -= M[q, a1] * out[q]
        out[a1] = v


@njit(cache=True)
def _dual_vertex(A, bv, rn, nrow, m, c, Wo, x, lam, M, piv, u, tmp, rhs, maxit):
    """Dual simplex from the vertex Wo (m rows) for min c^T x subject to A x <= bv.

    The previous sample's optimal vertex stays dual feasible (its multipliers depend on J and
    c only) but the new torques move the right-hand sides: while a row is violated, it enters
    and the row chosen by the dual ratio test leaves. Returns 0 optimal (x, lam, Wo), 1 the
    polytope is empty, 2 gave up (singular, not dual feasible, iteration limit).
    """
    cn = 0.0
    for q in range(m):
        cn = max(cn, abs(c[q]))
    for it in range(maxit):
        if not _lu_rows(A, Wo, m, M, piv, tmp):
            return 2
        for a1 in range(m):
            rhs[a1] = bv[Wo[a1]]
        _lu_solve(M, m, rhs, x)
        for a1 in range(m):
            rhs[a1] = -c[a1]
        _lu_solve_t(M, m, rhs, lam)
        if it == 0:
            for a1 in range(m):
                if lam[a1] < -1e-10 * cn:
                    return 2
        worst = 0.0
        r = -1
        for row in range(nrow):
            v = -bv[row]
            for q in range(m):
                v += A[row, q] * x[q]
            if v > 1e-9 * (1.0 + abs(bv[row])):
                v /= rn[row]  # violation in F units: the most violated row enters
                if v > worst:
                    worst = v
                    r = row
        if r < 0:
            return 0
        for q in range(m):
            rhs[q] = A[r, q]
        _lu_solve_t(M, m, rhs, u)
        theta = np.inf
        leave = -1
        for a1 in range(m):
            if u[a1] > 1e-12:
                t = max(lam[a1], 0.0) / u[a1]
                if t < theta:
                    theta = t
                    leave = a1
        if leave < 0:
            return 1
        Wo[leave] = r
    return 2


@njit(cache=True)
def _onto_rows(A, bv, W, nW, m, x, G, y):
    """Move ``x`` (m,) onto its working rows ``A[W[:nW]] x = bv[W[:nW]]`` by the least-norm
    correction ``x += A_W^T (A_W A_W^T)^-1 (b_W - A_W x)``: a point the primal steps left a
    little off its face (their rounding accumulates along long steps) is put back on it."""
    for a1 in range(nW):
        r1 = W[a1]
        for a2 in range(a1 + 1):
            r2 = W[a2]
            v = 0.0
            for q in range(m):
                v += A[r1, q] * A[r2, q]
            G[a1, a2] = v
        v = bv[r1]
        for q in range(m):
            v -= A[r1, q] * x[q]
        y[a1] = v
    if not _gram_solve(G, nW, y):
        return
    for q in range(m):
        v = 0.0
        for a1 in range(nW):
            v += A[W[a1], q] * y[a1]
        x[q] += v


@njit(cache=True)
def _set_membership_kernel(tb, J, a, b, sig, fb, halfbox, kk, ridge, lo_out, hi_out, st_out):
    N, m, n = J.shape
    nr = 2 * n + 2 * m
    d1 = m + 1
    A = np.zeros((nr + 1, d1))
    bv = np.zeros(nr + 1)
    G = np.empty((d1, d1))
    lam = np.empty(d1)
    dirn = np.empty(d1)
    x = np.empty(d1)
    c = np.zeros(d1)
    W = np.empty(d1, np.int64)
    Wp = np.empty(m, np.int64)
    xp = np.empty(m)
    lamp = np.empty(m)
    M = np.empty((m, m))
    piv = np.empty(m, np.int64)
    tmpw = np.empty(m, np.int64)
    u = np.empty(m)
    rhs = np.empty(m)
    rn = np.empty(nr + 1)
    # optimal working set of every objective (component i, min / max) at the previous sample
    Wst = np.full((2 * m, m), -1, np.int64)
    wval = np.zeros(2 * m, np.bool_)
    for k in range(N):
        tbk, Jk = tb[k], J[k]
        if st_out[k] >= 5:  # solved in torque coordinates (sm_square.square_block)
            continue
        nrow, nj = _sm_rows(tbk, Jk, a[k], b[k], sig[k], fb, halfbox, kk, ridge, 0, A, bv, m, n)
        for row in range(nrow):
            v = 1e-300
            for q in range(m):
                v += abs(A[row, q])
            rn[row] = v
        # warm start: the previous sample's optimal vertices, repaired by dual simplex pivots
        warm = True
        for o in range(2 * m):
            if not wval[o]:
                warm = False
                break
        if warm:
            for o in range(2 * m):
                i = o // 2
                sg = 1.0 if o % 2 == 0 else -1.0
                for q in range(m):
                    c[q] = 0.0
                c[i] = sg
                for a1 in range(m):
                    W[a1] = Wst[o, a1]
                st = _dual_vertex(
                    A, bv, rn, nrow - 1, m, c, W, x, lam, M, piv, u, tmpw, rhs, 4 * m + 8
                )
                if st != 0:
                    warm = False
                    break
                for a1 in range(m):
                    Wst[o, a1] = W[a1]
                val = x[i]
                for a1 in range(m):
                    row = W[a1]
                    if row >= nj and lam[a1] > 1e-9:
                        if ridge[(row - nj) // 2]:
                            val = -sg * np.inf
                if sg > 0:
                    lo_out[k, i] = val
                else:
                    hi_out[k, i] = val
            if warm:
                st_out[k] = 4
                continue
        # cold path: phase 1 (with the prior box, else without it), then 2m LPs chained
        for attempt in range(2):
            if attempt == 1:
                nrow, nj = _sm_rows(tbk, Jk, a[k], b[k], sig[k], fb, halfbox, kk, ridge, 1,
                                    A, bv, m, n)  # fmt: skip
            z0 = 0.0
            for row in range(nj):
                v = -bv[row]
                for i in range(m):
                    v += A[row, i] * fb[i]
                z0 = max(z0, v)
            for i in range(m):
                x[i] = fb[i]
                c[i] = 0.0
            x[m] = z0 + 1.0
            c[m] = 1.0
            st, nW = _lp_active_set(A, bv, nrow, d1, c, x, W, 0, G, lam, dirn, 50 * nrow)
            bscale = 1.0
            for row in range(nj):
                bscale = max(bscale, abs(bv[row]))
            if st == 0 and x[m] <= 1e-9 * bscale:
                st_out[k] = attempt
                break
            st_out[k] = 2 if st == 0 else 3
        if st_out[k] >= 2:
            for i in range(m):
                lo_out[k, i] = np.nan
                hi_out[k, i] = np.nan
            wval[:] = False
            continue
        # phase 2 in F alone (z fixed at 0: drop the z column; rows keep their order)
        for row in range(nrow):  # the rows may have been rebuilt without the prior box
            v = 1e-300
            for q in range(m):
                v += abs(A[row, q])
            rn[row] = v
        nW = 0
        for i in range(m):
            for sg in (1.0, -1.0):
                o = 2 * i + (0 if sg > 0 else 1)
                for q in range(m):
                    c[q] = 0.0
                c[i] = sg
                st, nW = _lp_active_set(A, bv, nrow - 1, m, c, x, W, nW, G, lam, dirn, 50 * nrow)
                if st == 0 and nW < m:  # an optimal face: its value, from a point on it
                    _onto_rows(A, bv, W, nW, m, x, G, xp)
                if st == 0 and nW == m:
                    # the vertex solved from its rows, not the point the steps accumulated, and
                    # its multipliers checked by the dual simplex (which repairs a vertex the
                    # primal method's tolerances accepted: up to 1e-3 N off linprog before)
                    for a1 in range(m):
                        Wp[a1] = W[a1]
                    if _dual_vertex(A, bv, rn, nrow - 1, m, c, Wp, xp, lamp, M, piv, u, tmpw,
                                    rhs, 4 * m + 8) == 0:  # fmt: skip
                        for a1 in range(m):
                            W[a1] = Wp[a1]
                            x[a1] = xp[a1]
                            lam[a1] = lamp[a1]
                wval[o] = st == 0 and nW == m and st_out[k] == 0
                if wval[o]:
                    for a1 in range(m):
                        Wst[o, a1] = W[a1]
                if st == 1:
                    val = -sg * np.inf
                elif st != 0:
                    val = np.nan
                    st_out[k] = 3
                else:
                    val = x[i]
                    # an artificial box row (no prior, or prior box dropped) that holds the
                    # optimum with a positive multiplier: without it the LP is unbounded
                    for a1 in range(nW):
                        row = W[a1]
                        if row >= nj and lam[a1] > 1e-9:
                            ib = (row - nj) // 2
                            if ridge[ib] or st_out[k] == 1:
                                val = -sg * np.inf
                if sg > 0:
                    lo_out[k, i] = val
                else:
                    hi_out[k, i] = val


def interval_k(level: float, n: int, n_prior: int) -> float:
    """Bonferroni half-width multiplier of the set-membership interval.

    ``k = Phi^-1(1 - (1 - level) / (2 q))`` with ``q = n + n_prior`` events (each joint's noise
    within ``+- k sigma``, each prior component within ``+- k prior_sigma``).
    """
    return normal_quantile(1.0 - (1.0 - level) / (2.0 * max(1, n + n_prior)))


def _halfbox(prob: Problem, k: float) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.where(
            prob.p_true > 0, k / np.sqrt(np.where(prob.p_true > 0, prob.p_true, 1.0)), np.inf
        )


def _set_membership(
    prob: Problem, level: float, progress=None, square: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numba set-membership bounds ``lo, hi (N, m)`` and a status per sample: 0 solved
    cold with the prior box, 1 without it (empty with it), 2 empty (NaN), 3 failure (NaN),
    4 solved by warm-started dual simplex pivots from the previous sample's vertices, 5 solved
    in torque coordinates (square ``J``, :mod:`.sm_square`) with the prior box, 6 there without
    it. ``square=False``: the general kernel for every sample (the reference of the torque
    coordinates' path)."""
    ridge = prob.p_true == 0.0
    kk = interval_k(level, prob.n, int((~ridge).sum()))
    lo_m, hi_m = np.empty((prob.N, prob.m)), np.empty((prob.N, prob.m))
    st = np.zeros(prob.N, np.int64)
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, _halfbox(prob, kk))
    square = square and prob.m == prob.n
    sq = square_state(prob.m)
    for sl in _chunks(prob.N, progress):
        args = (prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], sig[sl])
        if square:  # the samples it can take; st = -1 for the others
            square_block(*args, kk, prob.prior_mean, half, ridge, BIG_BOX, sq, lo_m[sl],
                         hi_m[sl], st[sl])  # fmt: skip
        _set_membership_kernel(
            *args, prob.prior_mean, half, kk, ridge, lo_m[sl], hi_m[sl], st[sl]
        )  # fmt: skip
        if progress is not None:
            progress(sl.stop, prob.N)
    return lo_m, hi_m, st


def set_membership_reference(prob: Problem, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """The set-membership interval by ``scipy.optimize.linprog`` (HiGHS), two LPs per component.

    Slow and obviously right: the reference for the numba fast path. Returns ``lo, hi (N, m)``
    over the estimated components (NaN where the polytope is empty even without the prior box,
    +-inf where unbounded: no ridge box here, so unobservable components come out infinite).
    """
    from scipy.optimize import linprog

    kk = interval_k(level, prob.n, int((prob.p_true > 0).sum()))
    half = _halfbox(prob, kk)
    N, m = prob.N, prob.m
    lo, hi = np.full((N, m), np.nan), np.full((N, m), np.nan)
    sig = 1.0 / np.sqrt(prob.w)
    bounds = [
        (prob.prior_mean[i] - half[i], prob.prior_mean[i] + half[i])
        if np.isfinite(half[i])
        else (None, None)
        for i in range(m)
    ]
    for k in range(N):
        Jt = prob.J[k].T  # (n, m)
        ub1 = prob.tau_bar[k] - prob.tau_min[k] + kk * sig[k]
        ub2 = -(prob.tau_bar[k] - prob.tau_max[k] - kk * sig[k])
        rows = np.vstack([Jt[np.isfinite(ub1)], -Jt[np.isfinite(ub2)]])
        rhs = np.concatenate([ub1[np.isfinite(ub1)], ub2[np.isfinite(ub2)]])
        bk = bounds
        if linprog(np.zeros(m), A_ub=rows, b_ub=rhs, bounds=bk, method="highs").status == 2:
            bk = [(None, None)] * m  # empty with the prior box: the data alone
            if linprog(np.zeros(m), A_ub=rows, b_ub=rhs, bounds=bk, method="highs").status == 2:
                continue  # empty: NaN
        for i in range(m):
            for sg in (1.0, -1.0):
                c = np.zeros(m)
                c[i] = sg
                for meth in ("highs-ds", "highs-ipm"):  # the dual simplex, else interior point
                    res = linprog(c, A_ub=rows, b_ub=rhs, bounds=bk, method=meth)
                    if res.status in (0, 2, 3):
                        break
                if res.status == 2:
                    # the polytope is known to be non-empty (checked above): HiGHS's presolve
                    # reports "infeasible or unbounded" as infeasible; it is unbounded
                    val = -sg * np.inf
                elif res.status not in (0, 3):
                    raise ConfigError(
                        f"estimator: linprog failed at sample {k} (status {res.status}: "
                        f"{res.message}); expected a solved LP"
                    )
                elif res.status == 3:
                    val = -sg * np.inf
                else:
                    val = res.x[i]
                (lo if sg > 0 else hi)[k, i] = val
    return lo, hi

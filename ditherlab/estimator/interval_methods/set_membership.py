"""The set-membership interval: ``[min F_i, max F_i]`` over the polytope of every ``F`` consistent
with the bands widened by ``k sigma`` and the prior box (see :mod:`ditherlab.estimator.interval_methods`):
a numba LP fast path and the HiGHS (``scipy.optimize.linprog``) reference.

The general kernel (:func:`_set_membership_kernel`) solves the ``2m`` LPs of a sample in ``F``:
warm, by dual simplex pivots from the previous sample's optimal vertices; else cold, a phase 1
for a feasible point and a primal active-set method per objective. Square Jacobians go to the
torque coordinates first (:mod:`.sm_square`). The reasoning is in
``docs/design/estimator-set-membership.md``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ditherlab.core.errors import ConfigError
from ditherlab.estimator.formulation import Problem, _chunks, normal_quantile
from ditherlab.estimator.interval_methods.sm_arrays import Bounds, SMProblem, square_state
from ditherlab.estimator.interval_methods.sm_square import square_block

#: Half-width [N, N·m] of the artificial box of the set-membership LP for prior-less components.
BIG_BOX = 1e9


class GeneralWork(NamedTuple):
    """Scratch of the general kernel for ``m`` components and ``n`` joints: ``d = m + 1``
    variables (``F`` and the phase-1 slack ``z``) and up to ``nr + 1 = 2n + 2m + 1`` rows.

    Attributes
    ----------
    A : (nr + 1, d) [m, 1 | 1]
        The LP's rows: joint slabs ``+-J_j^T F``, box rows ``+-F_i``, and ``-z <= 0``; column
        ``m`` is ``z``'s.
    bv : (nr + 1,) [N·m | N, N·m]
        Their right-hand sides.
    rn : (nr + 1,)
        1-norms of the rows' ``F`` part (a violation in ``F`` units).
    c : (d,)
        The objective.
    x : (d,) [N, N·m]
        The current point (``F``, then ``z``).
    W : (d,) int64
        The primal method's working rows.
    G : (d, d)
        Gram matrix of the working rows (Cholesky in place).
    lam, dirn : (d,)
        Multipliers; the projected descent direction.
    Wp, xp, lamp : (m,) int64, (m,), (m,)
        The dual simplex's vertex, point and multipliers (checking an optimum).
    M : (m, m)
        LU of the vertex's rows.
    piv, tmpw : (m,) int64
        Its pivot order; scratch.
    u, rhs : (m,)
        Solves and their right-hand sides.
    Wst : (2m, m) int64
        Each objective's optimal vertex at the previous sample.
    wval : (2m,) bool
        Whether ``Wst`` holds it.
    """

    A: np.ndarray
    bv: np.ndarray
    rn: np.ndarray
    c: np.ndarray
    x: np.ndarray
    W: np.ndarray
    G: np.ndarray
    lam: np.ndarray
    dirn: np.ndarray
    Wp: np.ndarray
    xp: np.ndarray
    lamp: np.ndarray
    M: np.ndarray
    piv: np.ndarray
    tmpw: np.ndarray
    u: np.ndarray
    rhs: np.ndarray
    Wst: np.ndarray
    wval: np.ndarray


@njit(cache=True)
def _general_work(m, n):
    """A :class:`GeneralWork` for ``m`` components and ``n`` joints (rows and objective zero,
    no previous vertex)."""
    nr = 2 * n + 2 * m
    d1 = m + 1
    return GeneralWork(
        np.zeros((nr + 1, d1)), np.zeros(nr + 1), np.empty(nr + 1), np.zeros(d1), np.empty(d1),
        np.empty(d1, np.int64), np.empty((d1, d1)), np.empty(d1), np.empty(d1),
        np.empty(m, np.int64), np.empty(m), np.empty(m), np.empty((m, m)),
        np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m), np.empty(m),
        np.full((2 * m, m), -1, np.int64), np.zeros(2 * m, np.bool_),
    )  # fmt: skip


@njit(cache=True, _nrt=False)
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


# ------------------------------------------------------------------ the primal active-set method


@njit(cache=True, inline="always", _nrt=False)
def _projected_descent(wk, d, nW):
    """``lam = -(A_W A_W^T)^-1 A_W c`` and ``dirn = -c - A_W^T lam``: the steepest descent
    direction projected on the working rows' null space. Returns its norm."""
    A, c, W, G, lam, dirn = wk.A, wk.c, wk.W, wk.G, wk.lam, wk.dirn
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
    return math.sqrt(dn)


@njit(cache=True, inline="always", _nrt=False)
def _most_negative(lam, nW, cn):
    """The working row with the most negative multiplier (below ``-1e-10 cn``), else -1."""
    worst = -1
    wl = -1e-10 * cn
    for a1 in range(nW):
        if lam[a1] < wl:
            wl = lam[a1]
            worst = a1
    return worst


@njit(cache=True, inline="always", _nrt=False)
def _blocking_row(wk, nr, d, nW, dn):
    """The first row outside the working set that blocks a step along ``dirn``, and the step:
    ``(alpha, row)``, row -1 when none does (unbounded)."""
    A, bv, x, W, dirn = wk.A, wk.bv, wk.x, wk.W, wk.dirn
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
    return alpha, kb


@njit(cache=True, _nrt=False)
def _lp_active_set(wk, nr, d, nW, maxit):
    """Minimise ``c^T x`` subject to ``A[:nr, :d] x <= bv[:nr]`` from the feasible point ``x``
    (the fields of ``wk``, :class:`GeneralWork`).

    Primal active-set method: ``W[:nW]`` are tight, linearly independent rows; move along the
    steepest descent direction projected on their null space as far as the first row that blocks
    (added); at a point where the projection vanishes, drop the row with the most negative
    multiplier; stop when all multipliers are >= 0 (optimal). Returns ``(status, nW)``: 0
    optimal, 1 unbounded, 2 iteration limit.
    """
    c, x, W, dirn = wk.c, wk.x, wk.W, wk.dirn
    cn = 0.0
    for q in range(d):
        cn += c[q] * c[q]
    cn = math.sqrt(cn)
    for _it in range(maxit):
        dn = _projected_descent(wk, d, nW)
        if nW == d or dn <= 1e-10 * cn:  # a vertex: the projected direction is zero
            worst = _most_negative(wk.lam, nW, cn)
            if worst < 0:
                return 0, nW
            W[worst] = W[nW - 1]
            nW -= 1
            continue
        alpha, kb = _blocking_row(wk, nr, d, nW, dn)
        if kb < 0:
            return 1, nW
        for q in range(d):
            x[q] += alpha * dirn[q]
        W[nW] = kb
        nW += 1
    return 2, nW


@njit(cache=True, _nrt=False)
def _sm_rows(P, k, attempt, wk):
    """The LP rows of sample ``k`` (:class:`~.sm_arrays.SMProblem` ``P``) into ``wk.A, wk.bv``:
    joint slabs, the (prior or, at ``attempt`` 1, artificial) box, and ``z >= 0``. Returns
    ``(rows, slab rows)``."""
    m, n = P.J.shape[1], P.J.shape[2]
    A, bv = wk.A, wk.bv
    tbk, Jk, ak, bk, sk = P.tau_bar[k], P.J[k], P.tau_min[k], P.tau_max[k], P.sigma[k]
    kk = P.k
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
        hb = P.half[i] if not P.ridge[i] and attempt == 0 else P.big
        for side in (1.0, -1.0):
            for q in range(d1):
                A[nrow, q] = 0.0
            A[nrow, i] = side
            bv[nrow] = side * P.prior_mean[i] + hb
            nrow += 1
    for q in range(d1):
        A[nrow, q] = 0.0
    A[nrow, m] = -1.0
    bv[nrow] = 0.0
    nrow += 1
    return nrow, nj


@njit(cache=True, _nrt=False)
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


@njit(cache=True, _nrt=False)
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


@njit(cache=True, _nrt=False)
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


@njit(cache=True, _nrt=False)
def _dual_vertex(wk, nrow, m, Wo, x, lam, maxit):
    """Dual simplex from the vertex ``Wo`` (m rows) for ``min c^T x`` subject to ``A x <= bv``
    (the fields of ``wk``, :class:`GeneralWork`; ``x (m,)``, ``lam (m,)`` written).

    The previous sample's optimal vertex stays dual feasible (its multipliers depend on J and
    c only) but the new torques move the right-hand sides: while a row is violated, it enters
    and the row chosen by the dual ratio test leaves. Returns 0 optimal (x, lam, Wo), 1 the
    polytope is empty, 2 gave up (singular, not dual feasible, iteration limit).
    """
    A, bv, rn, c = wk.A, wk.bv, wk.rn, wk.c
    M, piv, u, tmp, rhs = wk.M, wk.piv, wk.u, wk.tmpw, wk.rhs
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


@njit(cache=True, _nrt=False)
def _onto_rows(wk, nW, m):
    """Move ``wk.x[:m]`` onto its working rows ``A[W[:nW]] x = bv[W[:nW]]`` by the least-norm
    correction ``x += A_W^T (A_W A_W^T)^-1 (b_W - A_W x)``: a point the primal steps left a
    little off its face (their rounding accumulates along long steps) is put back on it
    (``wk.xp`` scratch)."""
    A, bv, W, x, G, y = wk.A, wk.bv, wk.W, wk.x, wk.G, wk.xp
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


# ------------------------------------------------------------------ the general kernel's steps


@njit(cache=True, inline="always", _nrt=False)
def _row_norms(wk, nrow, m):
    """``wk.rn``: the 1-norms of the rows' ``F`` part."""
    for row in range(nrow):
        v = 1e-300
        for q in range(m):
            v += abs(wk.A[row, q])
        wk.rn[row] = v


@njit(cache=True, inline="always", _nrt=False)
def _objective(wk, m, o):
    """``wk.c[:m]``: ``min F_i`` for even ``o``, ``max F_i`` (``min -F_i``) for odd, ``i = o //
    2``. Returns ``(i, sg)``."""
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    for q in range(m):
        wk.c[q] = 0.0
    wk.c[i] = sg
    return i, sg


@njit(cache=True, inline="always", _nrt=False)
def _warm_sample(P, k, nrow, nj, wk, out):
    """Sample ``k`` from the previous sample's optimal vertices, repaired by dual simplex
    pivots: True when every LP is solved so (bounds written), False when a vertex is missing or
    a repair gives up."""
    m = P.J.shape[1]
    for o in range(2 * m):
        if not wk.wval[o]:
            return False
    for o in range(2 * m):
        i, sg = _objective(wk, m, o)
        for a1 in range(m):
            wk.W[a1] = wk.Wst[o, a1]
        st = _dual_vertex(wk, nrow - 1, m, wk.W, wk.x, wk.lam, 4 * m + 8)
        if st != 0:
            return False
        for a1 in range(m):
            wk.Wst[o, a1] = wk.W[a1]
        val = wk.x[i]
        for a1 in range(m):
            row = wk.W[a1]
            if row >= nj and wk.lam[a1] > 1e-9:
                if P.ridge[(row - nj) // 2]:
                    val = -sg * np.inf
        if sg > 0:
            out.lo[k, i] = val
        else:
            out.hi[k, i] = val
    return True


@njit(cache=True, inline="always", _nrt=False)
def _phase1(P, k, nrow, nj, wk, out):
    """A point of sample ``k``'s polytope by minimising the slack ``z`` from ``F = prior_mean``,
    with the prior box, else without it. ``out.status[k]``: 0 found with the box, 1 without it,
    2 empty, 3 failure. Returns the rows ``(rows, slab rows)`` of the last attempt."""
    m = P.J.shape[1]
    d1 = m + 1
    A, bv, x, c = wk.A, wk.bv, wk.x, wk.c
    fb = P.prior_mean
    for attempt in range(2):
        if attempt == 1:
            nrow, nj = _sm_rows(P, k, 1, wk)
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
        st, nW = _lp_active_set(wk, nrow, d1, 0, 50 * nrow)
        bscale = 1.0
        for row in range(nj):
            bscale = max(bscale, abs(bv[row]))
        if st == 0 and x[m] <= 1e-9 * bscale:
            out.status[k] = attempt
            break
        out.status[k] = 2 if st == 0 else 3
    return nrow, nj


@njit(cache=True, inline="always", _nrt=False)
def _check_vertex(wk, nrow, m):
    """An optimal vertex the primal method reached: solved again from its rows (not the point
    the steps accumulated) and its multipliers checked by the dual simplex, which repairs a
    vertex the primal method's tolerances accepted; kept when the dual simplex confirms it."""
    for a1 in range(m):
        wk.Wp[a1] = wk.W[a1]
    if _dual_vertex(wk, nrow - 1, m, wk.Wp, wk.xp, wk.lamp, 4 * m + 8) == 0:
        for a1 in range(m):
            wk.W[a1] = wk.Wp[a1]
            wk.x[a1] = wk.xp[a1]
            wk.lam[a1] = wk.lamp[a1]


@njit(cache=True, inline="always", _nrt=False)
def _optimum_value(P, k, st, nW, nj, o, wk, out):
    """The bound of LP ``o`` from its status and optimum: ``F_i``, ``-+inf`` when unbounded or
    held by an artificial box row with a positive multiplier (no prior, or the prior box
    dropped: without it the LP is unbounded), NaN (and status 3) on failure."""
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    if st == 1:
        return -sg * np.inf
    if st != 0:
        out.status[k] = 3
        return np.nan
    val = wk.x[i]
    for a1 in range(nW):
        row = wk.W[a1]
        if row >= nj and wk.lam[a1] > 1e-9:
            ib = (row - nj) // 2
            if P.ridge[ib] or out.status[k] == 1:
                val = -sg * np.inf
    return val


@njit(cache=True, inline="always", _nrt=False)
def _phase2(P, k, nrow, nj, wk, out):
    """The ``2m`` LPs of sample ``k`` in ``F`` alone (``z`` fixed at 0: its column dropped, the
    rows keep their order), chained from the phase-1 point; each optimal vertex kept for the
    next sample's warm start."""
    m = P.J.shape[1]
    nW = 0
    for o in range(2 * m):
        i, sg = _objective(wk, m, o)
        st, nW = _lp_active_set(wk, nrow - 1, m, nW, 50 * nrow)
        if st == 0 and nW < m:  # an optimal face: its value, from a point on it
            _onto_rows(wk, nW, m)
        if st == 0 and nW == m:
            _check_vertex(wk, nrow, m)
        wk.wval[o] = st == 0 and nW == m and out.status[k] == 0
        if wk.wval[o]:
            for a1 in range(m):
                wk.Wst[o, a1] = wk.W[a1]
        val = _optimum_value(P, k, st, nW, nj, o, wk, out)
        if sg > 0:
            out.lo[k, i] = val
        else:
            out.hi[k, i] = val


@njit(cache=True, _nrt=False)
def _general_loop(P, out, wk):
    """:func:`_set_membership_kernel` on its scratch ``wk`` (:class:`GeneralWork`), compiled
    without reference counts."""
    N, m, n = P.J.shape
    for k in range(N):
        if out.status[k] >= 5:  # solved in torque coordinates (sm_square.square_block)
            continue
        nrow, nj = _sm_rows(P, k, 0, wk)
        _row_norms(wk, nrow, m)
        if _warm_sample(P, k, nrow, nj, wk, out):
            out.status[k] = 4
            continue
        nrow, nj = _phase1(P, k, nrow, nj, wk, out)
        if out.status[k] >= 2:
            for i in range(m):
                out.lo[k, i] = np.nan
                out.hi[k, i] = np.nan
            wk.wval[:] = False
            continue
        _row_norms(wk, nrow, m)  # the rows may have been rebuilt without the prior box
        _phase2(P, k, nrow, nj, wk, out)


@njit(cache=True)
def _set_membership_kernel(P, out):
    """The ``2m`` LPs of every sample of ``P`` (:class:`~.sm_arrays.SMProblem`) not already
    solved in torque coordinates (``out.status >= 5``), into ``out``
    (:class:`~.sm_arrays.Bounds`; status codes in :func:`_set_membership`)."""
    N, m, n = P.J.shape
    _general_loop(P, out, _general_work(m, n))


def interval_k(level: float, n: int, n_prior: int) -> float:
    """Bonferroni half-width multiplier of the set-membership interval.

    ``k = Phi^-1(1 - (1 - level) / (2 q))`` with ``q = n + n_prior`` events (each joint's noise
    within ``+- k sigma``, each prior component within ``+- k prior_sigma``); dimensionless (in
    sigmas).
    """
    return normal_quantile(1.0 - (1.0 - level) / (2.0 * max(1, n + n_prior)))


def _halfbox(prob: Problem, k: float) -> np.ndarray:
    """Half-widths ``k prior_sigma (m,)`` [N, N·m] of the prior box (``inf`` without a prior)."""
    with np.errstate(divide="ignore"):
        return np.where(
            prob.p_true > 0, k / np.sqrt(np.where(prob.p_true > 0, prob.p_true, 1.0)), np.inf
        )


def _set_membership(
    prob: Problem, level: float, progress=None, square: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numba set-membership bounds ``lo, hi (N, m)`` [N, N·m] and a status per sample: 0
    solved cold with the prior box, 1 without it (empty with it), 2 empty (NaN), 3 failure
    (NaN), 4 solved by warm-started dual simplex pivots from the previous sample's vertices, 5
    solved in torque coordinates (square ``J``, :mod:`.sm_square`) with the prior box, 6 there
    without it. ``square=False``: the general kernel for every sample (the reference of the
    torque coordinates' path)."""
    ridge = prob.p_true == 0.0
    kk = interval_k(level, prob.n, int((~ridge).sum()))
    lo_m, hi_m = np.empty((prob.N, prob.m)), np.empty((prob.N, prob.m))
    st = np.zeros(prob.N, np.int64)
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, _halfbox(prob, kk))
    square = square and prob.m == prob.n
    sq = square_state(prob.m)
    for sl in _chunks(prob.N, progress):
        P = SMProblem(
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], sig[sl], kk,
            prob.prior_mean, half, ridge, BIG_BOX,
        )  # fmt: skip
        out = Bounds(lo_m[sl], hi_m[sl], st[sl])
        if square:  # the samples it can take; status -1 for the others
            square_block(P, sq, out)
        _set_membership_kernel(P, out)
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

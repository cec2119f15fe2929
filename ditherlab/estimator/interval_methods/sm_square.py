"""The set-membership LPs of a sample whose Jacobian is square (as many estimated components as
joints, ``m = n``: the usual six-axis arm estimating the whole wrench), solved in joint-torque
coordinates.

With ``J`` (m x m) invertible, ``tau = J^T F`` is a change of variables: the joint slabs become
bounds on the variables, ``L_j <= tau_j <= U_j``, and the prior box becomes ``m`` ranged rows
``Fl_g <= B_g tau <= Fu_g`` with ``B = J^-T``. Each LP ``min sg F_i = sg B_i tau`` is then a
bounded-variable LP whose basis holds only the box rows that bind: a ``t x t`` system instead of
an ``m x m`` one, solved by a dual simplex (:func:`_lp`) from the previous sample's working set or
from the vertex of the bounds alone. :func:`square_block` takes the samples by blocks of
:data:`BLOCK`: the block's bounds and ``J^-T`` in lockstep, then per LP lockstep passes
(:mod:`.sm_lockstep`) that settle every sample where the current working set is optimal, and the
per-sample dual simplex at the first sample a pass leaves. ``lockstep=False`` takes one sample at
a time (the reference of the passes).

The result is the same LP optimum as the general kernel's (:mod:`.set_membership`). Samples this
path cannot take (an infinite band edge, an ill-conditioned ``J``, a bound beyond the artificial
box, a singular basis, the iteration limit) are left to the general kernel. The reasoning is in
``docs/design/estimator-set-membership.md``.

The kernels here are compiled without numba's reference counts (``_nrt=False``: they create no
array) and their helpers are inlined. numba's cache does not follow the calls into
:mod:`.sm_lockstep`: after editing that module alone, delete this one's cache
(``__pycache__/sm_square*.nbi/.nbc``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.estimator.interval_methods.sm_arrays import (
    block_work,
    lp_work,
    prior_box,
    sample_lp,
)
from ditherlab.estimator.interval_methods.sm_lockstep import lockstep_inverse, lockstep_verify

#: Largest ``||J^T||_1 ||J^-T||_1`` the torque-coordinate path accepts (else: the general kernel).
MAX_CONDITION = 1e8

#: Samples per lockstep block (the structure-of-arrays scratch: about 40 kB per ``m x m`` array).
BLOCK = 128
#: Lockstep passes per LP and block (each with the working set of the last solved sample).
PASSES = 4

#: The compiled options of the helpers: inlined into the kernels, no reference counts.
_INLINE = {"cache": True, "inline": "always", "_nrt": False}


@njit(cache=True, inline="always", _nrt=False)
def _lu(K, t, p):
    """In-place LU with partial pivoting of ``K[:t, :t]`` (``P K = L U``, ``p`` the row order).
    False if a pivot is below ``1e-12`` of the largest entry."""
    big = 0.0
    for a in range(t):
        p[a] = a
        for b in range(t):
            big = max(big, abs(K[a, b]))
    for c in range(t):
        pr = c
        for r in range(c + 1, t):
            if abs(K[r, c]) > abs(K[pr, c]):
                pr = r
        if not abs(K[pr, c]) > 1e-12 * big:
            return False
        if pr != c:
            for b in range(t):
                v = K[c, b]
                K[c, b] = K[pr, b]
                K[pr, b] = v
            q = p[c]
            p[c] = p[pr]
            p[pr] = q
        d = K[c, c]
        for r in range(c + 1, t):
            f = K[r, c] / d
            K[r, c] = f
            for b in range(c + 1, t):
                K[r, b] -= f * K[c, b]
    return True


@njit(cache=True, inline="always", _nrt=False)
def _lu_solve(K, t, p, rhs, out):
    """``out = K^-1 rhs`` from :func:`_lu`."""
    for a in range(t):
        v = rhs[p[a]]
        for b in range(a):
            v -= K[a, b] * out[b]
        out[a] = v
    for a in range(t - 1, -1, -1):
        v = out[a]
        for b in range(a + 1, t):
            v -= K[a, b] * out[b]
        out[a] = v / K[a, a]


@njit(cache=True, inline="always", _nrt=False)
def _lu_solve_t(K, t, p, rhs, w, out):
    """``out = K^-T rhs`` from :func:`_lu` (``w`` scratch)."""
    for a in range(t):
        v = rhs[a]
        for b in range(a):
            v -= K[b, a] * w[b]
        w[a] = v / K[a, a]
    for a in range(t - 1, -1, -1):
        v = w[a]
        for b in range(a + 1, t):
            v -= K[b, a] * w[b]
        w[a] = v
    for a in range(t):
        out[p[a]] = w[a]


@njit(cache=True, inline="always", _nrt=False)
def _inverse_t(J, k, m, B, M):
    """``B = (J_k^T)^-1`` (m x m) by Gauss-Jordan elimination with partial pivoting (each row
    operation runs over whole rows of ``[M | B]``: independent columns, not a chain of dependent
    divisions); False if a pivot is below ``1e-12`` of the largest entry or the condition is
    beyond :data:`MAX_CONDITION`."""
    nj = 0.0
    big = 0.0
    for j in range(m):
        v = 0.0
        for i in range(m):
            M[j, i] = J[k, i, j]
            B[j, i] = 1.0 if i == j else 0.0
            v += abs(J[k, i, j])
            big = max(big, abs(J[k, i, j]))
        nj = max(nj, v)  # ||J^T||_1: the largest column sum of J^T (row j of J^T is J[:, j])
    for c in range(m):
        pr = c
        for r in range(c + 1, m):
            if abs(M[r, c]) > abs(M[pr, c]):
                pr = r
        if not abs(M[pr, c]) > 1e-12 * big:
            return False
        if pr != c:
            for q in range(m):
                v = M[c, q]
                M[c, q] = M[pr, q]
                M[pr, q] = v
                v = B[c, q]
                B[c, q] = B[pr, q]
                B[pr, q] = v
        d = 1.0 / M[c, c]
        for q in range(m):
            M[c, q] *= d
            B[c, q] *= d
        for r in range(m):
            if r != c:
                f = M[r, c]
                for q in range(m):
                    M[r, q] -= f * M[c, q]
                    B[r, q] -= f * B[c, q]
    nb = 0.0
    for c in range(m):
        v = 0.0
        for r in range(m):
            v += abs(B[r, c])
        nb = max(nb, v)  # ||J^-T||_1
    return nb * nj <= MAX_CONDITION


# ------------------------------------------------------------------ one LP: the dual simplex
# The steps of _lp take the LP's arguments: ``lp`` (:class:`~.sm_arrays.SampleLP`), ``box``
# (:class:`~.sm_arrays.PriorBox`), ``S`` (:class:`~.sm_arrays.SquareState`, row ``o`` the
# working set), ``o`` (the LP: ``min sg B_i tau``, ``i = o // 2``, ``sg = +1`` for even ``o``),
# ``work`` (:class:`~.sm_arrays.LPWork`) and ``t`` (the working set's free variables).


@njit(**_INLINE)
def _working_set(lp, S, o, work):
    """The free variables ``work.free`` and held rows ``work.held`` of LP ``o``'s working set;
    the fixed variables of ``work.tau`` at their bounds. Returns ``t`` (-1: as many rows held as
    variables free is not the case)."""
    m = lp.B.shape[0]
    sxs, srs = S.var_side, S.row_side
    fr, tr, tau = work.free, work.held, work.tau
    t = 0
    for j in range(m):
        if sxs[o, j] == 0:
            fr[t] = j
            t += 1
        elif sxs[o, j] < 0:
            tau[j] = lp.L[j]
        else:
            tau[j] = lp.U[j]
    ta = 0
    for g in range(m):
        if srs[o, g] != 0:
            tr[ta] = g
            ta += 1
    return t if ta == t else -1


@njit(**_INLINE)
def _vertex(lp, box, S, o, work, t):
    """The free variables of the vertex: the held rows at their sides, ``K tau_free = d -
    B_T,fixed tau_fixed``. False if ``K`` is singular."""
    m = lp.B.shape[0]
    B = lp.B
    sxs, srs = S.var_side, S.row_side
    fr, tr, tau, K, p, rhs, ua = (
        work.free,
        work.held,
        work.tau,
        work.K,
        work.perm,
        work.rhs,
        work.ua,
    )
    for a in range(t):
        g = tr[a]
        v = box.hi[g] if srs[o, g] > 0 else box.lo[g]
        for j in range(m):
            if sxs[o, j] != 0:
                v -= B[g, j] * tau[j]
        rhs[a] = v
        for b in range(t):
            K[a, b] = B[g, fr[b]]
    if not _lu(K, t, p):
        return False
    _lu_solve(K, t, p, rhs, ua)
    for b in range(t):
        tau[fr[b]] = ua[b]
    return True


@njit(**_INLINE)
def _multipliers(lp, o, work, t):
    """The held rows' multipliers: ``K^T nu = c_free`` (``c = sg B_i``)."""
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    for b in range(t):
        work.rhs[b] = sg * lp.B[i, work.free[b]]
    _lu_solve_t(work.K, t, work.perm, work.rhs, work.w, work.nu)


@njit(**_INLINE)
def _dual_feasible(lp, S, o, work, t, cn):
    """Whether a warm start's multipliers have the right signs: a held row's ``nu_a``, a fixed
    variable's ``c_j - sum_a nu_a B[tr_a, j]`` (1e-10 of ``cn = max_j |B_ij|``)."""
    m = lp.B.shape[0]
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    B = lp.B
    sxs, srs = S.var_side, S.row_side
    tr, nu = work.held, work.nu
    for a in range(t):
        if srs[o, tr[a]] * nu[a] > 1e-10 * cn:
            return False
    for j in range(m):
        if sxs[o, j] != 0:
            mu = sg * B[i, j]
            for a in range(t):
                mu -= nu[a] * B[tr[a], j]
            if sxs[o, j] * mu > 1e-10 * cn:
                return False
    return True


@njit(**_INLINE)
def _entering(lp, box, S, o, work, t, bland):
    """The most violated box row or bound (violation in its own units over the row norm), or
    with ``bland`` the first violated row, then variable, in index order. Returns ``(ent, es)``:
    ``ent`` a variable ``j < m`` or the row ``m + g`` (-1: none, the vertex is optimal), ``es``
    the side it enters at (-1 lower, +1 upper)."""
    m = lp.B.shape[0]
    B, rn, L, U = lp.B, lp.rn, lp.L, lp.U
    Fl, Fu = box.lo, box.hi
    srs = S.row_side
    fr, tau = work.free, work.tau
    worst = 0.0
    ent = -1
    es = 0
    for g in range(m):
        if not box.has[g] or srs[o, g] != 0:
            continue
        f = 0.0
        for j in range(m):
            f += B[g, j] * tau[j]
        if f < Fl[g] - 1e-9 * (1.0 + abs(Fl[g])):
            v, s = (Fl[g] - f) / rn[g], -1
        elif f > Fu[g] + 1e-9 * (1.0 + abs(Fu[g])):
            v, s = (f - Fu[g]) / rn[g], 1
        else:
            continue
        if v > worst:
            worst, ent, es = v, m + g, s
            if bland:
                break
    for b in range(t):
        if bland and ent >= 0:
            break
        j = fr[b]
        if tau[j] < L[j] - 1e-9 * (1.0 + abs(L[j])):
            v, s = L[j] - tau[j], -1
        elif tau[j] > U[j] + 1e-9 * (1.0 + abs(U[j])):
            v, s = tau[j] - U[j], 1
        else:
            continue
        if v > worst:
            worst, ent, es = v, j, s
            if bland:
                break
    return ent, es


@njit(**_INLINE)
def _leaving(lp, S, o, work, t, ent, es):
    """The dual ratio test for the entering row or bound ``ent`` at side ``es``: the held row
    (``m + g``) or fixed variable (``j``) whose multiplier reaches zero first (ties to the first
    in index order); -1 when none can leave (the polytope is empty)."""
    m = lp.B.shape[0]
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    B, rn = lp.B, lp.rn
    sxs, srs = S.var_side, S.row_side
    fr, tr, nu, ua, rhs = work.free, work.held, work.nu, work.ua, work.rhs
    # the entering row a_e in terms of the working set's rows: K^T u_T = a_e,free, and for a
    # fixed variable u_j = a_e,j - sum_a u_a B[tr_a, j]
    an = 1.0
    for b in range(t):
        if ent < m:
            rhs[b] = 1.0 if fr[b] == ent else 0.0
        else:
            rhs[b] = B[ent - m, fr[b]]
    if ent >= m:
        an = rn[ent - m]
    _lu_solve_t(work.K, t, work.perm, rhs, work.w, ua)
    theta = np.inf
    leave = -1
    for a in range(t):  # held rows: multiplier nu_a + es theta u_a keeps its sign
        sw = srs[o, tr[a]]
        q = sw * es * ua[a]
        if q > 1e-11 * an:
            th = max(-sw * nu[a], 0.0) / q
            if th < theta:
                theta, leave = th, m + tr[a]
    for j in range(m):  # fixed variables
        if sxs[o, j] == 0:
            continue
        uj = 0.0 if ent < m else B[ent - m, j]
        mu = sg * B[i, j]
        for a in range(t):
            uj -= ua[a] * B[tr[a], j]
            mu -= nu[a] * B[tr[a], j]
        q = sxs[o, j] * es * uj
        if q > 1e-11 * an:
            th = max(-sxs[o, j] * mu, 0.0) / q
            if th < theta:
                theta, leave = th, j
    return leave


@njit(**_INLINE)
def _exchange(S, o, m, ent, es, leave):
    """The working set after the pivot: ``leave`` out, ``ent`` in at side ``es``."""
    if leave < m:
        S.var_side[o, leave] = 0
    else:
        S.row_side[o, leave - m] = 0
    if ent < m:
        S.var_side[o, ent] = es
    else:
        S.row_side[o, ent - m] = es


@njit(**_INLINE)
def _lp(lp, box, S, o, work, warm, maxit):
    """``min sg B_i tau`` over ``L <= tau <= U`` and ``Fl_g <= B_g tau <= Fu_g`` (``box.has[g]``),
    ``i = o // 2``, ``sg = +1`` for even ``o``, else ``-1``.

    The working set is row ``o`` of ``S.var_side`` and ``S.row_side``, updated in place (rows,
    not views, so that no array is made per LP). A ``warm`` start must be dual feasible (else
    status 2). The most violated row or bound enters, then (after ``m`` iterations) Bland's rule,
    which cannot cycle: with the objective's own row held every other multiplier is zero and the
    largest-violation rule can cycle. Returns ``(status, value)``: 0 optimal (the value
    ``B_i tau`` [N, N·m]), 1 the polytope is empty, 2 gave up (inconsistent or singular working
    set, not dual feasible, iteration limit).
    """
    m = lp.B.shape[0]
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    cn = 0.0
    for j in range(m):
        cn = max(cn, abs(lp.B[i, j]))
    for it in range(maxit):
        t = _working_set(lp, S, o, work)
        if t < 0 or not _vertex(lp, box, S, o, work, t):
            return 2, 0.0
        # a warm start whose working set holds the objective's own row on the side the
        # objective pushes to is dual feasible as it stands (nu = sg e_i, every other multiplier
        # zero): the multipliers are then only needed if the vertex is not primal feasible
        have_nu = not (it == 0 and warm and S.row_side[o, i] == (-1 if sg > 0 else 1))
        if have_nu:
            _multipliers(lp, o, work, t)
            if it == 0 and warm and not _dual_feasible(lp, S, o, work, t, cn):
                return 2, 0.0
        ent, es = _entering(lp, box, S, o, work, t, it >= m)
        if ent < 0:
            val = 0.0
            for j in range(m):
                val += lp.B[i, j] * work.tau[j]
            return 0, val
        if not have_nu:
            _multipliers(lp, o, work, t)
        leave = _leaving(lp, S, o, work, t, ent, es)
        if leave < 0:
            return 1, 0.0  # no multiplier can take the violated row: the polytope is empty
        _exchange(S, o, m, ent, es, leave)
    return 2, 0.0


@njit(**_INLINE)
def _cold(lp, S, o):
    """The vertex of the bounds alone for LP ``o``: each variable at the bound its cost
    prefers."""
    m = lp.B.shape[0]
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    for j in range(m):
        S.var_side[o, j] = -1 if sg * lp.B[i, j] >= 0.0 else 1
        S.row_side[o, j] = 0


@njit(**_INLINE)
def _solve_lp(lp, box, S, o, work, maxit):
    """LP ``o`` of the sample: warm from its working set when that is the previous optimum,
    else (or when the warm start gives up) cold. Returns ``(status, value)`` as :func:`_lp`;
    the working set is warm for the next sample when optimal."""
    st = 2
    val = 0.0
    if S.warm[o]:
        st, val = _lp(lp, box, S, o, work, True, maxit)
    if st == 2:
        _cold(lp, S, o)
        st, val = _lp(lp, box, S, o, work, False, maxit)
    S.warm[o] = st == 0
    return st, val


# ------------------------------------------------------------------ one sample's LP data


@njit(**_INLINE)
def _fill_prior_box(P, box):
    """The prior box's rows ``Fl <= B_g tau <= Fu`` = ``prior_mean -+ half`` (``box.has[g]``:
    component ``g`` has a prior)."""
    m = len(P.prior_mean)
    for g in range(m):
        box.has[g] = not P.ridge[g]
        box.lo[g] = P.prior_mean[g] - P.half[g]
        box.hi[g] = P.prior_mean[g] + P.half[g]


@njit(**_INLINE)
def _sample_bounds(P, k, lp):
    """``lp.L, lp.U``: the bounds of ``tau = J^T F`` at sample ``k`` [N·m]; False if one is
    infinite."""
    m = len(lp.L)
    kk = P.k
    finite = True
    for j in range(m):
        lp.L[j] = P.tau_bar[k, j] - P.tau_max[k, j] - kk * P.sigma[k, j]
        lp.U[j] = P.tau_bar[k, j] - P.tau_min[k, j] + kk * P.sigma[k, j]
        finite = finite and math.isfinite(lp.L[j]) and math.isfinite(lp.U[j])
    return finite


@njit(**_INLINE)
def _box_reach(P, lp):
    """``lp.rn``: the 1-norms of the rows of ``B``. True when a vertex of the torque box reaches
    the artificial box (where the general kernel reports an infinite bound):
    ``|B_g (tau - mid)| + |B_g mid - prior_mean_g| >= big`` for some ``g``."""
    m = len(lp.L)
    B, L, U, rn = lp.B, lp.L, lp.U, lp.rn
    far = False
    for g in range(m):
        c = 0.0
        r = 0.0
        rn[g] = 1e-300
        for j in range(m):
            c += B[g, j] * 0.5 * (L[j] + U[j])
            r += abs(B[g, j]) * 0.5 * (U[j] - L[j])
            rn[g] += abs(B[g, j])
        if not abs(c - P.prior_mean[g]) + r < P.big:
            far = True
    return far


@njit(**_INLINE)
def _torque_box_bounds(lp, k, out):
    """``out.lo[k], out.hi[k]``: ``min / max B_i tau`` over the torque box ``L <= tau <= U``
    alone (each at the bound vertex its row prefers), the bounds of a sample whose polytope is
    empty with the prior box (status 6)."""
    m = len(lp.L)
    B, L, U = lp.B, lp.L, lp.U
    for i in range(m):
        lo = 0.0
        hi = 0.0
        for j in range(m):
            if B[i, j] >= 0.0:
                lo += B[i, j] * L[j]
                hi += B[i, j] * U[j]
            else:
                lo += B[i, j] * U[j]
                hi += B[i, j] * L[j]
        out.lo[k, i] = lo
        out.hi[k, i] = hi


# ------------------------------------------------------------------ one sample at a time


@njit(**_INLINE)
def _solve_sample(lp, box, S, work, maxit, k, out):
    """The ``2m`` LPs of sample ``k`` in turn; returns its status: 5 solved, 6 empty with the
    prior box (the torque box's bounds instead), -1 an LP gave up."""
    m = len(lp.L)
    for o in range(2 * m):
        st, val = _solve_lp(lp, box, S, o, work, maxit)
        if st == 2:
            return -1
        if st == 1:  # empty with the prior box: the torque box alone
            _torque_box_bounds(lp, k, out)
            for q in range(2 * m):
                S.warm[q] = False
            return 6
        if o % 2 == 0:
            out.lo[k, o // 2] = val
        else:
            out.hi[k, o // 2] = val
    return 5


@njit(cache=True, _nrt=False)
def _square_block(P, S, out, lp, box, work):
    """:func:`square_block` one sample at a time, on scratch allocated by it (``lp``, ``box``,
    ``work``)."""
    N, m = P.tau_bar.shape
    maxit = 4 * m + 8
    _fill_prior_box(P, box)
    for k in range(N):
        out.status[k] = -1
        if not _sample_bounds(P, k, lp) or not _inverse_t(P.J, k, m, lp.B, work.M):
            continue
        if _box_reach(P, lp):
            continue
        out.status[k] = _solve_sample(lp, box, S, work, maxit, k, out)


# ------------------------------------------------------------------ lockstep, by blocks


@njit(cache=True, _nrt=False)
def _pivot_order(Bs, q, S, o, work):
    """The free variables ``work.free`` and held rows ``work.held`` of LP ``o``'s working set,
    ``held`` in the order partial pivoting takes them at sample ``q`` of the block; returns ``t``
    (-1: the working set is not square or ``K`` is singular there)."""
    m = Bs.shape[0]
    sxs, srs = S.var_side, S.row_side
    K, p, fr, tr = work.K, work.perm, work.free, work.held
    t = 0
    ta = 0
    for j in range(m):
        if sxs[o, j] == 0:
            fr[t] = j
            t += 1
        if srs[o, j] != 0:
            tr[ta] = j
            ta += 1
    if ta != t:
        return -1
    for a in range(t):
        for b in range(t):
            K[a, b] = Bs[tr[a], fr[b], q]
    if not _lu(K, t, p):
        return -1
    for a in range(t):
        p[a] = tr[p[a]]
    for a in range(t):
        tr[a] = p[a]
    return t


@njit(**_INLINE)
def _block_pivots(P, k0, work):
    """``work.perm``: the row order partial pivoting takes for ``J^T`` at sample ``k0`` (the
    identity when it is singular)."""
    m = P.J.shape[1]
    K, p = work.K, work.perm
    for j in range(m):
        for g in range(m):
            K[j, g] = P.J[k0, g, j]
    if not _lu(K, m, p):
        for j in range(m):
            p[j] = j


@njit(**_INLINE)
def _load_sample(blk, q, lp):
    """Sample ``q`` of the block into ``lp`` (its bounds, ``J^-T`` and row norms)."""
    m = len(lp.L)
    for g in range(m):
        lp.L[g] = blk.Ls[g, q]
        lp.U[g] = blk.Us[g, q]
        lp.rn[g] = blk.rns[g, q]
        for j in range(m):
            lp.B[g, j] = blk.Bs[g, j, q]


@njit(**_INLINE)
def _sample_fallback(P, k, q, lp, work, blk):
    """Sample ``k`` (``q``-th of the block) where the lockstep inverse does not hold: its bounds
    and ``J^-T`` by the per-sample code, into the block; ``blk.ok[q]`` whether the torque
    coordinates take it."""
    m = len(lp.L)
    finite = _sample_bounds(P, k, lp)
    for j in range(m):
        blk.Ls[j, q] = lp.L[j]
        blk.Us[j, q] = lp.U[j]
    blk.ok[q] = finite and _inverse_t(P.J, k, m, lp.B, work.M)
    if not blk.ok[q]:
        return
    far = _box_reach(P, lp)
    for g in range(m):
        blk.rns[g, q] = lp.rn[g]
        for j in range(m):
            blk.Bs[g, j, q] = lp.B[g, j]
    if far:
        blk.ok[q] = False  # a vertex reaches the artificial box: the general kernel


@njit(**_INLINE)
def _block_setup(P, k0, nb, lp, work, blk):
    """The block's bounds, ``J^-T`` and row norms: in lockstep in the pivot order of its first
    sample, per sample where that order does not fit."""
    _block_pivots(P, k0, work)
    lockstep_inverse(P, MAX_CONDITION, k0, nb, work.perm, blk)
    for q in range(nb):
        blk.bad[q] = False
        blk.empty[q] = False
        blk.ok[q] = blk.okv[q] != 0.0
        if not blk.ok[q]:
            _sample_fallback(P, k0 + q, q, lp, work, blk)


@njit(**_INLINE)
def _block_lp(box, S, o, nb, lp, work, blk, maxit):
    """LP ``o`` at every sample of the block the torque coordinates take: a lockstep pass with
    the current working set over the samples left (at most :data:`PASSES`, each after a solve
    found a new optimum), and the per-sample dual simplex at the first sample a pass leaves
    unsolved; its optimum is the next pass's working set. ``blk.vals[o]`` the values."""
    todo, done = blk.todo, blk.done
    for q in range(nb):
        todo[q] = blk.ok[q] and not blk.bad[q] and not blk.empty[q]
        done[q] = False
    passes = 0
    fresh = S.warm[o]  # a working set not yet tried by a lockstep pass
    q = 0
    while True:
        while q < nb and not (todo[q] and not done[q]):
            q += 1
        if q >= nb:
            break
        if fresh and passes < PASSES:
            passes += 1
            fresh = False
            t = _pivot_order(blk.Bs, q, S, o, work)
            q1 = nb  # up to the last sample left (a pass costs its whole range)
            while not (todo[q1 - 1] and not done[q1 - 1]):
                q1 -= 1
            if t >= 0:
                lockstep_verify(blk, box, S, o, work, t, q, q1)
                if done[q]:
                    continue
        _load_sample(blk, q, lp)
        st, val = _solve_lp(lp, box, S, o, work, maxit)
        fresh = st == 0
        if st == 2:
            blk.bad[q] = True
        elif st == 1:
            blk.empty[q] = True
        blk.vals[o, q] = val
        done[q] = True
        q += 1


@njit(**_INLINE)
def _block_results(k0, nb, out, lp, blk):
    """The block's bounds and statuses: 5 solved, 6 empty with the prior box (the torque box's
    bounds), -1 not taken."""
    m = len(lp.L)
    for q in range(nb):
        k = k0 + q
        if not blk.ok[q] or blk.bad[q]:
            out.status[k] = -1
        elif blk.empty[q]:  # empty with the prior box: the torque box alone
            out.status[k] = 6
            _load_sample(blk, q, lp)
            _torque_box_bounds(lp, k, out)
        else:
            out.status[k] = 5
            for i in range(m):
                out.lo[k, i] = blk.vals[2 * i, q]
                out.hi[k, i] = blk.vals[2 * i + 1, q]


@njit(cache=True, _nrt=False)
def _square_lockstep(P, S, out, lp, box, work, blk):
    """:func:`square_block` by blocks of :data:`BLOCK` samples: ``J^-T`` of every sample of the
    block, then each LP by lockstep passes and per-sample solves (:func:`_block_lp`)."""
    N, m = P.tau_bar.shape
    maxit = 4 * m + 8
    _fill_prior_box(P, box)
    for k0 in range(0, N, BLOCK):
        nb = min(BLOCK, N - k0)
        _block_setup(P, k0, nb, lp, work, blk)
        for o in range(2 * m):
            _block_lp(box, S, o, nb, lp, work, blk, maxit)
        _block_results(k0, nb, out, lp, blk)


@njit(cache=True)
def square_block(P, S, out, lockstep=True):
    """The ``2m`` set-membership LPs of every sample of a run in torque coordinates (module
    docstring), where this path can take them.

    Parameters
    ----------
    P : :class:`~.sm_arrays.SMProblem`
        The run of samples, ``m = n`` (the bounds of ``J^T F`` are ``tau_bar - tau_max - k sigma
        <= J^T F <= tau_bar - tau_min + k sigma`` [N·m]).
    S : :class:`~.sm_arrays.SquareState`
        The warm-start state (:func:`~.sm_arrays.square_state`), kept from run to run.
    out : :class:`~.sm_arrays.Bounds`
        Written: ``lo, hi (N, m)`` [N, N·m] and ``status (N,)``: 5 solved with the prior box, 6
        solved without it (empty with it), -1 not taken (an infinite band edge, an
        ill-conditioned ``J``, a bound beyond the artificial box, a singular basis, the
        iteration limit: the general kernel solves the sample).
    lockstep : bool
        False: one sample at a time, the 2m LPs in turn (the reference of the lockstep passes;
        the same optima to rounding).
    """
    m = P.tau_bar.shape[1]
    lp, box, work = sample_lp(m), prior_box(m), lp_work(m)
    if not lockstep:
        _square_block(P, S, out, lp, box, work)
        return
    _square_lockstep(P, S, out, lp, box, work, block_work(m, BLOCK))


__all__ = ["BLOCK", "MAX_CONDITION", "square_block"]

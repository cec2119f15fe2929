"""The set-membership LPs of a sample whose Jacobian is square (as many estimated components as
joints, ``m = n``: the usual six-axis arm estimating the whole wrench), solved in joint-torque
coordinates.

With ``J`` (m x m) invertible, ``tau = J^T F`` is a change of variables: the joint slabs become
bounds on the variables, ``L_j <= tau_j <= U_j``, and the prior box becomes ``m`` ranged rows
``Fl_g <= B_g tau <= Fu_g`` with ``B = J^-T``. Each LP ``min sg F_i = sg B_i tau`` is then a
bounded-variable LP whose basis holds only the box rows that bind (``t`` of them, with ``t`` free
variables): a ``t x t`` system instead of an ``m x m`` one. A dual simplex starts from the vertex
of the bounds alone (always dual feasible: each ``tau_j`` at the bound its cost coefficient
prefers), or from the previous sample's working set when that is still dual feasible, and
brings in violated box rows. One inversion of ``J^T`` per sample serves the ``2m`` LPs.

By default (:func:`square_block`, ``lockstep=True``) the samples go by blocks of :data:`BLOCK`:
the bounds and ``J^-T`` of the whole block in lockstep, then per LP a lockstep pass
(:mod:`.sm_lockstep`) checks the LP's current working set at every sample of the block at once
(primal and dual feasibility of its vertex: optimal there whatever the history), and the
per-sample dual simplex takes the first sample it leaves, whose optimum is the working set of
the next pass. On the estimator bench (a pushed IRB140, 100 000 samples) 99 % of the LPs are
settled by a pass (0.14 per-sample solves per sample, 0.15 passes per sample), 3-4x the
one-sample-at-a-time loop (``lockstep=False``, kept as the reference). Numba's cache does not
follow the calls into :mod:`.sm_lockstep`: after editing that module alone, delete this one's
cache (``__pycache__/sm_square*.nbi/.nbc``) or it runs the old code.

The result is the same LP optimum as the general kernel's (:mod:`.set_membership`): both are
tested against ``scipy.optimize.linprog``. Samples this path cannot take (an infinite band edge,
an ill-conditioned ``J``, a bound beyond the artificial box, a singular basis, the iteration
limit) are left to the general kernel.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.estimator.intervals.sm_lockstep import lockstep_inverse, lockstep_verify

#: Largest ``||J^T||_1 ||J^-T||_1`` the torque-coordinate path accepts (else: the general kernel).
MAX_CONDITION = 1e8


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
    operation runs over whole rows of ``[M | B]``: independent columns, where the column-by-column
    triangular solves were a chain of dependent divisions); False if a pivot is below ``1e-12``
    of the largest entry or the condition is beyond :data:`MAX_CONDITION`."""
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


@njit(cache=True, inline="always", _nrt=False)
def _lp(
    B, rn, L, U, Fl, Fu, box, i, sg, m, sxs, srs, o, K, p, fr, tr, tau, nu, ua, rhs, w, warm, maxit
):
    """``min sg B_i tau`` over ``L <= tau <= U`` and ``Fl_g <= B_g tau <= Fu_g`` (``box[g]``).

    The working set is row ``o`` of ``sxs`` (2m, m): -1 / +1 a variable at its lower / upper
    bound, 0 free; and of ``srs``: -1 / +1 a box row held at ``Fl`` / ``Fu``, 0 not held; updated
    in place (rows, not views: a view per LP cost a fifth of the time in reference counts). A
    ``warm`` start must be dual feasible (else status 2). The most violated row or bound enters,
    then (after ``m`` iterations) Bland's rule, which cannot cycle. Returns ``(status, value)``:
    0 optimal (the value ``B_i tau``), 1 the polytope is empty, 2 gave up (inconsistent or
    singular working set, not dual feasible, iteration limit).
    """
    cn = 0.0
    for j in range(m):
        cn = max(cn, abs(B[i, j]))
    for it in range(maxit):
        t = 0
        for j in range(m):
            if sxs[o, j] == 0:
                fr[t] = j
                t += 1
            elif sxs[o, j] < 0:
                tau[j] = L[j]
            else:
                tau[j] = U[j]
        ta = 0
        for g in range(m):
            if srs[o, g] != 0:
                tr[ta] = g
                ta += 1
        if ta != t:
            return 2, 0.0
        # the free variables: the held rows at their bounds, K tau_free = d - B_T,fixed tau_fixed
        for a in range(t):
            g = tr[a]
            v = Fu[g] if srs[o, g] > 0 else Fl[g]
            for j in range(m):
                if sxs[o, j] != 0:
                    v -= B[g, j] * tau[j]
            rhs[a] = v
            for b in range(t):
                K[a, b] = B[g, fr[b]]
        if not _lu(K, t, p):
            return 2, 0.0
        _lu_solve(K, t, p, rhs, ua)
        for b in range(t):
            tau[fr[b]] = ua[b]
        # multipliers: K^T nu = c_free; a fixed variable's is c_j - sum_a nu_a B[tr_a, j]. A
        # warm start whose working set holds the objective's own row on the side the objective
        # pushes to is dual feasible as it stands (nu = sg e_i, every other multiplier zero):
        # the multipliers are then only needed if the vertex is not primal feasible
        have_nu = False
        if it == 0 and warm and srs[o, i] == (-1 if sg > 0 else 1):
            pass
        else:
            for b in range(t):
                rhs[b] = sg * B[i, fr[b]]
            _lu_solve_t(K, t, p, rhs, w, nu)
            have_nu = True
        if it == 0 and warm and have_nu:
            for a in range(t):
                if srs[o, tr[a]] * nu[a] > 1e-10 * cn:
                    return 2, 0.0
            for j in range(m):
                if sxs[o, j] != 0:
                    mu = sg * B[i, j]
                    for a in range(t):
                        mu -= nu[a] * B[tr[a], j]
                    if sxs[o, j] * mu > 1e-10 * cn:
                        return 2, 0.0
        # the most violated bound or row enters (violation in its own units over the row norm);
        # after ``m`` iterations Bland's rule (the first violated row, then variable, in index
        # order; ties of the ratio test to the first in the same order): with the objective's own
        # row held every other multiplier is zero and the largest-violation rule can cycle
        bland = it >= m
        worst = 0.0
        ent = -1
        es = 0
        for g in range(m):
            if not box[g] or srs[o, g] != 0:
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
        if ent < 0:
            val = 0.0
            for j in range(m):
                val += B[i, j] * tau[j]
            return 0, val
        if not have_nu:
            for b in range(t):
                rhs[b] = sg * B[i, fr[b]]
            _lu_solve_t(K, t, p, rhs, w, nu)
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
        _lu_solve_t(K, t, p, rhs, w, ua)
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
        if leave < 0:
            return 1, 0.0  # no multiplier can take the violated row: the polytope is empty
        if leave < m:
            sxs[o, leave] = 0
        else:
            srs[o, leave - m] = 0
        if ent < m:
            sxs[o, ent] = es
        else:
            srs[o, ent - m] = es
    return 2, 0.0


@njit(cache=True, inline="always", _nrt=False)
def _prior_box(fb, half, ridge, m, box, Fl, Fu):
    """The prior box's rows ``Fl <= B_g tau <= Fu`` = ``fb -+ half`` (``box[g]``: component
    ``g`` has a prior)."""
    for g in range(m):
        box[g] = not ridge[g]
        Fl[g] = fb[g] - half[g]
        Fu[g] = fb[g] + half[g]


@njit(cache=True, inline="always", _nrt=False)
def _torque_box_bounds(B, L, U, m, k, lo_out, hi_out):
    """``lo_out[k], hi_out[k]``: ``min / max B_i tau`` over the torque box ``L <= tau <= U``
    alone (each at the bound vertex its row prefers), the bounds of a sample whose polytope is
    empty with the prior box (status 6)."""
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
        lo_out[k, i] = lo
        hi_out[k, i] = hi


@njit(cache=True, inline="always", _nrt=False)
def _cold(B, i, sg, m, sxs, srs, o):
    """The vertex of the bounds alone: each variable at the bound its cost prefers."""
    for j in range(m):
        sxs[o, j] = -1 if sg * B[i, j] >= 0.0 else 1
        srs[o, j] = 0


@njit(cache=True, _nrt=False)
def _square_block(
    tb, J, a, b, sig, kk, fb, half, ridge, big, sxs, srs, warm, lo_out, hi_out, st_out,
    B, M, K, L, U, Fl, Fu, box, p, fr, tr, tau, nu, ua, rhs, w, rn,
):  # fmt: skip
    """:func:`square_block` on scratch allocated by it, compiled without numba's reference
    counts (``_nrt=False``: no array is created here, and the inlined helpers' array arguments
    no longer cost an atomic increment and decrement each: 3.45 -> 2.44 us a sample on the
    bench's data)."""
    N, m = tb.shape
    maxit = 4 * m + 8
    _prior_box(fb, half, ridge, m, box, Fl, Fu)
    for k in range(N):
        st_out[k] = -1
        finite = True
        for j in range(m):
            L[j] = tb[k, j] - b[k, j] - kk * sig[k, j]
            U[j] = tb[k, j] - a[k, j] + kk * sig[k, j]
            finite = finite and math.isfinite(L[j]) and math.isfinite(U[j])
        if not finite or not _inverse_t(J, k, m, B, M):
            continue
        # no vertex of the torque box may reach the artificial box (where the general kernel
        # would report an infinite bound): |B_g (tau - mid)| + |B_g mid - fb_g| < big
        far = False
        for g in range(m):
            c = 0.0
            r = 0.0
            rn[g] = 1e-300
            for j in range(m):
                c += B[g, j] * 0.5 * (L[j] + U[j])
                r += abs(B[g, j]) * 0.5 * (U[j] - L[j])
                rn[g] += abs(B[g, j])
            if not abs(c - fb[g]) + r < big:
                far = True
        if far:
            continue
        status = 5
        for o in range(2 * m):
            i = o // 2
            sg = 1.0 if o % 2 == 0 else -1.0
            st = 2
            val = 0.0
            if warm[o]:
                st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sxs, srs, o, K, p, fr, tr, tau,
                              nu, ua, rhs, w, True, maxit)  # fmt: skip
            if st == 2:
                _cold(B, i, sg, m, sxs, srs, o)
                st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sxs, srs, o, K, p, fr, tr, tau,
                              nu, ua, rhs, w, False, maxit)  # fmt: skip
            warm[o] = st == 0
            if st == 2:
                status = -1
                break
            if st == 1:
                status = 6
                break
            if sg > 0:
                lo_out[k, i] = val
            else:
                hi_out[k, i] = val
        if status == 6:  # empty with the prior box: the torque box alone
            _torque_box_bounds(B, L, U, m, k, lo_out, hi_out)
            for o in range(2 * m):
                warm[o] = False
        st_out[k] = status


#: Samples per lockstep block (the structure-of-arrays scratch: about 40 kB per ``m x m`` array).
BLOCK = 128
#: Lockstep passes per LP and block (each with the working set of the last solved sample).
PASSES = 4


@njit(cache=True, _nrt=False)
def _pivot_order(Bs, q, sxs, srs, o, m, K, p, fr, tr):
    """The free variables ``fr`` and held rows ``tr`` of LP ``o``'s working set, ``tr`` in the
    order partial pivoting takes them at sample ``q``; returns ``t`` (-1: the working set is not
    square or ``K`` is singular there)."""
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


@njit(cache=True, _nrt=False)
def _square_lockstep(
    tb, J, a, b, sig, kk, fb, half, ridge, big, sxs, srs, warm, lo_out, hi_out, st_out,
    B, M, K, L, U, Fl, Fu, box, p, fr, tr, tau, nu, ua, rhs, w, rn,
    Bs, Ls, Us, rns, ok, bad, emp, todo, done, vals, Kl, rh, taul, nul, okv, cnv, fq,
):  # fmt: skip
    """:func:`square_block` by blocks of :data:`BLOCK` samples: ``J^-T`` of every sample of the
    block, then per LP lockstep passes (:func:`.sm_lockstep.lockstep_verify`) with the LP's
    current working set over the samples not yet solved, and the per-sample dual simplex
    (:func:`_lp`, warm from that working set, else cold) at the first sample a pass leaves
    unsolved; its optimum is the next pass's working set."""
    N, m = tb.shape
    maxit = 4 * m + 8
    _prior_box(fb, half, ridge, m, box, Fl, Fu)
    for k0 in range(0, N, BLOCK):
        nb = min(BLOCK, N - k0)
        # the row order partial pivoting takes for J^T at the block's first sample, then every
        # sample's bounds and J^-T in lockstep with that order; per sample where it does not fit
        for j in range(m):
            for g in range(m):
                K[j, g] = J[k0, g, j]
        if not _lu(K, m, p):
            for j in range(m):
                p[j] = j
        lockstep_inverse(tb, J, a, b, sig, kk, fb, big, MAX_CONDITION, k0, nb, m, p, Ls, Us, Bs,
                         rns, okv, Kl, cnv, fq)  # fmt: skip
        for q in range(nb):
            bad[q] = False
            emp[q] = False
            ok[q] = okv[q] != 0.0
            if ok[q]:
                continue
            k = k0 + q
            finite = True
            for j in range(m):
                Ls[j, q] = tb[k, j] - b[k, j] - kk * sig[k, j]
                Us[j, q] = tb[k, j] - a[k, j] + kk * sig[k, j]
                finite = finite and math.isfinite(Ls[j, q]) and math.isfinite(Us[j, q])
            ok[q] = finite and _inverse_t(J, k, m, B, M)
            if not ok[q]:
                continue
            for g in range(m):
                c = 0.0
                r = 0.0
                v = 1e-300
                for j in range(m):
                    Bs[g, j, q] = B[g, j]
                    c += B[g, j] * 0.5 * (Ls[j, q] + Us[j, q])
                    r += abs(B[g, j]) * 0.5 * (Us[j, q] - Ls[j, q])
                    v += abs(B[g, j])
                rns[g, q] = v
                if not abs(c - fb[g]) + r < big:
                    ok[q] = False  # a vertex reaches the artificial box: the general kernel
        for o in range(2 * m):
            i = o // 2
            sg = 1.0 if o % 2 == 0 else -1.0
            for q in range(nb):
                todo[q] = ok[q] and not bad[q] and not emp[q]
                done[q] = False
            passes = 0
            fresh = warm[o]  # a working set not yet tried by a lockstep pass
            q = 0
            while True:
                while q < nb and not (todo[q] and not done[q]):
                    q += 1
                if q >= nb:
                    break
                if fresh and passes < PASSES:
                    passes += 1
                    fresh = False
                    t = _pivot_order(Bs, q, sxs, srs, o, m, K, p, fr, tr)
                    q1 = nb  # up to the last sample left (a pass costs its whole range)
                    while not (todo[q1 - 1] and not done[q1 - 1]):
                        q1 -= 1
                    if t >= 0:
                        lockstep_verify(Bs, Ls, Us, Fl, Fu, box, i, sg, m, sxs, srs, fr, tr, t,
                                        q, q1, todo, done, vals, o, Kl, rh, taul, nul, okv,
                                        cnv, fq)  # fmt: skip
                        if done[q]:
                            continue
                # the per-sample dual simplex at sample q
                for g in range(m):
                    L[g] = Ls[g, q]
                    U[g] = Us[g, q]
                    rn[g] = rns[g, q]
                    for j in range(m):
                        B[g, j] = Bs[g, j, q]
                st = 2
                val = 0.0
                if warm[o]:
                    st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sxs, srs, o, K, p, fr, tr,
                                  tau, nu, ua, rhs, w, True, maxit)  # fmt: skip
                if st == 2:
                    _cold(B, i, sg, m, sxs, srs, o)
                    st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sxs, srs, o, K, p, fr, tr,
                                  tau, nu, ua, rhs, w, False, maxit)  # fmt: skip
                warm[o] = st == 0
                fresh = st == 0
                if st == 2:
                    bad[q] = True
                elif st == 1:
                    emp[q] = True
                vals[o, q] = val
                done[q] = True
                q += 1
        for q in range(nb):
            k = k0 + q
            if not ok[q] or bad[q]:
                st_out[k] = -1
            elif emp[q]:  # empty with the prior box: the torque box alone
                st_out[k] = 6
                for g in range(m):
                    L[g] = Ls[g, q]
                    U[g] = Us[g, q]
                    for j in range(m):
                        B[g, j] = Bs[g, j, q]
                _torque_box_bounds(B, L, U, m, k, lo_out, hi_out)
            else:
                st_out[k] = 5
                for i in range(m):
                    lo_out[k, i] = vals[2 * i, q]
                    hi_out[k, i] = vals[2 * i + 1, q]


@njit(cache=True)
def square_block(
    tb, J, a, b, sig, kk, fb, half, ridge, big, S, lo_out, hi_out, st_out, lockstep=True
):  # fmt: skip
    """The ``2m`` set-membership LPs of every sample of a block in torque coordinates (module
    docstring), where this path can take them.

    ``tb (N, m)``, ``J (N, m, m)``, ``a, b, sig (N, m)`` [N·m] as the general kernel's; the
    bounds of ``J^T F`` are ``tb - b - kk sig <= J^T F <= tb - a + kk sig``; ``fb, half (m,)``
    the prior box ``fb +- half`` [N, N·m] of the components with a prior (``ridge`` False);
    ``big`` the general kernel's artificial box half-width; ``S`` the warm-start state of
    :func:`square_state` (kept from block to block). Writes ``lo_out, hi_out (N, m)`` and
    ``st_out (N,)``: 5 solved with the prior box, 6 solved without it (empty with it), -1 not
    taken (an infinite band edge, an ill-conditioned ``J``, a bound beyond the artificial box, a
    singular basis, the iteration limit: the general kernel solves the sample).
    ``lockstep=False``: one sample at a time, the 2m LPs in turn (the reference of the lockstep
    passes; the same optima to rounding).
    """
    N, m = tb.shape
    sxs, srs, warm = S
    B = np.empty((m, m))
    M = np.empty((m, m))
    K = np.empty((m, m))
    L = np.empty(m)
    U = np.empty(m)
    Fl = np.empty(m)
    Fu = np.empty(m)
    box = np.empty(m, np.bool_)
    p = np.empty(m, np.int64)
    fr = np.empty(m, np.int64)
    tr = np.empty(m, np.int64)
    tau = np.empty(m)
    nu = np.empty(m)
    ua = np.empty(m)
    rhs = np.empty(m)
    w = np.empty(m)
    rn = np.empty(m)
    if not lockstep:
        _square_block(
            tb, J, a, b, sig, kk, fb, half, ridge, big, sxs, srs, warm, lo_out, hi_out, st_out,
            B, M, K, L, U, Fl, Fu, box, p, fr, tr, tau, nu, ua, rhs, w, rn,
        )  # fmt: skip
        return
    W = BLOCK
    _square_lockstep(
        tb, J, a, b, sig, kk, fb, half, ridge, big, sxs, srs, warm, lo_out, hi_out, st_out,
        B, M, K, L, U, Fl, Fu, box, p, fr, tr, tau, nu, ua, rhs, w, rn,
        np.empty((m, m, W)), np.empty((m, W)), np.empty((m, W)), np.empty((m, W)),
        np.empty(W, np.bool_), np.empty(W, np.bool_), np.empty(W, np.bool_),
        np.empty(W, np.bool_), np.empty(W, np.bool_), np.empty((2 * m, W)),
        np.empty((m, m, W)), np.empty((m, W)), np.empty((m, W)), np.empty((m, W)),
        np.empty(W), np.empty(W), np.empty(W),
    )  # fmt: skip


def square_state(m: int) -> tuple:
    """The warm-start state of :func:`square_block` for ``m`` components: each LP's working set
    (variables' and rows' sides) and whether it is the previous sample's optimum."""
    return (
        np.zeros((2 * m, m), np.int8),  # variables' sides per LP
        np.zeros((2 * m, m), np.int8),  # rows' sides per LP
        np.zeros(2 * m, np.bool_),  # the working set is from the previous sample's optimum
    )


__all__ = ["MAX_CONDITION", "square_block", "square_state"]

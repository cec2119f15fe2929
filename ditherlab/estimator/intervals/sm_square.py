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

The result is the same LP optimum as the general kernel's (:mod:`.set_membership`): both are
tested against ``scipy.optimize.linprog``. Samples this path cannot take (an infinite band edge,
an ill-conditioned ``J``, a bound beyond the artificial box, a singular basis, the iteration
limit) are left to the general kernel.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Largest ``||J^T||_1 ||J^-T||_1`` the torque-coordinate path accepts (else: the general kernel).
MAX_CONDITION = 1e8


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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


@njit(cache=True)
def _inverse_t(Jk, m, B, M, p, col, w):
    """``B = (Jk^T)^-1`` (m x m); False if singular or ill-conditioned (:data:`MAX_CONDITION`)."""
    nj = 0.0
    for j in range(m):
        v = 0.0
        for i in range(m):
            M[j, i] = Jk[i, j]
            v += abs(Jk[i, j])
        nj = max(nj, v)  # ||J^T||_1: the largest column sum of J^T (row j of J^T is J[:, j])
    if not _lu(M, m, p):
        return False
    nb = 0.0
    for c in range(m):
        for a in range(m):
            w[a] = 1.0 if a == c else 0.0
        _lu_solve(M, m, p, w, col)
        v = 0.0
        for r in range(m):
            B[r, c] = col[r]
            v += abs(col[r])
        nb = max(nb, v)  # ||J^-T||_1
    return nb * nj <= MAX_CONDITION


@njit(cache=True, inline="always")
def _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sx, sr, K, p, fr, tr, tau, nu, ua, rhs, w, warm, maxit):
    """``min sg B_i tau`` over ``L <= tau <= U`` and ``Fl_g <= B_g tau <= Fu_g`` (``box[g]``).

    The working set is ``sx`` (m,): -1 / +1 a variable at its lower / upper bound, 0 free; and
    ``sr`` (m,): -1 / +1 a box row held at ``Fl`` / ``Fu``, 0 not held; updated in place. A
    ``warm`` start must be dual feasible (else status 2). Returns ``(status, value)``: 0 optimal
    (the value ``B_i tau``), 1 the polytope is empty, 2 gave up (inconsistent or singular
    working set, not dual feasible, iteration limit).
    """
    cn = 0.0
    for j in range(m):
        cn = max(cn, abs(B[i, j]))
    for it in range(maxit):
        t = 0
        for j in range(m):
            if sx[j] == 0:
                fr[t] = j
                t += 1
            elif sx[j] < 0:
                tau[j] = L[j]
            else:
                tau[j] = U[j]
        ta = 0
        for g in range(m):
            if sr[g] != 0:
                tr[ta] = g
                ta += 1
        if ta != t:
            return 2, 0.0
        # the free variables: the held rows at their bounds, K tau_free = d - B_T,fixed tau_fixed
        for a in range(t):
            g = tr[a]
            v = Fu[g] if sr[g] > 0 else Fl[g]
            for j in range(m):
                if sx[j] != 0:
                    v -= B[g, j] * tau[j]
            rhs[a] = v
            for b in range(t):
                K[a, b] = B[g, fr[b]]
        if not _lu(K, t, p):
            return 2, 0.0
        _lu_solve(K, t, p, rhs, ua)
        for b in range(t):
            tau[fr[b]] = ua[b]
        # multipliers: K^T nu = c_free; a fixed variable's is c_j - sum_a nu_a B[tr_a, j]
        for b in range(t):
            rhs[b] = sg * B[i, fr[b]]
        _lu_solve_t(K, t, p, rhs, w, nu)
        if it == 0 and warm:
            for a in range(t):
                if sr[tr[a]] * nu[a] > 1e-10 * cn:
                    return 2, 0.0
            for j in range(m):
                if sx[j] != 0:
                    mu = sg * B[i, j]
                    for a in range(t):
                        mu -= nu[a] * B[tr[a], j]
                    if sx[j] * mu > 1e-10 * cn:
                        return 2, 0.0
        # the most violated bound or row enters (violation in its own units over the row norm)
        worst = 0.0
        ent = -1
        es = 0
        for b in range(t):
            j = fr[b]
            if tau[j] < L[j] - 1e-9 * (1.0 + abs(L[j])):
                v, s = L[j] - tau[j], -1
            elif tau[j] > U[j] + 1e-9 * (1.0 + abs(U[j])):
                v, s = tau[j] - U[j], 1
            else:
                continue
            if v > worst:
                worst, ent, es = v, j, s
        for g in range(m):
            if not box[g] or sr[g] != 0:
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
        if ent < 0:
            val = 0.0
            for j in range(m):
                val += B[i, j] * tau[j]
            return 0, val
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
            sw = sr[tr[a]]
            q = sw * es * ua[a]
            if q > 1e-11 * an:
                th = max(-sw * nu[a], 0.0) / q
                if th < theta:
                    theta, leave = th, m + tr[a]
        for j in range(m):  # fixed variables
            if sx[j] == 0:
                continue
            uj = 0.0 if ent < m else B[ent - m, j]
            mu = sg * B[i, j]
            for a in range(t):
                uj -= ua[a] * B[tr[a], j]
                mu -= nu[a] * B[tr[a], j]
            q = sx[j] * es * uj
            if q > 1e-11 * an:
                th = max(-sx[j] * mu, 0.0) / q
                if th < theta:
                    theta, leave = th, j
        if leave < 0:
            return 1, 0.0  # no multiplier can take the violated row: the polytope is empty
        if leave < m:
            sx[leave] = 0
        else:
            sr[leave - m] = 0
        if ent < m:
            sx[ent] = es
        else:
            sr[ent - m] = es
    return 2, 0.0


@njit(cache=True, inline="always")
def _cold(B, i, sg, m, sx, sr):
    """The vertex of the bounds alone: each variable at the bound its cost prefers."""
    for j in range(m):
        sx[j] = -1 if sg * B[i, j] >= 0.0 else 1
        sr[j] = 0


@njit(cache=True)
def square_sample(Jk, L, U, fb, half, ridge, big, S, lo, hi):
    """The ``2m`` set-membership LPs of one sample in torque coordinates (module docstring).

    ``Jk (m, m)``; ``L, U (m,)`` [N·m] the bounds of ``J^T F`` (finite); ``fb, half (m,)`` the
    prior box ``fb +- half`` [N, N·m] of the components with a prior (``ridge`` False); ``big``
    the general kernel's artificial box half-width; ``S`` the scratch and warm-start state of
    :func:`square_state`. Writes ``lo, hi (m,)``. Returns 0 solved with the prior box, 1 solved
    without it (empty with it), -1 not taken (the general kernel solves the sample).
    """
    m = Jk.shape[0]
    B, M, K, Fl, Fu, sxs, srs, warm, ints, vecs, box = S
    rn = vecs[5]
    p, fr, tr = ints[0], ints[1], ints[2]
    tau, nu, ua, rhs, w = vecs[0], vecs[1], vecs[2], vecs[3], vecs[4]
    if not _inverse_t(Jk, m, B, M, p, nu, w):
        return -1
    # no vertex of the torque box may reach the artificial box (where the general kernel would
    # report an infinite bound): |B_g (tau - mid)| + |B_g mid - fb_g| < big
    for g in range(m):
        c = 0.0
        r = 0.0
        rn[g] = 1e-300
        for j in range(m):
            c += B[g, j] * 0.5 * (L[j] + U[j])
            r += abs(B[g, j]) * 0.5 * (U[j] - L[j])
            rn[g] += abs(B[g, j])
        if not abs(c - fb[g]) + r < big:
            return -1
        box[g] = not ridge[g]
        Fl[g] = fb[g] - half[g]
        Fu[g] = fb[g] + half[g]
    maxit = 4 * m + 8
    status = 0
    for o in range(2 * m):
        i = o // 2
        sg = 1.0 if o % 2 == 0 else -1.0
        sx, sr = sxs[o], srs[o]
        st = 2
        if warm[o]:
            st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sx, sr, K, p, fr, tr, tau, nu, ua,
                          rhs, w, True, maxit)  # fmt: skip
        if st == 2:
            _cold(B, i, sg, m, sx, sr)
            st, val = _lp(B, rn, L, U, Fl, Fu, box, i, sg, m, sx, sr, K, p, fr, tr, tau, nu, ua,
                          rhs, w, False, maxit)  # fmt: skip
        warm[o] = st == 0
        if st == 2:
            return -1
        if st == 1:
            status = 1
            break
        if sg > 0:
            lo[i] = val
        else:
            hi[i] = val
    if status == 1:  # empty with the prior box: the torque box alone (each bound's vertex)
        for i in range(m):
            a = 0.0
            b = 0.0
            for j in range(m):
                if B[i, j] >= 0.0:
                    a += B[i, j] * L[j]
                    b += B[i, j] * U[j]
                else:
                    a += B[i, j] * U[j]
                    b += B[i, j] * L[j]
            lo[i] = a
            hi[i] = b
        for o in range(2 * m):
            warm[o] = False
    return status


def square_state(m: int) -> tuple:
    """Scratch arrays and warm-start working sets of :func:`square_sample` for ``m``
    components."""
    return (
        np.empty((m, m)),  # B = J^-T
        np.empty((m, m)),  # LU of J^T
        np.empty((m, m)),  # LU of the held rows' block
        np.empty(m),  # Fl
        np.empty(m),  # Fu
        np.zeros((2 * m, m), np.int8),  # variables' sides per LP
        np.zeros((2 * m, m), np.int8),  # rows' sides per LP
        np.zeros(2 * m, np.bool_),  # the working set is from the previous sample's optimum
        np.empty((3, m), np.int64),
        np.empty((6, m)),
        np.empty(m, np.bool_),  # the rows with a prior box
    )


__all__ = ["MAX_CONDITION", "square_sample", "square_state"]

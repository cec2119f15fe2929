"""One set-membership LP of :mod:`.sm_square` checked for a whole run of samples at once: the
lockstep pass.

An LP's optimal working set (which variables ``tau_j`` sit at which bound, which prior-box rows
``B_g tau`` are held at which side) seldom changes from one sample to the next (on the estimator
bench 0.6-28 % of the samples per LP, 6 % on average), and whether a given working set is optimal
at a sample is a question about that sample alone: its vertex (a ``t x t`` solve) must satisfy
every other row and bound (primal feasibility) and its multipliers must have the right signs
(dual feasibility). A working set that passes both is optimal whatever the history; its value is
the LP's. This module answers that question for one working set over a run of samples with the
samples innermost (structure of arrays, ``(.., W)`` with ``W`` samples): the same arithmetic as
:func:`.sm_square._lp`'s first iteration, without branches that depend on the sample, so that
LLVM vectorises it across samples (AVX2/AVX-512) where the per-sample solver runs one sample's
short dependent loops at a time. The LU has a fixed row order (the caller's: partial pivoting's
order at one sample of the run); a sample whose pivots would not be chosen by partial pivoting
within a factor 2 (or whose ``K`` is numerically singular) is left unsolved for the per-sample
solver, like any sample where the working set is not optimal. :func:`lockstep_inverse` does the
same for the block's ``J^-T`` (Gauss-Jordan in a fixed pivot order).

Numba caches :mod:`.sm_square`'s kernels with these calls compiled in and does not notice when
only this file changes: delete ``__pycache__/sm_square*.nbi/.nbc`` after editing it.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(inline="always", _nrt=False)
def _dot6(Bs, g, v, q):
    """``sum_j Bs[g, j, q] v[j, q]`` for six columns, written out (one pass over the samples
    instead of six; the same additions in the same order as the loop)."""
    return (
        Bs[g, 0, q] * v[0, q] + Bs[g, 1, q] * v[1, q] + Bs[g, 2, q] * v[2, q]
        + Bs[g, 3, q] * v[3, q] + Bs[g, 4, q] * v[4, q] + Bs[g, 5, q] * v[5, q]
    )  # fmt: skip


@njit(cache=True, error_model="numpy", _nrt=False)
def lockstep_verify(
    Bs, Ls, Us, Fl, Fu, box, i, sg, m, sxs, srs, fr, tr, t, q0, q1, todo, done, vals, o,
    K, rh, tau, nu, okv, cnv, fq,
):  # fmt: skip
    """Check LP ``o``'s working set, ``min sg B_i tau`` over ``L <= tau <= U``,
    ``Fl <= B tau <= Fu``, at the samples ``q0 <= q < q1`` with ``todo[q]`` and not ``done[q]``;
    where it is optimal, ``done[q] = True`` and ``vals[o, q] = B_i tau`` (the LP's value).

    ``Bs (m, m, W)`` ``B = J^-T`` per sample [1/m or 1], ``Ls, Us (m, W)`` the torque bounds
    [N·m], ``Fl, Fu (m,)`` the prior box [N, N·m] (rows with ``box[g]`` False are not rows),
    ``sxs[o] (m,)`` -1 / +1 / 0: variable at lower / upper bound / free, ``srs[o] (m,)`` -1 / +1 /
    0: row held at ``Fl`` / ``Fu`` / not held; ``fr (t,)`` the free variables, ``tr (t,)`` the
    held rows in the LU's row order. Scratch: ``K (m, m, W)``, ``rh, tau, nu (m, W)``,
    ``okv, cnv, fq (W,)``. Tolerances are :func:`.sm_square._lp`'s: primal 1e-9 relative, dual
    1e-10 of ``max_j |B_ij|``. Every loop over samples is innermost and free of branches that
    depend on the sample (selects instead), so that it vectorises; it runs over unsigned sample
    indices (numba's wraparound of negative signed indices kept LLVM from vectorising).
    """
    u0 = np.uint64(q0)
    u1 = np.uint64(q1)
    for q in range(u0, u1):
        okv[q] = 1.0 if todo[q] and not done[q] else 0.0
    # the fixed variables at their bounds
    for j in range(m):
        if srs[o, j] != 0 and not box[j]:
            return  # a held row that is not a row: not a working set of this LP
        if sxs[o, j] < 0:
            for q in range(u0, u1):
                tau[j, q] = Ls[j, q]
        elif sxs[o, j] > 0:
            for q in range(u0, u1):
                tau[j, q] = Us[j, q]
    # K tau_free = d - B_T,fixed tau_fixed (rows in the caller's pivot order)
    for q in range(u0, u1):
        cnv[q] = 0.0
    for a in range(t):
        g = tr[a]
        bnd = Fu[g] if srs[o, g] > 0 else Fl[g]
        if m == 6:  # the six-axis arm: one pass (a fixed variable's term, else exactly 0)
            x0, x1, x2 = sxs[o, 0] != 0, sxs[o, 1] != 0, sxs[o, 2] != 0
            x3, x4, x5 = sxs[o, 3] != 0, sxs[o, 4] != 0, sxs[o, 5] != 0
            for q in range(u0, u1):
                v = bnd
                v -= Bs[g, 0, q] * tau[0, q] if x0 else 0.0
                v -= Bs[g, 1, q] * tau[1, q] if x1 else 0.0
                v -= Bs[g, 2, q] * tau[2, q] if x2 else 0.0
                v -= Bs[g, 3, q] * tau[3, q] if x3 else 0.0
                v -= Bs[g, 4, q] * tau[4, q] if x4 else 0.0
                v -= Bs[g, 5, q] * tau[5, q] if x5 else 0.0
                rh[a, q] = v
        else:
            for q in range(u0, u1):
                rh[a, q] = bnd
            for j in range(m):
                if sxs[o, j] != 0:
                    for q in range(u0, u1):
                        rh[a, q] -= Bs[g, j, q] * tau[j, q]
        for b in range(t):
            jb = fr[b]
            for q in range(u0, u1):
                v = Bs[g, jb, q]
                K[a, b, q] = v
                cnv[q] = max(cnv[q], abs(v))
    # LU without row exchanges; each pivot at least half the column's largest candidate
    for c in range(t):
        for q in range(u0, u1):
            d = K[c, c, q]
            sing = not abs(d) > 1e-12 * cnv[q]
            okv[q] = 0.0 if sing else okv[q]
            K[c, c, q] = 1.0 if sing else d
        for r in range(c + 1, t):
            for q in range(u0, u1):
                e = K[r, c, q]
                d = K[c, c, q]
                okv[q] = 0.0 if 2.0 * abs(d) < abs(e) else okv[q]
                K[r, c, q] = e / d
            for b in range(c + 1, t):
                for q in range(u0, u1):
                    K[r, b, q] -= K[r, c, q] * K[c, b, q]
    # forward (unit lower) and back substitution: the free variables
    for a in range(t):
        for b in range(a):
            for q in range(u0, u1):
                rh[a, q] -= K[a, b, q] * rh[b, q]
    for a in range(t - 1, -1, -1):
        for b in range(a + 1, t):
            for q in range(u0, u1):
                rh[a, q] -= K[a, b, q] * rh[b, q]
        j = fr[a]
        for q in range(u0, u1):
            v = rh[a, q] / K[a, a, q]
            rh[a, q] = v
            tau[j, q] = v
    # primal feasibility: the free variables within their bounds, the rows not held in the box
    for a in range(t):
        j = fr[a]
        for q in range(u0, u1):
            lj = Ls[j, q]
            uj = Us[j, q]
            v = tau[j, q]
            out = v < lj - 1e-9 * (1.0 + abs(lj)) or v > uj + 1e-9 * (1.0 + abs(uj))
            okv[q] = 0.0 if out else okv[q]
    for g in range(m):
        if not box[g] or srs[o, g] != 0:
            continue
        lo = Fl[g] - 1e-9 * (1.0 + abs(Fl[g]))
        hi = Fu[g] + 1e-9 * (1.0 + abs(Fu[g]))
        if m == 6:
            for q in range(u0, u1):
                f = _dot6(Bs, g, tau, q)
                okv[q] = 0.0 if f < lo or f > hi else okv[q]
            continue
        for q in range(u0, u1):
            fq[q] = 0.0
        for j in range(m):
            for q in range(u0, u1):
                fq[q] += Bs[g, j, q] * tau[j, q]
        for q in range(u0, u1):
            f = fq[q]
            okv[q] = 0.0 if f < lo or f > hi else okv[q]
    # dual feasibility; with the objective's own row held on the side it pushes to the
    # multipliers are sg e_i (every other one zero): dual feasible as it stands
    if srs[o, i] != (-1 if sg > 0 else 1):
        for q in range(u0, u1):
            cnv[q] = 0.0
        for j in range(m):
            for q in range(u0, u1):
                cnv[q] = max(cnv[q], abs(Bs[i, j, q]))
        # K^T nu = sg B_i,free: U^T y = c, then L^T nu = y
        for a in range(t):
            ja = fr[a]
            for q in range(u0, u1):
                nu[a, q] = sg * Bs[i, ja, q]
            for b in range(a):
                for q in range(u0, u1):
                    nu[a, q] -= K[b, a, q] * nu[b, q]
            for q in range(u0, u1):
                nu[a, q] /= K[a, a, q]
        for a in range(t - 1, -1, -1):
            for b in range(a + 1, t):
                for q in range(u0, u1):
                    nu[a, q] -= K[b, a, q] * nu[b, q]
        for a in range(t):
            s = float(srs[o, tr[a]])
            for q in range(u0, u1):
                okv[q] = 0.0 if s * nu[a, q] > 1e-10 * cnv[q] else okv[q]
        for j in range(m):
            if sxs[o, j] == 0:
                continue
            s = float(sxs[o, j])
            for q in range(u0, u1):
                fq[q] = sg * Bs[i, j, q]
            for a in range(t):
                ga = tr[a]
                for q in range(u0, u1):
                    fq[q] -= nu[a, q] * Bs[ga, j, q]
            for q in range(u0, u1):
                okv[q] = 0.0 if s * fq[q] > 1e-10 * cnv[q] else okv[q]
    if m == 6:
        for q in range(u0, u1):
            fq[q] = _dot6(Bs, i, tau, q)
    else:
        for q in range(u0, u1):
            fq[q] = 0.0
        for j in range(m):
            for q in range(u0, u1):
                fq[q] += Bs[i, j, q] * tau[j, q]
    for q in range(u0, u1):
        if okv[q] != 0.0:
            done[q] = True
            vals[o, q] = fq[q]


@njit(cache=True, error_model="numpy", _nrt=False)
def lockstep_inverse(
    tb, J, a, b, sig, kk, fb, big, max_cond, k0, nb, m, perm, Ls, Us, Bs, rns, okv, Ms, cnv, fq,
):  # fmt: skip
    """The torque bounds, ``B = J^-T`` and the row norms of samples ``k0 .. k0 + nb`` in lockstep
    (samples innermost): ``Ls, Us (m, W)`` [N·m], ``Bs (m, m, W)``, ``rns (m, W)`` the rows'
    1-norms, for the ``q``-th sample of the block; ``okv[q]`` 1.0 where all of it holds and the
    sample is one :func:`.sm_square.square_block` takes (finite bounds, pivots as partial
    pivoting would choose them within a factor 2, ``||J^T||_1 ||J^-T||_1 <= max_cond``, no
    vertex of the torque box reaching the artificial box ``fb +- big``), 0.0 where the caller
    must decide by its per-sample code.

    ``tb, a, b, sig (N, m)``, ``J (N, m, m)`` as :func:`.sm_square.square_block`'s; ``perm (m,)``
    the row order of ``J^T`` partial pivoting chose at a nearby sample. Gauss-Jordan on
    ``[P J^T | P]`` (``P`` the row permutation), whose right half ends as ``(P J^T)^-1 P =
    J^-T``; scratch ``Ms (m, m, W)``, ``cnv, fq (W,)``.
    """
    u1 = np.uint64(nb)
    for q in range(u1):
        okv[q] = 1.0
    for j in range(m):
        for q in range(u1):
            k = k0 + q
            lj = tb[k, j] - b[k, j] - kk * sig[k, j]
            uj = tb[k, j] - a[k, j] + kk * sig[k, j]
            Ls[j, q] = lj
            Us[j, q] = uj
            fin = abs(lj) < np.inf and abs(uj) < np.inf
            okv[q] = okv[q] if fin else 0.0
    # [P J^T | P]; ||J^T||_1 (cnv) and the largest entry (fq) as sm_square._inverse_t's
    for q in range(u1):
        cnv[q] = 0.0
        fq[q] = 0.0
    for r in range(m):
        pr = perm[r]
        for c in range(m):
            for q in range(u1):
                v = J[k0 + q, c, pr]
                Ms[r, c, q] = v
                fq[q] = max(fq[q], abs(v))
            e = 1.0 if c == pr else 0.0
            for q in range(u1):
                Bs[r, c, q] = e
        for q in range(u1):
            v = 0.0
            for c in range(m):
                v += abs(Ms[r, c, q])
            cnv[q] = max(cnv[q], v)
    for c in range(m):
        for q in range(u1):
            d = Ms[c, c, q]
            bad = not abs(d) > 1e-12 * fq[q]
            okv[q] = 0.0 if bad else okv[q]
            Ms[c, c, q] = 1.0 if bad else 1.0 / d  # the pivot's reciprocal, for the row scaling
        for r in range(c + 1, m):
            for q in range(u1):
                okv[q] = 0.0 if abs(Ms[r, c, q]) > 2.0 * abs(1.0 / Ms[c, c, q]) else okv[q]
        for e in range(c + 1, m):
            for q in range(u1):
                Ms[c, e, q] *= Ms[c, c, q]
        for e in range(m):
            for q in range(u1):
                Bs[c, e, q] *= Ms[c, c, q]
        for r in range(m):
            if r == c:
                continue
            for e in range(c + 1, m):
                for q in range(u1):
                    Ms[r, e, q] -= Ms[r, c, q] * Ms[c, e, q]
            for e in range(m):
                for q in range(u1):
                    Bs[r, e, q] -= Ms[r, c, q] * Bs[c, e, q]
    # ||J^-T||_1 (the largest column sum), the rows' 1-norms and the artificial box
    for q in range(u1):
        fq[q] = 0.0
    for e in range(m):
        for q in range(u1):
            v = 0.0
            for r in range(m):
                v += abs(Bs[r, e, q])
            fq[q] = max(fq[q], v)
    for q in range(u1):
        okv[q] = okv[q] if fq[q] * cnv[q] <= max_cond else 0.0
    for g in range(m):
        for q in range(u1):
            c = 0.0
            r = 0.0
            v = 1e-300
            for j in range(m):
                bgj = Bs[g, j, q]
                c += bgj * 0.5 * (Ls[j, q] + Us[j, q])
                r += abs(bgj) * 0.5 * (Us[j, q] - Ls[j, q])
                v += abs(bgj)
            rns[g, q] = v
            okv[q] = okv[q] if abs(c - fb[g]) + r < big else 0.0


__all__ = ["lockstep_inverse", "lockstep_verify"]

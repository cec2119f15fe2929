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
solver, like any sample where the working set is not optimal.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
    for q in range(u0, u1):
        fq[q] = 0.0
    for j in range(m):
        for q in range(u0, u1):
            fq[q] += Bs[i, j, q] * tau[j, q]
    for q in range(u0, u1):
        if okv[q] != 0.0:
            done[q] = True
            vals[o, q] = fq[q]


__all__ = ["lockstep_verify"]

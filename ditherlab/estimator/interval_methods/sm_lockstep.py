"""One set-membership LP of :mod:`.sm_square` checked for a whole run of samples at once: the
lockstep pass.

Whether a given working set of an LP (which variables ``tau_j`` sit at which bound, which
prior-box rows ``B_g tau`` are held at which side) is optimal at a sample is a question about
that sample alone: its vertex (a ``t x t`` solve) must satisfy every other row and bound (primal
feasibility) and its multipliers must have the right signs (dual feasibility). An optimal
working set seldom changes from one sample to the next, so :func:`lockstep_verify` answers that
question for one working set over a run of samples with the samples innermost, in the arithmetic
of :func:`.sm_square._lp`'s first iteration and without branches that depend on the sample, so
that the compiler vectorises it across samples. :func:`lockstep_inverse` computes the block's
bounds and ``J^-T`` the same way. Samples a fixed pivot order does not fit are left to the
per-sample solver. The reasoning is in ``docs/design/estimator-set-membership.md``.

numba caches :mod:`.sm_square`'s kernels with these calls compiled in and does not notice when
only this file changes: delete ``__pycache__/sm_square*.nbi/.nbc`` after editing it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: The compiled options of the lockstep steps: ``error_model="numpy"`` (a division is not
#: checked for zero, so the loops over samples have no branch), no reference counts.
_LOCKSTEP = {"error_model": "numpy", "_nrt": False}


@njit(inline="always", _nrt=False)
def _dot6(Bs, g, v, q):
    """``sum_j Bs[g, j, q] v[j, q]`` for six columns, written out (one pass over the samples
    instead of six; the same additions in the same order as the loop)."""
    return (
        Bs[g, 0, q] * v[0, q] + Bs[g, 1, q] * v[1, q] + Bs[g, 2, q] * v[2, q]
        + Bs[g, 3, q] * v[3, q] + Bs[g, 4, q] * v[4, q] + Bs[g, 5, q] * v[5, q]
    )  # fmt: skip


# ------------------------------------------------------------------ the steps of lockstep_verify
# Each step takes the pass's own arguments (see lockstep_verify) and is inlined into it.


@njit(cache=True, inline="always", **_LOCKSTEP)
def _fixed_variables(blk, box, S, o, work, t, u0, u1):
    """``okv`` = the samples to check; the fixed variables at their bounds. False when a held
    row is not a row of the LP (no working set of it)."""
    m = blk.Bs.shape[0]
    sxs, srs = S.var_side, S.row_side
    for q in range(u0, u1):
        blk.okv[q] = 1.0 if blk.todo[q] and not blk.done[q] else 0.0
    for j in range(m):
        if srs[o, j] != 0 and not box.has[j]:
            return False
        if sxs[o, j] < 0:
            for q in range(u0, u1):
                blk.tau[j, q] = blk.Ls[j, q]
        elif sxs[o, j] > 0:
            for q in range(u0, u1):
                blk.tau[j, q] = blk.Us[j, q]
    return True


@njit(cache=True, inline="always", **_LOCKSTEP)
def _held_rows(blk, box, S, o, work, t, u0, u1):
    """``K tau_free = d - B_T,fixed tau_fixed``: the held rows (in the caller's pivot order)
    restricted to the free variables, and their right-hand sides; ``cnv`` the largest entry."""
    m = blk.Bs.shape[0]
    sxs, srs = S.var_side, S.row_side
    Bs, tau, rh, K, cnv = blk.Bs, blk.tau, blk.rh, blk.K, blk.cnv
    for q in range(u0, u1):
        cnv[q] = 0.0
    for a in range(t):
        g = work.held[a]
        bnd = box.hi[g] if srs[o, g] > 0 else box.lo[g]
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
            jb = work.free[b]
            for q in range(u0, u1):
                v = Bs[g, jb, q]
                K[a, b, q] = v
                cnv[q] = max(cnv[q], abs(v))


@njit(cache=True, inline="always", **_LOCKSTEP)
def _factor_in_order(blk, box, S, o, work, t, u0, u1):
    """LU of ``K`` without row exchanges; a sample whose pivot is (numerically) zero or below
    half its column's largest candidate is not checked."""
    K, okv, cnv = blk.K, blk.okv, blk.cnv
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


@njit(cache=True, inline="always", **_LOCKSTEP)
def _free_variables(blk, box, S, o, work, t, u0, u1):
    """The free variables of the vertex: forward (unit lower) and back substitution."""
    K, rh = blk.K, blk.rh
    for a in range(t):
        for b in range(a):
            for q in range(u0, u1):
                rh[a, q] -= K[a, b, q] * rh[b, q]
    for a in range(t - 1, -1, -1):
        for b in range(a + 1, t):
            for q in range(u0, u1):
                rh[a, q] -= K[a, b, q] * rh[b, q]
        j = work.free[a]
        for q in range(u0, u1):
            v = rh[a, q] / K[a, a, q]
            rh[a, q] = v
            blk.tau[j, q] = v


@njit(cache=True, inline="always", **_LOCKSTEP)
def _primal_feasible(blk, box, S, o, work, t, u0, u1):
    """Primal feasibility: the free variables within their bounds, the box rows not held
    within their sides (1e-9 relative)."""
    m = blk.Bs.shape[0]
    srs = S.row_side
    Bs, tau, okv, fq = blk.Bs, blk.tau, blk.okv, blk.fq
    for a in range(t):
        j = work.free[a]
        for q in range(u0, u1):
            lj = blk.Ls[j, q]
            uj = blk.Us[j, q]
            v = tau[j, q]
            out = v < lj - 1e-9 * (1.0 + abs(lj)) or v > uj + 1e-9 * (1.0 + abs(uj))
            okv[q] = 0.0 if out else okv[q]
    for g in range(m):
        if not box.has[g] or srs[o, g] != 0:
            continue
        lo = box.lo[g] - 1e-9 * (1.0 + abs(box.lo[g]))
        hi = box.hi[g] + 1e-9 * (1.0 + abs(box.hi[g]))
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


@njit(cache=True, inline="always", **_LOCKSTEP)
def _dual_feasible(blk, box, S, o, work, t, u0, u1):
    """Dual feasibility: the held rows' multipliers ``K^T nu = sg B_i,free`` and the fixed
    variables' reduced costs of the right signs (1e-10 of ``max_j |B_ij|``). With the
    objective's own row held on the side it pushes to the multipliers are ``sg e_i``: dual
    feasible as it stands."""
    m = blk.Bs.shape[0]
    i = o // 2
    sg = 1.0 if o % 2 == 0 else -1.0
    sxs, srs = S.var_side, S.row_side
    Bs, K, nu, okv, cnv, fq = blk.Bs, blk.K, blk.nu, blk.okv, blk.cnv, blk.fq
    if srs[o, i] == (-1 if sg > 0 else 1):
        return
    for q in range(u0, u1):
        cnv[q] = 0.0
    for j in range(m):
        for q in range(u0, u1):
            cnv[q] = max(cnv[q], abs(Bs[i, j, q]))
    # K^T nu = sg B_i,free: U^T y = c, then L^T nu = y
    for a in range(t):
        ja = work.free[a]
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
        s = float(srs[o, work.held[a]])
        for q in range(u0, u1):
            okv[q] = 0.0 if s * nu[a, q] > 1e-10 * cnv[q] else okv[q]
    for j in range(m):
        if sxs[o, j] == 0:
            continue
        s = float(sxs[o, j])
        for q in range(u0, u1):
            fq[q] = sg * Bs[i, j, q]
        for a in range(t):
            ga = work.held[a]
            for q in range(u0, u1):
                fq[q] -= nu[a, q] * Bs[ga, j, q]
        for q in range(u0, u1):
            okv[q] = 0.0 if s * fq[q] > 1e-10 * cnv[q] else okv[q]


@njit(cache=True, inline="always", **_LOCKSTEP)
def _record_optima(blk, box, S, o, work, t, u0, u1):
    """Where the working set passed both checks: ``done`` and the LP's value ``B_i tau``."""
    m = blk.Bs.shape[0]
    i = o // 2
    Bs, tau, fq = blk.Bs, blk.tau, blk.fq
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
        if blk.okv[q] != 0.0:
            blk.done[q] = True
            blk.vals[o, q] = fq[q]


@njit(cache=True, **_LOCKSTEP)
def lockstep_verify(blk, box, S, o, work, t, q0, q1):
    """Check LP ``o``'s working set at the samples ``q0 <= q < q1`` of the block with ``todo[q]``
    and not ``done[q]``; where it is optimal, ``done[q] = True`` and ``vals[o, q] = B_i tau``
    (the LP's value).

    LP ``o`` is ``min sg B_i tau`` over ``L <= tau <= U`` and the prior box's rows (``i = o //
    2``, ``sg = +1`` for even ``o``, else ``-1``).

    Parameters
    ----------
    blk : :class:`~.sm_arrays.BlockWork`
        The block: ``Bs``, ``Ls``, ``Us`` read; ``todo``, ``done``, ``vals`` the LP's progress;
        the rest scratch.
    box : :class:`~.sm_arrays.PriorBox`
        The prior box's rows.
    S : :class:`~.sm_arrays.SquareState`
        Row ``o`` of ``var_side`` and ``row_side`` is the working set checked.
    o : int
        The LP.
    work : :class:`~.sm_arrays.LPWork`
        ``free[:t]`` the free variables, ``held[:t]`` the held rows in the LU's row order.
    t : int
        Free variables (= held rows).
    q0, q1 : int
        The samples of the block to check.

    Tolerances are :func:`.sm_square._lp`'s: primal 1e-9 relative, dual 1e-10 of
    ``max_j |B_ij|``. Every loop over samples is innermost and free of branches that depend on
    the sample (selects instead), so that it vectorises; it runs over unsigned sample indices
    (numba's wraparound of negative signed indices keeps LLVM from vectorising).
    """
    u0 = np.uint64(q0)
    u1 = np.uint64(q1)
    if not _fixed_variables(blk, box, S, o, work, t, u0, u1):
        return  # a held row that is not a row: not a working set of this LP
    _held_rows(blk, box, S, o, work, t, u0, u1)
    _factor_in_order(blk, box, S, o, work, t, u0, u1)
    _free_variables(blk, box, S, o, work, t, u0, u1)
    _primal_feasible(blk, box, S, o, work, t, u0, u1)
    _dual_feasible(blk, box, S, o, work, t, u0, u1)
    _record_optima(blk, box, S, o, work, t, u0, u1)


# ------------------------------------------------------------------ the steps of lockstep_inverse


@njit(cache=True, inline="always", **_LOCKSTEP)
def _block_bounds(P, k0, nb, blk):
    """``Ls, Us``: the torque bounds of the block's samples; ``okv`` 0.0 where one is infinite."""
    m = P.J.shape[1]
    u1 = np.uint64(nb)
    kk = P.k
    for q in range(u1):
        blk.okv[q] = 1.0
    for j in range(m):
        for q in range(u1):
            k = k0 + q
            lj = P.tau_bar[k, j] - P.tau_max[k, j] - kk * P.sigma[k, j]
            uj = P.tau_bar[k, j] - P.tau_min[k, j] + kk * P.sigma[k, j]
            blk.Ls[j, q] = lj
            blk.Us[j, q] = uj
            fin = abs(lj) < np.inf and abs(uj) < np.inf
            blk.okv[q] = blk.okv[q] if fin else 0.0


@njit(cache=True, inline="always", **_LOCKSTEP)
def _load_transposed(P, k0, nb, perm, blk):
    """``[P J^T | P]`` into ``K`` and ``Bs``; ``cnv`` = ``||J^T||_1``, ``fq`` = the largest
    entry (as :func:`.sm_square._inverse_t`)."""
    m = P.J.shape[1]
    u1 = np.uint64(nb)
    Ms, Bs, cnv, fq = blk.K, blk.Bs, blk.cnv, blk.fq
    for q in range(u1):
        cnv[q] = 0.0
        fq[q] = 0.0
    for r in range(m):
        pr = perm[r]
        for c in range(m):
            for q in range(u1):
                v = P.J[k0 + q, c, pr]
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


@njit(cache=True, inline="always", **_LOCKSTEP)
def _gauss_jordan(m, nb, blk):
    """Gauss-Jordan on ``[P J^T | P]`` in the fixed pivot order: the right half ends as
    ``J^-T``; ``okv`` 0.0 where a pivot is (numerically) zero or not within a factor 2 of the
    one partial pivoting would choose."""
    u1 = np.uint64(nb)
    Ms, Bs, okv, fq = blk.K, blk.Bs, blk.okv, blk.fq
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


@njit(cache=True, inline="always", **_LOCKSTEP)
def _condition_and_box(P, max_cond, nb, blk):
    """``okv`` 0.0 where ``||J^T||_1 ||J^-T||_1 > max_cond`` or a vertex of the torque box
    reaches the artificial box; ``rns`` the rows' 1-norms."""
    m = P.J.shape[1]
    u1 = np.uint64(nb)
    Bs, okv, cnv, fq = blk.Bs, blk.okv, blk.cnv, blk.fq
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
                c += bgj * 0.5 * (blk.Ls[j, q] + blk.Us[j, q])
                r += abs(bgj) * 0.5 * (blk.Us[j, q] - blk.Ls[j, q])
                v += abs(bgj)
            blk.rns[g, q] = v
            okv[q] = okv[q] if abs(c - P.prior_mean[g]) + r < P.big else 0.0


@njit(cache=True, **_LOCKSTEP)
def lockstep_inverse(P, max_cond, k0, nb, perm, blk):
    """The torque bounds, ``B = J^-T`` and the row norms of samples ``k0 .. k0 + nb`` in lockstep
    (samples innermost).

    Parameters
    ----------
    P : :class:`~.sm_arrays.SMProblem`
        The run of samples (``m = n``).
    max_cond : float
        Largest ``||J^T||_1 ||J^-T||_1`` accepted.
    k0, nb : int
        First sample of the block and its number of samples.
    perm : (m,) int64
        The row order of ``J^T`` partial pivoting chose at a nearby sample.
    blk : :class:`~.sm_arrays.BlockWork`
        Written: ``Ls, Us (m, W)`` [N·m], ``Bs (m, m, W)``, ``rns (m, W)`` the rows' 1-norms, for
        the ``q``-th sample of the block; ``okv[q]`` 1.0 where all of it holds and the sample is
        one :func:`.sm_square.square_block` takes (finite bounds, pivots as partial pivoting would
        choose them within a factor 2, the condition within ``max_cond``, no vertex of the torque
        box reaching the artificial box ``prior_mean +- big``), 0.0 where the caller must decide
        by its per-sample code. Scratch: ``K``, ``cnv``, ``fq``.

    Gauss-Jordan on ``[P J^T | P]`` (``P`` the row permutation), whose right half ends as
    ``(P J^T)^-1 P = J^-T``.
    """
    m = P.J.shape[1]
    _block_bounds(P, k0, nb, blk)
    _load_transposed(P, k0, nb, perm, blk)
    _gauss_jordan(m, nb, blk)
    _condition_and_box(P, max_cond, nb, blk)


__all__ = ["lockstep_inverse", "lockstep_verify"]

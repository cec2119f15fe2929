"""The profile-likelihood interval: ``{t : min_{F: F_i = t} f(F) - min_F f(F) <= chi2_1(level)}``
followed exactly along the path of constrained minimisers (see :mod:`ditherlab.estimator.intervals`).

Two kernels follow the same path: :func:`_profile_reference_kernel` refactors the active set at
every segment (slow, obviously right: :func:`profile_reference`), and :func:`_profile_kernel`
factors once per sample and carries ``H^-1`` along the path by rank-one updates (what
:func:`ditherlab.estimator.intervals` uses; samples where the updates could lose accuracy are
handed to the reference).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ditherlab.estimator.piecewise import _cost, _dist, _givens_row, _sides
from ditherlab.estimator.problem import Problem, _chunks, chi2_1_quantile

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
def _profile_reference_kernel(
    tb, J, a, b, w, p, fb, Fh, thr, ridge, unobs, lo_out, hi_out, seg_out
):
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


#: The fast kernel hands a sample to the reference kernel when its rank-one updates may have
#: magnified rounding by more than this (sum over a path of (1 + |U_j^T H^-1 U_j|) /
#: min(1, |denominator|)). Measured: the replay hour's data reach 4.1e4 with bounds within
#: 2.2e-11 (relative) of the reference; 40 fuzzed problems (noise down to 1e-3 N·m) stay within
#: 7e-10 at this threshold, 3.9e-9 at 2e5.
MAX_MAGNIFICATION = 5e4

#: The fast kernel factors ``H0`` by Cholesky; a pivot below this fraction of its diagonal entry
#: (``H0`` near singular in that direction: the inverse's relative error grows as 1 / pivot)
#: hands the sample to the reference kernel's Givens QR.
MIN_PIVOT = 1e-5


@njit(cache=True)
def _profile_kernel(
    tb, J, a, b, w, p, fb, Fh, thr, ridge, unobs, lo_out, hi_out, seg_out, maxmag, mag_out
):
    """The profile bounds along the path of :func:`_profile_reference_kernel`, without a
    factorisation per segment.

    Each sample is factored once, at the active set of ``F_hat`` (the reference's ``R0``, here by
    Cholesky of ``H0``; a pivot below :data:`MIN_PIVOT` of its diagonal hands the sample back); from
    it come ``diag(H0^-1)``, ``H0^-1 grad``, ``G0 = H0^-1 U^T`` and ``M0 = U H0^-1 U^T``
    (``U_j = sqrt(w_j) J_j^T``, one row per joint). Along the path of component ``i`` a
    breakpoint adds or removes one joint, ``H -> H +- U_j U_j^T``, and all the path needs of
    ``H^-1`` — ``h = (H^-1)_ii`` (the curvature of the profile is ``1 / h``) and
    ``g_k = (H^-1 U_k)_i`` (the joints' residual slopes ``c_k = g_k / (sqrt(w_k) h)``) — follows
    by the Sherman–Morrison formula, with the column of ``M`` it needs rebuilt from ``M0`` and
    the path's earlier updates. The residuals and the profile are carried along the path
    (``r_j -= D c_j``; ``p += dp D + D^2 / h``, ``dp += 2 D / h``). A segment costs ``O(n)`` and
    a breakpoint ``O(n t)`` after ``t`` updates, instead of a refactorisation.

    Rank-one updates lose accuracy when a denominator ``1 +- U_j^T H^-1 U_j`` cancels; a
    sample whose path magnifies rounding by more than :data:`MAX_MAGNIFICATION`, whose ``h``
    turns non-positive, or that exceeds the segment limit gets ``seg_out = -1`` and is redone
    by the reference kernel (:func:`_profile`).
    """
    N, m, n = J.shape
    R0 = np.empty((m, m))
    Z = np.empty((m, m))
    hd = np.empty(m)
    zg = np.empty(m)
    U = np.empty((n, m))
    Wt = np.empty((n, m))
    G0 = np.empty((m, n))
    M0 = np.empty((n, n))
    u = np.empty(m)
    grad = np.empty(m)
    hg = np.empty(m)
    ip = np.empty(m)
    isw = np.empty(n)
    r0 = np.empty(n)
    r = np.empty(n)
    g = np.empty(n)
    cs = np.empty(n)
    col = np.empty(n)
    s0 = np.zeros(n, np.int8)
    s = np.zeros(n, np.int8)
    maxseg = 4 * n + 8
    At = np.empty((maxseg, n))
    ft = np.empty(maxseg)
    for k in range(N):
        tbk, Jk, ak, bk, wk, pk, Fk = tb[k], J[k], a[k], b[k], w[k], p[k], Fh[k]
        bad = False
        # one pass over J: the cost at F_hat (as _cost), the residuals, sides, the gradient (zero
        # up to rounding: F_hat is the minimiser), the data information and U
        f0 = 0.0
        for q in range(m):
            f0 += pk[q] * (Fk[q] - fb[q]) ** 2
            grad[q] = 2.0 * pk[q] * (Fk[q] - fb[q])
            ip[q] = 1.0 / pk[q]
        scale = 0.0
        for j in range(n):
            rj = tbk[j]
            for q in range(m):
                rj -= Jk[q, j] * Fk[q]
            r0[j] = rj
            if rj > bk[j]:
                s0[j] = 1
            elif rj < ak[j]:
                s0[j] = -1
            else:
                s0[j] = 0
            dj = _dist(rj, ak[j], bk[j])
            f0 += wk[j] * dj * dj
            sw = math.sqrt(wk[j])
            isw[j] = 1.0 / sw
            for q in range(m):
                scale += wk[j] * Jk[q, j] ** 2
                grad[q] -= 2.0 * wk[j] * Jk[q, j] * dj
                U[j, q] = sw * Jk[q, j]
        target = f0 + thr
        scale = scale / m if scale > 0.0 else 1.0
        far = unobs * math.sqrt(thr / scale)
        # the factor at F_hat's active set, and what the paths need of its inverse
        inside = True
        for j in range(n):
            if s0[j] != 0:
                inside = False
                break
        if inside:  # every joint inside its band: H0 = diag(p)
            for i in range(m):
                hd[i] = ip[i]
                hg[i] = grad[i] * ip[i]
                for j in range(n):
                    G0[i, j] = U[j, i] * ip[i]
            for j in range(n):
                for l in range(j, n):
                    v = 0.0
                    for q in range(m):
                        v += U[j, q] * G0[q, l]
                    M0[j, l] = v
                    M0[l, j] = v
        else:
            # R0^T R0 = H0 = diag(p) + sum over joints outside their band of U_j U_j^T: H0 formed
            # and Cholesky-factored (6 square roots, not a Givens QR's m per joint); a pivot
            # that cancels to below MIN_PIVOT of its diagonal hands the sample to the reference
            for q in range(m):
                for c in range(q, m):
                    v = pk[q] if c == q else 0.0
                    for j in range(n):
                        if s0[j] != 0:
                            v += U[j, q] * U[j, c]
                    R0[q, c] = v
            for q in range(m):
                d = R0[q, q]
                v = d
                for t in range(q):
                    v -= R0[t, q] * R0[t, q]
                if not v > MIN_PIVOT * d:
                    bad = True
                    break
                rq = math.sqrt(v)
                R0[q, q] = rq
                u[q] = 1.0 / rq
                for c in range(q + 1, m):
                    v = R0[q, c]
                    for t in range(q):
                        v -= R0[t, q] * R0[t, c]
                    R0[q, c] = v * u[q]
            if bad:  # the reference redoes it
                seg_out[k] = -1
                continue
            for c in range(m):  # Z = R0^-T (lower triangular): column c solves R0^T z = e_c
                for q in range(c):
                    Z[q, c] = 0.0
                Z[c, c] = u[c]
                for q in range(c + 1, m):
                    v = 0.0
                    for t in range(c, q):
                        v -= R0[t, q] * Z[t, c]
                    Z[q, c] = v * u[q]
            for q in range(m):  # zg = Z grad
                v = 0.0
                for t in range(q + 1):
                    v += Z[q, t] * grad[t]
                zg[q] = v
            for i in range(m):  # diag(H0^-1) and H0^-1 grad, H0^-1 = Z^T Z
                v = 0.0
                v2 = 0.0
                for t in range(i, m):
                    v += Z[t, i] * Z[t, i]
                    v2 += Z[t, i] * zg[t]
                hd[i] = v
                hg[i] = v2
            for j in range(n):  # Wt_j = Z U_j (R0^-T U_j)
                for q in range(m):
                    v = 0.0
                    for t in range(q + 1):
                        v += Z[q, t] * U[j, t]
                    Wt[j, q] = v
            for j in range(n):  # M0 = Wt Wt^T
                for l in range(j, n):
                    v = 0.0
                    for q in range(m):
                        v += Wt[j, q] * Wt[l, q]
                    M0[j, l] = v
                    M0[l, j] = v
            for i in range(m):  # G0 = H0^-1 U^T = Z^T Wt^T
                for j in range(n):
                    v = 0.0
                    for t in range(i, m):
                        v += Z[t, i] * Wt[j, t]
                    G0[i, j] = v
        for i in range(m):
            for side in range(2):
                sg = 1.0 - 2.0 * side
                for j in range(n):
                    r[j] = r0[j]
                    s[j] = s0[j]
                    g[j] = G0[i, j]
                h = hd[i]
                dp = sg * hg[i] / h  # slope of the profile along the path: grad f . v
                pcur = f0
                pos = 0.0
                mag = 0.0
                nt = 0
                end = np.nan
                nseg = 0
                while nseg < maxseg:
                    nseg += 1
                    invh = 1.0 / h
                    fac = sg * invh
                    db = np.inf
                    jb = -1
                    for j in range(n):
                        cj = fac * g[j] * isw[j]  # r_j(D) = r_j - D cj
                        cs[j] = cj
                        # the edge r_j reaches next, (r_j - edge) / cj away: going down (cj > 0)
                        # from inside or above, going up from inside or below
                        sj = s[j]
                        if cj > 0.0:
                            if sj < 0:
                                continue
                            num = r[j] - (bk[j] if sj > 0 else ak[j])
                            if not num < db * cj:  # dj >= db: skip the division
                                continue
                        elif cj < 0.0:
                            if sj > 0:
                                continue
                            num = r[j] - (ak[j] if sj < 0 else bk[j])
                            if not num > db * cj:
                                continue
                        else:
                            continue
                        dj = num / cj
                        if dj < 0.0:
                            dj = 0.0
                        if dj < db:
                            db = dj
                            jb = j
                    # p(D) = pcur + dp D + D^2 / h on this piece, increasing from below the
                    # target: it is reached on the piece iff p(db) >= target
                    rem = target - pcur
                    pnext = pcur + db * (dp + db * invh)
                    if rem <= 0.0 or not pnext < target:  # (db = inf: reached)
                        dstar = 0.0
                        if rem > 0.0:
                            dstar = 2.0 * rem / (dp + math.sqrt(dp * dp + 4.0 * invh * rem))
                        end = sg * (pos + min(dstar, db))
                        break
                    pos += db
                    pcur = pnext
                    dp += 2.0 * db * invh
                    for j in range(n):
                        r[j] -= db * cs[j]
                    # the joint that crossed: on the edge it went out (or came in) through
                    if s[jb] == 0:
                        s[jb] = 1 if cs[jb] < 0.0 else -1
                        r[jb] = bk[jb] if s[jb] > 0 else ak[jb]
                        sig = 1.0
                    else:
                        r[jb] = bk[jb] if s[jb] > 0 else ak[jb]
                        s[jb] = 0
                        sig = -1.0
                    # H -> H + sig U_jb U_jb^T: the column jb of M = U H^-1 U^T, then
                    # Sherman-Morrison on h and g
                    for l in range(n):
                        col[l] = M0[l, jb]
                    for t in range(nt):
                        f = ft[t] * At[t, jb]
                        for l in range(n):
                            col[l] -= f * At[t, l]
                    den = 1.0 + sig * col[jb]
                    if not den != 0.0:
                        bad = True
                        break
                    # rounding is magnified by 1 + |M_jj| (h and g cancel when adding a joint
                    # its data dominate), and again by 1 / den when removing one
                    mag += (1.0 + abs(col[jb])) / min(1.0, abs(den))
                    f = sig / den
                    gj = g[jb]
                    h -= f * gj * gj
                    for l in range(n):
                        g[l] -= f * gj * col[l]
                        At[nt, l] = col[l]
                    ft[nt] = f
                    nt += 1
                    if not h > 0.0 or mag > maxmag:
                        bad = True
                        break
                if bad or nseg >= maxseg and not end == end:
                    bad = True
                    break
                seg_out[k] = max(seg_out[k], nseg)
                mag_out[k] = max(mag_out[k], mag)
                if ridge[i] and abs(end) > far:
                    end = sg * np.inf
                if sg > 0:
                    hi_out[k, i] = Fk[i] + end
                else:
                    lo_out[k, i] = Fk[i] + end
            if bad:
                break
        if bad:
            seg_out[k] = -1


def _run_profile(
    prob: Problem, Fm: np.ndarray, level: float, progress=None, fast: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds ``lo, hi (N, m)`` and which samples the fast kernel handed back (``fast``: the
    fast kernel, those samples redone by the reference; else the reference alone)."""
    N, m = prob.N, prob.m
    lo_m, hi_m = np.empty((N, m)), np.empty((N, m))
    ridge = prob.p_true == 0.0
    thr = chi2_1_quantile(level)
    seg = np.zeros(N, np.int64)
    mag = np.zeros(N)
    redone = np.zeros(N, np.bool_)
    Fm = np.ascontiguousarray(Fm)
    for sl in _chunks(N, progress):
        args = (
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], prob.w[sl],
            prob.p[sl], prob.prior_mean, Fm[sl], thr, ridge, UNOBSERVABLE, lo_m[sl], hi_m[sl],
            seg[sl],
        )  # fmt: skip
        if not fast:
            _profile_reference_kernel(*args)
        else:
            _profile_kernel(*args, MAX_MAGNIFICATION, mag[sl])
            redo = sl.start + np.flatnonzero(seg[sl] < 0)
            if len(redo):  # handed back by the fast kernel: the reference path for these
                lo_r, hi_r = np.empty((len(redo), m)), np.empty((len(redo), m))
                _profile_reference_kernel(
                    prob.tau_bar[redo], prob.J[redo], prob.tau_min[redo], prob.tau_max[redo],
                    prob.w[redo], prob.p[redo], prob.prior_mean, Fm[redo], thr, ridge,
                    UNOBSERVABLE, lo_r, hi_r, np.zeros(len(redo), np.int64),
                )  # fmt: skip
                lo_m[redo], hi_m[redo], redone[redo] = lo_r, hi_r, True
        if progress is not None:
            progress(sl.stop, N)
    return lo_m, hi_m, redone


def _profile(
    prob: Problem, Fm: np.ndarray, level: float, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    """The profile bounds ``lo, hi (N, m)`` of the estimated components around ``Fm (N, m)``
    (the estimate: the path starts at the minimiser), by the fast kernel."""
    lo_m, hi_m, _ = _run_profile(prob, Fm, level, progress)
    return lo_m, hi_m


def profile_reference(
    prob: Problem, Fm: np.ndarray, level: float = 0.95
) -> tuple[np.ndarray, np.ndarray]:
    """The profile bounds ``lo, hi (N, m)`` by the reference kernel: the same path, every
    segment's active set refactored from scratch (:func:`_qr_factor`), its ``H^-1 e_i`` solved
    and the cost recomputed from ``F``. Slow and obviously right; the fast kernel is tested
    against it."""
    lo_m, hi_m, _ = _run_profile(prob, Fm, level, fast=False)
    return lo_m, hi_m

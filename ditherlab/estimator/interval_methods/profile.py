"""The profile-likelihood interval: ``{t : min_{F: F_i = t} f(F) - min_F f(F) <= chi2_1(level)}``
followed exactly along the path of constrained minimisers (see :mod:`ditherlab.estimator.interval_methods`).

Two kernels follow the same path: :func:`_profile_reference_kernel` refactors the active set at
every segment (slow, obviously right: :func:`profile_reference`), and :func:`_profile_kernel`
factors once per sample and carries ``H^-1`` along the path by rank-one updates (what
:func:`ditherlab.estimator.intervals` uses; samples where the updates could lose accuracy are
handed to the reference). The reasoning is in ``docs/design/estimator-intervals.md``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ditherlab.estimator.formulation import Problem, _chunks, chi2_1_quantile
from ditherlab.estimator.piecewise import _cost, _dist, _givens_row, _sides, sample_at

#: Intervals whose half-width exceeds this many "information units" are reported as infinite.
UNOBSERVABLE = 1e5

#: The fast kernel hands a sample to the reference kernel when its rank-one updates may have
#: magnified rounding by more than this (sum over a path of (1 + |U_j^T H^-1 U_j|) /
#: min(1, |denominator|)): below it the bounds agree with the reference's to rounding
#: (``tests/test_estimator.py`` and ``tests/test_replay.py`` compare them).
MAX_MAGNIFICATION = 5e4

#: The fast kernel factors ``H0`` by Cholesky; a pivot below this fraction of its diagonal entry
#: (``H0`` near singular in that direction: the inverse's relative error grows as 1 / pivot)
#: hands the sample to the reference kernel's Givens QR.
MIN_PIVOT = 1e-5


class ProfileOptions(NamedTuple):
    """What the profile kernels follow the paths to.

    Attributes
    ----------
    threshold : float
        The rise of the profiled cost that ends a path: ``chi2_1(level)`` (3.84 at 0.95).
    ridge : (m,) bool
        Components without a prior (their bounds beyond ``unobservable`` are infinite).
    unobservable : float
        Half-widths beyond this many "information units" ``sqrt(threshold / mean info)`` are
        reported infinite for the ridge components (:data:`UNOBSERVABLE`).
    max_magnification : float
        The fast kernel's limit on the rounding its updates may magnify
        (:data:`MAX_MAGNIFICATION`).
    """

    threshold: float
    ridge: np.ndarray
    unobservable: float
    max_magnification: float


class ProfileOut(NamedTuple):
    """What the profile kernels write per sample.

    Attributes
    ----------
    lo, hi : (N, m) [N, N·m]
        The interval's bounds.
    segments : (N,) int64
        The longest path's segments; -1 where the fast kernel hands the sample back.
    magnification : (N,)
        The fast kernel's largest magnification of rounding along a path.
    """

    lo: np.ndarray
    hi: np.ndarray
    segments: np.ndarray
    magnification: np.ndarray


# ------------------------------------------------------------------ the reference kernel


@njit(cache=True, _nrt=False)
def _qr_factor(smp, s, R, u):
    """Upper-triangular ``R (m, m)`` with ``R^T R = diag(p) + sum_{s_j != 0} w_j J_j J_j^T`` at
    the sample ``smp`` (Givens rows; ``u (m,)`` scratch)."""
    J, w, p = smp.J, smp.w, smp.p
    m, n = J.shape
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


@njit(cache=True, _nrt=False)
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


class ReferenceWork(NamedTuple):
    """Scratch of the reference kernel: ``R, R0 (m, m)`` the factors of the path's segment and
    of ``F_hat``'s active set; ``u, y, v, F (m,)``; ``r (n,)`` residuals [N·m]; ``s, s0 (n,)``
    int8 the joints' sides on the path and at ``F_hat``."""

    R: np.ndarray
    R0: np.ndarray
    u: np.ndarray
    y: np.ndarray
    v: np.ndarray
    F: np.ndarray
    r: np.ndarray
    s: np.ndarray
    s0: np.ndarray


@njit(cache=True, inline="always", _nrt=False)
def _slope_and_edge(smp, i, sg, ws):
    """On the segment from ``ws.F`` along ``v = H^-1 e_i / h`` in direction ``sg``: the slope of
    the profile ``grad f . v`` and the first joint to reach an edge of its band, ``(dp, D, j)``
    (``D`` the distance along ``F_i``; ``j`` -1 when none does)."""
    tbk, Jk, ak, bk, wk, pk, fb = smp
    m, n = Jk.shape
    F, v, r, s = ws.F, ws.v, ws.r, ws.s
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
    return dp * sg, db, jb


@njit(cache=True, inline="always", _nrt=False)
def _step_to_edge(smp, sg, db, jb, ws):
    """Move ``ws.F`` by ``db`` along the path to where joint ``jb`` reaches its edge, and flip
    its side (in, or out through the edge it reached)."""
    Jk = smp.J
    m = Jk.shape[0]
    F, v, s = ws.F, ws.v, ws.s
    for q in range(m):
        F[q] += sg * db * v[q]
    if s[jb] == 0:
        cj = 0.0
        for q in range(m):
            cj += Jk[q, jb] * v[q]
        s[jb] = 1 if sg * cj < 0.0 else -1
    else:
        s[jb] = 0


@njit(cache=True, inline="always", _nrt=False)
def _follow_reference(smp, Fk, i, sg, f0, target, ws):
    """The path of component ``i`` from ``F_hat = Fk`` in direction ``sg`` to where the profile
    reaches ``target``, each segment refactored (``ws.R0`` holds ``F_hat``'s factor). Returns
    ``(end, segments)``: ``end`` the offset from ``F_hat_i`` [N, N·m] (NaN past the segment
    limit)."""
    m, n = smp.J.shape
    F, v, s = ws.F, ws.v, ws.s
    maxseg = 4 * n + 8
    for q in range(m):
        F[q] = Fk[q]
    for j in range(n):
        s[j] = ws.s0[j]
    pcur = f0
    end = np.nan
    nseg = 0
    while nseg < maxseg:
        nseg += 1
        if nseg == 1:
            _hinv_col(ws.R0, i, m, ws.y, v)
        else:
            _qr_factor(smp, s, ws.R, ws.u)
            _hinv_col(ws.R, i, m, ws.y, v)
        h = v[i]
        for q in range(m):
            v[q] /= h
        dp, db, jb = _slope_and_edge(smp, i, sg, ws)
        rem = target - pcur
        if rem <= 0.0:
            dstar = 0.0
        else:
            qq = 1.0 / h  # p(D) = pcur + dp D + D^2 / h on this piece
            dstar = 2.0 * rem / (dp + math.sqrt(dp * dp + 4.0 * qq * rem))
        if dstar <= db:
            end = F[i] + sg * dstar - Fk[i]
            break
        _step_to_edge(smp, sg, db, jb, ws)
        pcur = _cost(smp, F)
    return end, nseg


@njit(cache=True, inline="always", _nrt=False)
def _information_scale(smp, unobs, thr):
    """The half-width beyond which a ridge component's bound is infinite: ``unobs`` information
    units ``sqrt(thr / mean_i sum_j w_j J_ij^2)`` (components outer, as the reference sums)."""
    Jk, wk = smp.J, smp.w
    m, n = Jk.shape
    scale = 0.0
    for i in range(m):
        for j in range(n):
            scale += wk[j] * Jk[i, j] ** 2
    scale = scale / m if scale > 0.0 else 1.0
    return unobs * math.sqrt(thr / scale)


@njit(cache=True, _nrt=False)
def _reference_loop(S, Fh, opts, out, ws):
    """:func:`_profile_reference_kernel` on its scratch ``ws`` (:class:`ReferenceWork`),
    compiled without reference counts."""
    N, m, n = S.J.shape
    thr = opts.threshold
    for k in range(N):
        smp = sample_at(S, k)
        f0 = _cost(smp, Fh[k])
        target = f0 + thr
        far = _information_scale(smp, opts.unobservable, thr)
        # every path starts at F_hat with the same active set: factor it once per sample
        _sides(smp, Fh[k], ws.s0)
        _qr_factor(smp, ws.s0, ws.R0, ws.u)
        for i in range(m):
            for sg in (1.0, -1.0):
                end, nseg = _follow_reference(smp, Fh[k], i, sg, f0, target, ws)
                out.segments[k] = max(out.segments[k], nseg)
                if opts.ridge[i] and abs(end) > far:
                    end = sg * np.inf
                if sg > 0:
                    out.hi[k, i] = Fh[k, i] + end
                else:
                    out.lo[k, i] = Fh[k, i] + end


@njit(cache=True)
def _profile_reference_kernel(S, Fh, opts, out):
    """The profile bounds of every sample of the run ``S``
    (:class:`~ditherlab.estimator.formulation.Samples`) around the estimate ``Fh (N, m)`` [N, N·m],
    refactoring at every segment; ``opts`` a :class:`ProfileOptions`, ``out`` a
    :class:`ProfileOut` (``lo``, ``hi``, ``segments`` written)."""
    N, m, n = S.J.shape
    ws = ReferenceWork(
        np.empty((m, m)), np.empty((m, m)), np.empty(m), np.empty(m), np.empty(m), np.empty(m),
        np.empty(n), np.zeros(n, np.int8), np.zeros(n, np.int8),
    )  # fmt: skip
    _reference_loop(S, Fh, opts, out, ws)


# ------------------------------------------------------------------ the fast kernel


class ProfileWork(NamedTuple):
    """Scratch of the fast kernel for ``m`` components, ``n`` joints and up to ``T`` segments
    (``U_j = sqrt(w_j) J_j^T``, ``H0`` the Hessian of ``F_hat``'s piece).

    Attributes
    ----------
    R0, Z : (m, m)
        ``H0``'s Cholesky factor (upper) and ``R0^-T``.
    hd, hg : (m,)
        ``diag(H0^-1)`` and ``H0^-1 grad``.
    zg, u, ip : (m,)
        ``Z grad``; the factor's reciprocal pivots; ``1 / p``.
    grad : (m,)
        The gradient of ``f`` at ``F_hat``.
    U, Wt : (n, m)
        ``U_j`` and ``Z U_j``.
    G0 : (m, n)
        ``H0^-1 U^T``.
    M0 : (n, n)
        ``U H0^-1 U^T``.
    isw, r0, r, g, cs, col : (n,)
        ``1 / sqrt(w)``; the residuals [N·m] at ``F_hat`` and along the path; ``(H^-1 U_j)_i``;
        the residuals' slopes; a column of ``M``.
    s0, s : (n,) int8
        The joints' sides at ``F_hat`` and along the path.
    At, ft : (T, n), (T,)
        The path's rank-one updates.
    """

    R0: np.ndarray
    Z: np.ndarray
    hd: np.ndarray
    hg: np.ndarray
    zg: np.ndarray
    u: np.ndarray
    ip: np.ndarray
    grad: np.ndarray
    U: np.ndarray
    Wt: np.ndarray
    G0: np.ndarray
    M0: np.ndarray
    isw: np.ndarray
    r0: np.ndarray
    r: np.ndarray
    g: np.ndarray
    cs: np.ndarray
    col: np.ndarray
    s0: np.ndarray
    s: np.ndarray
    At: np.ndarray
    ft: np.ndarray


@njit(cache=True)
def _profile_work(m, n, maxseg):
    """A :class:`ProfileWork` for ``m`` components, ``n`` joints and ``maxseg`` segments."""
    return ProfileWork(
        np.empty((m, m)), np.empty((m, m)), np.empty(m), np.empty(m), np.empty(m), np.empty(m),
        np.empty(m), np.empty(m), np.empty((n, m)), np.empty((n, m)), np.empty((m, n)),
        np.empty((n, n)), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n),
        np.empty(n), np.zeros(n, np.int8), np.zeros(n, np.int8), np.empty((maxseg, n)),
        np.empty(maxseg),
    )  # fmt: skip


@njit(cache=True, inline="always", _nrt=False)
def _first_pass(smp, Fk, ws):
    """One pass over ``J`` at ``F_hat = Fk``: the cost (as :func:`_cost`), the residuals ``r0``,
    sides ``s0``, the gradient (zero up to rounding: ``F_hat`` is the minimiser), ``1 / p``,
    ``1 / sqrt(w)`` and ``U``. Returns ``(f0, the data information sum_j w_j |J_j|^2)``."""
    tbk, Jk, ak, bk, wk, pk, fb = smp
    m, n = Jk.shape
    grad, ip, r0, s0, isw, U = ws.grad, ws.ip, ws.r0, ws.s0, ws.isw, ws.U
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
    return f0, scale


@njit(cache=True, inline="always", _nrt=False)
def _inverse_inside(m, n, ws):
    """Every joint inside its band: ``H0 = diag(p)``, so ``diag(H0^-1) = 1 / p``,
    ``H0^-1 grad``, ``G0 = H0^-1 U^T`` and ``M0 = U H0^-1 U^T`` directly."""
    U, G0, M0, ip = ws.U, ws.G0, ws.M0, ws.ip
    for i in range(m):
        ws.hd[i] = ip[i]
        ws.hg[i] = ws.grad[i] * ip[i]
        for j in range(n):
            G0[i, j] = U[j, i] * ip[i]
    for j in range(n):
        for l in range(j, n):
            v = 0.0
            for q in range(m):
                v += U[j, q] * G0[q, l]
            M0[j, l] = v
            M0[l, j] = v


@njit(cache=True, inline="always", _nrt=False)
def _cholesky_h0(pk, m, n, ws):
    """``R0^T R0 = H0 = diag(p) + sum over joints outside their band of U_j U_j^T``, formed and
    Cholesky-factored (m square roots, not a Givens QR's m per joint); ``u`` the reciprocal
    pivots. False when a pivot cancels to below :data:`MIN_PIVOT` of its diagonal."""
    R0, U, u, s0 = ws.R0, ws.U, ws.u, ws.s0
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
            return False
        rq = math.sqrt(v)
        R0[q, q] = rq
        u[q] = 1.0 / rq
        for c in range(q + 1, m):
            v = R0[q, c]
            for t in range(q):
                v -= R0[t, q] * R0[t, c]
            R0[q, c] = v * u[q]
    return True


@njit(cache=True, inline="always", _nrt=False)
def _inverse_diagonal(m, ws):
    """``Z = R0^-T`` (lower triangular), ``diag(H0^-1)`` and ``H0^-1 grad`` (``H0^-1 = Z^T
    Z``)."""
    R0, Z, u, zg = ws.R0, ws.Z, ws.u, ws.zg
    for c in range(m):  # Z = R0^-T: column c solves R0^T z = e_c
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
            v += Z[q, t] * ws.grad[t]
        zg[q] = v
    for i in range(m):
        v = 0.0
        v2 = 0.0
        for t in range(i, m):
            v += Z[t, i] * Z[t, i]
            v2 += Z[t, i] * zg[t]
        ws.hd[i] = v
        ws.hg[i] = v2


@njit(cache=True, inline="always", _nrt=False)
def _joint_products(m, n, ws):
    """``Wt_j = Z U_j``, ``M0 = Wt Wt^T = U H0^-1 U^T`` and ``G0 = H0^-1 U^T = Z^T Wt^T``."""
    Z, U, Wt, M0, G0 = ws.Z, ws.U, ws.Wt, ws.M0, ws.G0
    for j in range(n):
        for q in range(m):
            v = 0.0
            for t in range(q + 1):
                v += Z[q, t] * U[j, t]
            Wt[j, q] = v
    for j in range(n):
        for l in range(j, n):
            v = 0.0
            for q in range(m):
                v += Wt[j, q] * Wt[l, q]
            M0[j, l] = v
            M0[l, j] = v
    for i in range(m):
        for j in range(n):
            v = 0.0
            for t in range(i, m):
                v += Z[t, i] * Wt[j, t]
            G0[i, j] = v


@njit(cache=True, inline="always", _nrt=False)
def _factor_at_estimate(smp, ws):
    """What every path of the sample needs of ``H0^-1`` at ``F_hat``'s active set; False when
    ``H0``'s factor is too close to singular (the reference redoes the sample)."""
    m, n = smp.J.shape
    inside = True
    for j in range(n):
        if ws.s0[j] != 0:
            inside = False
            break
    if inside:
        _inverse_inside(m, n, ws)
        return True
    if not _cholesky_h0(smp.p, m, n, ws):
        return False
    _inverse_diagonal(m, ws)
    _joint_products(m, n, ws)
    return True


@njit(cache=True, inline="always", _nrt=False)
def _next_edge(smp, fac, ws):
    """The residuals' slopes ``cs = fac g / sqrt(w)`` (``r_j(D) = r_j - D cs_j``) and the first
    joint to reach the edge it moves towards: going down (``cs_j > 0``) from inside or above,
    going up from inside or below. Returns ``(D, j)`` (``inf, -1`` when none does)."""
    ak, bk = smp.tau_min, smp.tau_max
    n = len(ak)
    g, isw, cs, s, r = ws.g, ws.isw, ws.cs, ws.s, ws.r
    db = np.inf
    jb = -1
    for j in range(n):
        cj = fac * g[j] * isw[j]
        cs[j] = cj
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
    return db, jb


@njit(cache=True, inline="always", _nrt=False)
def _cross_edge(smp, db, jb, ws):
    """The residuals after a step ``db``; joint ``jb`` on the edge it went out (or came in)
    through. Returns the sign of the update of ``H``: +1 (out: ``H + U_jb U_jb^T``) or -1."""
    ak, bk = smp.tau_min, smp.tau_max
    r, s, cs = ws.r, ws.s, ws.cs
    for j in range(len(r)):
        r[j] -= db * cs[j]
    if s[jb] == 0:
        s[jb] = 1 if cs[jb] < 0.0 else -1
        r[jb] = bk[jb] if s[jb] > 0 else ak[jb]
        return 1.0
    r[jb] = bk[jb] if s[jb] > 0 else ak[jb]
    s[jb] = 0
    return -1.0


@njit(cache=True, inline="always", _nrt=False)
def _update_inverse(jb, sig, nt, h, ws):
    """``H -> H + sig U_jb U_jb^T``: the column ``jb`` of ``M = U H^-1 U^T`` rebuilt from ``M0``
    and the path's ``nt`` earlier updates, then Sherman-Morrison on ``h`` and ``g``; the update
    stored as number ``nt``. Returns ``(h, magnification, ok)``: rounding is magnified by
    ``1 + |M_jj|`` (``h`` and ``g`` cancel when adding a joint its data dominate), and again by
    ``1 / den`` when removing one; not ok when the denominator vanishes."""
    col, g, At, ft = ws.col, ws.g, ws.At, ws.ft
    n = len(col)
    for l in range(n):
        col[l] = ws.M0[l, jb]
    for t in range(nt):
        f = ft[t] * At[t, jb]
        for l in range(n):
            col[l] -= f * At[t, l]
    den = 1.0 + sig * col[jb]
    if not den != 0.0:
        return h, 0.0, False
    dmag = (1.0 + abs(col[jb])) / min(1.0, abs(den))
    f = sig / den
    gj = g[jb]
    h -= f * gj * gj
    for l in range(n):
        g[l] -= f * gj * col[l]
        At[nt, l] = col[l]
    ft[nt] = f
    return h, dmag, True


@njit(cache=True, inline="always", _nrt=False)
def _follow_fast(smp, i, sg, f0, target, maxmag, ws):
    """The path of component ``i`` in direction ``sg`` from ``F_hat`` to where the profile reaches
    ``target``, carrying ``h = (H^-1)_ii`` and ``g`` by rank-one updates, the residuals and the
    profile (``p += dp D + D^2 / h``, ``dp += 2 D / h``). Returns ``(end, segments,
    magnification, bad)``: ``end`` the offset from ``F_hat_i`` [N, N·m]; ``bad`` when an update
    fails, ``h`` turns non-positive, the magnification exceeds ``maxmag`` or the path exceeds
    the segment limit."""
    n = len(ws.r)
    maxseg = 4 * n + 8
    for j in range(n):
        ws.r[j] = ws.r0[j]
        ws.s[j] = ws.s0[j]
        ws.g[j] = ws.G0[i, j]
    h = ws.hd[i]
    dp = sg * ws.hg[i] / h  # slope of the profile along the path: grad f . v
    pcur = f0
    pos = 0.0
    mag = 0.0
    nt = 0
    end = np.nan
    nseg = 0
    bad = False
    while nseg < maxseg:
        nseg += 1
        invh = 1.0 / h
        db, jb = _next_edge(smp, sg * invh, ws)
        # p(D) = pcur + dp D + D^2 / h on this piece, increasing from below the target: it is
        # reached on the piece iff p(db) >= target
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
        sig = _cross_edge(smp, db, jb, ws)
        h, dmag, ok = _update_inverse(jb, sig, nt, h, ws)
        if not ok:
            bad = True
            break
        mag += dmag
        nt += 1
        if not h > 0.0 or mag > maxmag:
            bad = True
            break
    bad = bad or nseg >= maxseg and not end == end
    return end, nseg, mag, bad


@njit(cache=True, _nrt=False)
def _fast_loop(S, Fh, opts, out, ws):
    """:func:`_profile_kernel` on its scratch ``ws`` (:class:`ProfileWork`), compiled without
    reference counts."""
    N, m, n = S.J.shape
    thr = opts.threshold
    for k in range(N):
        smp = sample_at(S, k)
        Fk = Fh[k]
        f0, scale = _first_pass(smp, Fk, ws)
        target = f0 + thr
        scale = scale / m if scale > 0.0 else 1.0
        far = opts.unobservable * math.sqrt(thr / scale)
        if not _factor_at_estimate(smp, ws):  # the reference redoes it
            out.segments[k] = -1
            continue
        bad = False
        for i in range(m):
            for side in range(2):
                sg = 1.0 - 2.0 * side
                end, nseg, mag, bad = _follow_fast(
                    smp, i, sg, f0, target, opts.max_magnification, ws
                )
                if bad:
                    break
                out.segments[k] = max(out.segments[k], nseg)
                out.magnification[k] = max(out.magnification[k], mag)
                if opts.ridge[i] and abs(end) > far:
                    end = sg * np.inf
                if sg > 0:
                    out.hi[k, i] = Fk[i] + end
                else:
                    out.lo[k, i] = Fk[i] + end
            if bad:
                break
        if bad:
            out.segments[k] = -1


@njit(cache=True)
def _profile_kernel(S, Fh, opts, out):
    """The profile bounds along the path of :func:`_profile_reference_kernel`, without a
    factorisation per segment: ``S`` a :class:`~ditherlab.estimator.formulation.Samples`, ``Fh (N,
    m)`` [N, N·m] the estimate, ``opts`` a :class:`ProfileOptions`, ``out`` a
    :class:`ProfileOut` (all four written).

    Each sample is factored once, at the active set of ``F_hat`` (the reference's ``R0``, here by
    Cholesky of ``H0``; a pivot below :data:`MIN_PIVOT` of its diagonal hands the sample back); from
    it come ``diag(H0^-1)``, ``H0^-1 grad``, ``G0 = H0^-1 U^T`` and ``M0 = U H0^-1 U^T``
    (``U_j = sqrt(w_j) J_j^T``, one row per joint). Along the path of component ``i`` a
    breakpoint adds or removes one joint, ``H -> H +- U_j U_j^T``, and all the path needs of
    ``H^-1`` — ``h = (H^-1)_ii`` (the curvature of the profile is ``1 / h``) and
    ``g_k = (H^-1 U_k)_i`` (the joints' residual slopes ``c_k = g_k / (sqrt(w_k) h)``) — follows
    by the Sherman–Morrison formula, with the column of ``M`` it needs rebuilt from ``M0`` and
    the path's earlier updates. A segment costs ``O(n)`` and a breakpoint ``O(n t)`` after ``t``
    updates, instead of a refactorisation.

    Rank-one updates lose accuracy when a denominator ``1 +- U_j^T H^-1 U_j`` cancels; a
    sample whose path magnifies rounding by more than ``opts.max_magnification``, whose ``h``
    turns non-positive, or that exceeds the segment limit gets ``segments = -1`` and is redone
    by the reference kernel (:func:`_run_profile`).
    """
    N, m, n = S.J.shape
    _fast_loop(S, Fh, opts, out, _profile_work(m, n, 4 * n + 8))


def _run_profile(
    prob: Problem, Fm: np.ndarray, level: float, progress=None, fast: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds ``lo, hi (N, m)`` [N, N·m] and which samples the fast kernel handed back
    (``fast``: the fast kernel, those samples redone by the reference; else the reference
    alone)."""
    N, m = prob.N, prob.m
    lo_m, hi_m = np.empty((N, m)), np.empty((N, m))
    opts = ProfileOptions(
        chi2_1_quantile(level), prob.p_true == 0.0, UNOBSERVABLE, MAX_MAGNIFICATION
    )
    seg = np.zeros(N, np.int64)
    mag = np.zeros(N)
    redone = np.zeros(N, np.bool_)
    Fm = np.ascontiguousarray(Fm)
    for sl in _chunks(N, progress):
        out = ProfileOut(lo_m[sl], hi_m[sl], seg[sl], mag[sl])
        if not fast:
            _profile_reference_kernel(prob.samples(sl), Fm[sl], opts, out)
        else:
            _profile_kernel(prob.samples(sl), Fm[sl], opts, out)
            redo = sl.start + np.flatnonzero(seg[sl] < 0)
            if len(redo):  # handed back by the fast kernel: the reference path for these
                lo_r, hi_r = np.empty((len(redo), m)), np.empty((len(redo), m))
                back = ProfileOut(lo_r, hi_r, np.zeros(len(redo), np.int64), np.zeros(len(redo)))
                _profile_reference_kernel(prob.samples(redo), Fm[redo], opts, back)
                lo_m[redo], hi_m[redo], redone[redo] = lo_r, hi_r, True
        if progress is not None:
            progress(sl.stop, N)
    return lo_m, hi_m, redone


def _profile(
    prob: Problem, Fm: np.ndarray, level: float, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    """The profile bounds ``lo, hi (N, m)`` [N, N·m] of the estimated components around
    ``Fm (N, m)`` (the estimate: the path starts at the minimiser), by the fast kernel."""
    lo_m, hi_m, _ = _run_profile(prob, Fm, level, progress)
    return lo_m, hi_m


def profile_reference(
    prob: Problem, Fm: np.ndarray, level: float = 0.95
) -> tuple[np.ndarray, np.ndarray]:
    """The profile bounds ``lo, hi (N, m)`` [N, N·m] by the reference kernel: the same path, every
    segment's active set refactored from scratch (:func:`_qr_factor`), its ``H^-1 e_i`` solved
    and the cost recomputed from ``F``. Slow and obviously right; the fast kernel is tested
    against it."""
    lo_m, hi_m, _ = _run_profile(prob, Fm, level, fast=False)
    return lo_m, hi_m

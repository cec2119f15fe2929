"""The ``exact`` backend: semi-smooth Newton / active-set iteration on ``f``, compiled with
numba, all samples in one call (see :mod:`ditherlab.estimator` for the method and
``docs/design/estimator-exact-solver.md`` for its reasoning and limits).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ditherlab.estimator.formulation import Problem, Solution, _chunks, _complete_sample, complete
from ditherlab.estimator.piecewise import _cost, _dist, _sides, sample_at


class PieceWork(NamedTuple):
    """Scratch of :func:`_newton_piece` for ``m`` components and ``n`` joints.

    Attributes
    ----------
    R : (m, m)
        The triangular factor of the stacked least-squares matrix.
    z : (m,)
        Its right-hand side, rotated.
    Bm : (n, m)
        The active joints' rows ``sqrt(w_j) J_j^T``.
    bb : (n,)
        Their right-hand side.
    """

    R: np.ndarray
    z: np.ndarray
    Bm: np.ndarray
    bb: np.ndarray


class ExactWork(NamedTuple):
    """Scratch of the exact solver at one sample.

    Attributes
    ----------
    piece : PieceWork
        The piece's solve.
    x : (m,) [N, N·m]
        The minimiser of the current piece.
    d : (m,) [N, N·m]
        A step, or the minimiser of a trial piece.
    s, sn, sa : (n,) int8
        The joints' sides at ``F``, at ``x`` and of a trial piece (+1 above the band, -1 below,
        0 inside).
    F : (m,) [N, N·m]
        The current point (the previous sample's solution when warm).
    r0, c : (n,)
        The line search's residuals [N·m] at ``F`` and their slopes along the step.
    bps : (2n + 1,)
        The line search's breakpoints.
    """

    piece: PieceWork
    x: np.ndarray
    d: np.ndarray
    s: np.ndarray
    sn: np.ndarray
    sa: np.ndarray
    F: np.ndarray
    r0: np.ndarray
    c: np.ndarray
    bps: np.ndarray


@njit(cache=True)
def piece_work(m, n):
    """A :class:`PieceWork` for ``m`` components and ``n`` joints (uninitialised)."""
    return PieceWork(np.empty((m, m)), np.empty(m), np.empty((n, m)), np.empty(n))


@njit(cache=True, _nrt=False)
def _newton_piece(smp, s, work, x):
    """Minimiser ``x (m,)`` [N, N·m] of the quadratic piece of ``f`` at the sample ``smp``
    (:class:`~ditherlab.estimator.piecewise.Sample`)
    with active set ``s (n,)`` (joint ``j`` outside on side ``s_j``); ``work`` a
    :class:`PieceWork`.

    The piece is the least-squares problem ``|sqrt(p) (F - F_bar)|^2 + sum_{j active}
    w_j (tau_bar_j - e_j - J_j^T F)^2``; it is solved by QR, not by the normal equations: with
    tiny noise the normal equations square a large condition number and lose accuracy in the
    prior-held directions. The QR is by Householder reflections on the stacked matrix
    ``[diag(sqrt(p)); sqrt(w_j) J_j^T for the active joints]`` (``Bm``, ``bb``: the active rows
    and their right-hand side): the top block stays triangular, so column ``c`` reflects its
    diagonal entry and the active rows only — one square root per column instead of one per
    column and active joint by Givens rotations.
    """
    tb, J, a, b, w, p, fb = smp
    m, n = J.shape
    R, z, Bm, bb = work
    na = 0
    for j in range(n):
        if s[j] == 0:
            continue
        e = b[j] if s[j] > 0 else a[j]
        sw = math.sqrt(w[j])
        beta = tb[j] - e
        for i in range(m):
            beta -= J[i, j] * fb[i]
            Bm[na, i] = sw * J[i, j]
        bb[na] = beta * sw
        na += 1
    if na == 0:  # the prior alone: its mean (what the solve below gives, without R)
        for i in range(m):
            x[i] = 0.0 + fb[i]
        return
    for i in range(m):
        for k in range(m):
            R[i, k] = 0.0
        R[i, i] = math.sqrt(p[i])
        z[i] = 0.0  # unknown: dF = F - F_bar
    if na:
        for c in range(m):
            sig = 0.0
            for r in range(na):
                sig += Bm[r, c] * Bm[r, c]
            if sig == 0.0:
                continue
            alpha = R[c, c]  # > 0, untouched by the earlier columns' reflections
            nrm = math.sqrt(alpha * alpha + sig)
            v0 = alpha + nrm
            f2 = 2.0 / (v0 * v0 + sig)
            R[c, c] = -nrm
            for k in range(c + 1, m):
                t = v0 * R[c, k]
                for r in range(na):
                    t += Bm[r, c] * Bm[r, k]
                t *= f2
                R[c, k] -= t * v0
                for r in range(na):
                    Bm[r, k] -= t * Bm[r, c]
            t = v0 * z[c]
            for r in range(na):
                t += Bm[r, c] * bb[r]
            t *= f2
            z[c] -= t * v0
            for r in range(na):
                bb[r] -= t * Bm[r, c]
    for i in range(m - 1, -1, -1):
        v = z[i]
        for k in range(i + 1, m):
            v -= R[i, k] * x[k]
        x[i] = v / R[i, i]
    for i in range(m):
        x[i] += fb[i]


#: :func:`_newton_piece` inlined into the Newton loop of :func:`_solve_sample`: the same code,
#: without the call that passes every array of the sample and of the scratch (a sizeable part of
#: the piece's time on these small problems).
_newton_piece_inline = njit(cache=True, inline="always", _nrt=False)(_newton_piece.py_func)


@njit(cache=True, inline="always", _nrt=False)
def _sort_small(x, n):
    """``x[:n]`` sorted in place (insertion sort: a handful of breakpoints, no allocation)."""
    for q in range(1, n):
        v = x[q]
        j = q
        while j > 0 and x[j - 1] > v:
            x[j] = x[j - 1]
            j -= 1
        x[j] = v


@njit(cache=True, _nrt=False)
def _line_search(smp, F, d, ws):
    """Exact minimiser ``t`` in [0, 1] of the convex piecewise quadratic ``phi(t) = f(F + t d)``
    at the sample ``smp`` (:class:`~ditherlab.estimator.piecewise.Sample`); ``F, d (m,)``
    [N, N·m]; ``ws`` an :class:`ExactWork` (``r0``, ``c``, ``bps`` scratch)."""
    tb, J, a, b, w, p, fb = smp
    m, n = J.shape
    r0, c, bps = ws.r0, ws.c, ws.bps
    nb = 0
    for j in range(n):
        r = tb[j]
        cj = 0.0
        for i in range(m):
            r -= J[i, j] * F[i]
            cj += J[i, j] * d[i]
        r0[j] = r
        c[j] = cj
        if cj != 0.0:
            for e in (a[j], b[j]):
                t = (r - e) / cj
                if 0.0 < t < 1.0:
                    bps[nb] = t
                    nb += 1
    bps[nb] = 1.0
    nb += 1
    _sort_small(bps, nb)

    def dphi(t):
        v = 0.0
        for i in range(m):
            v += p[i] * d[i] * (F[i] + t * d[i] - fb[i])
        for j in range(n):
            v -= w[j] * c[j] * _dist(r0[j] - t * c[j], a[j], b[j])
        return v

    t0 = 0.0
    g0 = dphi(0.0)
    if g0 >= 0.0:
        return 0.0
    for q in range(nb):
        t1 = bps[q]
        g1 = dphi(t1)
        if g1 >= 0.0:
            # phi' is linear on [t0, t1]: its root
            return t0 - g0 * (t1 - t0) / (g1 - g0)
        t0, g0 = t1, g1
    return 1.0


@njit(cache=True, inline="always", _nrt=False)
def _same_piece(smp, s, sn):
    """Whether the sides ``sn`` at the piece's minimiser are the sides ``s`` it was computed
    from. A joint of zero-width band is on the same piece on either side of it (the edge is the
    same number): a sign change there is not a new active set."""
    a, b = smp.tau_min, smp.tau_max
    for j in range(len(s)):
        if sn[j] != s[j] and not (a[j] == b[j] and sn[j] != 0 and s[j] != 0):
            return False
    return True


@njit(cache=True, inline="always", _nrt=False)
def _release_ambiguous(smp, F, ws):
    """Joints held active at a distance within rounding of their band edge at the piece's
    minimiser ``ws.x``: with a huge ``w_j`` (tiny noise) and a weak prior the sign of that
    distance is noise, and the piece without such a joint may be the true optimum. Each is
    released in turn (its piece solved into ``ws.d``); ``F`` takes the best that lowers ``f``.
    Returns ``(improved, f at F)``."""
    tb, J, a, b = smp.tau_bar, smp.J, smp.tau_min, smp.tau_max
    m, n = J.shape
    s, sa, x, d = ws.s, ws.sa, ws.x, ws.d
    improved = False
    fbest = np.nan  # computed at the first joint near its edge
    for j in range(n):
        if s[j] == 0:
            continue
        e = b[j] if s[j] > 0 else a[j]
        r = tb[j]
        size = abs(tb[j]) + abs(e)
        for i in range(m):
            r -= J[i, j] * x[i]
            size += abs(J[i, j] * x[i])
        if abs(r - e) > 1e-9 * size:
            continue
        if fbest != fbest:
            f1 = _cost(smp, x)
            fbest = f1 - 1e-12 * (1.0 + f1)
        for q in range(n):
            sa[q] = s[q]
        sa[j] = 0
        _newton_piece(smp, sa, ws.piece, d)
        f2 = _cost(smp, d)
        if f2 < fbest:
            fbest = f2
            improved = True
            for i in range(m):
                F[i] = d[i]
    return improved, fbest


@njit(cache=True, inline="always", _nrt=False)
def _descend(smp, F, fcur, ws):
    """From ``F`` towards the piece's minimiser ``ws.x``: the full step when it lowers ``f``
    (``fcur``, f at ``F``), else the exact line search along it. Returns ``(f at F, stop)``,
    ``stop`` when ``F`` cannot move (the minimiser is ``F`` up to ties at a band edge)."""
    m = len(F)
    x, d = ws.x, ws.d
    fnew = _cost(smp, x)
    if fnew < fcur:
        for i in range(m):
            F[i] = x[i]
        for j in range(len(ws.s)):
            ws.s[j] = ws.sn[j]
        return fnew, False
    step = 0.0
    for i in range(m):
        d[i] = x[i] - F[i]
        step = max(step, abs(d[i]) / (1.0 + abs(F[i])))
    if step < 1e-15:
        return fcur, True  # the piece's minimiser is the current point: ties at a band edge
    t = _line_search(smp, F, d, ws)
    if t <= 0.0:
        return fcur, True
    for i in range(m):
        F[i] += t * d[i]
    _sides(smp, F, ws.s)
    return _cost(smp, F), False


@njit(cache=True, inline="always", _nrt=False)
def _solve_sample(smp, F, ws, max_iter, keep_sides):
    """The minimiser of ``f`` at the sample ``smp`` into ``F (m,)`` (which holds the start):
    Newton steps from piece to piece, each to the minimiser of the current piece (the answer
    when it lies on that piece), with the line search when a step does not lower ``f``. The
    first piece is the joints' sides at ``F``, or with ``keep_sides`` the sides ``ws.s`` holds
    (the previous sample's final piece: at a joint held on its band edge the side at the
    previous ``F`` is the noise's sign, the previous piece is the likely answer; the loops keep
    it after a sample whose first piece was its answer, so that a series of unrelated samples
    does not pay a missed guess at each). A kept piece
    whose minimiser lies on it is the answer (``f`` is convex); one whose minimiser does not is
    dropped for the sides at ``F``, from which the iteration goes on as without it (its step
    from ``F`` is a descent direction only on ``F``'s own piece). Returns the iterations."""
    m = len(F)
    if not keep_sides:
        _sides(smp, F, ws.s)
    # the cost at F, computed when first needed (most samples stop at the first piece)
    fcur = 0.0
    have_fcur = False
    it = 0
    n_amb_tries = 0
    while it < max_iter:
        it += 1
        _newton_piece_inline(smp, ws.s, ws.piece, ws.x)
        _sides(smp, ws.x, ws.sn)
        if _same_piece(smp, ws.s, ws.sn):
            improved = False
            fbest = 0.0
            if n_amb_tries < 8:
                improved, fbest = _release_ambiguous(smp, F, ws)
            if improved:
                n_amb_tries += 1
                fcur = fbest
                have_fcur = True
                _sides(smp, F, ws.s)
                continue
            for i in range(m):
                F[i] = ws.x[i]
            break
        if keep_sides:  # the kept piece missed: the sides at F from here on
            keep_sides = False
            _sides(smp, F, ws.s)
            continue
        if not have_fcur:
            fcur = _cost(smp, F)
            have_fcur = True
        fcur, stop = _descend(smp, F, fcur, ws)
        if stop:
            break
    return it


@njit(cache=True, _nrt=False)
def _solve_exact_loop(S, max_iter, warm, F_out, it_out, ws):
    """:func:`_solve_exact_kernel` on its scratch ``ws`` (:class:`ExactWork`), compiled without
    reference counts."""
    N, m, n = S.J.shape
    fb = S.prior_mean
    F = ws.F
    for i in range(m):
        F[i] = fb[i]
    for k in range(N):
        if not warm:
            for i in range(m):
                F[i] = fb[i]
        keep = warm and k > 0 and it_out[k - 1] == 1  # the previous piece was right at once
        it_out[k] = _solve_sample(sample_at(S, k), F, ws, max_iter, keep)
        for i in range(m):
            F_out[k, i] = F[i]


@njit(cache=True)
def exact_work(m, n):
    """An :class:`ExactWork` for ``m`` components and ``n`` joints."""
    return ExactWork(
        piece_work(m, n), np.empty(m), np.empty(m), np.zeros(n, np.int8), np.zeros(n, np.int8),
        np.zeros(n, np.int8), np.empty(m), np.empty(n), np.empty(n), np.empty(2 * n + 1),
    )  # fmt: skip


@njit(cache=True)
def _solve_exact_kernel(S, max_iter, warm, F_out, it_out):
    """The exact solution ``F_out (N, m)`` [N, N·m] and iterations ``it_out (N,)`` of every
    sample of the run ``S`` (:class:`~ditherlab.estimator.formulation.Samples`); ``warm``: each sample
    starts from the previous one's solution (time series are smooth), else from the prior
    mean."""
    N, m, n = S.J.shape
    _solve_exact_loop(S, max_iter, warm, F_out, it_out, exact_work(m, n))


class ExactOut(NamedTuple):
    """What :func:`_solve_complete_kernel` writes per sample: ``F (N, m)`` [N, N·m], ``it (N,)``
    and the rest of a :class:`~ditherlab.estimator.formulation.Solution`: ``tau_f (N, n)``
    [N·m], ``active (N, n)``, ``cost (N,)``, ``kkt (N,)``."""

    F: np.ndarray
    it: np.ndarray
    tau_f: np.ndarray
    active: np.ndarray
    cost: np.ndarray
    kkt: np.ndarray


@njit(cache=True, inline="always", _nrt=False)
def _prior_mean_inside(smp, k, out):
    """Whether every joint's residual at the prior mean lies in its band: then the prior mean
    is the minimiser (``f`` is 0 there and positive elsewhere), written with its completion
    (``tau_f`` the residuals, nothing active, cost and kkt 0) as sample ``k`` of ``out``
    (:class:`ExactOut`)."""
    tb, J, a, b, w, p, fb = smp
    m, n = J.shape
    for j in range(n):
        r = tb[j]
        for i in range(m):
            r -= J[i, j] * fb[i]
        if r > b[j] or r < a[j]:
            return False
        out.tau_f[k, j] = r
    for j in range(n):
        out.active[k, j] = False
    for i in range(m):
        out.F[k, i] = 0.0 + fb[i]
    out.it[k] = 1
    out.cost[k] = 0.0
    out.kkt[k] = 0.0
    return True


@njit(cache=True, _nrt=False)
def _solve_complete_loop(S, p_true, max_iter, warm, out, ws, grad, mag):
    """:func:`_solve_exact_loop` and, while the sample's numbers are in the cache, its
    completion (:func:`~ditherlab.estimator.formulation.complete`) into ``out``
    (:class:`ExactOut`); ``grad``, ``mag`` (m,) scratch. A sample whose joints all lie in their
    bands at the prior mean (a robot at rest: most samples) is answered by
    :func:`_prior_mean_inside` alone."""
    N, m, n = S.J.shape
    fb = S.prior_mean
    F = ws.F
    for i in range(m):
        F[i] = fb[i]
    solved = False  # whether ws.s holds the previous sample's final piece
    for k in range(N):
        if not warm:
            for i in range(m):
                F[i] = fb[i]
        smp = sample_at(S, k)
        if _prior_mean_inside(smp, k, out):
            for i in range(m):
                F[i] = out.F[k, i]
            solved = False
            continue
        keep = warm and solved and out.it[k - 1] == 1  # the previous piece was right at once
        out.it[k] = _solve_sample(smp, F, ws, max_iter, keep)
        solved = True
        for i in range(m):
            out.F[k, i] = F[i]
        out.cost[k], out.kkt[k] = _complete_sample(
            smp, p_true, F, out.tau_f[k], out.active[k], grad, mag
        )


@njit(cache=True)
def _solve_complete_kernel(S, p_true, max_iter, warm, out):
    """The exact solution of every sample of the run ``S`` and its completion into ``out``
    (:class:`ExactOut`); ``p_true (m,)`` the prior weights without the ridge."""
    N, m, n = S.J.shape
    _solve_complete_loop(S, p_true, max_iter, warm, out, exact_work(m, n), np.empty(m), np.empty(m))


def solve_exact(prob: Problem, max_iter: int = 100, warm: bool = True, progress=None) -> Solution:
    """The exact backend's :class:`~ditherlab.estimator.formulation.Solution` of a prepared
    :class:`Problem`: the solve and its completion in one pass over the samples (the ``F`` of
    :func:`_solve_exact` with :func:`~ditherlab.estimator.formulation.complete`; a sample
    answered by the prior mean counts one iteration), by chunks of
    :data:`~ditherlab.estimator.formulation.CHUNK` when ``progress`` is given."""
    N, m, n = prob.N, prob.m, prob.n
    if not (N and m):
        return complete(prob, *_solve_exact(prob, max_iter, warm, progress))
    out = ExactOut(
        np.empty((N, m)), np.zeros(N, np.int64), np.empty((N, n)), np.empty((N, n), np.bool_),
        np.empty(N), np.empty(N),
    )  # fmt: skip
    for sl in _chunks(N, progress):
        part = ExactOut(*(a[sl] for a in out))
        _solve_complete_kernel(prob.samples(sl), prob.p_true, max_iter, warm, part)
        if progress is not None:
            progress(sl.stop, N)
    if m == 6:  # every component estimated: the kernel's F is the answer
        F = out.F
    else:
        F = np.broadcast_to(prob.full_mean, (N, 6)).copy()
        F[:, prob.free] = out.F
    return Solution(F, out.tau_f, out.active, out.cost, out.it, out.kkt)


def _solve_exact(
    prob: Problem, max_iter: int = 100, warm: bool = True, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    """The exact backend on a prepared :class:`Problem`: ``F (N, m)`` [N, N·m] and the Newton
    iterations ``(N,)``, by chunks of :data:`~ditherlab.estimator.formulation.CHUNK` when
    ``progress`` is given."""
    F = np.empty((prob.N, prob.m))
    it = np.zeros(prob.N, np.int64)
    if prob.N and prob.m:
        for sl in _chunks(prob.N, progress):
            _solve_exact_kernel(prob.samples(sl), max_iter, warm, F[sl], it[sl])
            if progress is not None:
                progress(sl.stop, prob.N)
    return F, it

"""Fitting an effect to the band-aware residual: stacked, sign-constrained least squares.

:func:`fit_effect` fits one effect on one joint (or shared over all joints) to the scored
residuals of one or more recordings (:func:`ditherlab.physics.residual.scored`): every value of the
effect's nonlinear parameter on its grid by the band-aware least squares :func:`solve_signed`,
with the bands and the sliding line re-fitted beside it (:func:`stack`);
:func:`identifiability` says whether the bands could take the effect instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from ditherlab.core.linalg import spd_solve
from ditherlab.core.names import MOVING, Regime
from ditherlab.core.timeseries import autocorrelation_time, tmm
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.effects import Effect, FitResult, Signals, design_at, make_spec
from ditherlab.physics.effects.ranges import OutOfRange
from ditherlab.physics.residual import Scored

__all__ = [
    "ACTS_SNR",
    "MIN_IDENTIFIABILITY",
    "Stack",
    "fit_effect",
    "held_lines",
    "identifiability",
    "linear_stderr",
    "not_identifiable",
    "out_of_range",
    "recentre",
    "physical_fits",
    "shared_in_range",
    "pool_weak_joints",
    "pooled_lines",
    "pooled_note",
    "solve_signed",
    "stack",
    "undetermined",
]


def solve_signed(
    e, h, s, C, W, o, signs: Sequence[int], tied: dict[int, tuple[int, ...]] | None = None
) -> tuple[np.ndarray, float]:
    """:func:`_solve` with sign constraints on the parameters (+1: >= 0, -1: <= 0, 0: free).

    A parameter whose unconstrained value has the wrong sign is held at 0 and the rest re-fitted
    (an active-set loop; the problem is convex, so this reaches the constrained optimum for the
    one- and two-parameter effects with constraints here). ``tied`` maps a parameter to those
    held at 0 with it (:attr:`Effect.tied`: a payload's first moments vanish with its mass).
    """
    k = C.shape[1]
    sg = np.asarray(signs, dtype=float)
    tied = tied or {}
    free = np.ones(k, dtype=bool)
    w = np.zeros(k)
    L = float(np.sum((np.maximum(np.abs(e - o) - h, 0.0) / s) ** 2))
    for _ in range(k + 1):
        if not free.any():
            break
        wf, L = _solve(e, h, s, C[:, free], W[:, free], o)
        w = np.zeros(k)
        w[free] = wf
        bad = free & (sg * w < 0)
        if not bad.any():
            return w, L
        for i in np.flatnonzero(bad):
            bad[list(tied.get(int(i), ()))] = True
        free &= ~bad
    w = np.zeros(k)
    if free.any():
        wf, L = _solve(e, h, s, C[:, free], W[:, free], o)
        w[free] = wf
    else:
        L = float(np.sum((np.maximum(np.abs(e - o) - h, 0.0) / s) ** 2))
    return w, L


def _solve(e, h, s, C, W, o, w0=None, iters: int = 40) -> tuple[np.ndarray, float]:
    """Minimise ``sum((max(0, |e - o - C w| - h - W w) / s)²)`` over w (convex).

    Semi-smooth Gauss–Newton on the active set (samples outside the band) with a backtracking
    line search, compiled with numba (:func:`_solve_kernel`: diagnosis runs thousands of these
    on a few thousand samples each, too small for numpy's per-call overhead;
    ``docs/design/physics-effect-fit.md``). :func:`_solve_reference` is the same iteration in
    numpy.

    Parameters
    ----------
    e : (M,) [N·m] residual about the band centre ; o : (M,) [N·m] its offset
    h : (M,) [N·m] band half-widths ; s : (M,) [N·m] noise levels
    C, W : (M, k) [N·m per unit parameter] the designs that shift and widen
    w0 : (k,) the start (default 0) ; iters : most Gauss-Newton steps

    Returns
    -------
    w (k,), loss [-]
    """
    f = np.ascontiguousarray
    C = f(C, dtype=float)
    W = f(W, dtype=float)
    base = f(np.asarray(e, dtype=float) - o)
    k = C.shape[1]
    w = np.zeros(k) if w0 is None else np.array(w0, dtype=float)
    if len(base) == 0:  # nothing to fit (a fold of a very short log): the start, no loss
        return w, 0.0
    w, L = _solve_kernel(
        base, f(h, dtype=float), f(s, dtype=float), C, W, w, int(iters), bool(W.any())
    )
    return w, float(L)


@njit(cache=True, inline="always")
def _residual_at(base, h, C, W, w, i, widen):  # pragma: no cover - compiled
    """Sample i's residual ``x = base - C w`` and its excess ``|x| - h - W w`` beyond the band."""
    x = base[i]
    ww = 0.0
    for c in range(C.shape[1]):
        x -= C[i, c] * w[c]
        if widen:
            ww += W[i, c] * w[c]
    return x, abs(x) - h[i] - ww


@njit(cache=True)
def _loss_kernel(base, h, s, C, W, w, widen):  # pragma: no cover - compiled
    """The loss ``sum((max(0, excess) / s)²)`` at the parameters ``w`` (k,)."""
    L = 0.0
    for i in range(C.shape[0]):
        ex = _residual_at(base, h, C, W, w, i, widen)[1]
        if ex > 0.0:
            L += (ex / s[i]) ** 2
    return L


# Its problem as flat arrays: bundled in a NamedTuple they slow it (docs/design/physics-effect-fit.md)
@njit(cache=True)
def _solve_kernel(base, h, s, C, W, w, iters, widen):  # pragma: no cover - compiled
    """:func:`_solve`'s iteration from the start ``w`` (k,) -> (w, loss)."""
    M, k = C.shape
    L = _loss_kernel(base, h, s, C, W, w, widen)
    if k == 0:
        return w, L
    scale = _column_scale(C, W)
    act = np.zeros(M, dtype=np.bool_)
    prev = np.zeros(M, dtype=np.bool_)
    have_prev = False
    for _ in range(iters):
        G, g, n_act = _gauss_newton(base, h, s, C, W, w, widen, scale, act)
        if n_act == 0:
            break
        if have_prev and _same(act, prev):
            break  # the last full Gauss-Newton step solved this piece exactly
        d = _newton_step(G, g, scale)
        if d is None:
            break
        ok, t, wn, Ln = _line_search(base, h, s, C, W, w, widen, d, L)
        if not ok:
            break
        improve = L - Ln
        w = wn
        L = Ln
        have_prev = t == 1.0
        if have_prev:
            prev[:] = act
        if improve <= 1e-12 * max(L, 1e-300) and t == 1.0:
            break
    return w, L


@njit(cache=True, inline="always")
def _column_scale(C, W):  # pragma: no cover - compiled
    """(k,): each parameter's RMS design, ``sqrt(mean(C²) + mean(W²))`` (never 0)."""
    M, k = C.shape
    scale = np.empty(k)
    for c in range(k):
        a = 0.0
        b = 0.0
        for i in range(M):
            a += C[i, c] ** 2
            b += W[i, c] ** 2
        scale[c] = math.sqrt(a / M + b / M) + 1e-300
    return scale


@njit(cache=True, inline="always")
def _gauss_newton(base, h, s, C, W, w, widen, scale, act):  # pragma: no cover - compiled
    """The Gauss-Newton system at ``w`` in the scaled parameters: ``G`` (k, k) (its lower
    triangle), ``g`` (k,) and the number of samples outside the band, marked in ``act`` (M,)."""
    k = C.shape[1]
    G = np.zeros((k, k))
    g = np.zeros(k)
    row = np.empty(k)
    n_act = 0
    for i in range(C.shape[0]):
        x, ex = _residual_at(base, h, C, W, w, i, widen)
        act[i] = ex > 0.0
        if not act[i]:
            continue
        n_act += 1
        sg = 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
        for c in range(k):
            row[c] = (-(sg * C[i, c]) - W[i, c]) / (s[i] * scale[c])
        r = ex / s[i]
        for a in range(k):
            g[a] += row[a] * r
            for b in range(a + 1):
                G[a, b] += row[a] * row[b]
    return G, g, n_act


@njit(cache=True, inline="always")
def _same(act, prev):  # pragma: no cover - compiled
    """The two (M,) bool arrays are equal."""
    for i in range(act.shape[0]):
        if act[i] != prev[i]:
            return False
    return True


@njit(cache=True, inline="always")
def _newton_step(G, g, scale):  # pragma: no cover - compiled
    """The step (k,) in the parameters: ``G`` symmetrised from its lower triangle, a ridge of
    1e-9 of its mean diagonal (keeps singular designs, e.g. no motion, finite), solved and
    unscaled; None when ``G`` is not positive definite."""
    k = G.shape[0]
    tr = 0.0
    for a in range(k):
        for b in range(a):
            G[b, a] = G[a, b]
        tr += G[a, a]
    for a in range(k):
        G[a, a] += 1e-9 * (tr / k + 1e-300)
    d = spd_solve(G, g)
    if d is None:
        return None
    for c in range(k):
        d[c] = -d[c] / scale[c]
    return d


@njit(cache=True, inline="always")
def _line_search(base, h, s, C, W, w, widen, d, L):  # pragma: no cover - compiled
    """Backtracking from the full step ``d`` until the loss is not above ``L``: (found, step
    length, parameters, loss)."""
    k = w.shape[0]
    t = 1.0
    ok = False
    wn = w.copy()
    Ln = L
    while t > 1e-4:
        for c in range(k):
            wn[c] = w[c] + t * d[c]
        Ln = _loss_kernel(base, h, s, C, W, wn, widen)
        if Ln <= L:
            ok = True
            break
        t *= 0.5
    return ok, t, wn, Ln


def _solve_reference(e, h, s, C, W, o, w0=None, iters: int = 40) -> tuple[np.ndarray, float]:
    """The obviously right version of :func:`_solve` in numpy (its test's reference).

    Minimise ``sum((max(0, |e - o - C w| - h - W w) / s)²)`` over w (convex).

    Semi-smooth Gauss–Newton on the active set (samples outside the band) with a backtracking
    line search. Shapes: e, h, s, o (M,); C, W (M, k).

    Returns
    -------
    w (k,), loss
    """
    k = C.shape[1]
    base = e - o
    s2 = 1.0 / s**2
    if k == 0:
        return np.zeros(0), float(np.sum(np.maximum(np.abs(base) - h, 0.0) ** 2 * s2))

    def mv(A: np.ndarray, w: np.ndarray) -> np.ndarray:
        # single-threaded matrix-vector product (see _mm)
        return np.einsum("mk,k->m", A, w)

    def loss_of(w: np.ndarray) -> float:
        x = base - mv(C, w)
        return float(np.sum(np.maximum(np.abs(x) - h - mv(W, w), 0.0) ** 2 * s2))

    w = np.zeros(k) if w0 is None else np.asarray(w0, dtype=float).copy()
    L = loss_of(w)
    scale = np.sqrt(np.mean(C**2, axis=0) + np.mean(W**2, axis=0)) + 1e-300
    prev_act = None
    for _ in range(iters):
        x = base - mv(C, w)
        sg = np.sign(x)
        ex = np.abs(x) - h - mv(W, w)
        act = ex > 0
        if not act.any():
            break
        if prev_act is not None and np.array_equal(act, prev_act):
            break  # the last full Gauss-Newton step solved this piece exactly
        Jm = (-(sg[act, None] * C[act]) - W[act]) / (s[act, None] * scale)
        r = ex[act] / s[act]
        # ridge-regularised normal equations (keeps singular designs, e.g. no motion, finite)
        G = tmm(Jm, Jm)
        G[np.diag_indices(k)] += 1e-9 * (np.trace(G) / k + 1e-300)
        try:
            d = -np.linalg.solve(G, np.einsum("mk,m->k", Jm, r)) / scale
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while t > 1e-4:
            wn = w + t * d
            Ln = loss_of(wn)
            if Ln <= L:
                break
            t *= 0.5
        else:
            break
        improve = L - Ln
        w, L = wn, Ln
        prev_act = act if t == 1.0 else None
        if improve <= 1e-12 * max(L, 1e-300) and t == 1.0:
            break
    return w, L


@dataclass
class Stack:
    """Samples of one or several recordings stacked for one joint (or all joints, shared).

    The design ``C`` (and ``W``) holds the effect's ``k`` columns followed by nuisance columns:
    one indicator per (joint, regime) group, and per joint ``sign(dq)`` and ``dq`` in the moving
    regime (when the model has Coulomb / viscous terms). Identification re-fits the bands and
    the sliding line with the effect in place, so they absorb whatever part of an effect is
    constant within a regime or proportional to sign(dq) or dq: an effect is credited only with
    the rest, and the baseline it is compared with gets the same nuisance columns.
    """

    e: np.ndarray
    h: np.ndarray
    s: np.ndarray
    C: np.ndarray
    W: np.ndarray
    o: np.ndarray
    block: np.ndarray  # (M,) row of the whole recordings, concatenated (for folds)
    k: int  # number of effect columns (the rest are intercepts)
    joint: np.ndarray | None = None  # (M,) joint of each row (time order: lexsort by joint, block)

    def time_order(self) -> np.ndarray:
        """(M,) row order by joint, then row of the recordings: the same however the
        recordings were cut into pieces (the stack itself runs piece by piece)."""
        if self.joint is None:
            return np.argsort(self.block, kind="stable")
        return np.lexsort((self.block, self.joint))

    def signs(self, eff: Sequence[int]) -> tuple[int, ...]:
        """The signs of all columns: the effect's (free where it gives fewer, e.g. an effect
        whose number of columns is chosen from the data), then the free nuisance columns."""
        eff = tuple(eff)[: self.k]
        return eff + (0,) * (self.C.shape[1] - len(eff))


@dataclass
class StackRows:
    """What a :class:`Stack` of joint ``j`` holds whatever the effect's parameter: the rows
    (:func:`stack_rows`), their residual, band, noise, block and joint, and the nuisance
    columns ``N`` (M, p); :func:`stack` adds the effect's design at one parameter value."""

    e: np.ndarray
    h: np.ndarray
    s: np.ndarray
    block: np.ndarray
    joint: np.ndarray
    N: np.ndarray
    #: per recording and joint: (recording, joint, rows used (L,) bool, moving rows (L,) bool)
    rows: list[tuple[int, int, np.ndarray, np.ndarray]]


def stack_rows(sc: Sequence[Scored], j: int | None) -> StackRows:
    """The parameter-free part of :func:`stack` (joint j, or all joints when None)."""
    es, hs, ss, bs, gs, js, rows = [], [], [], [], [], [], []
    ns: list[tuple[int, np.ndarray]] = []
    t0 = 0
    for i, s in enumerate(sc):
        joints = range(s.sig.n) if j is None else [j]
        for jj in joints:
            m = s.use[:, jj]
            mv = s.sig.regime[:, jj] == MOVING
            rows.append((i, jj, m, mv))
            es.append(s.e[m, jj])
            hs.append(s.h[m, jj])
            ss.append(s.sigma[m, jj])
            bs.append(t0 + s.sig.index[m])
            gs.append(jj * 3 + s.sig.regime[m, jj].astype(np.int64))
            js.append(np.full(int(m.sum()), jj, np.int64))
            # sliding-friction nuisance (moving only): joint jj's sign(dq) and dq columns
            dqm = np.where(mv, s.sig.dq[:, jj], 0.0)[m]
            cols = []
            if s.sliding[0]:
                cols.append(np.sign(dqm))
            if s.sliding[1]:
                cols.append(dqm)
            ns.append((jj, np.column_stack(cols) if cols else np.zeros((len(dqm), 0))))
        t0 += s.sig.length
    e_, h_, s_, b_, g_ = (np.concatenate(a) for a in (es, hs, ss, bs, gs))
    _, gi = np.unique(g_, return_inverse=True)
    G = np.zeros((len(g_), int(gi.max()) + 1 if len(g_) else 0))
    G[np.arange(len(g_)), gi] = 1.0
    # sliding columns per joint, block-placed (zeros for the other joints' rows)
    joints_in = sorted({jj for jj, _ in ns})
    width = max((a.shape[1] for _, a in ns), default=0)
    S = np.zeros((len(g_), width * len(joints_in)))
    r0 = 0
    for jj, a in ns:
        c0 = joints_in.index(jj) * width
        S[r0 : r0 + len(a), c0 : c0 + a.shape[1]] = a
        r0 += len(a)
    S = S[:, np.any(S != 0, axis=0)]
    return StackRows(e_, h_, s_, b_, np.concatenate(js), np.hstack([G, S]), rows)


def stack(
    e: Effect,
    sc: Sequence[Scored],
    j: int | None,
    h: Any,
    ref: dict[str, Any],
    lags: Sequence[int] | None = None,
    rows: StackRows | None = None,
) -> Stack:
    """Flatten the scored samples of joint j (or all joints when the effect is shared).

    ``lags`` (one per recording, samples): the effect's design circularly shifted in time by
    this much against the residual, a surrogate whose driving variable carries no information
    about the residual (the bands and the sliding line stay where they are). On scored rows
    of a recording (:meth:`Signals.take`) the lags count those rows, and ``block`` numbers the
    samples by their rows in the whole recordings. ``rows``: :func:`stack_rows` of the same
    ``sc`` and ``j``, computed once for a search over ``h`` (the same stack, bit for bit).
    """
    r = stack_rows(sc, j) if rows is None else rows
    Cs, Ws, os_ = [], [], []
    designs: dict[int, Any] = {}
    for i, jj, m, mv in r.rows:
        if i not in designs:
            d = design_at(e, sc[i].sig, j, h, ref)
            designs[i] = d.rolled(int(lags[i])) if lags is not None and lags[i] else d
        d = designs[i]
        if j is None:
            C = d.centre[:, jj, :]
            Wd = d.widen[:, jj, :] if d.widen is not None else None
            o = d.offset[:, jj] if d.offset is not None else None
        else:
            C, Wd, o = d.centre, d.widen, d.offset
        Cs.append(C[m])
        Ws.append(np.zeros_like(C[m]) if Wd is None else (Wd * ~mv[:, None])[m])
        os_.append(np.zeros(int(m.sum())) if o is None else o[m])
    C_, W_, o_ = (np.concatenate(a) for a in (Cs, Ws, os_))
    k = C_.shape[1]
    W = np.hstack([W_, np.zeros_like(r.N)])
    return Stack(r.e, r.h, r.s, np.hstack([C_, r.N]), W, o_, r.block, k, r.joint)


def recentre(model: TorqueModel, sc: Sequence[Scored]) -> TorqueModel:
    """A copy of ``model`` with each joint's bands moved and its sliding line changed by what
    :func:`fit_effect` re-fits beside an effect (the nuisance columns of :func:`stack`: one
    intercept per regime, ``sign(dq)`` and ``dq`` while moving), fitted to the residuals ``sc``
    of ``model`` on the recordings (scored under it, its effects in place).

    An effect's fit credits it only with what the bands and the sliding line cannot take; where
    the bands are not re-identified after adding it (no sensor and no statement that no force
    acts), they must move by what that fit moved them, or the model applies the effect's mean
    part on top of bands that already hold it.
    """
    out = model.copy()
    for j in range(model.n):
        r = stack_rows(sc, j)
        if not len(r.e) or not r.N.shape[1]:
            continue
        free = (0,) * r.N.shape[1]
        w, _ = solve_signed(r.e, r.h, r.s, r.N, np.zeros_like(r.N), np.zeros(len(r.e)), free)
        codes = np.unique(np.concatenate([s.sig.regime[s.use[:, j], j] for s in sc]))
        for c, shift in zip(codes, w, strict=False):
            band = out.regimes.get(Regime(int(c)).label)
            if band is not None:
                band.tau_min[j] += shift
                band.tau_max[j] += shift
        _slide(out, sc, j, w[len(codes) :])
    return out


def _slide(model: TorqueModel, sc: Sequence[Scored], j: int, w: np.ndarray) -> None:
    """Add the fitted ``sign(dq)`` and ``dq`` coefficients ``w`` of joint ``j`` (those of
    :func:`stack_rows`'s sliding columns that act) to the moving band's Coulomb and viscous."""
    band = model.regimes.get(Regime.MOVING.label)
    if band is None or not len(w):
        return
    names = [n for n, on in zip(("coulomb", "viscous"), sc[0].sliding, strict=True) if on]
    acts = []
    for n in names:
        col = [
            (np.sign if n == "coulomb" else np.asarray)(
                np.where(s.sig.regime[:, j] == MOVING, s.sig.dq[:, j], 0.0)[s.use[:, j]]
            )
            for s in sc
        ]
        acts.append(bool(np.any(np.concatenate(col) != 0)))
    for n, v in zip([n for n, a in zip(names, acts, strict=True) if a], w, strict=False):
        arr = getattr(band, n)
        if arr is not None:
            arr[j] += float(v)


#: Smallest :func:`identifiability` for which add_effect accepts a fit.
MIN_IDENTIFIABILITY = 0.02


def identifiability(st: Stack) -> float:
    """How much of the effect's design is left once the nuisance columns are projected out.

    The smallest singular value of the effect columns (weighted by 1/sigma) after removing
    their least-squares projection on the intercept and sliding-friction columns, relative to
    their own norm: 1 = fully distinct, 0 = the bands and the sliding line can take it all (e.g.
    ``ft_bias`` or ``payload`` in one fixed pose), and then its parameters are arbitrary.
    Effect columns that are zero on every sample (a parameter that does not act on these
    recordings at all, e.g. the offset of a joint gravity does not depend on) are left out;
    all zero gives 0.
    """
    if st.k == 0 or len(st.e) == 0:
        return 0.0
    w = 1.0 / st.s[:, None]
    acts = np.any(st.C[:, : st.k] != 0, axis=0)
    if not acts.any():
        return 0.0
    Ce = st.C[:, : st.k][:, acts] * w
    N = st.C[:, st.k :] * w
    if N.shape[1]:
        coef, *_ = np.linalg.lstsq(N, Ce, rcond=None)
        Ce = Ce - N @ coef
    norms = np.linalg.norm(st.C[:, : st.k][:, acts] * w, axis=0)
    if not np.all(norms > 0):
        return 0.0
    return float(np.linalg.svd(Ce / norms, compute_uv=False).min())


def fit_effect(
    e: Effect,
    sc: Sequence[Scored],
    j: int | None,
    train: Callable[[np.ndarray], np.ndarray] | None = None,
) -> FitResult:
    """Fit effect ``e`` on joint ``j`` (None: shared parameters over all joints).

    Every value of the nonlinear parameter on the effect's grid is fitted by band-aware least
    squares (:func:`_solve`); the one with the smallest loss is kept. For an effect whose
    parameter is continuous (``position_ripple``'s period), the final fit (``train`` None)
    refines it between the best value's grid neighbours (bounded Brent search): the grid is
    spaced a quarter cycle over the joint's span, which leaves up to 1/8 cycle of phase error at
    the ends of the span (``docs/design/physics-effect-fit.md``).

    Parameters
    ----------
    e : Effect
    sc : scored residuals (:func:`scored`) of one or more recordings
    j : 0-based joint, or None for a shared effect
    train : optional function of the stack's time index (M,) -> bool mask of training samples

    Returns
    -------
    FitResult (w, h, ref, loss on the training samples)
    """
    sigs = [s.sig for s in sc]
    ref = e.reference(sigs, j)
    best: FitResult | None = None
    grid = full = e.grid(sigs, j)
    rows = stack_rows(sc, j)  # the same for every value of the parameter
    if not e.shared and j is not None and len(grid) > 1:
        st0 = stack(e, sc, j, grid[0], ref, rows=rows)
        m0 = train(st0.block) if train is not None else np.ones(len(st0.e), dtype=bool)
        grid = e.shortlist(sc, j, grid, [m0])[0]

    def fit_at(h: Any) -> FitResult:
        st = stack(e, sc, j, h, ref, rows=rows)
        m = train(st.block) if train is not None else slice(None)
        w, L = solve_signed(
            st.e[m], st.h[m], st.s[m], st.C[m], st.W[m], st.o[m], st.signs(e.signs(h)), e.tied
        )
        return FitResult(w[: st.k], h, ref, L)

    for h in grid:
        f = fit_at(h)
        if best is None or f.loss < best.loss:
            best = f
    assert best is not None
    if e.continuous and train is None and len(full) > 2:
        # the final fit: the grid's best value refined between its grid neighbours
        k = int(np.argmin(np.abs(np.asarray(full, dtype=float) - float(best.h))))
        lo, hi = sorted((float(full[max(k - 1, 0)]), float(full[min(k + 1, len(full) - 1)])))
        r = minimize_scalar(
            lambda h: fit_at(float(h)).loss,
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-6 * abs(float(best.h))},
        )
        f = fit_at(float(r.x))
        if f.loss < best.loss:
            best = f
    return best


def not_identifiable(e: Effect, sc: Sequence[Scored], j: int | None, fit: FitResult) -> str | None:
    """Why effect ``e`` fitted on joint ``j`` (None: shared) cannot be told apart from the bands
    on these scored recordings, or None when it can: the one rule behind both ``identify --add``
    (which refuses) and diagnosis (which does not suggest such an effect, and says why).

    The rule: :func:`identifiability` of the fitted effect's design, after the bands and the
    sliding line have taken what they can, is at least :data:`MIN_IDENTIFIABILITY`.
    """
    why = e.unsupported([s.sig for s in sc], j, fit.h)
    if why is not None:
        return why
    st = stack(e, sc, j, fit.h, fit.ref)
    if identifiability(st) >= MIN_IDENTIFIABILITY:
        return None
    where = "these recordings" if j is None else f"joint {j + 1} of these recordings"
    return (
        f"effect {e.name!r} cannot be told apart from the bands in {where}: its torque "
        f"barely changes within a regime ({e.driven_by}); record a varying pose, motion "
        "or force"
    )


def out_of_range(
    e: Effect, sc: Sequence[Scored], fits: dict[int, FitResult]
) -> dict[int, OutOfRange]:
    """The fits of ``e`` (0-based joint -> :class:`FitResult`; -1 for a shared effect) with a
    value outside its physical range (:meth:`Effect.outside_range` on these scored
    recordings), by joint: the one rule behind ``identify --add`` (which refuses them) and
    diagnosis (which does not suggest the effect there and lists them)."""
    sigs = [s.sig for s in sc]
    out = {}
    for j, f in fits.items():
        spec = make_spec(e, {j: f})
        p = spec.params if e.shared else {k: v[0] for k, v in spec.params.items()}
        why = e.outside_range(p, sigs, None if j < 0 else j)
        if why is not None:
            out[j] = why
    return out


#: block length for the standard errors of :func:`linear_stderr` [s]: the residual of one push
#: (0.5-2 s) and its extraction's lag are correlated; blocks of 2 s hold one each (identify's
#: bootstrap uses the same length)
STDERR_BLOCK_S = 2.0


def linear_stderr(
    e: Effect, sc: Sequence[Scored], j: int, fit: FitResult, block_s: float = STDERR_BLOCK_S
) -> np.ndarray:
    """Standard errors of the linear parameters of a per-joint fit, from the fit's own
    information: the Gauss–Newton matrix of the band-aware loss at the fitted value (rows
    outside the band), with the score's variance summed over contiguous blocks of ``block_s``
    seconds (a cluster "sandwich": neighbouring samples of one push are not independent, and
    counting them as such makes a gain fitted on a few pushes look exact;
    ``docs/design/physics-effect-fit.md``).

    Parameters
    ----------
    e, sc, j, fit : the effect, the scored recordings, the 0-based joint and its fit
        (:func:`fit_effect`)
    block_s : block length [s]

    Returns
    -------
    (k,) standard errors in the parameters' units; ``inf`` where the parameter is not
    determined (no row outside the band, or a singular information matrix).
    """
    st = stack(e, sc, j, fit.h, fit.ref)
    k = st.k
    w, _ = solve_signed(st.e, st.h, st.s, st.C, st.W, st.o, st.signs(e.signs(fit.h)), e.tied)
    r = st.e - st.o - st.C @ w
    sg = np.sign(r)
    ex = sg * np.maximum(np.abs(r) - st.h - st.W @ w, 0.0)  # the excess beyond the band
    act = ex != 0
    if act.sum() <= st.C.shape[1]:
        return np.full(k, np.inf)
    D = (st.C + sg[:, None] * st.W)[act] / st.s[act, None]  # d(excess / s) / dw, up to sign
    keep = np.any(D != 0, axis=0)
    D = D[:, keep]
    H = D.T @ D
    try:
        Hi = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full(k, np.inf)
    rate = sc[0].sig.rec.sample_rate if sc else 1.0
    blk = (st.block[act] // max(int(round(block_s * rate)), 1)).astype(np.int64)
    _, b = np.unique(blk, return_inverse=True)
    g = D * (ex[act] / st.s[act])[:, None]
    G = np.zeros((int(b.max()) + 1, D.shape[1]))
    np.add.at(G, b, g)
    nb = G.shape[0]
    scale = nb / (nb - D.shape[1]) if nb > D.shape[1] else np.inf
    cov = Hi @ (G.T @ G) @ Hi * scale
    var = np.full(keep.shape, np.inf)
    var[keep] = np.diag(cov)
    var = np.where(np.isfinite(var) & (var >= 0), var, np.inf)
    return np.sqrt(var[:k])


def _linear_ranges(e: Effect, sc: Sequence[Scored], j: int) -> list[tuple[float, float]]:
    """The physical range of each of ``e``'s linear parameters on joint ``j`` (``e.bounds``
    that bound the parameter itself or, by :attr:`Bound.linear`, an offset of it; unbounded
    where none does), in the order of ``e.linear``."""
    sigs = [s.sig for s in sc]
    ranges: dict[str, tuple[float, float]] = {}
    for b in e.bounds:
        lo, hi = b.limits(sigs, j)
        if b.linear is not None:
            ranges[b.linear[0]] = (lo - b.linear[1], hi - b.linear[1])
        elif b.value is None:
            ranges[b.param] = (lo, hi)
    return [ranges.get(name, (-np.inf, np.inf)) for name in e.linear]


def _weak_reason(e: Effect, sc: Sequence[Scored], j: int, fit: FitResult) -> str | None:
    """Why a per-joint fit of ``e`` rests on too little evidence (``e.evidence_rules``), or
    None: a linear parameter whose standard error (:func:`linear_stderr`) exceeds its
    ``stderr_max``, or that lies more than two standard errors outside its physical range
    (``e.bounds``: the data contradict the physics there, so the joint takes the shared values;
    a fit within two standard errors of the range is held at its edge by :func:`pool_weak_joints`)."""
    rules = e.evidence_rules or {}
    se = linear_stderr(e, sc, j, fit)
    for i, (name, (lo, hi)) in enumerate(zip(e.linear, _linear_ranges(e, sc, j), strict=True)):
        v, s = float(fit.w[i]), float(se[i])
        top = rules.get("stderr_max", {}).get(name)
        if top is not None and not s <= top:
            return f"{name} {v:.3g} ± {s:.2g} (standard error above {top:g})"
        if v - 2 * s > hi or v + 2 * s < lo:
            return (
                f"{name} {v:.3g} ± {s:.2g} (outside {lo:g}..{hi:g}, its physical range, "
                "by more than 2 standard errors)"
            )
    return None


def _held_in_range(e: Effect, sc: Sequence[Scored], j: int, fit: FitResult) -> FitResult:
    """``fit`` with each linear parameter held at the nearest edge of its physical range (the
    bounded least-squares fit of a single linear parameter at the fit's own hyper-parameter);
    ``fit`` itself when every value is inside."""
    lims = np.array(_linear_ranges(e, sc, j), dtype=float).reshape(-1, 2)
    w = np.clip(np.asarray(fit.w, dtype=float)[: len(lims)], lims[:, 0], lims[:, 1])
    if np.array_equal(w, np.asarray(fit.w, dtype=float)[: len(lims)]):
        return fit
    return FitResult(np.concatenate([w, np.asarray(fit.w)[len(lims) :]]), fit.h, fit.ref, fit.loss)


#: the level of the likelihood-ratio test by which :func:`bounded_fit` holds parameters at the
#: edge of their physical range: the edge is kept unless the data reject it at this level
EDGE_LEVEL = 0.05

#: noise sigmas a term must reach on at least one scored sample to act there: a joint an
#: effect's design acts on (:func:`ditherlab.analysis.scoring.acting_joints`), a linear
#: parameter the data can move across its physical range (:func:`undetermined`)
ACTS_SNR = 3.0


def _linear_nominals(e: Effect) -> list[float | None]:
    """The declared nominal value of each of ``e``'s linear parameters (``Bound.nominal`` of
    the bound on the parameter itself), None where none is declared, in the order of
    ``e.linear``."""
    nom = {b.param: b.nominal for b in e.bounds if b.value is None and b.linear is None}
    return [nom.get(name) for name in e.linear]


def undetermined(e: Effect, st: Any, lims: np.ndarray) -> np.ndarray:
    """(k,) bool: the linear parameters of ``e`` with a declared nominal
    (:attr:`~ditherlab.physics.effects.ranges.Bound.nominal`) whose term, moved across the whole
    physical range ``lims`` (k, 2), changes the torque by less than :data:`ACTS_SNR` noise
    sigmas on every row of the stack ``st``: the data cannot determine them (a wrist's last
    link, whose own dynamic torque stays at 0.01-0.03 sigma while its rotor's reaches 30-60), so
    any value fits whatever else the residual holds."""
    nom = _linear_nominals(e)
    out = np.zeros(st.k, dtype=bool)
    for i in range(st.k):
        width = float(lims[i, 1] - lims[i, 0])
        if nom[i] is None or not np.isfinite(width) or not len(st.s):
            continue
        col = (np.abs(st.C[:, i]) + np.abs(st.W[:, i])) / st.s
        out[i] = float(np.max(col)) * width < ACTS_SNR
    return out


def _solve_held(
    st: Any, sg: np.ndarray, held: np.ndarray, v: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """The band-aware least-squares fit of the stack ``st`` with the columns ``held`` at the
    values ``v`` and the others free: (every column's value, loss); None when a held width
    falls below zero (no band-aware loss to compare)."""
    o = st.o + st.C[:, held] @ v[held]
    h = st.h + st.W[:, held] @ v[held]
    if np.any(h < 0):
        return None
    wf, L = solve_signed(st.e, h, st.s, st.C[:, ~held], st.W[:, ~held], o, sg[~held])
    w = v.copy()
    w[~held] = wf
    return w, L


def bounded_fit(e: Effect, sc: Sequence[Scored], j: int, fit: FitResult) -> FitResult:
    """The per-joint fit of ``e`` on joint ``j`` (0-based) as it can be written, at the fit's own
    hyper-parameter:

    1. a linear parameter the data cannot determine (:func:`undetermined`) is held at its
       declared nominal value and the others re-fitted;
    2. a linear parameter still outside its physical range (:func:`_linear_ranges`) is held at
       the nearest edge and the others re-fitted (an active set: bounded least squares), when
       the data do not reject the held values: the likelihood-ratio statistic ``n_eff ·
       ln(L_held / L)`` against the fit of step 1 (the band-aware losses, ``n_eff`` the samples
       outside the band over their :func:`~ditherlab.core.timeseries.autocorrelation_time`, as
       diagnosis's BIC counts them) is within the χ² quantile of :data:`EDGE_LEVEL` with one
       degree of freedom per parameter held at an edge. Two parameters that the data tell apart
       only together (a wrist's link inertia scale and its rotor inertia, both driven by
       ``ddq``) fit as well with one at its edge.

    Returns ``fit`` itself when nothing is held; the fit of step 1 when the edges of step 2 are
    rejected (the data insist on an unphysical value: :func:`out_of_range` says so) or a
    re-fitted value leaves its own range.
    """
    lims = np.array(_linear_ranges(e, sc, j), dtype=float).reshape(-1, 2)
    w0 = np.asarray(fit.w, dtype=float)
    k = len(lims)
    if k == 0:
        return fit
    st = stack(e, sc, j, fit.h, fit.ref)
    fixed = undetermined(e, st, lims)
    inside = np.all((w0[:k] >= lims[:, 0]) & (w0[:k] <= lims[:, 1]))
    if inside and not fixed.any():
        return fit
    sg = np.asarray(st.signs(e.signs(fit.h)))
    held = np.zeros(st.C.shape[1], dtype=bool)
    v = np.zeros(st.C.shape[1])
    if fixed.any():
        held[:k] = fixed
        v[:k][fixed] = [_linear_nominals(e)[i] for i in np.flatnonzero(fixed)]
        got = _solve_held(st, sg, held, v)
        if got is None:
            return fit
        w_base, L_base = got
    else:
        w_base, L_base = solve_signed(st.e, st.h, st.s, st.C, st.W, st.o, sg, e.tied)
    base = FitResult(w_base[: st.k], fit.h, fit.ref, L_base) if fixed.any() else fit
    w, L = w_base, L_base
    edge = np.zeros_like(held)
    for _ in range(k):
        out = np.flatnonzero(~held[:k] & ((w[:k] < lims[:, 0]) | (w[:k] > lims[:, 1])))
        if not len(out):
            break
        held[out] = edge[out] = True
        v[out] = np.clip(w[out], lims[out, 0], lims[out, 1])
        got = _solve_held(st, sg, held, v)
        if got is None:
            return base
        w, L = got
    if not edge.any():
        return base
    if np.any((w[:k] < lims[:, 0] - 1e-12) | (w[:k] > lims[:, 1] + 1e-12)):
        return base
    if not _edge_accepted(st, w_base, L_base, L, int(edge.sum())):
        return base
    return FitResult(w[: st.k], fit.h, fit.ref, L)


def _edge_accepted(st: Any, w_free: np.ndarray, L_free: float, L_held: float, df: int) -> bool:
    """Whether the data accept a fit held at the edge of a range (loss ``L_held``) against the
    free one (``w_free``, ``L_free``): the likelihood-ratio statistic ``n_eff · ln(L_held /
    L_free)`` within the χ² quantile of :data:`EDGE_LEVEL` with ``df`` degrees of freedom,
    ``n_eff`` the free fit's samples outside the band over their autocorrelation time."""
    x = st.e - st.o - st.C @ w_free
    ex = np.maximum(np.abs(x) - st.h - st.W @ w_free, 0.0) / st.s
    act = ex > 0
    order = st.time_order()
    n_eff = max(act.sum() / autocorrelation_time(ex[order][act[order]]), 1.0)
    return L_free > 0 and n_eff * math.log(L_held / L_free) <= chi2.ppf(1 - EDGE_LEVEL, df)


def shared_in_range(e: Effect, sc: Sequence[Scored], fit: FitResult) -> FitResult:
    """A shared fit of ``e`` outside a range moved to the nearest point inside, the bands'
    centres and sliding line re-fitted beside it, when the data do not reject it
    (:func:`_edge_accepted`, one degree of freedom per range left); ``fit`` itself otherwise,
    which :func:`out_of_range` then reports. The nearest point: :meth:`Effect.to_range` for a
    range that is a function of several parameters (a sensor's rotation angle), else each
    linear parameter clipped to its own range (:func:`_clipped`: a sensor bias's axes)."""
    bad = out_of_range(e, sc, {-1: fit})
    sigs = [x.sig for x in sc]
    w = None
    if bad:
        w0 = np.asarray(fit.w, dtype=float)
        w = e.to_range(w0)
        w = _clipped(e, sigs, w0) if w is None else w
    if w is None:
        return fit
    st = stack(e, sc, None, fit.h, fit.ref)
    sg = np.asarray(st.signs(e.signs(fit.h)))
    w_free, L_free = solve_signed(st.e, st.h, st.s, st.C, st.W, st.o, sg, e.tied)
    held = np.zeros(st.C.shape[1], dtype=bool)
    held[: st.k] = True
    v = np.zeros(st.C.shape[1])
    v[: st.k] = w
    got = _solve_held(st, sg, held, v)
    if got is None:
        return fit
    p = make_spec(e, {-1: fit}).params
    df = 0
    for b in e.bounds:
        lo, hi = b.limits(sigs, None)
        df += any(not lo <= x <= hi for _, x in b.values(p, sigs, None))
    held_fit = FitResult(w, fit.h, fit.ref, got[1])
    if out_of_range(e, sc, {-1: held_fit}) or not _edge_accepted(
        st, w_free, L_free, got[1], max(df, 1)
    ):
        return fit
    return held_fit


def _clipped(e: Effect, sigs: Sequence[Signals], w: np.ndarray) -> np.ndarray | None:
    """The shared fit's linear parameters ``w`` (k,) each clipped to the range of its own
    :class:`~ditherlab.physics.effects.ranges.Bound` (one that bounds the parameter itself) on
    the recordings ``sigs``; None when no linear parameter has one."""
    lims = {
        b.param: b.limits(sigs, None) for b in e.bounds if b.value is None and b.param in e.linear
    }
    if not lims:
        return None
    out = np.array(w, dtype=float)
    for i, name in enumerate(e.linear):
        if name in lims:
            lo, hi = lims[name]
            out[i] = min(max(out[i], lo), hi)
    return out


def physical_fits(
    e: Effect, sc: Sequence[Scored], fits: dict[int, FitResult]
) -> tuple[dict[int, FitResult], dict[int, str]]:
    """The per-joint fits as ``identify --add`` writes them and diagnosis judges them: weak
    joints pooled (:func:`pool_weak_joints`, an effect with ``evidence_rules``), else each
    joint's :func:`bounded_fit`, a shared fit :func:`shared_in_range`; the weak joints' reasons
    by 0-based joint."""
    if not fits:
        return fits, {}
    if e.shared:
        return {j: shared_in_range(e, sc, f) for j, f in fits.items()}, {}
    if e.evidence_rules:
        return pool_weak_joints(e, sc, fits)
    return {j: bounded_fit(e, sc, j, f) for j, f in fits.items()}, {}


def held_lines(
    e: Effect,
    sc: Sequence[Scored],
    free: dict[int, FitResult],
    fits: dict[int, FitResult],
    weak: dict[int, str],
) -> list[str]:
    """One phrase per linear parameter :func:`bounded_fit` held (the free fits ``free``
    against the written ``fits``, 0-based joint -> fit; the ``weak`` joints' shared values are
    said by :func:`pooled_note`): ``"inertia joint 6: scale held at 1, its nominal (fitted
    53.9; the data cannot determine it)"``, ``"... held at 4, the edge of its range 0.25..4
    (fitted 4.3)"``."""
    nominals = _linear_nominals(e)
    out = []
    sigs = [x.sig for x in sc]
    for j, f in sorted(fits.items()):
        if j in weak or j not in free or f is free[j]:
            continue
        if j < 0:  # a shared fit moved into a range of several parameters (shared_in_range)
            was, now = make_spec(e, {-1: free[j]}).params, make_spec(e, {-1: f}).params
            for b in e.bounds:
                a = dict(b.values(was, sigs, None))
                for where, v in b.values(now, sigs, None):
                    if a.get(where) is not None and a[where] != v:
                        lo, hi = b.limits(sigs, None)
                        out.append(
                            f"{e.name}: {b.param} held at {v:.3g} {b.unit}, the edge of its range "
                            f"{lo:g}..{hi:g} (fitted {a[where]:.3g})"
                        )
            continue
        lims = _linear_ranges(e, sc, j)
        for i, name in enumerate(e.linear):
            a, b = float(free[j].w[i]), float(f.w[i])
            if a == b:
                continue
            lo, hi = lims[i]
            if nominals[i] is not None and b == nominals[i]:
                how = f"its nominal (fitted {a:.3g}; the data cannot determine it)"
            elif b in (lo, hi):
                how = f"the edge of its range {lo:g}..{hi:g} (fitted {a:.3g})"
            else:  # re-fitted beside a held one
                continue
            out.append(f"{e.name} joint {j + 1}: {name} held at {b:.3g}, {how}")
    return out


def pool_weak_joints(
    e: Effect, sc: Sequence[Scored], fits: dict[int, FitResult]
) -> tuple[dict[int, FitResult], dict[int, str]]:
    """Per-joint fits where the joints with too little evidence take shared parameters.

    For an effect with ``evidence_rules`` (``dither_extraction``): a joint whose fit fails them
    (:func:`_weak_reason`: its own standard error, or a value beyond the physical range by more
    than two standard errors) takes the median of each parameter (linear ones and the searched
    one, e.g. the lag, then its nearest value on the effect's grid) over the joints whose fits
    pass, or the effect's ``prior`` when none passes; a passing fit just outside the range is
    held at its edge. Other effects are returned unchanged.

    Parameters
    ----------
    e : the effect; sc : the scored recordings; fits : 0-based joint -> :func:`fit_effect` result

    Returns
    -------
    (the fits, the weak joints' reasons by 0-based joint). A shared fit keeps its joint's
    ``ref`` and has ``loss`` NaN (not fitted there).
    """
    rules = e.evidence_rules
    if not rules or e.shared or not fits:
        return fits, {}
    weak = {j: why for j, f in fits.items() if (why := _weak_reason(e, sc, j, f)) is not None}
    fits = {j: f if j in weak else _held_in_range(e, sc, j, f) for j, f in fits.items()}
    if not weak:
        return fits, {}
    good = [fits[j] for j in fits if j not in weak]
    prior = rules.get("prior", {})
    if good:
        w = np.median(np.array([f.w for f in good], dtype=float), axis=0)
        hs = [f.h for f in good]
        h = (
            int(round(float(np.median(hs))))
            if all(isinstance(x, int | np.integer) for x in hs)
            else float(np.median(hs))
        )
    else:
        w = np.array([float(prior[name]) for name in e.linear])
        h = prior.get(e.hyper) if isinstance(e.hyper, str) else None
    out = dict(fits)
    for j in weak:
        out[j] = FitResult(np.array(w, dtype=float), _on_grid(e, sc, j, h), fits[j].ref, math.nan)
    return out, weak


def _on_grid(e: Effect, sc: Sequence[Scored], j: int, h: Any) -> Any:
    """The value of ``e``'s searched parameter nearest to ``h`` among those its grid searches on
    joint ``j``: a median or a prior between two grid values is not one the design was
    computed at (diagnosis computes a filter's design on each piece of a long log only there)."""
    if h is None:
        return h
    grid = e.grid([s.sig for s in sc], j)
    if h in grid or not all(isinstance(x, int | float | np.number) for x in grid):
        return h
    return min(grid, key=lambda x: abs(float(x) - float(h)))


def pooled_lines(model: Any) -> list[str]:
    """One line per joint where a per-joint effect of ``model`` (a
    :class:`~ditherlab.data.torque_model.TorqueModel`) took values shared over the other joints
    (:func:`pool_weak_joints`; the model file's ``pooled`` flags), for identify's summary."""
    lines = []
    for spec in model.effects:
        pooled = spec.params.get("pooled")
        if not isinstance(pooled, list) or not any(pooled):
            continue
        for k, (jj, p) in enumerate(zip(spec.joints, pooled, strict=True)):
            if p:
                vals = ", ".join(
                    f"{name} {v[k] if isinstance(v, list) else v:.3g}"
                    for name, v in spec.params.items()
                    if name != "pooled"
                )
                lines.append(
                    f"[{spec.name}] joint {jj}: too little evidence, shared values ({vals})"
                )
    return lines


def pooled_note(e: Effect, fits: dict[int, FitResult], weak: dict[int, str]) -> str:
    """One sentence for the model's notes and identify's output: which joints took shared
    parameters of ``e`` and why (``weak`` from :func:`pool_weak_joints`); '' when none."""
    if not weak:
        return ""
    good = sorted(j for j in fits if j not in weak)
    f = fits[next(iter(weak))]
    vals = ", ".join(f"{n} {float(v):.3g}" for n, v in zip(e.linear, f.w, strict=True))
    if isinstance(e.hyper, str):
        vals += f", {e.hyper} {f.h}"
    src = (
        f"the median over joint(s) {', '.join(str(j + 1) for j in good)}"
        if good
        else "the effect's prior (no joint had good evidence)"
    )
    why = "; ".join(f"joint {j + 1}: {r}" for j, r in sorted(weak.items()))
    return (
        f"{e.name} on joint(s) {', '.join(str(j + 1) for j in sorted(weak))}: too little "
        f"evidence ({why}), shared values {vals} from {src}"
    )

"""Held-out scoring of candidate effects: which library effect the residual lacks, on which joints.

Every library effect not yet in the model is fitted to the residual
(band-aware least squares) and scored on held-out data with time-blocked folds (K contiguous
blocks, a guard of ``guard`` seconds removed from the training side of each boundary so
neighbouring samples cannot leak; nonlinear parameters are searched inside each training
fold), and by BIC with an effective sample size (the number of scored samples outside the band
divided by the integrated autocorrelation time of the fitted residual: samples at 250 Hz are
not independent).

**Decision rule.** An effect is suggested on joint j when all four hold: held-out explained
fraction ``>= min_fraction`` (default 0.05), the held-out loss falls in at least ``K - 1`` of the
``K`` folds, ``ΔBIC <= -10`` (strong evidence on the Kass–Raftery scale), and the effect beats
its surrogates: fitted and scored the same way (same folds, same search of its nonlinear
parameter) to its own design circularly shifted in time — the lags where the design is least
correlated with itself, so the shifted driver carries no information about the residual — its
held-out gain is at least :data:`SURROGATE_RATIO` times the best surrogate's. A flexible effect
that fits any structured residual (a ripple whose period is searched, a drift) explains as much
with a shifted driver and is not suggested. Shared-parameter effects (``payload``,
``ft_bias``) are tested once over all joints. Candidates are ranked by the share of the residual
(all joints, in noise-floor units) they explain on held-out data.

"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.stats import chi2

from ditherlab.core.errors import ModelError
from ditherlab.core.timeseries import autocorrelation_time
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.effect_fit import (
    ACTS_SNR,
    Stack,
    not_identifiable,
    out_of_range,
    physical_fits,
    solve_signed,
    stack,
)
from ditherlab.physics.effects import (
    EFFECTS,
    Effect,
    FitResult,
    clean_none,
    design_at,
    get_effect,
    make_spec,
)
from ditherlab.physics.effects.ranges import OutOfRange
from ditherlab.physics.residual import Scored, scored

__all__ = [
    "BIC_THRESHOLD",
    "MIN_FRACTION",
    "SURROGATE_RATIO",
    "ACTS_SNR",
    "Candidate",
    "acting_joints",
    "JointScore",
    "candidates",
    "rescored",
    "select_joints",
    "thinned",
]

MIN_FRACTION = 0.05
BIC_THRESHOLD = -10.0
#: the family-wise error rate of one diagnosis: a joint is named only when its likelihood-ratio
#: test rejects "no effect" at this level divided by the number of tests (Bonferroni over every
#: effect of the library on every joint, :attr:`JointScore.tests`)
FAMILY_LEVEL = 0.01
#: an effect's held-out gain must be at least this times its best surrogate's
SURROGATE_RATIO = 2.0
#: surrogates per candidate joint (lags of the design, each fitted like the effect)
SURROGATES = 3
#: relative difference of held-out losses below which a fold is a tie (rounding), not better
TIE = 1e-9


@dataclass
class JointScore:
    """Held-out and BIC evidence for one effect on one joint (or the shared fit, joint=None)."""

    joint: int | None
    loss0: float  # baseline held-out loss [floor units]
    loss1: float  # held-out loss with the effect
    folds_better: int
    folds: int
    delta_bic: float
    n_eff: float
    fit: FitResult
    #: held-out gain of the best surrogate (None: not computed, the other criteria failed)
    surrogate: float | None = None
    #: the parameters the BIC and the likelihood-ratio test count (linear columns that act,
    #: plus the searched ones)
    k: int = 1
    #: the tests of one diagnosis the family-wise level is divided by (every effect of the
    #: library on every joint)
    tests: int = 1

    @property
    def gain(self) -> float:
        return self.loss0 - self.loss1

    @property
    def fraction(self) -> float:
        return self.gain / self.loss0 if self.loss0 > 0 else 0.0

    @property
    def p_value(self) -> float:
        """The likelihood-ratio test's p-value of "the effect is absent": the statistic
        ``n_eff · ln(L0 / L1)`` (the band-aware losses of the fits without and with the effect,
        ``n_eff`` the effective samples outside the band) against χ² with :attr:`k` degrees of
        freedom (Wilks). The BIC difference holds the same statistic:
        ``ΔBIC = k · ln(n_eff) - statistic``."""
        lr = self.k * math.log(max(self.n_eff, 2.0)) - self.delta_bic
        return float(chi2.sf(max(lr, 0.0), self.k))

    @property
    def surrogate_fraction(self) -> float | None:
        """The best surrogate's held-out explained fraction (None: not computed)."""
        if self.surrogate is None:
            return None
        return self.surrogate / self.loss0 if self.loss0 > 0 else 0.0

    def passes(self, min_fraction: float) -> bool:
        return self.evidence(min_fraction) and (
            self.surrogate is None or self.gain >= SURROGATE_RATIO * self.surrogate
        )

    def evidence(self, min_fraction: float) -> bool:
        """The held-out, fold, BIC and family-wise criteria (the surrogates are tested only
        after these)."""
        return (
            self.fraction >= min_fraction
            and self.folds_better >= self.folds - 1
            and self.delta_bic <= BIC_THRESHOLD
            and self.p_value <= FAMILY_LEVEL / self.tests
        )


@dataclass
class Candidate:
    """One effect's evidence: joints (1-based) where it passes, held-out explained fraction."""

    effect: str
    joints: list[int]
    explained_fraction: float
    suggested: bool
    scores: list[JointScore] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    figure: str | None = None
    #: why the evidence is not enough to fit it (the rule of ``identify --add``), or None
    not_identifiable: str | None = None
    #: the joints whose evidence passes but whose fit lies outside a physical range
    #: (:func:`physical_joints`): not suggested there
    unphysical: list[OutOfRange] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        e = EFFECTS[self.effect]
        return {
            "effect": self.effect,
            "joints": self.joints,
            "explained_fraction": round(float(self.explained_fraction), 6),
            "suggested": self.suggested,
            "physics": e.physics,
            "driven_by": e.driven_by,
            "per_joint": [
                {
                    "joint": s.joint + 1 if s.joint is not None else "all",
                    "explained_fraction": round(float(s.fraction), 6),
                    "folds_better": s.folds_better,
                    "folds": s.folds,
                    "delta_bic": round(float(s.delta_bic), 3),
                    "n_eff": round(float(s.n_eff), 1),
                    "p_value": float(f"{s.p_value:.3g}"),
                    "p_family": float(f"{min(1.0, s.p_value * s.tests):.3g}"),
                    "surrogate_fraction": (
                        None
                        if s.surrogate_fraction is None
                        else round(float(s.surrogate_fraction), 6)
                    ),
                }
                for s in self.scores
            ],
            "params": self.params,
            "not_identifiable": self.not_identifiable,
            "unphysical": [u.to_dict() for u in self.unphysical],
            "figure": self.figure,
            "text": self.text(),
        }

    def text(self) -> str:
        e = EFFECTS[self.effect]
        where = (
            "all joints"
            if not self.joints
            else "joint"
            + ("s " if len(self.joints) > 1 else " ")
            + ", ".join(map(str, self.joints))
        )
        verdict = "suggested" if self.suggested else "not suggested"
        if self.not_identifiable:
            verdict = (
                "not identifiable on these recordings: " + self.not_identifiable.split(": ", 1)[-1]
            )
        text = (
            f"{self.effect} ({e.physics}; driven by {e.driven_by}) on {where}: explains "
            f"{100 * self.explained_fraction:.1f} % of the residual on held-out data ({verdict})"
        )
        return text + unphysical_text(self.unphysical)


def unphysical_text(unphysical: Sequence[OutOfRange]) -> str:
    """``"; fits only with an unphysical value: k 423 on joint 6 (range 0.5..2)"`` for the
    fits outside their physical range, '' for none."""
    if not unphysical:
        return ""
    parts = [
        f"{u.param} {u.value:.3g} on {u.where} (range {u.lo:.3g}..{u.hi:.3g}"
        f"{'' if u.unit in ('', '-') else ' ' + u.unit})"
        for u in unphysical
    ]
    return "; fits only with an unphysical value: " + ", ".join(parts)


def physical_joints(
    e: Effect,
    scs: Sequence[Scored],
    passed: Sequence[JointScore],
    folds: tuple[int, float] = (5, 0.25),
) -> tuple[list[JointScore], list[OutOfRange]]:
    """The joint scores whose fit lies inside every physical range of ``e`` (``Effect.bounds``,
    :func:`~ditherlab.physics.effect_fit.out_of_range`: the rule ``identify --add`` refuses by,
    on the fits as it writes them, :func:`~ditherlab.physics.effect_fit.physical_fits`: the
    kept scores carry those fits, and where a fit changed — held at a range's edge, or shared
    over the joints — its held-out gain as written, :func:`rescored` with ``folds`` (K, guard
    [s])), and the values outside a range of the others: a candidate is never suggested on a
    joint it fits only with an unphysical value. A fit the bands could take instead
    (:func:`~ditherlab.physics.effect_fit.not_identifiable`) has arbitrary values: it is kept
    here, and said to be not identifiable."""
    ident = [s for s in passed if not_identifiable(e, scs, s.joint, s.fit) is None]
    fits = {-1 if s.joint is None else s.joint: s.fit for s in ident}
    fits, _ = physical_fits(e, scs, fits)  # as identify --add writes them
    bad = out_of_range(e, scs, fits)
    keep = []
    for s in passed:
        key = -1 if s.joint is None else s.joint
        if key in bad:
            continue
        fit = fits.get(key, s.fit)
        keep.append(s if fit is s.fit else rescored(e, scs, s, fit, *folds))
    return keep, list(bad.values())


def rescored(
    e: Effect, scs: Sequence[Scored], s: JointScore, fit: FitResult, K: int, guard_s: float
) -> JointScore:
    """``s`` with the held-out loss of the effect at the fixed parameters ``fit`` (the fit as
    ``identify --add`` writes it: held at a range's edge, or shared over the joints): per fold,
    the nuisance columns (band centres, sliding line) fitted on the training samples beside it,
    the loss on the test samples [σ²]; the same folds as :func:`_score`."""
    total = sum(x.sig.length for x in scs)
    fs = scs[0].sig.rec.sample_rate
    guard = int(round(guard_s * fs)) if np.isfinite(fs) else 0
    st = stack(e, scs, s.joint, fit.h, fit.ref)
    k = st.k
    folds = _folds(st, total, K, guard)
    test_l0 = _baseline(st, folds)[0]
    shift = st.o + st.C[:, :k] @ fit.w
    h = st.h + st.W[:, :k] @ fit.w
    Cn, Wn = st.C[:, k:], st.W[:, k:]
    free = (0,) * Cn.shape[1]
    test_l1 = []
    for test, train in folds:
        tr = train(st.block)
        w, _ = solve_signed(st.e[tr], h[tr], st.s[tr], Cn[tr], Wn[tr], shift[tr], free)
        x = st.e[test] - shift[test] - Cn[test] @ w
        gap = np.maximum(np.abs(x) - h[test] - Wn[test] @ w, 0) / st.s[test]
        test_l1.append(float(np.sum(gap**2)))
    better = sum(1 for a, b in zip(test_l0, test_l1, strict=True) if b < a - TIE * abs(a))
    return replace(s, loss0=sum(test_l0), loss1=sum(test_l1), folds_better=better, fit=fit)


def _folds(st: Stack, total: int, K: int, guard: int) -> list[tuple[np.ndarray, Callable]]:
    """K contiguous time blocks: (test mask, train-mask function) per fold.

    The block edges split the *informative* samples evenly (moving samples, where the band has
    collapsed, and samples outside the band), not the time axis: a push campaign has all its
    motion in the first seconds, and equal time blocks would put it all in one fold, leaving
    nothing to train on when that fold is held out. Each block stays contiguous in time, and
    ``guard`` samples on each side of it are removed from training.
    """
    info = (st.h == 0) | (np.abs(st.e) > st.h)
    b = np.sort(st.block[info]) if info.any() else np.sort(st.block)
    if len(b) >= K:
        inner = [int(b[int(len(b) * k / K)]) for k in range(1, K)]
    else:
        inner = list(np.linspace(0, total, K + 1).astype(int)[1:-1])
    edges = [0, *inner, total + 1]
    out = []
    for k in range(K):
        lo, hi = int(edges[k]), int(edges[k + 1])
        test = (st.block >= lo) & (st.block < hi)

        def train(bl: np.ndarray, lo: int = lo, hi: int = hi) -> np.ndarray:
            return (bl < lo - guard) | (bl >= hi + guard)

        out.append((test, train))
    return out


def _score(
    e: Effect,
    scs: Sequence[Scored],
    j: int | None,
    K: int,
    guard_s: float,
    lags: Sequence[int] | None = None,
) -> JointScore:
    """Held-out and BIC evidence of effect e on joint j (None: shared fit over all joints);
    ``lags`` (one per recording): of the surrogate whose design is shifted by that much."""
    sigs = [s.sig for s in scs]
    ref = e.reference(sigs, j)
    total = sum(s.sig.length for s in scs)
    fs = scs[0].sig.rec.sample_rate
    guard = int(round(guard_s * fs)) if np.isfinite(fs) else 0
    grid = e.grid(sigs, j)
    pb = _Scoring(e, scs, j, K, guard, total, ref, grid, lags)
    allowed = _shortlist(pb) if j is not None and len(grid) > 1 else None
    grid_idx = sorted(allowed) if allowed is not None else list(range(len(grid)))
    return _joint_score(pb, _search(pb, grid_idx, allowed))


@dataclass(frozen=True)
class _Scoring:
    """One effect ``e`` on joint ``j`` (None: shared fit over all joints) to score on ``scs``:
    ``K`` folds with ``guard`` samples removed from training on each side of a test block,
    ``total`` samples, the effect's reference ``ref`` and ``grid`` of hyper-parameters, and
    ``lags`` (one per recording: the surrogate whose design is shifted by that much, or None)."""

    e: Effect
    scs: Sequence[Scored]
    j: int | None
    K: int
    guard: int
    total: int
    ref: Any
    grid: list
    lags: Sequence[int] | None

    def stack(self, h: Any) -> Stack:
        """The stacked problem at grid value ``h``."""
        return stack(self.e, self.scs, self.j, h, self.ref, self.lags)


def _shortlist(pb: _Scoring) -> dict[int, set[int]]:
    """Per grid index, the fits (folds ``0..K-1``, and ``K`` the full fit) on whose training
    data the effect's shortlist keeps that grid value."""
    st0 = pb.stack(pb.grid[0])
    fl0 = _folds(st0, pb.total, pb.K, pb.guard)
    masks = [tr(st0.block) for _, tr in fl0] + [np.ones(len(st0.e), dtype=bool)]
    lists = pb.e.shortlist(pb.scs, pb.j, pb.grid, masks, pb.lags)
    allowed: dict[int, set[int]] = {}
    for k, lst in enumerate(lists):
        for h in lst:
            allowed.setdefault(pb.grid.index(h), set()).add(k)
    return allowed


@dataclass
class _Searched:
    """The grid search's result: the folds, the first grid value's stack (the baseline's),
    the held-out loss per fold of the best training fit, the best full fit and its residual
    beyond the band [sigma]."""

    folds: list[tuple[np.ndarray, Callable]]
    base_st: Stack
    test_l1: list[float]
    full: FitResult
    full_resid: np.ndarray


def _search(
    pb: _Scoring, grid_idx: Sequence[int], allowed: dict[int, set[int]] | None
) -> _Searched:
    """Fit the effect at every grid value of ``grid_idx`` on every fold's training data (where
    ``allowed`` lets it) and on all data: per fold the held-out loss of the best training fit,
    and the best full fit."""
    K = pb.K
    folds = None
    best_train = [math.inf] * K
    test_l1 = [0.0] * K
    full: FitResult | None = None
    full_resid = None
    base_st = None
    for gi in grid_idx:
        h = pb.grid[gi]
        st = pb.stack(h)
        sg = st.signs(pb.e.signs(h))
        if folds is None:
            folds = _folds(st, pb.total, K, pb.guard)
            base_st = st
        for k, (test, train) in enumerate(folds):
            if allowed is not None and k not in allowed[gi]:
                continue
            tr = train(st.block)
            w, L = solve_signed(
                st.e[tr], st.h[tr], st.s[tr], st.C[tr], st.W[tr], st.o[tr], sg, pb.e.tied
            )
            if L < best_train[k]:
                best_train[k] = L
                test_l1[k] = _loss(st, test, w)
        if allowed is not None and K not in allowed[gi]:
            continue
        w, L = solve_signed(st.e, st.h, st.s, st.C, st.W, st.o, sg, pb.e.tied)
        if full is None or L < full.loss:
            full = FitResult(w[: st.k], h, pb.ref, L)
            x = st.e - st.o - st.C @ w
            full_resid = np.sign(x) * np.maximum(np.abs(x) - st.h - st.W @ w, 0) / st.s
    assert folds is not None and base_st is not None and full is not None
    assert full_resid is not None
    return _Searched(folds, base_st, test_l1, full, full_resid)


def _joint_score(pb: _Scoring, sr: _Searched) -> JointScore:
    """The evidence of the search against the baseline (no effect): held-out losses, the folds
    that improve, and the BIC difference over the effective samples outside the band."""
    base_st, full, full_resid = sr.base_st, sr.full, sr.full_resid
    test_l0, L0, b0 = _baseline(base_st, sr.folds)
    L1 = full.loss
    # samples outside the band (in sigma units; beyond rounding, which differs with the order of
    # the sums when the log is read in pieces)
    active = (np.abs(b0) > TIE) | (np.abs(full_resid) > TIE)
    n_act = int(active.sum())
    order = base_st.time_order()  # the autocorrelation along time, however the log was cut
    tau = autocorrelation_time(full_resid[order][active[order]]) if n_act > 10 else 1.0
    n_eff = max(n_act / tau, 1.0)
    # parameters: the design's columns that act on these samples (an effect's count may follow
    # the robot, e.g. one offset per joint), plus the searched ones
    e = pb.e
    k_lin = int(np.any(base_st.C[:, : base_st.k] != 0, axis=0).sum())
    k_par = k_lin + (len(e.hyper) if isinstance(e.hyper, tuple) else 1 if e.hyper else 0)
    if L0 > 0 and L1 > 0:
        dbic = n_eff * math.log(L1 / L0) + k_par * math.log(max(n_eff, 2.0))
    else:
        dbic = 0.0
    # a fold counts as better only beyond rounding: an effect that changes nothing on a fold
    # (equal losses, summed in another order when the log is read in pieces) is not better there
    better = sum(1 for a, b in zip(test_l0, sr.test_l1, strict=True) if b < a - TIE * abs(a))
    tests = len(EFFECTS) * pb.scs[0].sig.n
    return JointScore(
        pb.j, sum(test_l0), sum(sr.test_l1), better, pb.K, dbic, n_eff, full, k=k_par, tests=tests
    )


def _judged(
    e: Effect, scs: Sequence[Scored], j: int | None, K: int, guard_s: float, min_fraction: float
) -> JointScore:
    """:func:`_score`, and where its evidence passes, the best surrogate's gain beside it."""
    s = _score(e, scs, j, K, guard_s)
    if s.evidence(min_fraction):
        s.surrogate = _surrogate_gain(e, scs, j, K, guard_s, s.fit)
    return s


def _surrogate_lags(
    e: Effect, scs: Sequence[Scored], j: int | None, fit: FitResult
) -> list[list[int]]:
    """:data:`SURROGATES` lag vectors (one lag per recording, samples) at which the effect's
    fitted design is least correlated with itself (circular autocorrelation of its
    mean-removed, unit-norm columns over the scored samples, summed in absolute value), between
    15 % and 85 % of each recording and at least 10 % of it apart."""
    per_rec: list[list[int]] = []
    for s in scs:
        d = design_at(e, s.sig, j, fit.h, fit.ref)
        N = len(s.e)
        use = s.use.any(axis=1) if j is None else s.use[:, j]
        cols = [a.reshape(N, -1) for a in (d.centre, d.widen) if a is not None]
        X = np.hstack(cols)
        X = np.where(use[:, None], X - X[use].mean(axis=0) if use.any() else X, 0.0)
        nrm = np.linalg.norm(X, axis=0)
        X = X[:, nrm > 0] / nrm[nrm > 0]
        lo, hi, gap = int(0.15 * N), int(0.85 * N), max(int(0.1 * N), 1)
        if X.shape[1] == 0 or hi <= lo:
            per_rec.append([int(N * f) for f in np.linspace(0.3, 0.7, SURROGATES)])
            continue
        F = np.fft.rfft(X, axis=0)
        acf = np.abs(np.fft.irfft(np.abs(F) ** 2, n=N, axis=0)).sum(axis=1)
        cand = np.arange(lo, hi)
        score = acf[cand]
        picked: list[int] = []
        for _ in range(SURROGATES):
            ok = np.ones(len(cand), dtype=bool)
            for p in picked:
                ok &= np.abs(cand - p) >= gap
            if not ok.any():
                break
            picked.append(int(cand[ok][np.argmin(score[ok])]))
        per_rec.append(picked)
    k = min(len(p) for p in per_rec)
    return [[p[i] for p in per_rec] for i in range(k)]


def _surrogate_gain(
    e: Effect, scs: Sequence[Scored], j: int | None, K: int, guard_s: float, fit: FitResult
) -> float:
    """The largest held-out gain of the effect fitted to its own shifted design."""
    return max(
        (_score(e, scs, j, K, guard_s, lags).gain for lags in _surrogate_lags(e, scs, j, fit)),
        default=0.0,
    )


def _loss(st: Stack, m: np.ndarray, w: np.ndarray) -> float:
    """Band-aware loss of the stacked samples ``m`` for the full parameter vector w."""
    x = st.e[m] - st.o[m] - st.C[m] @ w
    return float(np.sum((np.maximum(np.abs(x) - st.h[m] - st.W[m] @ w, 0) / st.s[m]) ** 2))


def _baseline(st: Stack, folds: list) -> tuple[list[float], float, np.ndarray]:
    """The effect-free model (intercepts only): held-out loss per fold, full loss, residual."""
    k = st.k
    zero = np.zeros(len(st.e))
    Cn, Wn = st.C[:, k:], st.W[:, k:]
    free = (0,) * Cn.shape[1]
    out = []
    for test, train in folds:
        tr = train(st.block)
        w, _ = solve_signed(st.e[tr], st.h[tr], st.s[tr], Cn[tr], Wn[tr], zero[tr], free)
        x = st.e[test] - Cn[test] @ w
        out.append(float(np.sum((np.maximum(np.abs(x) - st.h[test], 0) / st.s[test]) ** 2)))
    w, L = solve_signed(st.e, st.h, st.s, Cn, Wn, zero, free)
    x = st.e - Cn @ w
    return out, L, np.sign(x) * np.maximum(np.abs(x) - st.h, 0) / st.s


def _baseline_total(scs: Sequence[Scored], n: int, K: int, guard_s: float) -> float:
    """Held-out loss of the effect-free model summed over all joints (the candidates' share
    of the residual is measured against this)."""
    e = EFFECTS["viscous"]  # any per-joint effect: only its intercept columns are used
    total = sum(s.sig.length for s in scs)
    fs = scs[0].sig.rec.sample_rate
    guard = int(round(guard_s * fs)) if np.isfinite(fs) else 0
    out = 0.0
    for j in range(n):
        st = stack(e, scs, j, None, {})
        out += sum(_baseline(st, _folds(st, total, K, guard))[0])
    return out


def _evaluate(
    model: TorqueModel,
    scs: Sequence[Scored],
    name: str,
    K: int,
    guard_s: float,
    min_fraction: float,
    total_loss: float,
    quiet: Sequence[int] = (),
) -> Candidate:
    e = get_effect(name)
    if e.shared:
        s = _judged(e, scs, None, K, guard_s, min_fraction)
        kept, unphysical = physical_joints(
            e, scs, [s] if s.passes(min_fraction) else [], (K, guard_s)
        )
        ok = bool(kept)
        # the shared fit covers every joint: its own held-out baseline is the whole residual
        frac = s.fraction
        spec = make_spec(e, {-1: s.fit})
        why = not_identifiable(e, scs, None, s.fit) if ok else None
        return Candidate(
            name,
            list(range(1, model.n + 1)) if ok else [],
            frac,
            ok and why is None,
            [s],
            spec.params,
            not_identifiable=why,
            unphysical=unphysical,
        )
    scores = [_judged(e, scs, j, K, guard_s, min_fraction) for j in range(model.n)]
    # joints by each joint's own held-out evidence; the candidate by its share of the whole
    # residual (the >= min_fraction rule holds for what is suggested, not only per joint); a
    # joint whose residual is far below its noise floor is never named
    passed = [s for s in scores if s.passes(min_fraction) and s.joint + 1 not in quiet]
    sel, unphysical = physical_joints(e, scs, passed, (K, guard_s))
    # a fit changed to what is written must still explain its share there
    sel = [s for s in sel if s.fraction >= min_fraction and s.folds_better >= s.folds - 1]
    gain = sum(s.gain for s in sel) if sel else max((s.gain for s in scores), default=0.0)
    frac = gain / total_loss if total_loss > 0 else 0.0
    params: dict[str, Any] = {}
    if sel:
        params = clean_none(make_spec(e, {s.joint: s.fit for s in sel})).params
    if sel:
        joints = [s.joint + 1 for s in sel]
    else:  # the best joint; among gains equal to 1e-9 of the residual (ties: 0 where nothing
        # is explained, summed piece by piece in another order) the first, so that a log read
        # in pieces names the joint the whole does
        best = max(s.gain for s in scores)
        tie = 1e-9 * max(abs(total_loss), abs(best))
        joints = [min(s.joint for s in scores if s.gain >= best - tie) + 1]
    why = None
    if sel and frac >= min_fraction:
        whys = [w for w in (not_identifiable(e, scs, s.joint, s.fit) for s in sel) if w]
        why = whys[0] if whys else None
    suggested = bool(sel) and frac >= min_fraction and why is None
    return Candidate(
        name, joints, frac, suggested, scores, params, not_identifiable=why, unphysical=unphysical
    )


def _applicable(name: str, scs: Sequence[Scored]) -> str | None:
    """Why an effect cannot be tried on these scored recordings (None when it can)."""
    e = get_effect(name)
    try:
        for s in scs:
            e.check(s.sig)
    except ModelError as exc:
        return str(exc)
    return None


def candidates(
    model: TorqueModel,
    recs: Sequence[Recording],
    *,
    effects: Sequence[str] | None = None,
    folds: int = 5,
    guard: float = 0.25,
    min_fraction: float = MIN_FRACTION,
    scored_recs: Sequence[Scored] | None = None,
    max_samples: int = 4000,
    progress: Callable[[int, int], None] | None = None,
    quiet: Sequence[int] = (),
) -> tuple[list[Candidate], dict[str, str]]:
    """Fit and score every library effect not yet in the model; best first.

    Parameters
    ----------
    model : TorqueModel
    recs : recordings
    effects : names to try (default: every library effect not in the model)
    folds : number of time-blocked folds K
    guard : [s] removed from the training side of every fold boundary
    min_fraction : smallest held-out explained fraction that may be suggested
    max_samples : longer recordings are scored on every k-th sample (k = ceil(N / max_samples))
    quiet : 1-based joints whose residual is far below their noise floor: a per-joint effect is
        never named there (a share of what is noise already is no evidence of an effect)

    Returns
    -------
    (candidates best first — suggested ones first, by explained fraction —, skipped: name -> why)
    """
    scs = list(scored_recs) if scored_recs is not None else [scored(model, r) for r in recs]
    scs = thinned(scs, max_samples)
    have = set(model.effect_names())
    names = [n for n in (effects or EFFECTS) if n not in have]
    for n in names:
        get_effect(n)
    total = _baseline_total(scs, model.n, folds, guard)
    out, skipped = [], {}
    for i, n in enumerate(names):
        why = _applicable(n, scs)
        if why is not None:
            skipped[n] = why
        else:
            out.append(_evaluate(model, scs, n, folds, guard, min_fraction, total, quiet))
        if progress is not None:
            progress(i + 1, len(names))
    out.sort(key=lambda c: (not c.suggested, -c.explained_fraction))
    return out, skipped


def thinned(scs: Sequence[Scored], max_samples: int = 4000) -> list[Scored]:
    """The scored recordings at every k-th sample, k = ceil(N / max_samples) over their N
    samples together: neighbours at 250 Hz carry little new information, and the folds and
    guards stay in the original time index."""
    n_all = sum(len(s.e) for s in scs)
    stride = max(1, -(-n_all // max_samples))
    if stride == 1:
        return list(scs)
    return [s.at(np.arange(0, len(s.e), stride)) for s in scs]


def acting_joints(e: Effect, scs: Sequence[Scored]) -> list[int]:
    """0-based joints on which effect ``e``'s design acts on these scored recordings: its
    columns at the first value of its searched parameter (``dither_extraction``: no lag), at
    unit parameters, exceed :data:`ACTS_SNR` times the joint's noise ``sigma`` [N·m] on at
    least one scored sample. Elsewhere (a joint that does not dither, or one a push does not
    load: the wrist's last joint under a force at the tool point, 0.003-0.01 N·m against a
    noise of 0.013 N·m) any value of its parameters fits the noise alike."""
    sigs = [s.sig for s in scs]
    out = []
    n = scs[0].sig.n if scs else 0
    for j in range(n):
        h = e.grid(sigs, j)[0]
        ref = e.reference(sigs, j)
        snr = 0.0
        for s in scs:
            m = s.use[:, j]
            if not m.any():
                continue
            C = np.asarray(design_at(e, s.sig, j, h, ref).centre)[m]
            if C.size:
                snr = max(snr, float(np.max(np.abs(C) / s.sigma[m, j][:, None])))
        if snr >= ACTS_SNR:
            out.append(j)
    return out


def select_joints(
    model: TorqueModel,
    recs: Sequence[Recording],
    name: str,
    *,
    scored_recs: Sequence[Scored] | None = None,
) -> list[int]:
    """0-based joints to fit effect ``name`` on: where diagnosis finds it (the best joint when
    none passes); for an effect of the measurement pipeline (:attr:`Effect.on_every_joint`)
    every joint where its design acts (:func:`acting_joints`), whatever one recording's
    evidence says there (diagnosis's joints when it acts on none)."""
    e = get_effect(name)
    if e.on_every_joint:
        scs = list(scored_recs) if scored_recs is not None else [scored(model, r) for r in recs]
        js = acting_joints(e, scs)
        if js:
            return js
        scored_recs = scs
    cands, skipped = candidates(model, recs, effects=[name], scored_recs=scored_recs)
    if name in skipped:
        raise ModelError(skipped[name])
    return [j - 1 for j in cands[0].joints]

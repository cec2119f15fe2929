"""Diagnosis: where a torque model fails against measurements, and which physical effect is missing.

For a model and one or more recordings (with an F/T sensor when available):

1. **Torque residual** per joint and regime: ``rho = tau - gravity - effects - J^T F_sensor`` about
   the model's friction (see :func:`ditherlab.effects.scored`), *band-aware*: in the still and
   dither regimes only the part outside the stick band counts (stick friction may take any value
   in the band); in the moving regime the band collapses onto the sliding friction line and the
   whole residual about it counts. Its RMS is compared with the **noise floor**: the RMS the same
   quantity may have while the model is right, with ``sigma`` the white-noise level measured
   model-free from first differences of the residual (:func:`ditherlab.effects.white_noise`; the
   model's own sigma would absorb any missing effect): moving, ``sigma``; still/dither, the excess
   beyond the band of a friction sitting at the band edge plus noise, ``sqrt(sigma²/2 + ...)``,
   the largest any placement of the friction inside the band gives.
2. **Force error** (estimate of eq. (3) minus the sensor) per axis and regime, and the coverage of
   the 95 % set-membership interval, when :mod:`ditherlab.estimator` and F/T columns are present.
3. The **worst time windows** (1 s) by residual energy in units of the noise floor.
4. **Candidates**: every library effect not yet in the model is fitted to the residual
   (band-aware least squares) and scored on held-out data with time-blocked folds (K contiguous
   blocks, a guard of ``guard`` seconds removed from the training side of each boundary so
   neighbouring samples cannot leak; nonlinear parameters are searched inside each training
   fold), and by BIC with an effective sample size (the number of scored samples outside the band
   divided by the integrated autocorrelation time of the fitted residual: samples at 250 Hz are
   not independent).

**Decision rule.** An effect is suggested on joint j when all three hold: held-out explained
fraction ``>= min_fraction`` (default 0.05), the held-out loss falls in at least ``K - 1`` of the
``K`` folds, and ``ΔBIC <= -10`` (strong evidence on the Kass–Raftery scale). Shared-parameter
effects (``payload``, ``ft_bias``) are tested once over all joints. Candidates are ranked by the
share of the residual (all joints, in noise-floor units) they explain on held-out data.

Which physics shows where: ``viscous``, ``stribeck``, ``inertia`` and ``position_ripple`` only in
motion (standing still they are constant and the band takes them); ``load_friction`` and
``temperature_friction`` change sliding friction in motion and the band's width standing still;
``payload`` is a gravity error that changes with the pose (in one fixed pose it is a constant
that the band absorbs: it cannot be told apart from band asymmetry); ``attenuation_lag`` and
``ft_bias`` show wherever the external torque leaves the band (large pushes, the dither regime,
motion) and need a varying pose or force to be told apart from the band.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import norm

from ditherlab.effects import (
    EFFECTS,
    Effect,
    FitResult,
    clean_none,
    effects_torque,
    get_effect,
    make_spec,
    model_text,
    sensor_wrench,
    signals,
)
from ditherlab.errors import ModelError
from ditherlab.estimator import estimate, intervals
from ditherlab.fit import Stack, solve_signed, stack
from ditherlab.model import TorqueModel
from ditherlab.recording import (
    DITHER,
    MOVING,
    REGIME_NAMES,
    STILL,
    WRENCH_COLUMNS,
    Recording,
    Regime,
)
from ditherlab.residual import Scored, scored, white_noise

__all__ = [
    "Candidate",
    "Diagnosis",
    "append_history",
    "candidates",
    "diagnose",
    "noise_floor_sq",
    "residual_summary",
    "select_joints",
]

MIN_FRACTION = 0.05
#: A regime with fewer samples than this on every joint needs no band (identify's min_samples).
MIN_REGIME_SAMPLES = 200
BIC_THRESHOLD = -10.0
AXES = WRENCH_COLUMNS


def nanmean(x: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Mean over the finite values; NaN (without a warning) where there are none."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    cnt = ok.sum(axis=axis)
    tot = np.where(ok, x, 0.0).sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)


# ============================================================== noise floor
def noise_floor_sq(sigma: np.ndarray, half: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Expected squared band-aware residual while the model is right, per sample.

    Moving (band collapsed): ``sigma²``.
    Still/dither: friction at a band edge plus noise ``n``: ``E[n_+²] + E[(-n - 2h)_+²]``
    ``= sigma²/2 + (sigma² + 4h²) Φ(-2h/sigma) - 2 h sigma φ(2h/sigma)`` (``sigma²`` for h = 0);
    the largest value any placement of the friction inside the band gives.

    Parameters
    ----------
    sigma, half : (...) [N·m]; half is the band half-width
    moving : (...) bool

    Returns
    -------
    (...) [N·m²]
    """
    s = np.asarray(sigma, dtype=float)
    h = np.asarray(half, dtype=float)
    z = 2 * h / s
    edge = s**2 / 2 + (s**2 + 4 * h**2) * norm.cdf(-z) - 2 * h * s * norm.pdf(z)
    return np.where(moving, s**2, edge)


# ============================================================== residual summary
def _excess_and_floor(model: TorqueModel, sc: Scored) -> tuple[np.ndarray, np.ndarray]:
    """(N, n) excess [N·m] and per-sample floor² [N·m²] (NaN where not scored)."""
    reg = sc.sig.regime
    ex = sc.excess()
    s = sc.sigma
    if sc.sigma_hf is not None:
        s = np.where(np.isfinite(sc.sigma_hf), sc.sigma_hf, sc.sigma)
    fl = noise_floor_sq(s, sc.h, reg == MOVING)
    ex = np.where(sc.use, ex, np.nan)
    fl = np.where(sc.use, fl, np.nan)
    return ex, fl


def residual_summary(model: TorqueModel, scs: Sequence[Scored]) -> dict[str, Any]:
    """Torque residual per joint and regime against the noise floor.

    Returns
    -------
    dict with ``torque_rms`` (n,) [N·m], ``noise_floor`` (n,) [N·m], ``ratio`` (n,), and
    ``per_regime``: list of {joint, regime, samples, rms, floor, outside_fraction, mean_excess}
    where ``mean_excess`` is the signed mean excess in units of sigma (a bias shows here).
    """
    n = model.n
    exs, fls, regs, sigs = [], [], [], []
    for sc in scs:
        ex, fl = _excess_and_floor(model, sc)
        exs.append(ex)
        fls.append(fl)
        regs.append(sc.sig.regime)
        sigs.append(sc.sigma)
    ex, fl, reg, sg = (np.concatenate(a) for a in (exs, fls, regs, sigs))
    rms = np.sqrt(nanmean(ex**2, axis=0))
    floor = np.sqrt(nanmean(fl, axis=0))
    rows = []
    for j in range(n):
        for code, name in ((r, r.label) for r in Regime):
            m = (reg[:, j] == code) & np.isfinite(ex[:, j])
            if not m.any():
                continue
            x = ex[m, j]
            rows.append(
                {
                    "joint": j + 1,
                    "regime": name,
                    "samples": int(m.sum()),
                    "rms": float(np.sqrt(np.mean(x**2))),
                    "floor": float(np.sqrt(np.mean(fl[m, j]))),
                    "outside_fraction": float(np.mean(x != 0)),
                    "mean_excess_sigma": float(np.mean(x / sg[m, j])),
                }
            )
    return {
        "torque_rms": [float(v) for v in rms],
        "noise_floor": [float(v) for v in floor],
        "ratio": [float(a / b) if b > 0 else float("nan") for a, b in zip(rms, floor, strict=True)],
        "per_regime": rows,
    }


def worst_windows(
    model: TorqueModel, scs: Sequence[Scored], width: float = 1.0, count: int = 5
) -> list[dict[str, Any]]:
    """The ``count`` windows of ``width`` seconds (half-overlapping) with the largest residual
    energy in units of the noise floor (mean over joints of excess² / floor²)."""
    out = []
    for sc in scs:
        ex, fl = _excess_and_floor(model, sc)
        t = sc.sig.t
        r = np.where(np.isfinite(ex), ex**2 / np.where(fl > 0, fl, 1.0), np.nan)
        start = t[0]
        while start < t[-1]:
            m = (t >= start) & (t < start + width)
            if m.sum() > 3:
                per = nanmean(r[m], axis=0)
                if np.isfinite(per).any():
                    j = int(np.nanargmax(per))
                    out.append(
                        {
                            "recording": sc.sig.rec.name or "<memory>",
                            "t0": float(start),
                            "t1": float(start + width),
                            "energy": float(nanmean(per)),
                            "worst_joint": j + 1,
                            "worst_joint_ratio": float(math.sqrt(per[j])),
                        }
                    )
            start += width / 2
    out.sort(key=lambda d: -d["energy"])
    return out[:count]


# ============================================================== force error
def _regime_per_sample(reg: np.ndarray) -> np.ndarray:
    """(N,) regime of the robot: moving if any joint moves, else dither if any, else still."""
    out = np.full(len(reg), STILL, dtype=np.int8)
    out[(reg == DITHER).any(axis=1)] = DITHER
    out[(reg == MOVING).any(axis=1)] = MOVING
    return out


def force_error(
    model: TorqueModel,
    scs: Sequence[Scored],
    level: float = 0.95,
    max_interval_samples: int = 500,
) -> dict[str, Any] | None:
    """Estimate of eq. (3) minus the (bias-corrected) sensor, per axis and regime, and coverage.

    Returns None when no recording has F/T columns. Otherwise
    ``{"rms": (6,) [N, N·m], "bias": (6,), "per_regime": [...], "coverage": (6,) or None,
    "interval": {"method", "level"}}``.
    """
    errs, regs, covs = [], [], []
    for sc in scs:
        rec = sc.sig.rec
        if not rec.has_wrench:
            continue
        reg = sc.sig.regime
        # the estimator is sensorless: the model's effects without the F/T columns
        tau_bar = sc.tau - sc.sig.gravity - effects_torque(model, rec, sensor=False)
        lo = np.zeros(tau_bar.shape)
        hi = np.zeros(tau_bar.shape)
        sg = np.ones(tau_bar.shape)
        for code, name in ((r, r.label) for r in Regime):
            if name not in model.regimes:
                continue
            b = model.regimes[name]
            cen = np.zeros(tau_bar.shape)
            if code == MOVING:
                if b.coulomb is not None:
                    cen = cen + b.coulomb * np.sign(sc.sig.dq)
                if b.viscous is not None:
                    cen = cen + b.viscous * sc.sig.dq
            m = reg == code
            lo = np.where(m, b.tau_min + cen, lo)
            hi = np.where(m, b.tau_max + cen, hi)
            sg = np.where(m, b.sigma, sg)
        # joints not scored (e.g. dither without extraction): leave them out with a huge band
        lo = np.where(sc.use, lo, -1e9)
        hi = np.where(sc.use, hi, 1e9)
        J = sc.sig.jac
        sol = estimate(tau_bar, J, lo, hi, sg, model.prior_mean, model.prior_sigma)
        Fs = sensor_wrench(model, rec)
        errs.append(sol.F - Fs)
        regs.append(_regime_per_sample(reg))
        try:
            # coverage on an evenly spaced subset (intervals cost far more than estimates)
            k = max(1, len(Fs) // max_interval_samples)
            sub = slice(None, None, k)
            ilo, ihi = intervals(
                tau_bar[sub],
                J[sub],
                lo[sub],
                hi[sub],
                sg[sub],
                model.prior_mean,
                model.prior_sigma,
                F_hat=sol.F[sub],
                method="set_membership",
                level=level,
            )
            cov = np.full(Fs.shape, np.nan)
            cov[sub] = (Fs[sub] >= ilo) & (Fs[sub] <= ihi)
            covs.append(cov)
        except Exception:  # noqa: BLE001 - coverage is reported as unavailable
            covs.append(np.full(Fs.shape, np.nan))
    if not errs:
        return None
    err = np.concatenate(errs)
    reg = np.concatenate(regs)
    cov = np.concatenate(covs).astype(float)
    rows = []
    for code, name in ((r, r.label) for r in Regime):
        m = reg == code
        if m.any():
            rows.append(
                {
                    "regime": name,
                    "samples": int(m.sum()),
                    "rms": [float(v) for v in np.sqrt(np.mean(err[m] ** 2, axis=0))],
                    "bias": [float(v) for v in np.mean(err[m], axis=0)],
                }
            )
    coverage = nanmean(cov, axis=0) if np.isfinite(cov).any() else None
    return {
        "axes": list(AXES),
        "rms": [float(v) for v in np.sqrt(np.mean(err**2, axis=0))],
        "bias": [float(v) for v in np.mean(err, axis=0)],
        "per_regime": rows,
        "coverage": None if coverage is None else [float(v) for v in coverage],
        "interval": {"method": "set_membership", "level": level},
    }


# ============================================================== candidates
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

    @property
    def gain(self) -> float:
        return self.loss0 - self.loss1

    @property
    def fraction(self) -> float:
        return self.gain / self.loss0 if self.loss0 > 0 else 0.0

    def passes(self, min_fraction: float) -> bool:
        return (
            self.fraction >= min_fraction
            and self.folds_better >= self.folds - 1
            and self.delta_bic <= BIC_THRESHOLD
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
                }
                for s in self.scores
            ],
            "params": self.params,
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
        return (
            f"{self.effect} ({e.physics}; driven by {e.driven_by}) on {where}: explains "
            f"{100 * self.explained_fraction:.1f} % of the residual on held-out data ({verdict})"
        )


def _tau_int(x: np.ndarray, max_lag: int = 1000) -> float:
    """Integrated autocorrelation time of a series (>= 1), summed until the ACF drops < 0.05."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    n = len(x)
    if n < 10 or not np.any(x):
        return 1.0
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: min(max_lag, n - 1) + 1]
    ac = ac / ac[0]
    s = 0.0
    for k in range(1, len(ac)):
        if ac[k] < 0.05:
            break
        s += ac[k]
    return 1.0 + 2.0 * s


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


def _score(e: Effect, scs: Sequence[Scored], j: int | None, K: int, guard_s: float) -> JointScore:
    """Held-out and BIC evidence of effect e on joint j (None: shared fit over all joints)."""
    sigs = [s.sig for s in scs]
    ref = e.reference(sigs, j)
    total = sum(len(s.e) for s in scs)
    fs = scs[0].sig.rec.sample_rate
    guard = int(round(guard_s * fs)) if np.isfinite(fs) else 0
    grid = e.grid(sigs, j)
    allowed: dict[int, set[int]] | None = None
    if j is not None and len(grid) > 1:
        st0 = stack(e, scs, j, grid[0], ref)
        fl0 = _folds(st0, total, K, guard)
        masks = [tr(st0.block) for _, tr in fl0] + [np.ones(len(st0.e), dtype=bool)]
        lists = e.shortlist(scs, j, grid, masks)
        allowed = {}
        for k, lst in enumerate(lists):
            for h in lst:
                allowed.setdefault(grid.index(h), set()).add(k)
        grid_idx = sorted(allowed)
    else:
        grid_idx = list(range(len(grid)))
    folds = None
    best_train = [math.inf] * K
    test_l1 = [0.0] * K
    full: FitResult | None = None
    full_resid = None
    base_st = None
    for gi in grid_idx:
        h = grid[gi]
        st = stack(e, scs, j, h, ref)
        sg = st.signs(e.signs(h))
        if folds is None:
            folds = _folds(st, total, K, guard)
            base_st = st
        for k, (test, train) in enumerate(folds):
            if allowed is not None and k not in allowed[gi]:
                continue
            tr = train(st.block)
            w, L = solve_signed(st.e[tr], st.h[tr], st.s[tr], st.C[tr], st.W[tr], st.o[tr], sg)
            if L < best_train[k]:
                best_train[k] = L
                test_l1[k] = _loss(st, test, w)
        if allowed is not None and K not in allowed[gi]:
            continue
        w, L = solve_signed(st.e, st.h, st.s, st.C, st.W, st.o, sg)
        if full is None or L < full.loss:
            full = FitResult(w[: st.k], h, ref, L)
            x = st.e - st.o - st.C @ w
            full_resid = np.sign(x) * np.maximum(np.abs(x) - st.h - st.W @ w, 0) / st.s
    assert folds is not None and base_st is not None and full is not None
    test_l0, L0, b0 = _baseline(base_st, folds)
    L1 = full.loss
    active = (b0 != 0) | (full_resid != 0)
    n_act = int(active.sum())
    tau = _tau_int(full_resid[active]) if n_act > 10 else 1.0
    n_eff = max(n_act / tau, 1.0)
    k_par = e.k + (len(e.hyper) if isinstance(e.hyper, tuple) else 1 if e.hyper else 0)
    if L0 > 0 and L1 > 0:
        dbic = n_eff * math.log(L1 / L0) + k_par * math.log(max(n_eff, 2.0))
    else:
        dbic = 0.0
    better = sum(1 for a, b in zip(test_l0, test_l1, strict=True) if b < a)
    return JointScore(j, sum(test_l0), sum(test_l1), better, K, dbic, n_eff, full)


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
    total = sum(len(s.e) for s in scs)
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
) -> Candidate:
    e = get_effect(name)
    if e.shared:
        s = _score(e, scs, None, K, guard_s)
        ok = s.passes(min_fraction)
        # the shared fit covers every joint: its own held-out baseline is the whole residual
        frac = s.fraction
        spec = make_spec(e, {-1: s.fit})
        return Candidate(
            name, list(range(1, model.n + 1)) if ok else [], frac, ok, [s], spec.params
        )
    scores = [_score(e, scs, j, K, guard_s) for j in range(model.n)]
    sel = [s for s in scores if s.passes(min_fraction)]
    gain = sum(s.gain for s in sel) if sel else max((s.gain for s in scores), default=0.0)
    frac = gain / total_loss if total_loss > 0 else 0.0
    params: dict[str, Any] = {}
    if sel:
        params = clean_none(make_spec(e, {s.joint: s.fit for s in sel})).params
    joints = [s.joint + 1 for s in sel] if sel else [max(scores, key=lambda s: s.gain).joint + 1]
    return Candidate(name, joints, frac, bool(sel), scores, params)


def _applicable(name: str, recs: Sequence[Recording]) -> str | None:
    """Why an effect cannot be tried on these recordings (None when it can)."""
    e = get_effect(name)
    try:
        for r in recs:
            e.check(signals(r))
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

    Returns
    -------
    (candidates best first — suggested ones first, by explained fraction —, skipped: name -> why)
    """
    scs = list(scored_recs) if scored_recs is not None else [scored(model, r) for r in recs]
    # every stride-th sample: neighbours at 250 Hz carry little new information, and the folds
    # and guards stay in the original time index
    n_all = sum(len(s.e) for s in scs)
    stride = max(1, -(-n_all // max_samples))
    if stride > 1:
        scs = [_thin(s, stride) for s in scs]
    have = set(model.effect_names())
    names = [n for n in (effects or EFFECTS) if n not in have]
    for n in names:
        get_effect(n)
    total = _baseline_total(scs, model.n, folds, guard)
    out, skipped = [], {}
    for i, n in enumerate(names):
        why = _applicable(n, recs)
        if why is not None:
            skipped[n] = why
        else:
            out.append(_evaluate(model, scs, n, folds, guard, min_fraction, total))
        if progress is not None:
            progress(i + 1, len(names))
    out.sort(key=lambda c: (not c.suggested, -c.explained_fraction))
    return out, skipped


def _thin(sc: Scored, stride: int) -> Scored:
    keep = (np.arange(len(sc.e)) % stride == 0)[:, None]
    return Scored(
        sc.sig, sc.e, sc.h, sc.sigma, sc.use & keep, sc.tau, sc.notes, sc.sigma_hf, sc.sliding
    )


def select_joints(
    model: TorqueModel,
    recs: Sequence[Recording],
    name: str,
    *,
    scored_recs: Sequence[Scored] | None = None,
) -> list[int]:
    """0-based joints on which diagnosis finds effect ``name`` (the best joint when none passes)."""
    cands, skipped = candidates(model, recs, effects=[name], scored_recs=scored_recs)
    if name in skipped:
        raise ModelError(skipped[name])
    return [j - 1 for j in cands[0].joints]


# ============================================================== the whole diagnosis
@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found; ``to_dict()`` is the ``--json`` output."""

    model: TorqueModel
    residual: dict[str, Any]
    force: dict[str, Any] | None
    windows: list[dict[str, Any]]
    candidates: list[Candidate]
    skipped: dict[str, str]
    notes: list[str]
    recordings: list[str]
    scs: list[Scored] = field(repr=False, default_factory=list)

    @property
    def suggested(self) -> list[Candidate]:
        return [c for c in self.candidates if c.suggested]

    def history_entry(self) -> dict[str, Any]:
        """One row of the model's history: version, effects, torque/force RMS, coverage."""
        f = self.force
        cov = None
        if f is not None and f.get("coverage") is not None:
            cov = float(np.mean(f["coverage"][:3]))
        return {
            "version": self.model.version,
            "effects": [s.name for s in self.model.effects],
            "recordings": self.recordings,
            "torque_rms": [round(v, 6) for v in self.residual["torque_rms"]],
            "noise_floor": [round(v, 6) for v in self.residual["noise_floor"]],
            "force_rms": None if f is None else [round(v, 6) for v in f["rms"]],
            "coverage": None if cov is None else round(cov, 6),
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": model_text(self.model).splitlines(),
            "version": self.model.version,
            "effects": [s.to_dict() for s in self.model.effects],
            "recordings": self.recordings,
            "residual": {**self.residual, "worst_windows": self.windows},
            "force": self.force,
            "candidates": [c.to_dict() for c in self.candidates],
            "skipped": self.skipped,
            "history": _hist_plain(self.model.history),
            "notes": self.notes,
        }

    def summary(self) -> str:
        """Plain-words summary (what the CLI prints)."""
        r = self.residual
        lines = [model_text(self.model), "", "torque residual RMS per joint [N·m] (noise floor):"]
        lines.append(
            "  "
            + "  ".join(
                f"j{j + 1} {a:.3g} ({b:.3g})"
                for j, (a, b) in enumerate(zip(r["torque_rms"], r["noise_floor"], strict=True))
            )
        )
        if self.force is not None:
            lines.append(
                "force error RMS [N, N·m]: "
                + "  ".join(f"{a} {v:.3g}" for a, v in zip(AXES, self.force["rms"], strict=True))
            )
            if self.force.get("coverage") is not None:
                lines.append(
                    "95 % interval coverage: "
                    + "  ".join(
                        f"{a} {v:.2f}" for a, v in zip(AXES, self.force["coverage"], strict=True)
                    )
                )
        if self.windows:
            w = self.windows[0]
            lines.append(
                f"worst window: t={w['t0']:.1f}..{w['t1']:.1f} s, joint {w['worst_joint']} at "
                f"{w['worst_joint_ratio']:.2g}× the noise floor"
            )
        lines.append("")
        if self.suggested:
            lines.append("missing effects (best first):")
            for c in self.suggested:
                lines.append("  " + c.text())
        else:
            best = self.candidates[0] if self.candidates else None
            lines.append(
                "no candidate effect clearly beats the noise"
                + (f" (best: {best.effect}, {100 * best.explained_fraction:.1f} %)" if best else "")
            )
        for n, why in self.skipped.items():
            lines.append(f"  skipped {n}: {why}")
        for n in self.notes:
            lines.append(f"note: {n}")
        return "\n".join(lines)


def _hist_plain(h: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return json.loads(json.dumps(h, default=float))


def diagnose(
    model: TorqueModel,
    recs: Sequence[Recording],
    *,
    folds: int = 5,
    guard: float = 0.25,
    min_fraction: float = MIN_FRACTION,
    effects: Sequence[str] | None = None,
    regimes: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Diagnosis:
    """Compare model and measurements, and rank the missing effects.

    Parameters
    ----------
    model : TorqueModel
    recs : recordings of the model's robot (F/T columns make the force error and the
        ``attenuation_lag`` / ``ft_bias`` candidates possible)
    folds, guard, min_fraction : see :func:`candidates`
    effects : candidate names to try (default: all not in the model)
    regimes : score only these regimes (e.g. ``("still", "dither")`` for the force estimate at
        rest); default all
    progress : ``progress(done, total)``

    Returns
    -------
    Diagnosis

    Raises
    ------
    ModelError
        A recording contains a regime the model has no band for, an unknown effect name, or a
        model effect needs a column a recording lacks.
    """
    recs = list(recs)
    if not recs:
        raise ModelError("diagnose needs at least one recording")
    notes: list[str] = []
    scs = []
    for r in recs:
        # regimes present but absent from the model -> one clear error
        reg = signals(r).regime
        for code, name in ((r, r.label) for r in Regime):
            wanted = regimes is None or name in regimes
            if (
                wanted
                and name not in model.regimes
                and (reg == code).sum(axis=0).max() >= MIN_REGIME_SAMPLES
            ):
                where = f"{r.name}: " if r.name else ""
                raise ModelError(
                    f"{where}the recording has {int((reg == code).any(axis=1).sum())} {name} samples "
                    f"but the model has no [regimes.{name}] (it has {', '.join(model.regimes) or 'none'}); "
                    "identify the model from a recording with that regime"
                )
        sc = scored(model, r)
        if regimes is not None:
            bad = [x for x in regimes if x not in REGIME_NAMES]
            if bad:
                raise ModelError(
                    f"regime {bad[0]!r} is unknown, expected one of: {', '.join(REGIME_NAMES)}"
                )
            keep = np.isin(sc.sig.regime, [r for r in Regime if r.label in regimes])
            sc.use = sc.use & keep
            sc.sigma_hf = white_noise(sc.e, sc.use & (sc.sig.regime != DITHER), sc.sig.regime)
        scs.append(sc)
        notes.extend(f"{r.name or 'recording'}: {x}" for x in sc.notes)
        if not r.has_wrench:
            notes.append(
                f"{r.name or 'recording'}: no F/T columns: the residual contains any external "
                "force, and there is no force error"
            )
    residual = residual_summary(model, scs)
    force = force_error(model, scs)
    windows = worst_windows(model, scs)
    cands, skipped = candidates(
        model,
        recs,
        effects=effects,
        folds=folds,
        guard=guard,
        min_fraction=min_fraction,
        scored_recs=scs,
        progress=progress,
    )
    return Diagnosis(
        model,
        residual,
        force,
        windows,
        cands,
        skipped,
        notes,
        [r.name or "<memory>" for r in recs],
        scs,
    )


# ============================================================== history and report
def append_history(model_path: str | Path, entry: dict[str, Any]) -> TorqueModel:
    """Append a diagnosis row to the model file's history, atomically.

    Re-running diagnosis of the same model version on the same recordings replaces that row.
    """
    m = TorqueModel.load(model_path)
    hist = list(m.history)
    if (
        hist
        and hist[-1].get("version") == entry["version"]
        and hist[-1].get("recordings") == entry["recordings"]
    ):
        hist[-1] = entry
    else:
        hist.append(entry)
    m.history = [{k: v for k, v in h.items() if v is not None} for h in hist]
    m.save(model_path)
    return m

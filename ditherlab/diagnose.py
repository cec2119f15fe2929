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
4. **Candidates**: every library effect not yet in the model, fitted and scored on held-out
   data (:mod:`ditherlab.scoring`, which states the decision rule).

Which physics shows where: ``viscous``, ``stribeck``, ``inertia`` and ``position_ripple`` only in
motion (standing still they are constant and the band takes them); ``load_friction`` and
``temperature_friction`` change sliding friction in motion and the band's width standing still;
``payload`` is a gravity error that changes with the pose (in one fixed pose it is a constant
that the band absorbs: it cannot be told apart from band asymmetry); ``attenuation_lag`` and
``ft_bias`` show wherever the external torque leaves the band (large pushes, the dither regime,
motion) and need a varying pose or force to be told apart from the band.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import norm

from ditherlab.effects import (
    effects_torque,
    force_gain,
    model_text,
    sensor_wrench,
    signals,
)
from ditherlab.errors import ModelError
from ditherlab.estimator import estimate, intervals
from ditherlab.io.atomic import plain
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
from ditherlab.scoring import MIN_FRACTION, Candidate, candidates

__all__ = [
    "Candidate",
    "Diagnosis",
    "append_history",
    "candidates",
    "diagnose",
    "noise_floor_sq",
    "residual_summary",
]

#: A regime with fewer samples than this on every joint needs no band (identify's min_samples).
MIN_REGIME_SAMPLES = 200
#: a candidate whose joints' residual RMS is below this share of their noise floor is noise
FLOOR_SHARE = 0.5
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
        for code, name in ((g, g.label) for g in Regime):
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
    energy in units of the noise floor (mean over joints of excess² / floor²).

    Window ``k`` of a recording is ``[t_0 + k·width/2, t_0 + k·width/2 + width)`` (``t_0`` its
    first time stamp), for every ``k`` that starts before the last sample; a window with fewer
    than four samples is skipped. Each sample falls in two windows, found by one division, so
    the cost is linear in the samples (sums per window by ``np.bincount``).
    """
    out = []
    half = width / 2
    for sc in scs:
        ex, fl = _excess_and_floor(model, sc)
        t = sc.sig.t
        if len(t) == 0:
            continue
        r = np.where(np.isfinite(ex), ex**2 / np.where(fl > 0, fl, 1.0), np.nan)
        t0 = float(t[0])
        nwin = int(math.ceil((float(t[-1]) - t0) / half))
        k = np.floor((t - t0) / half).astype(np.int64)
        ok = np.isfinite(r)
        rz = np.where(ok, r, 0.0)
        samples = _per_window(k, None, nwin)
        tot = np.column_stack([_per_window(k, rz[:, j], nwin) for j in range(r.shape[1])])
        cnt = np.column_stack(
            [_per_window(k, ok[:, j].astype(float), nwin) for j in range(r.shape[1])]
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            per = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
        for w in np.flatnonzero((samples > 3) & np.isfinite(per).any(axis=1)):
            j = int(np.nanargmax(per[w]))
            start = t0 + w * half
            out.append(
                {
                    "recording": sc.sig.rec.name or "<memory>",
                    "t0": float(start),
                    "t1": float(start + width),
                    "energy": float(nanmean(per[w])),
                    "worst_joint": j + 1,
                    "worst_joint_ratio": float(math.sqrt(per[w, j])),
                }
            )
    out.sort(key=lambda d: -d["energy"])
    return out[:count]


def _per_window(k: np.ndarray, w: np.ndarray | None, nwin: int) -> np.ndarray:
    """(nwin,) sums of ``w`` (None: counts) per half-overlapping window: a sample of slot ``k``
    is in window ``k`` and in window ``k - 1``."""
    c = np.bincount(k, weights=w, minlength=nwin + 1)
    return c[:nwin] + c[1 : nwin + 1]


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
        lo, hi, sg = model.sample_bands(reg, sc.sig.dq, dither=True)
        # joints not scored (e.g. dither without extraction): leave them out with a huge band
        lo = np.where(sc.use, lo, -1e9)
        hi = np.where(sc.use, hi, 1e9)
        J = sc.sig.jac * force_gain(model)[None, None, :]
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
    for code, name in ((g, g.label) for g in Regime):
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
    verdict: dict[str, Any] | None = None

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
            "history": plain(self.model.history),
            "notes": self.notes,
            "verdict": self.verdict,
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
        for c in self.candidates:
            if c.not_identifiable and c.explained_fraction >= MIN_FRACTION:
                lines.append("  " + c.text())
        for n, why in self.skipped.items():
            lines.append(f"  skipped {n}: {why}")
        if self.verdict is not None:
            lines.append(f"verdict: {self.verdict['text']}")
        for n in self.notes:
            lines.append(f"note: {n}")
        return "\n".join(lines)


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
        for code, name in ((g, g.label) for g in Regime):
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
    for c in cands:
        # nothing to explain where the residual is far below the noise floor: a share of what
        # is noise already is not evidence of an effect (a standing UR10e: viscous "explained"
        # 6.6 % of joint 1's residual at 0.34x its floor). Right models of moving logs sit at
        # 0.83-0.87x, and a real 5 degree F/T mount rotation at 0.84-0.97x: hence half the floor
        ratio = residual["ratio"]
        low = [j for j in c.joints if not ratio[j - 1] > FLOOR_SHARE]
        if c.suggested and low == c.joints:
            c.suggested = False
            notes.append(
                f"{c.effect} explains {100 * c.explained_fraction:.1f} % on joint(s) "
                f"{', '.join(map(str, c.joints))}, but their residual is far below the noise floor "
                f"({', '.join(f'{ratio[j - 1]:.2f}x' for j in c.joints)}): not "
                "suggested"
            )
    cands.sort(key=lambda c: (not c.suggested, -c.explained_fraction))
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
        verdict(residual, cands, scs),
    )


# ============================================================== the verdict
#: a joint-regime whose residual RMS exceeds its noise floor by more than this fails
FAIL_RATIO = 1.5
#: what to check when the residual correlates with a driving variable
CHECKS = {
    "tau": "the torque's units and drive gains (a scale error grows with the torque itself)",
    "gravity": "the torque's units and drive gains, the encoder zeros and the URDF's masses "
    "(an error that grows with gravity)",
    "ddq": "the robot's dynamics (URDF inertials, a moving base: a leg on a slider or a mobile "
    "platform is not a fixed base)",
    "dq": "the friction model (viscous or Stribeck friction, a velocity scale error)",
    "sign(dq)": "the Coulomb friction per direction (an asymmetric or load-dependent friction)",
    "q": "the encoder zeros and the URDF's kinematics (an error that varies with the pose)",
    "J^T F": "the F/T sensor's frame, bias and scale, and where the tool point is",
    "t": "a drift in time (temperature, a sensor drifting, a log that mixes sessions)",
}


def verdict(
    residual: dict[str, Any], cands: Sequence[Candidate], scs: Sequence[Scored]
) -> dict[str, Any] | None:
    """What the diagnosis concludes where the model fails, and no library effect explains it.

    A joint-regime fails when its residual RMS exceeds :data:`FAIL_RATIO` times its noise floor.
    None when nothing fails. Otherwise ``{"status", "failing", "correlations", "checks",
    "text"}``: ``status`` is ``"explained"`` (a suggested effect is the next step),
    ``"unexplained"`` (no effect of the library explains the residual: the model misses something
    outside it); ``failing`` lists joint, regime and ratio; ``correlations`` per failing joint the
    driving variables the residual correlates with most (|r| over the scored samples); ``checks``
    what to look at for the strongest ones.
    """
    failing = [
        {"joint": r["joint"], "regime": r["regime"], "ratio": r["rms"] / r["floor"]}
        for r in residual["per_regime"]
        if r["floor"] > 0 and r["rms"] > FAIL_RATIO * r["floor"]
    ]
    if not failing:
        return None
    suggested = [c for c in cands if c.suggested]
    joints = sorted({f["joint"] for f in failing})
    corr = {j: _correlations(scs, j - 1) for j in joints}
    strongest = sorted(
        {(name, abs(v)) for c in corr.values() for name, v in c[:2]}, key=lambda x: -x[1]
    )
    checks = list(dict.fromkeys(CHECKS[name] for name, r in strongest if r >= 0.3))
    worst = max(failing, key=lambda f: f["ratio"])
    where = ", ".join(f"{f['joint']} ({f['regime']}, {f['ratio']:.1f}×)" for f in failing)
    if suggested:
        status = "explained"
        text = (
            f"the residual exceeds the noise floor on joint(s) {where}; add the suggested "
            f"effect ({suggested[0].effect}) and diagnose again"
        )
    else:
        status = "unexplained"
        lines = [
            f"the residual stays up to {worst['ratio']:.1f}× the noise floor (joint(s) {where}) "
            "and no effect of the library explains it: the model misses something outside the "
            "library."
        ]
        for j in joints:
            if corr[j]:
                lines.append(
                    f"joint {j} correlates most with "
                    + ", ".join(f"{name} (r = {v:+.2f})" for name, v in corr[j][:3])
                    + "."
                )
        if checks:
            lines.append("Check " + "; ".join(checks) + ".")
        text = " ".join(lines)
    return {
        "status": status,
        "failing": [{**f, "ratio": round(float(f["ratio"]), 4)} for f in failing],
        "correlations": {
            str(j): [[name, round(float(v), 4)] for name, v in c] for j, c in corr.items()
        },
        "checks": checks,
        "text": text,
    }


def _correlations(scs: Sequence[Scored], j: int) -> list[tuple[str, float]]:
    """Pearson r of joint j's scored residual with its driving variables, strongest first."""
    parts: dict[str, list[np.ndarray]] = {}
    for sc in scs:
        m = sc.use[:, j] & np.isfinite(sc.e[:, j])
        if not m.any():
            continue
        sig = sc.sig
        drivers = {
            "residual": sc.e[:, j],
            "tau": sig.tau[:, j],
            "gravity": sig.gravity[:, j],
            "q": sig.q[:, j],
            "dq": sig.dq[:, j],
            "sign(dq)": np.sign(sig.dq[:, j]),
            "ddq": sig.ddq[:, j],
            "t": sig.ts,
        }
        if sig.has_wrench:
            drivers["J^T F"] = sig.sensor_torque("verdict")[:, j]
        for name, x in drivers.items():
            parts.setdefault(name, []).append(np.asarray(x, dtype=float)[m])
    if "residual" not in parts:
        return []
    e = np.concatenate(parts.pop("residual"))
    out = []
    for name, xs in parts.items():
        if len(xs) != len(parts["tau"]):  # J^T F where only some recordings have the sensor
            continue
        x = np.concatenate(xs)
        if len(x) != len(e) or len(x) < 10 or np.std(x) == 0 or np.std(e) == 0:
            continue
        out.append((name, float(np.corrcoef(e, x)[0, 1])))
    return sorted(out, key=lambda kv: -abs(kv[1]))


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

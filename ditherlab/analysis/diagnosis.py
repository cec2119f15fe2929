"""Diagnosis: where a torque model fails against measurements, and which physical effect is missing.

For a model and one or more recordings (with an F/T sensor when available):

1. **Torque residual** per joint and regime: ``rho = tau - gravity - effects - J^T F_sensor`` about
   the model's friction (see :func:`ditherlab.physics.effects.scored`), *band-aware*: in the still and
   dither regimes only the part outside the stick band counts (stick friction may take any value
   in the band); in the moving regime the band collapses onto the sliding friction line and the
   whole residual about it counts. Its RMS is compared with the **noise floor**: the RMS the same
   quantity may have while the model is right, with ``sigma`` the white-noise level measured
   model-free from first differences of the residual (:func:`ditherlab.physics.residual.white_noise`; the
   model's own sigma would absorb any missing effect): moving, ``sigma``; still/dither, the excess
   beyond the band of a friction sitting at the band edge plus noise, ``sqrt(sigma²/2 + ...)``,
   the largest any placement of the friction inside the band gives.
2. **Force error** (estimate of eq. (3) minus the sensor) per axis and regime, and the coverage of
   the 95 % set-membership interval, when :mod:`ditherlab.estimator` and F/T columns are present.
3. The **worst time windows** (1 s) by residual energy in units of the noise floor.
4. **Candidates**: every library effect not yet in the model, fitted and scored on held-out
   data (:mod:`ditherlab.analysis.scoring`, which states the decision rule).

Which physics shows where: ``viscous``, ``stribeck``, ``inertia`` and ``position_ripple`` only in
motion (standing still they are constant and the band takes them); ``load_friction`` and
``temperature_friction`` change sliding friction in motion and the band's width standing still;
``payload`` is a gravity error that changes with the pose (in one fixed pose it is a constant
that the band absorbs: it cannot be told apart from band asymmetry); ``attenuation_lag`` and
``ft_bias`` show wherever the external torque leaves the band (large pushes, the dither regime,
motion) and need a varying pose or force to be told apart from the band.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ditherlab.analysis.diagnosis_sums import (
    AXES,
    Correlations,
    ForceError,
    ResidualSums,
    Windows,
    nanmean,
    noise_floor_sq,
)
from ditherlab.analysis.scoring import MIN_FRACTION, Candidate, candidates
from ditherlab.core.errors import ModelError, where_prefix
from ditherlab.core.files import plain
from ditherlab.core.names import REGIME_NAMES, Regime
from ditherlab.core.spill import Spill
from ditherlab.core.ticker import Ticker
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Piece, Source, pieces_of
from ditherlab.physics.effects import (
    EFFECTS,
    Effect,
    Signals,
    design_at,
    get_effect,
    model_text,
    release,
)
from ditherlab.physics.residual import (
    Local,
    Scored,
    ScoreStats,
    StatsBuilder,
    check_noise,
    local,
    noband_rows,
    score_notes,
    scored,
)

__all__ = [
    "Candidate",
    "Diagnosis",
    "candidates",
    "diagnose",
    "force_error",
    "nanmean",
    "noise_floor_sq",
    "residual_summary",
    "with_history_row",
]

#: A regime with fewer samples than this on every joint needs no band (identify's min_samples).
MIN_REGIME_SAMPLES = 200
#: a candidate whose joints' residual RMS is below this share of their noise floor is noise
FLOOR_SHARE = 0.5


# ============================================================== one recording in memory
def residual_summary(model: TorqueModel, scs: Sequence[Scored]) -> dict[str, Any]:
    """Torque residual per joint and regime against the noise floor.

    Returns
    -------
    dict with ``torque_rms`` (n,) [N·m], ``noise_floor`` (n,) [N·m], ``ratio`` (n,), and
    ``per_regime``: list of {joint, regime, samples, rms, floor, outside_fraction, mean_excess}
    where ``mean_excess`` is the signed mean excess in units of sigma (a bias shows here).
    """
    acc = ResidualSums(model.n)
    for sc in scs:
        acc.add(sc)
    return acc.result()


def worst_windows(
    model: TorqueModel, scs: Sequence[Scored], width: float = 1.0, count: int = 5
) -> list[dict[str, Any]]:
    """The ``count`` windows of ``width`` seconds (half-overlapping) with the largest residual
    energy in units of the noise floor (mean over joints of excess² / floor²).

    Window ``k`` of a recording is ``[t_0 + k·width/2, t_0 + k·width/2 + width)`` (``t_0`` its
    first time stamp), for every ``k`` that starts before the last sample; a window with fewer
    than four samples is skipped (:class:`~ditherlab.analysis.diagnosis_sums.Windows`: linear in the
    samples).
    """
    out = []
    for sc in scs:
        t = sc.sig.t
        if len(t):
            w = Windows(sc.sig.rec.name or "<memory>", t[0], t[-1], model.n, width)
            w.add(sc)
            out += w.result()
    out.sort(key=lambda d: -d["energy"])
    return out[:count]


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
    acc = ForceError(model, level, max_interval_samples)
    for sc in scs:
        acc.add(sc, slice(0, len(sc.e)), 0, len(sc.e))
    return acc.result()


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

    def recorded(self) -> TorqueModel:
        """A copy of the diagnosed model with this diagnosis's row in its history
        (:func:`with_history_row`): what ``ditherlab diagnose`` writes back."""
        return with_history_row(self.model, self.history_entry())

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
            if (c.not_identifiable or c.unphysical) and not c.suggested:
                lines.append("  " + c.text())
        for n, why in self.skipped.items():
            lines.append(f"  skipped {n}: {why}")
        if self.verdict is not None:
            lines.append(f"verdict: {self.verdict['text']}")
        for n in self.notes:
            lines.append(f"note: {n}")
        return "\n".join(lines)


#: context rows on either side of a piece [s]: the first-order lag of ``attenuation_lag`` (up to
#: 0.3 s, in the model or as a candidate) starts at rest at a piece's first row, and forgets that
#: start below 1e-16 after 37 time constants (11.1 s)
HALO_S = 12.0


def diagnose(
    recs: Sequence[Recording | Source],
    model: TorqueModel,
    *,
    folds: int = 5,
    guard: float = 0.25,
    min_fraction: float = MIN_FRACTION,
    effects: Sequence[str] | None = None,
    regimes: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    chunk_rows: int = CHUNK_ROWS,
    max_samples: int = 4000,
) -> Diagnosis:
    """Compare model and measurements, and rank the missing effects.

    A recording is read twice, a piece of ``chunk_rows`` rows at a time (one piece when it is
    held in memory): the first pass gathers what scoring needs of the whole recording (which
    regimes have too few samples, where the moving band sits, the white noise:
    :class:`~ditherlab.physics.residual.StatsBuilder`), the second scores every piece and adds it to
    sums (:mod:`ditherlab.analysis.diagnosis_sums`), keeping every k-th sample (at most
    ``max_samples`` in all) on which the candidates are fitted. Memory holds a piece, the sums,
    those samples and the white noise's differences (16 bytes per sample, spilled to disk past
    256 MB).

    Parameters
    ----------
    recs : recordings of the model's robot, in memory or :class:`~ditherlab.io.stream.Source`
        s (F/T columns make the force error and the ``attenuation_lag`` / ``ft_bias``
        candidates possible)
    model : TorqueModel
    folds, guard, min_fraction : see :func:`candidates`
    effects : candidate names to try (default: all not in the model)
    regimes : score only these regimes (e.g. ``("still", "dither")`` for the force estimate at
        rest); default all
    progress : ``progress(done, total)``
    chunk_rows : rows a piece owns (pieces carry :data:`HALO_S` of context on either side)
    max_samples : the candidates are fitted on every k-th sample, k = ceil(N / max_samples)

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
    _check_regimes(regimes)
    have = set(model.effect_names())
    names = [n for n in (effects or EFFECTS) if n not in have]
    totals = [len(r) if isinstance(r, Recording) else r.n_rows for r in recs]
    counts = [1 if isinstance(r, Recording) else max(1, -(-r.n_rows // chunk_rows)) for r in recs]
    run = _Run(
        model,
        regimes,
        chunk_rows,
        stride=max(1, -(-sum(totals) // max_samples)),
        timed=[get_effect(n) for n in names if not get_effect(n).pointwise],
        tick=Ticker(2 * sum(counts) + len(names), progress),
    )
    sums = _Sums(ResidualSums(model.n), ForceError(model), Correlations(model.n))
    for r, total in zip(recs, totals, strict=True):
        if total >= 2:  # one sample: no step, no rate, nothing to score (said below if all are)
            _score_recording(run, r, total, sums)
    summary = sums.residual.result()
    if not summary["per_regime"]:
        _nothing_scored(recs, sum(totals), regimes)
    sums.windows.sort(key=lambda d: -d["energy"])
    cands, skipped = candidates(
        model,
        [],
        effects=effects,
        folds=folds,
        guard=guard,
        min_fraction=min_fraction,
        scored_recs=sums.thinned,
        max_samples=max(1, sum(len(s.e) for s in sums.thinned)),
        progress=lambda i, n: run.tick(),
        quiet=quiet_joints(summary["ratio"]),
    )
    demote_below_floor(cands, summary["ratio"], sums.notes)
    sums.notes += added_notes(model)
    cands.sort(key=lambda c: (not c.suggested, -c.explained_fraction))
    return Diagnosis(
        model,
        summary,
        sums.force.result(),
        sums.windows[:5],
        cands,
        skipped,
        sums.notes,
        [r.name or "<memory>" for r in recs],
        sums.thinned,
        verdict(summary, cands, sums.corr),
    )


def added_notes(model: TorqueModel) -> list[str]:
    """What ``identify --add`` recorded in the model's history for its current version that a
    diagnosis must repeat: a force error that grew when the last effect was added."""
    return [
        f"model v{h['version']}: {h['warning']}"
        for h in model.history
        if h.get("version") == model.version and h.get("warning")
    ]


def _check_regimes(regimes: Sequence[str] | None) -> None:
    """Every asked-for regime is one of :data:`REGIME_NAMES`."""
    bad = [x for x in regimes or () if x not in REGIME_NAMES]
    if bad:
        raise ModelError(
            f"regime {bad[0]!r} is unknown, expected one of: {', '.join(REGIME_NAMES)}"
        )


@dataclass(frozen=True)
class _Run:
    """What every recording of one :func:`diagnose` call is scored with: the model, the regimes
    asked for (None: all), the rows of a piece, every ``stride``-th row kept for the candidates,
    the candidate effects that filter in time, and the progress ticker."""

    model: TorqueModel
    regimes: Sequence[str] | None
    chunk_rows: int
    stride: int
    timed: list[Effect]
    tick: Ticker


@dataclass
class _Sums:
    """What the recordings add up to: the residual, force error and correlation sums, the worst
    windows, the thinned scored samples (one per recording) and the notes."""

    residual: ResidualSums
    force: ForceError
    corr: Correlations
    windows: list[dict[str, Any]] = field(default_factory=list)
    thinned: list[Scored] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _recording_stats(run: _Run, r: Recording | Source) -> tuple[ScoreStats, Local | None, bool]:
    """The first pass over a recording: what scoring needs of the whole of it
    (:class:`StatsBuilder`), the Local of a recording of one piece (it serves both passes, else
    None), and whether it has F/T columns."""
    with Spill() as spill:
        built = StatsBuilder(run.model, MIN_REGIME_SAMPLES, spill)
        has_wrench = False
        held = None
        for piece in _pieces(r, run.chunk_rows):
            loc = local(run.model, piece.rec)
            built.add(loc, piece.keep)
            held = loc if piece.count == 1 else None
            has_wrench = piece.rec.has_wrench
            run.tick()
        _absent_regimes(run.model, built, run.regimes, r.name)
        stats = built.finish(run.regimes)
    check_noise(r.name, stats.sigma_hf)
    return stats, held, has_wrench


def _score_recording(run: _Run, r: Recording | Source, total: int, sums: _Sums) -> None:
    """Both passes over one recording of ``total`` rows: every piece scored and added to
    ``sums``, every ``run.stride``-th row kept for the candidates, the recording's notes."""
    model = run.model
    stats, held, has_wrench = _recording_stats(run, r)
    t = r.t if isinstance(r, Recording) else r.times()
    win = Windows(r.name or "<memory>", t[0], t[-1], model.n)
    left = {"near": 0, "rev": 0, "no_extraction": False}
    noband: dict[str, int] = {}
    parts: list[Scored] = []
    for piece in _pieces(r, run.chunk_rows):
        loc = held if held is not None else local(model, piece.rec)
        sc = scored(model, piece.rec, stats=stats, loc=loc)
        if run.regimes is not None:
            sc.use = sc.use & np.isin(sc.sig.regime, [g for g in Regime if g.label in run.regimes])
        k = piece.keep
        sums.residual.add(sc, k)
        win.add(sc, k)
        sums.force.add(sc, k, piece.start, total)
        sums.corr.add(sc, k)
        left["near"] += int(loc.near[k].sum())
        left["rev"] += int(loc.rev[k].sum())
        left["no_extraction"] |= loc.no_extraction
        for x, rows in noband_rows(model, loc, stats).items():
            noband[x] = noband.get(x, 0) + int(rows[k].sum())
        own = np.arange(k.start, k.stop)
        rows = own[(piece.start + own) % run.stride == 0]
        if len(rows):
            parts.append(
                _thin(sc, rows, run.timed, piece.start, parts[0].sig.rec if parts else None)
            )
        run.tick()
    sums.windows.extend(win.result())
    sums.thinned.append(_join(parts, total))
    sums.notes.extend(_recording_notes(r.name, left, noband, has_wrench))


def _recording_notes(
    name: str | None, left: dict[str, Any], noband: dict[str, int], has_wrench: bool
) -> list[str]:
    """What the scoring of one recording left out (``left``: rows near a stick transition or a
    velocity reversal, no dither extraction; ``noband``: rows per regime without a band), and
    that it has no F/T columns."""
    why = score_notes(bool(left["no_extraction"]), left["near"], left["rev"], noband)
    out = [f"{name or 'recording'}: {x}" for x in why]
    if not has_wrench:
        out.append(
            f"{name or 'recording'}: no F/T columns: the residual contains any external "
            "force, and there is no force error"
        )
    return out


def _nothing_scored(
    recs: Sequence[Recording | Source], rows: int, regimes: Sequence[str] | None
) -> None:
    """The error when no sample of ``rows`` in all was left to score."""
    names = ", ".join(r.name or "<memory>" for r in recs)
    raise ModelError(
        f"{names}: no sample left to score ({rows} rows; stick transitions, velocity "
        "reversals and the first dither period are not scored"
        + (f", and only the regimes {', '.join(regimes)} were asked for" if regimes else "")
        + "); expected a longer recording"
    )


def quiet_joints(ratio: Sequence[float]) -> list[int]:
    """1-based joints whose residual RMS sits below :data:`FLOOR_SHARE` of their noise floor
    (``ratio`` per joint): no per-joint effect is named there (:func:`candidates`' ``quiet``),
    whatever the other joints do."""
    return [j + 1 for j, r in enumerate(ratio) if not r > FLOOR_SHARE]


def demote_below_floor(
    cands: Sequence[Candidate], ratio: Sequence[float], notes: list[str]
) -> None:
    """No candidate is suggested whose joints all sit below :data:`FLOOR_SHARE` of their noise
    floor (``ratio``: residual RMS over floor per joint); a note says so, and one for the
    joints such a joint's evidence passed on but a per-joint effect does not name
    (:func:`quiet_joints`).

    Nothing is left to explain where the residual is far below the noise floor: a share of what
    is noise already is not evidence of an effect (a standing UR10e: viscous "explained" 6.6 %
    of joint 1's residual at 0.34x its floor). Right models of moving logs sit at 0.83-0.87x,
    and a real 5 degree F/T mount rotation at 0.84-0.97x: hence half the floor."""
    quiet = set(quiet_joints(ratio))
    for c in cands:
        left = [s.joint + 1 for s in c.scores if s.joint is not None and s.joint + 1 in quiet
                and s.passes(MIN_FRACTION)]  # fmt: skip
        if left and c.suggested:
            notes.append(
                f"{c.effect} also passes on joint(s) {', '.join(map(str, left))}, whose residual "
                f"is far below the noise floor ({', '.join(f'{ratio[j - 1]:.2f}x' for j in left)}"
                "): not named there"
            )
    for c in cands:
        low = [j for j in c.joints if not ratio[j - 1] > FLOOR_SHARE]
        if c.suggested and low == c.joints:
            c.suggested = False
            notes.append(
                f"{c.effect} explains {100 * c.explained_fraction:.1f} % on joint(s) "
                f"{', '.join(map(str, c.joints))}, but their residual is far below the noise floor "
                f"({', '.join(f'{ratio[j - 1]:.2f}x' for j in c.joints)}): not "
                "suggested"
            )


def _pieces(r: Recording | Source, rows: int) -> Iterator[Piece]:
    """The recording's pieces with :data:`HALO_S` of context, each one's cached Signals
    released when the next is asked for (a recording in memory is one piece, kept)."""
    for piece in pieces_of(r, rows, HALO_S):
        yield piece
        if piece.count > 1:
            release(piece.rec)


def _absent_regimes(
    model: TorqueModel, built: StatsBuilder, regimes: Sequence[str] | None, name: str | None
) -> None:
    """A regime of the recording (>= :data:`MIN_REGIME_SAMPLES` samples on a joint) the model
    has no band for: one clear error."""
    for code in Regime:
        wanted = regimes is None or code.label in regimes
        if (
            wanted
            and code.label not in model.regimes
            and built.present[code].max() >= MIN_REGIME_SAMPLES
        ):
            raise ModelError(
                f"{where_prefix(name)}the recording has {int(built.present_rows[code])} "
                f"{code.label} samples but the model has no [regimes.{code.label}] (it has "
                f"{', '.join(model.regimes) or 'none'}); identify the model from a recording "
                "with that regime"
            )


def _thin(
    sc: Scored,
    rows: np.ndarray,
    timed: Sequence[Effect],
    start: int,
    rec: Recording | None = None,
) -> Scored:
    """The rows of a scored piece the candidates are fitted on (:meth:`Scored.at`), with the
    designs of effects that filter in time (``timed``) computed here, on the piece, for every
    value of their grid; then detached from the piece (:meth:`Signals.detach`: ``start`` is
    the recording's row of the piece's row 0, ``rec`` the recording kept in the piece's place,
    default the piece's own)."""
    part = sc.at(rows)
    for e in timed:
        try:
            e.check(part.sig)
        except ModelError:
            continue  # the candidates skip it and say why
        for j in [None] if e.shared else range(part.sig.n):
            ref = e.reference([part.sig], j)
            for h in e.grid([part.sig], j):
                design_at(e, part.sig, j, h, ref)
    part.sig.detach(start, rec if rec is not None else sc.sig.rec)
    part.notes = []
    return part


def _join(parts: list[Scored], total: int) -> Scored:
    """One scored recording of the thinned rows of its pieces (``total``: its rows)."""
    if not parts:
        raise ModelError("diagnose: a recording without samples")
    return Scored(
        Signals.join([p.sig for p in parts], total),
        *(
            np.concatenate([getattr(p, f) for p in parts])
            for f in ("e", "h", "sigma", "use", "tau")
        ),
        [],
        parts[0].sigma_hf,
        parts[0].sliding,
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
    residual: dict[str, Any], cands: Sequence[Candidate], correlations: Correlations
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
    corr = {j: correlations.result(j - 1) for j in joints}
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


def with_history_row(model: TorqueModel, entry: dict[str, Any]) -> TorqueModel:
    """A copy of ``model`` with a diagnosis row (:meth:`Diagnosis.history_entry`) appended to its
    history; a diagnosis of the same model version on the same recordings replaces the last
    row instead, and the first diagnosis of a version completes the row ``identify --add``
    wrote for it (what it added, promised and delivered are kept)."""
    m = model.copy()
    hist = list(m.history)
    last = hist[-1] if hist else {}
    if last.get("version") == entry["version"] and "torque_rms" not in last:
        hist[-1] = {**last, **entry}
    elif last.get("version") == entry["version"] and last.get("recordings") == entry["recordings"]:
        hist[-1] = {**{k: v for k, v in last.items() if k not in entry}, **entry}
    else:
        hist.append(entry)
    m.history = [{k: v for k, v in h.items() if v is not None} for h in hist]
    return m

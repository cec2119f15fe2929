"""The band-aware torque residual of a recording under a model, and its noise floor.

``rho = tau - gravity - effects - J^T F``; in the ``still`` and ``dither`` regimes the friction
band absorbs whatever lies inside it, in ``moving`` the band collapses onto the sliding friction
line (:func:`scored`). Samples no friction curve describes (break-away transients, short slips,
velocity reversals: :func:`ditherlab.core.timeseries.stick_transitions`) are not scored. Fitting effects to
it is :mod:`ditherlab.physics.effect_fit`; scoring them on held-out data is :mod:`ditherlab.analysis.diagnosis`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ditherlab.core.errors import ModelError, RecordingError, where_prefix
from ditherlab.core.names import DITHER, MOVING, Regime
from ditherlab.core.spill import Spill
from ditherlab.core.timeseries import REVERSAL_V, STICK_SETTLE_S, smooth_wrench, stick_transitions
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.band_fit import noise_lag
from ditherlab.physics.dither import (
    extract_dither,
    ramp_in,
    ramp_level,
    ramp_samples,
    window_samples,
)
from ditherlab.physics.effects import (
    Signals,
    check_model_effects,
    effects_torque,
    external_torque,
    sensor_wrench,
    signals,
    widening,
)
from ditherlab.physics.effects.extraction import as_extracted, extracted_rows

__all__ = [
    "NO_NOISE",
    "check_noise",
    "Local",
    "ScoreStats",
    "Scored",
    "StatsBuilder",
    "band_loss",
    "local",
    "noband_rows",
    "score_notes",
    "scored",
    "white_noise",
]


@dataclass
class Scored:
    """The band-aware residual of one recording under a model, ready for fitting.

    Attributes
    ----------
    sig : Signals
    e : (N, n) [N·m] residual about the band centre (moving: about the sliding friction line)
    h : (N, n) [N·m] half-width of the band that absorbs it (0 in the moving regime)
    sigma : (N, n) [N·m] noise level of each sample's regime
    use : (N, n) bool, samples that are scored
    tau : (N, n) [N·m] the torque used (the dither-extracted signal in the dither regime)
    """

    sig: Signals
    e: np.ndarray
    h: np.ndarray
    sigma: np.ndarray
    use: np.ndarray
    tau: np.ndarray
    notes: list[str] = field(default_factory=list)
    sigma_hf: np.ndarray | None = None
    #: the model's moving band has (coulomb, viscous): identification re-fits them
    sliding: tuple[bool, bool] = (False, False)

    def at(self, rows: np.ndarray) -> Scored:
        """These scored samples at some rows (M,) only, with the Signals of those rows
        (:meth:`ditherlab.physics.effects.Signals.take`: effects' designs are computed there alone)."""
        return Scored(
            self.sig.take(rows),
            self.e[rows],
            self.h[rows],
            self.sigma[rows],
            self.use[rows],
            self.tau[rows],
            self.notes,
            self.sigma_hf,
            self.sliding,
        )

    def excess(
        self, shift: np.ndarray | None = None, widen: np.ndarray | None = None
    ) -> np.ndarray:
        """(N, n) [N·m]: the signed part of ``e - shift`` outside the band (0 inside)."""
        x = self.e if shift is None else self.e - shift
        hh = self.h if widen is None else np.maximum(self.h + widen, 0.0)
        return np.sign(x) * np.maximum(np.abs(x) - hh, 0.0)


def _dither_signal(
    rec: Recording,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int] | None:
    """The paper's extracted dither signal (N, n) [N·m], its validity (N,), the extracted
    amplitude (N, n) [N·m] and the window [samples per period], or None."""
    sig = extract_dither(rec)
    if sig is None:
        return None
    w = window_samples(sig.period, rec.sample_rate)
    return np.asarray(sig.signal, dtype=float), np.asarray(sig.valid, dtype=bool), sig.amplitude, w


@dataclass
class Local:
    """What scoring a recording (or a piece of one, with its context rows) computes from its own
    samples, before the statistics of the whole recording (:class:`ScoreStats`).

    Attributes
    ----------
    sig : Signals ; reg : (N, n) regime codes ; tau : (N, n) [N·m] the torque used
    rho : (N, n) [N·m] ``tau - gravity - effects - J^T F``
    cen : (N, n) [N·m] the band centre, plus the sliding line where moving (without the moving
        offset of the whole recording)
    use : (N, n) bool, scored before the whole recording's rules (dither windows, sticks,
        reversals, a regime without a band)
    near, rev : (N, n) bool, near a stick ; a velocity reversal while moving
    no_extraction : the recording has dither samples but no dither extraction
    """

    sig: Signals
    reg: np.ndarray
    tau: np.ndarray
    rho: np.ndarray
    cen: np.ndarray
    use: np.ndarray
    near: np.ndarray
    rev: np.ndarray
    no_extraction: bool


@dataclass
class ScoreStats:
    """The statistics of a whole recording that scoring one of its samples needs.

    Attributes
    ----------
    few : (3, n) bool, a regime (code) of a joint with fewer than ``min_samples`` scored
        samples in the whole recording (not scored)
    shift : (n,) [N·m] where the moving band's one point sits, minus the band centre
    sigma_hf : (n,) [N·m] :func:`white_noise`, NaN where there are too few pairs
    """

    few: np.ndarray
    shift: np.ndarray
    sigma_hf: np.ndarray


#: [N·m] a noise (fitted or measured) below this is none: the joint's torque residual does not
#: vary — a dead or unlogged channel, since a measured torque always has noise
NO_NOISE = 1e-6


def check_noise(name: str | None, sigma: np.ndarray) -> None:
    """Raise RecordingError for the first joint whose noise ``sigma`` (n,) [N·m] (NaN: unknown,
    skipped) lies below :data:`NO_NOISE`: identify and diagnose refuse such a log alike."""
    for j, s in enumerate(np.asarray(sigma, dtype=float)):
        if np.isfinite(s) and s < NO_NOISE:
            raise RecordingError(
                f"{name or 'recording'}: the torque residual of joint {j + 1} does not vary "
                f"(noise {s:.1g} N·m); expected a measured tau_{j + 1}, which always has "
                "noise: is it constant or not logged?"
            )


def local(model: TorqueModel, rec: Recording, *, use_sensor: bool = True) -> Local:
    """:class:`Local` of a recording (or a piece with context rows): see :func:`scored`."""
    sig = signals(rec)
    if model.n != rec.n:
        raise ModelError(
            f"{where_prefix(rec.name)}the recording has {rec.n} joints, the model {model.n}; expected the same robot"
        )
    check_model_effects(model, rec)
    reg = sig.regime
    tau = rec.tau.copy()
    use = np.ones(tau.shape, dtype=bool)
    no_extraction = False
    window = 0  # samples per dither period where the dither regime reads the extraction
    if (reg == DITHER).any():
        ext = _dither_signal(rec)
        if ext is None:
            use &= reg != DITHER
            no_extraction = True
        else:
            tau = np.where(reg == DITHER, ext[0], tau)
            window = ext[3]
            # the first dither period has no full window
            use &= (reg != DITHER) | ext[1][:, None]
            if rec.dither is not None:
                # the dither's ramp-in: the joint's residual is not yet the regime's
                ramp = ramp_in(
                    rec.dither, ext[1], ext[2], ramp_level(model), ramp_samples(rec.sample_rate)
                )
                use &= ~(ramp & (reg == DITHER))
    near = stick_transitions(reg, rec.sample_rate)
    use &= ~near
    # velocity reversals inside a motion: the joint is at rest for a few samples and its
    # friction passes through the static band, neither on the sliding line nor a stick
    rev = (reg == MOVING) & (np.abs(rec.dq) < REVERSAL_V) & use
    use &= ~rev
    model_tau = sig.gravity + effects_torque(model, rec)
    ext = None
    if use_sensor and rec.has_wrench:
        ext = external_torque(model, rec, smooth_wrench(sensor_wrench(model, rec), rec.sample_rate))
    rho = tau - model_tau - (0.0 if ext is None else ext)
    if window:
        # the extracted signal is compared with the model torque through the same window
        shown = extracted_rows(model.effects, sig) if ext is not None and model.effects else None
        seen = as_extracted(model_tau, ext, shown, window)
        rho = np.where(reg == DITHER, tau - seen, rho)
    cen = np.zeros_like(rho)
    for code in Regime:
        if code.label not in model.regimes:
            continue
        b = model.band(code.label)
        m = reg == code
        c = np.broadcast_to(0.5 * (b.tau_min + b.tau_max), rho.shape)
        if code == MOVING:
            c = c + b.sliding(sig.dq)
        cen[m] = c[m]
    return Local(sig, reg, tau, rho, cen, use, near, rev, no_extraction)


class StatsBuilder:
    """:class:`ScoreStats` of a whole recording gathered piece by piece (:meth:`add` the
    :class:`Local` of each piece with the rows it owns, then :meth:`finish`); the differences for
    :func:`white_noise` go to a :class:`~ditherlab.core.spill.Spill` (16 bytes per pair)."""

    def __init__(self, model: TorqueModel, min_samples: int = 200, spill: Spill | None = None):
        self.model = model
        self.min_samples = min_samples
        n = model.n
        self.counts = np.zeros((3, n), dtype=np.int64)  # scored samples per regime and joint
        self.present = np.zeros((3, n), dtype=np.int64)  # samples per regime and joint
        self.present_rows = np.zeros(3, dtype=np.int64)  # rows with a joint in the regime
        self.off_sum = np.zeros(n)
        self.off_n = np.zeros(n, dtype=np.int64)
        self.spill = spill if spill is not None else Spill()

    def add(self, loc: Local, keep: slice = slice(None)) -> None:
        """Gather the rows ``keep`` of ``loc`` (a piece's own rows)."""
        reg, use = loc.reg, loc.use
        N = len(reg)
        lo, hi, _ = keep.indices(N)
        mb = self.model.regimes.get("moving")
        for code in Regime:
            m = (reg[lo:hi] == code) & use[lo:hi]
            self.present[code] += (reg[lo:hi] == code).sum(axis=0)
            self.present_rows[code] += int((reg[lo:hi] == code).any(axis=1).sum())
            self.counts[code] += m.sum(axis=0)
            if code == MOVING and mb is not None:
                centre = 0.5 * (mb.tau_min + mb.tau_max)
                for j in range(reg.shape[1]):
                    mj = m[:, j]
                    if mj.any():
                        v = (loc.rho - loc.cen + centre)[lo:hi][mj, j] - centre[j]
                        self.off_sum[j] += float(np.sum(v))
                        self.off_n[j] += int(mj.sum())
        # white noise: differences of scored samples of one regime L = noise_lag rows apart (one
        # row up to 250 Hz), for the pairs ending in an own row (the rows before the first are
        # the piece's context)
        known = np.isin(reg, [c for c in Regime if c.label in self.model.regimes])
        u = use & known & (reg != DITHER)
        L = noise_lag(loc.sig.sample_rate)
        a = max(lo, L)
        if hi <= a:
            return
        e0 = loc.rho[a - L : hi] - loc.cen[a - L : hi]
        d = e0[L:] - e0[:-L]
        ok = u[a:hi] & u[a - L : hi - L] & (reg[a:hi] == reg[a - L : hi - L])
        r2 = reg[a:hi]
        for j in range(reg.shape[1]):
            for code in (c for c in Regime if c != DITHER):
                sel = ok[:, j] & (r2[:, j] == code)
                if sel.any():
                    self.spill.append(("wn", j, int(code)), d[sel, j])

    def finish(self, regimes: Sequence[str] | None = None) -> ScoreStats:
        """The statistics; ``regimes``: only these regimes' pairs make the white noise."""
        model = self.model
        n = model.n
        few = self.counts < self.min_samples
        shift = np.zeros(n)
        mb = model.regimes.get("moving")
        if mb is not None:
            centre = 0.5 * (mb.tau_min + mb.tau_max)
            for j in range(n):
                if self.off_n[j]:
                    off = self.off_sum[j] / self.off_n[j]
                    shift[j] = np.clip(centre[j] + off, mb.tau_min[j], mb.tau_max[j]) - centre[j]
        hf = np.full(n, np.nan)
        for j in range(n):
            parts = [
                self.spill.load(("wn", j, int(c)))
                for c in Regime
                if c != DITHER
                and not few[c, j]
                and (regimes is None or c.label in regimes)
                and self.spill.count(("wn", j, int(c)))
            ]
            hf[j] = white_noise(np.concatenate(parts) if parts else np.zeros(0))
        return ScoreStats(few, shift, hf)


def noband_rows(model: TorqueModel, loc: Local, stats: ScoreStats) -> dict[str, np.ndarray]:
    """(N,) bool per regime the model has no band for: the rows where a joint would be scored
    in it (not scored: the note says how many)."""
    out = {}
    for code in Regime:
        if code.label not in model.regimes:
            m = (loc.reg == code) & loc.use & ~stats.few[code][None, :]
            if m.any():
                out[code.label] = m.any(axis=1)
    return out


def score_notes(no_extraction: bool, near: int, rev: int, noband: dict[str, int]) -> list[str]:
    """What scoring left out, in words: dither samples without extraction, ``near`` joint-samples
    near a stick, ``rev`` of velocity reversals, rows of regimes without a band."""
    notes = []
    if no_extraction:
        notes.append("dither samples not scored (no dither extraction for this recording)")
    if near:
        notes.append(f"{near} joint-samples within {STICK_SETTLE_S:g} s of a stick not scored")
    if rev:
        notes.append(
            f"{rev} joint-samples of velocity reversals (|dq| < {REVERSAL_V:g} rad/s "
            "while moving) not scored"
        )
    notes += [f"{k} {name} samples not scored (no band)" for name, k in noband.items() if k]
    return notes


def scored(
    model: TorqueModel,
    rec: Recording,
    *,
    use_sensor: bool = True,
    min_samples: int = 200,
    stats: ScoreStats | None = None,
    loc: Local | None = None,
) -> Scored:
    """The band-aware residual ``rho = tau - gravity - effects - J^T F`` of a recording.

    Per regime: in ``still`` and ``dither`` the stick band ``[tau_min, tau_max]`` (widened by the
    model's load/temperature effects) absorbs whatever lies inside it; in ``moving`` the band
    collapses onto the sliding friction ``coulomb·sign(dq) + viscous·dq`` (when the model has
    them) plus one offset in ``[tau_min, tau_max]`` (the data's mean offset, clipped into the
    band), and the whole residual about that line counts. In the dither regime the torque is the
    paper's extracted signal (:func:`ditherlab.physics.dither.extract_dither`); without it dither samples
    are not scored.

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    use_sensor : subtract ``external_torque(sensor_wrench)`` (needs F/T columns); when False or
        absent, the residual contains the external torque (free-motion logs have none).
    min_samples : a joint's regime with fewer samples in this recording is not scored (as in
        :func:`ditherlab.analysis.identification.identify`).
    stats : the whole recording's statistics when ``rec`` is a piece of it (pass 1 of a
        recording read in pieces: :class:`StatsBuilder`); default: this recording's own
    loc : its :class:`Local`, when already computed

    Raises
    ------
    ModelError
        When the recording contains a regime the model has no band for.
    """
    if loc is None:
        loc = local(model, rec, use_sensor=use_sensor)
    if stats is None:
        with Spill() as spill:
            b = StatsBuilder(model, min_samples, spill)
            b.add(loc)
            stats = b.finish()
    sig, reg = loc.sig, loc.reg
    use = loc.use.copy()
    notes = score_notes(
        loc.no_extraction,
        int(loc.near.sum()),
        int(loc.rev.sum()),
        {k: int(v.sum()) for k, v in noband_rows(model, loc, stats).items()},
    )
    e = np.zeros_like(loc.rho)
    h = np.zeros_like(loc.rho)
    sigma = np.ones_like(loc.rho)
    for code in Regime:
        name = code.label
        m = (reg == code) & use
        if not m.any():
            continue
        few = stats.few[code]
        if few.any():
            # a handful of samples (e.g. velocity reversals flagged still) is not a regime:
            # identification fits no band from it either
            use &= ~(m & few)
            m &= ~few
            if not m.any():
                continue
        if name not in model.regimes:
            use &= ~m
            continue
        b = model.band(name)
        cen = loc.cen
        if code == MOVING:
            # the band collapses to one point in [tau_min, tau_max]: the one the data sit at
            # (mean offset from the sliding line, clipped into the band)
            cen = cen + stats.shift[None, :]
            hh = np.zeros(loc.rho.shape)
        else:
            hh = np.broadcast_to(0.5 * (b.tau_max - b.tau_min), loc.rho.shape)
        e[m] = (loc.rho - cen)[m]
        h[m] = hh[m]
        sigma[m] = np.broadcast_to(b.sigma, loc.rho.shape)[m]
    wid = widening(model, rec)
    h = np.where(reg == MOVING, h, np.maximum(h + wid, 0.0))
    mb = model.regimes.get("moving")
    sliding = (mb is not None and mb.coulomb is not None, mb is not None and mb.viscous is not None)
    return Scored(sig, e, h, sigma, use, loc.tau, notes, stats.sigma_hf, sliding)


def white_noise(d: np.ndarray) -> float:
    """Model-free noise level [N·m] from first differences ``d`` (M,) of the residual.

    Effects are smooth in time; white measurement noise is not: a difference has standard
    deviation ``sqrt(2)·sigma``. A robust scale (1.4826 · median absolute deviation) ignores the
    few jumps at velocity reversals and regime changes. :class:`StatsBuilder` gathers the
    differences of consecutive samples that are both scored and in the same regime (dither
    samples are excluded: the extracted signal is a window mean). NaN for fewer than 20.
    """
    if d.size < 20:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def band_loss(x: np.ndarray, h: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per-sample band-aware loss ``(max(0, |x| - h) / s)²`` [σ² units].

    ``x`` residual about the band centre, ``h`` half-width (0: plain least squares), ``s`` noise.
    """
    return (np.maximum(np.abs(x) - h, 0.0) / s) ** 2

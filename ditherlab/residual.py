"""The band-aware torque residual of a recording under a model, and its noise floor.

``rho = tau - gravity - effects - J^T F``; in the ``still`` and ``dither`` regimes the friction
band absorbs whatever lies inside it, in ``moving`` the band collapses onto the sliding friction
line (:func:`scored`). Samples no friction curve describes (break-away transients, short slips,
velocity reversals: :func:`ditherlab.signal.stick_transitions`) are not scored. Fitting effects to
it is :mod:`ditherlab.fit`; scoring them on held-out data is :mod:`ditherlab.diagnose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ditherlab.dither import extract_dither
from ditherlab.effects import (
    Signals,
    check_model_effects,
    effects_torque,
    external_torque,
    sensor_wrench,
    signals,
    widening,
)
from ditherlab.errors import ModelError, where_prefix
from ditherlab.model import TorqueModel
from ditherlab.recording import DITHER, MOVING, Recording, Regime
from ditherlab.signal import REVERSAL_V, STICK_SETTLE_S, smooth_wrench, stick_transitions

__all__ = ["Scored", "band_loss", "scored", "white_noise"]


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

    def excess(
        self, shift: np.ndarray | None = None, widen: np.ndarray | None = None
    ) -> np.ndarray:
        """(N, n) [N·m]: the signed part of ``e - shift`` outside the band (0 inside)."""
        x = self.e if shift is None else self.e - shift
        hh = self.h if widen is None else np.maximum(self.h + widen, 0.0)
        return np.sign(x) * np.maximum(np.abs(x) - hh, 0.0)


def _dither_signal(rec: Recording) -> tuple[np.ndarray, np.ndarray] | None:
    """The paper's extracted dither signal (N, n) and its validity (N,), or None."""
    sig = extract_dither(rec)
    if sig is None:
        return None
    return np.asarray(sig.signal, dtype=float), np.asarray(sig.valid, dtype=bool)


def scored(
    model: TorqueModel, rec: Recording, *, use_sensor: bool = True, min_samples: int = 200
) -> Scored:
    """The band-aware residual ``rho = tau - gravity - effects - J^T F`` of a recording.

    Per regime: in ``still`` and ``dither`` the stick band ``[tau_min, tau_max]`` (widened by the
    model's load/temperature effects) absorbs whatever lies inside it; in ``moving`` the band
    collapses onto the sliding friction ``coulomb·sign(dq) + viscous·dq`` (when the model has
    them) plus one offset in ``[tau_min, tau_max]`` (the data's mean offset, clipped into the
    band), and the whole residual about that line counts. In the dither regime the torque is the
    paper's extracted signal (:func:`ditherlab.dither.extract_dither`); without it dither samples
    are not scored.

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    use_sensor : subtract ``external_torque(sensor_wrench)`` (needs F/T columns); when False or
        absent, the residual contains the external torque (free-motion logs have none).
    min_samples : a joint's regime with fewer samples in this recording is not scored (as in
        :func:`ditherlab.identify.identify`).

    Raises
    ------
    ModelError
        When the recording contains a regime the model has no band for.
    """
    sig = signals(rec)
    if model.n != rec.n:
        raise ModelError(
            f"{where_prefix(rec.name)}the recording has {rec.n} joints, the model {model.n}; expected the same robot"
        )
    check_model_effects(model, rec)
    reg = sig.regime
    tau = rec.tau.copy()
    notes: list[str] = []
    use = np.ones(tau.shape, dtype=bool)
    if (reg == DITHER).any():
        ext = _dither_signal(rec)
        if ext is None:
            use &= reg != DITHER
            notes.append("dither samples not scored (no dither extraction for this recording)")
        else:
            tau = np.where(reg == DITHER, ext[0], tau)
            # the first dither period has no full window
            use &= (reg != DITHER) | ext[1][:, None]
    near = stick_transitions(reg, rec.sample_rate)
    if near.any():
        use &= ~near
        notes.append(
            f"{int(near.sum())} joint-samples within {STICK_SETTLE_S:g} s of a stick not scored"
        )
    # velocity reversals inside a motion: the joint is at rest for a few samples and its
    # friction passes through the static band, neither on the sliding line nor a stick
    rev = (reg == MOVING) & (np.abs(rec.dq) < REVERSAL_V) & use
    if rev.any():
        use &= ~rev
        notes.append(
            f"{int(rev.sum())} joint-samples of velocity reversals (|dq| < {REVERSAL_V:g} rad/s "
            "while moving) not scored"
        )
    rho = tau - sig.gravity - effects_torque(model, rec)
    if use_sensor and rec.has_wrench:
        rho -= external_torque(
            model, rec, smooth_wrench(sensor_wrench(model, rec), rec.sample_rate)
        )
    e = np.zeros_like(rho)
    h = np.zeros_like(rho)
    sigma = np.ones_like(rho)
    for code in Regime:
        name = code.label
        m = (reg == code) & use
        if not m.any():
            continue
        few = m.sum(axis=0) < min_samples
        if few.any():
            # a handful of samples (e.g. velocity reversals flagged still) is not a regime:
            # identification fits no band from it either
            use &= ~(m & few)
            m &= ~few
            if not m.any():
                continue
        if name not in model.regimes:
            use &= ~m
            notes.append(f"{int(m.any(axis=1).sum())} {name} samples not scored (no band)")
            continue
        b = model.band(name)
        centre = 0.5 * (b.tau_min + b.tau_max)
        half = 0.5 * (b.tau_max - b.tau_min)
        cen = np.broadcast_to(centre, rho.shape).copy()
        if code == MOVING:
            cen += b.sliding(sig.dq)
            # the band collapses to one point in [tau_min, tau_max]: the one the data sit at
            # (mean offset from the sliding line, clipped into the band)
            for j in range(rec.n):
                mj = m[:, j]
                if mj.any():
                    off = float(np.mean((rho - cen + centre)[mj, j] - centre[j]))
                    cen[:, j] += np.clip(centre[j] + off, b.tau_min[j], b.tau_max[j]) - centre[j]
            hh = np.zeros(rho.shape)
        else:
            hh = np.broadcast_to(half, rho.shape)
        e[m] = (rho - cen)[m]
        h[m] = hh[m]
        sigma[m] = np.broadcast_to(b.sigma, rho.shape)[m]
    wid = widening(model, rec)
    h = np.where(reg == MOVING, h, np.maximum(h + wid, 0.0))
    mb = model.regimes.get("moving")
    sliding = (mb is not None and mb.coulomb is not None, mb is not None and mb.viscous is not None)
    hf = white_noise(e, use & (reg != DITHER), reg)
    return Scored(sig, e, h, sigma, use, tau, notes, hf, sliding)


def white_noise(e: np.ndarray, use: np.ndarray, reg: np.ndarray) -> np.ndarray:
    """Model-free noise level per joint from first differences of the residual.

    Effects are smooth in time; white measurement noise is not: ``diff(e)`` has standard
    deviation ``sqrt(2)·sigma``. A robust scale (1.4826 · median absolute deviation) ignores the
    few jumps at velocity reversals and regime changes. Only consecutive samples that are both
    scored and in the same regime count (dither samples are excluded: the extracted signal is a
    window mean).

    Parameters
    ----------
    e : (N, n) [N·m] ; use : (N, n) bool ; reg : (N, n) regime codes

    Returns
    -------
    (n,) [N·m]; NaN for a joint with fewer than 20 usable pairs
    """
    out = np.full(e.shape[1], np.nan)
    if len(e) < 2:
        return out
    d = np.diff(e, axis=0)
    ok = use[1:] & use[:-1] & (reg[1:] == reg[:-1])
    for j in range(e.shape[1]):
        x = d[ok[:, j], j]
        if x.size >= 20:
            out[j] = 1.4826 * np.median(np.abs(x - np.median(x))) / np.sqrt(2.0)
    return out


def band_loss(x: np.ndarray, h: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per-sample band-aware loss ``(max(0, |x| - h) / s)²`` [σ² units].

    ``x`` residual about the band centre, ``h`` half-width (0: plain least squares), ``s`` noise.
    """
    return (np.maximum(np.abs(x) - h, 0.0) / s) ** 2

"""How the dither's extraction shows a push: ``dither_extraction``.

With the dither on, the torque the estimator reads is not the logged torque but the extracted
signal (paper §IV-A, :func:`ditherlab.physics.dither.extract`): per joint the mean of the samples above
and below the mean of the last dither period, averaged. For the slow part of the torque (a push
lasts 0.5-2 s, the dither period is 79 ms) this is the causal mean over one period ``W``
samples: a push's torque ``J^T F`` is seen ``(W - 1) / 2`` samples late (40 ms at 80 rad/s and
250 Hz) with its rise smoothed over the period. While dithering the position loop's gain is off
(the simulator's ``Kp = 0``; the paper's Fig. 5 loop), the joint creeps under a push and the
velocity loop's integral builds the torque that holds it: the extracted signal follows the
push only in part and late, a first-order lag (the paper's underestimate and lag, Fig. 4 and
§VI-C).

The effect: where the dither has been on over a whole window and the joint stands in the
``dither`` regime or creeps (``moving``), the servo shows ``gain · lag(mean_W(J^T F))``;
elsewhere ``J^T F`` itself. ``W`` is the recording's dither period (known, not searched);
``gain`` (linear) and the lag (samples, searched on a grid, 0 included) are fitted per joint from
pushes made with the dither on. On a recording without dither, or without pushes, its design is
zero: diagnose cannot suggest it there and ``identify --add`` refuses it. The extraction runs on
every dithering joint (``on_every_joint``): ``identify --add`` fits it on every joint a push
loads above the noise (:func:`ditherlab.analysis.scoring.acting_joints`; joints 1-5 of the IRB140), not
only where one recording's diagnosis evidence passed. Identification compares it with the
extracted signal only (its dither regime, :func:`extracted_rows`); its still and moving regimes
read the logged torque (:func:`logged_view`).

Diagnosis reads the extracted signal in the ``dither`` regime and the logged torque while a
joint moves, so on the creeping rows the effect's one-period mean is half a period early
against what diagnosis compares it with; replay reads the extracted signal on both
(:func:`ditherlab.analysis.estimation.variant_inputs`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ditherlab.core.names import DITHER, MOVING
from ditherlab.core.timeseries import causal_mean
from ditherlab.physics.dither import dither_on, dither_period, full_window, has_dither
from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound
from ditherlab.physics.effects.sensor import AttenuationLag, late_bounds
from ditherlab.physics.effects.signals import Signals

__all__ = [
    "DitherExtraction",
    "extracted_rows",
    "logged_view",
    "as_extracted",
    "extraction_gain",
    "extraction_mask",
    "extraction_window",
]


def extraction_window(sig: Signals) -> int:
    """Samples per dither period of the recording behind ``sig`` (the extraction's window), 0
    when the recording has no dither."""
    rec = sig.rec
    if not has_dither(rec):
        return 0
    return max(int(round(dither_period(rec) * rec.sample_rate)), 1)


def extraction_mask(sig: Signals, j: int) -> np.ndarray:
    """(N,) bool: the dither was on over the whole window ending at the sample and joint ``j``
    (0-based) stands in the ``dither`` regime or moves (creeps under a push): the rows where
    the estimator's dither variants read the extracted signal
    (:func:`ditherlab.analysis.estimation.variant_inputs`)."""
    w = extraction_window(sig)
    if w == 0:
        return np.zeros(len(sig.t), dtype=bool)
    on = dither_on(sig.rec)
    if on is None:
        return np.zeros(len(sig.t), dtype=bool)
    reg = sig.regime[:, j]
    return ((reg == DITHER) | (reg == MOVING)) & full_window(np.asarray(on, dtype=bool), w)


class DitherExtraction(Effect):
    """The extracted signal shows ``gain`` of the push's joint torque, averaged over the last
    dither period: ``gain · mean_W(J^T F)`` in the dither regime (module docstring)."""

    name = "dither_extraction"
    order = 30
    physics = (
        "with the dither on, the extracted torque shows the push late (half a period) and in part"
    )
    driven_by = "J^T F (F/T sensor) averaged over the dither period, in the dither regime"
    linear = ("gain",)
    hyper = "lag"
    kind = "external"
    shows_in = ("dither", "moving")
    pointwise = False  # a mean over time
    needs_dither = True
    on_every_joint = True  # the extraction runs on every dithering joint
    #: evidence rules of a per-joint fit (:func:`ditherlab.physics.effect_fit.pool_weak_joints`). The gain is
    #: the part of a push the extracted signal shows: 0..1 (:attr:`bounds`; the servo and the
    #: centre loop take up the rest, the paper's underestimate). A joint whose gain has a
    #: standard error above 0.25 (a 95 % interval of more than ±0.5: it cannot tell a joint that
    #: shows half of a push from one that shows all of it), or whose gain lies outside that
    #: range, has too little evidence: it takes the median gain and lag of the
    #: joints with good evidence, or with none the prior: the medians of the joint fits on
    #: clean dithered simulator recordings (``docs/design/physics-effect-models.md``).
    evidence_rules: ClassVar[dict[str, Any]] = {
        "stderr_max": {"gain": 0.25},
        "prior": {"gain": 0.84, "lag": 16},
    }
    bounds = (
        Bound(
            "gain",
            "-",
            "0 .. 1",
            "the extraction shows part of a push; the servo and the centre loop take the rest "
            "(paper §VI-C)",
            0.0,
            1.0,
        ),
        *late_bounds(("lag",)),
    )

    def signs(self, h):
        return (1,)

    def check(self, sig):
        sig.wrench(self.name)

    def grid(self, sig, j):
        fs = sig[0].sample_rate
        kmax = max(int(round(0.3 * fs)), 2)
        return [0] + sorted(
            set(np.unique(np.round(np.geomspace(1, kmax, 16)).astype(int)).tolist())
        )

    @staticmethod
    def filtered(sig: Signals, X: np.ndarray, lag: Any) -> np.ndarray:
        """(N,): ``X`` (N,) averaged over the last dither period and passed through a
        first-order lag of ``lag`` samples (0 or None: none), from rest at its first value."""
        w = extraction_window(sig)
        out = causal_mean(X, w) if w else X
        return AttenuationLag.delayed(sig, out, (0, lag or 0))

    @classmethod
    def seen(cls, sig: Signals, j: int, X: np.ndarray, gain: float, lag: Any) -> np.ndarray:
        """(N,) [N·m]: the external torque ``X`` (N,) of joint ``j`` as the extraction shows it:
        ``gain · lag(mean_W(X))`` where :func:`extraction_mask`, ``X`` elsewhere."""
        if extraction_window(sig) == 0:
            return X
        m = extraction_mask(sig, j)
        return np.where(m, gain * cls.filtered(sig, X, lag), X)

    def design(self, sig, j, h, ref):
        X = sig._get("jtf_lp", lambda: sig.jtf(sig.wrench_lp(self.name)))[:, j]
        if extraction_window(sig) == 0:
            return Design(np.zeros((len(X), 1)), offset=np.zeros(len(X)))
        m = extraction_mask(sig, j)
        Y = self.filtered(sig, X, h)
        # what the model without the effect subtracts there: the external torque through the
        # window where the dither regime reads the extraction (as_extracted), else itself
        shown = np.where(sig.regime[:, j] == DITHER, self.filtered(sig, X, 0), X)
        return Design(np.where(m, Y, 0.0)[:, None], offset=np.where(m, -shown, 0.0))

    def driver(self, sig, j, p):
        X = sig.jtf(sig.wrench_lp(self.name))[:, j]
        w = extraction_window(sig)
        return (
            causal_mean(X, w) if w else X
        ), f"mean over a dither period of (J^T F)_{j + 1} [N·m]"

    def external(self, sig, j, X, w, h):
        return self.seen(sig, j, X, float(w[0]), h)

    def external_text(self, p, ext):
        return f"{fmt(p['gain'])}·lag_{fmt(p.get('lag') or 0)}(mean_period({ext})) (dither on)"

    def term(self, p, j):
        pooled = (
            "; shared: too little evidence on this joint" if float(p.get("pooled") or 0) else ""
        )
        return (
            f"dither_extraction(gain={fmt(p['gain'])}, mean over one dither period, "
            f"lag={fmt(p.get('lag') or 0)} samples{pooled})"
        )


def extraction_gain(specs: Any, n: int, key: str = "gain") -> np.ndarray | None:
    """(n,): the ``dither_extraction`` parameter ``key`` per joint of a model's effect specs
    (``"gain"`` [-], 1 on joints it does not name; ``"lag"`` [samples], 0 there), or None when
    the model does not have the effect."""
    out, found = np.full(n, 1.0 if key == "gain" else 0.0), False
    for spec in specs:
        if spec.name != DitherExtraction.name:
            continue
        found = True
        for jj in spec.joints:
            if jj - 1 < n:
                v = spec.params.get(key)
                v = v[spec.joints.index(jj)] if isinstance(v, list) else v
                out[jj - 1] = float(v or 0.0)
    return out if found else None


def extracted_rows(specs: Any, sig: Signals) -> np.ndarray:
    """(N, n) bool: the rows and joints where a model's external torque (effect specs
    ``specs``, on the recording behind ``sig``) already is what the extraction shows, a
    one-period mean (:func:`extraction_mask` of every joint its ``dither_extraction`` names).

    A consumer that compares the extracted signal with the model torque passed through the
    dither window (identification's dither regime, :mod:`ditherlab.analysis.identification`) takes the external
    torque there as it is: windowed once, by the effect, not twice.
    """
    out = np.zeros((len(sig.t), sig.n), dtype=bool)
    if extraction_window(sig) == 0:
        return out
    for spec in specs:
        if spec.name != DitherExtraction.name:
            continue
        for jj in spec.joints:
            if 1 <= jj <= sig.n:
                out[:, jj - 1] = extraction_mask(sig, jj - 1)
    return out


def as_extracted(
    model_tau: np.ndarray, ext: np.ndarray | None, shown: np.ndarray | None, w: int
) -> np.ndarray:
    """(N, n) [N·m]: the model torque as the dither's extraction shows it, what the extracted
    signal is compared with wherever a consumer reads it (identification's and diagnosis's
    dither regime, the estimator's dither variants).

    The extracted signal is (for the slow part of the torque) the mean of the last ``w``
    samples, so the model torque passes through the same window: its half-period delay does
    not count as friction, and what the model computes at the dither's own frequency (an
    inertia times the vibration's acceleration, a drive gain times the square wave) averages
    out as the dither does in the extraction. The external torque ``ext`` (N, n) [N·m] (None:
    none) is windowed too except where the model's ``dither_extraction`` already shows it as
    a one-period mean (``shown`` (N, n) bool, :func:`extracted_rows`; None: nowhere).

    Parameters
    ----------
    model_tau : (N, n) [N·m] gravity and the model's torque effects, per sample
    ext : (N, n) [N·m] the model's external torque, or None
    shown : (N, n) bool, or None
    w : samples per dither period (the extraction's window)
    """
    out = causal_mean(model_tau, w)
    if ext is None:
        return out
    windowed = causal_mean(ext, w)
    return out + (windowed if shown is None else np.where(shown, ext, windowed))


def logged_view(specs: Any) -> list[Any]:
    """The effect specs ``specs`` of a model without its ``dither_extraction``: the external
    torque as the **logged** torque shows it. The extraction's gain and lag describe the
    extracted signal; a consumer that compares the logged torque with the model (identification's
    still and moving regimes, where a joint creeps under a push with the dither on) takes
    ``J^T F`` through the model's other external effects."""
    return [s for s in specs if s.name != DitherExtraction.name]

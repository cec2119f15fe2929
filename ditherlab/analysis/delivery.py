"""Whether an added effect delivers what diagnosis promised, and what it does to the force error.

``identify --add`` fits an effect, writes it into a new model and re-fits the bands. Diagnosis
promised a held-out share of the residual for it (:class:`~ditherlab.analysis.scoring.Candidate`,
per joint ``JointScore.gain / loss0``). :func:`delivery` measures the same band-aware loss
``sum((excess / sigma)²)`` per named joint, as diagnosis measures it: with each regime's band
centre and the sliding line free (the nuisance columns of
:func:`~ditherlab.physics.effect_fit.stack_rows`, fitted to the residual), under the model
before and the model written, both with the noise of the model before (one unit for both), and
the share it fell by. The band centres are free on both sides because the band fit places a
centre by the band-plus-noise likelihood, not by this loss: a centre the two criteria place
apart is neither the effect's gain nor its failure. Promise and delivery are averaged over the
joints weighted by each joint's share of the promised gain (a joint promised little weighs
little). An effect that delivers less than :data:`DELIVERY_SHARE` of its promise is not written.

:func:`force_change` compares the sensorless force estimate's error (estimate minus sensor) of
the two models per axis where the recordings have an F/T sensor: a growth beyond its sampling
uncertainty (the paired difference of the mean square over blocks of :data:`BLOCK_S` seconds,
more than :data:`FORCE_Z` standard errors) and by more than :data:`FORCE_GROWTH` of the RMS is
reported: a systematic change of a thousandth is no news.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ditherlab.analysis.diagnosis_sums import force_inputs
from ditherlab.analysis.scoring import Candidate
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.effect_fit import solve_signed, stack_rows
from ditherlab.physics.residual import Scored

__all__ = [
    "BLOCK_S",
    "DELIVERY_SHARE",
    "FORCE_GROWTH",
    "FORCE_Z",
    "Delivery",
    "ForceChange",
    "delivery",
    "force_change",
    "promised",
]

#: the share of its promised held-out gain an added effect must deliver on the named joints
DELIVERY_SHARE = 0.5
#: block length [s] of the force error's sampling uncertainty (one push and its lag per block)
BLOCK_S = 2.0
#: standard errors a force error must grow by to be reported
FORCE_Z = 2.0
#: and the share of its RMS [-]
FORCE_GROWTH = 0.05


def promised(cand: Candidate, joints: Sequence[int]) -> tuple[float, list[float] | None]:
    """The held-out share [-] of the residual on ``joints`` (0-based) that the candidate's scores
    promise, and the weight of each joint (its share of the promised gain; None for a shared
    fit, scored once over all joints): per joint ``gain / loss0``, averaged with the weights."""
    by = {s.joint: s for s in cand.scores}
    if None in by:
        s = by[None]
        return (s.gain / s.loss0 if s.loss0 > 0 else 0.0), None
    scores = [by[j] for j in joints if j in by]
    gains = np.array([max(s.gain, 0.0) for s in scores])
    w = gains / gains.sum() if gains.sum() > 0 else np.full(len(scores), 1.0 / max(len(scores), 1))
    share = sum(
        wi * (s.gain / s.loss0 if s.loss0 > 0 else 0.0) for wi, s in zip(w, scores, strict=True)
    )
    return float(share), [float(x) for x in w]


@dataclass
class Delivery:
    """The promise and the delivery of an added effect on ``joints`` (0-based).

    Attributes
    ----------
    effect, joints : the effect and its joints
    promise : held-out share of the residual diagnosis promised [-]
    loss : per joint, band-aware loss [σ²] with the band centres fitted, under the model
        before, the model with the effect and the bands before, and the model written (bands
        re-fitted)
    rms : (before, written) residual RMS outside the band per joint [N·m]
    weights : per joint, its share of the promised gain (None: the losses are summed)
    """

    effect: str
    joints: list[int]
    promise: float
    loss: list[tuple[float, float, float]]
    rms: tuple[list[float], list[float]]
    weights: list[float] | None = None

    def share(self, k: int = 2) -> float:
        """The share [-] the loss fell by: with the effect alone (k=1) or as written (k=2),
        per joint averaged with :attr:`weights` (summed over the joints without)."""
        if self.weights is None:
            a, b = sum(x[0] for x in self.loss), sum(x[k] for x in self.loss)
            return 1.0 - b / a if a > 0 else 0.0
        return float(
            sum(
                w * (1.0 - x[k] / x[0] if x[0] > 0 else 0.0)
                for w, x in zip(self.weights, self.loss, strict=True)
            )
        )

    @property
    def ok(self) -> bool:
        """The written model lowers the loss by at least :data:`DELIVERY_SHARE` of the promise."""
        return self.share() >= DELIVERY_SHARE * self.promise

    def text(self) -> str:
        """One line: what was promised, what the written model delivers, and why not."""
        where = ", ".join(str(j + 1) for j in self.joints)
        rms = ", ".join(
            f"joint {j + 1} {a:.3g} -> {b:.3g} N·m"
            for j, a, b in zip(self.joints, *self.rms, strict=True)
        )
        why = (
            "the re-fitted bands take back what the effect explained"
            if self.share(1) >= DELIVERY_SHARE * self.promise
            else "the effect as the model applies it does not lower the residual as its fit "
            "with re-fitted bands did (the bands, not the effect, carried the gain)"
        )
        return (
            f"{self.effect} on joint(s) {where} was promised {100 * self.promise:.1f} % of the "
            f"held-out residual but the written model lowers it by {100 * self.share():.1f} % "
            f"(residual outside the band {rms}): {why}"
        )

    def to_dict(self) -> dict[str, Any]:
        """The promise and delivery for the model's history row."""
        return {
            "promised": round(self.promise, 6),
            "delivered": round(self.share(), 6),
            "delivery_joints": [j + 1 for j in self.joints],
        }


def _centred_loss(sc: Sequence[Scored], j: int, sigma: np.ndarray | None = None) -> float:
    """The band-aware loss [σ²] of joint ``j`` over the rows ``sc`` use, with the regimes' band
    centres and the sliding line fitted to it (the nuisance columns diagnosis fits beside an
    effect); ``sigma`` (M,) [N·m] the noise per stacked row (default: each row's own)."""
    r = stack_rows(sc, j)
    if not len(r.e):
        return 0.0
    zero = np.zeros(len(r.e))
    s = r.s if sigma is None else sigma
    _, L = solve_signed(r.e, r.h, s, r.N, np.zeros_like(r.N), zero, (0,) * r.N.shape[1])
    return float(L)


def _loss_rms(
    before: Sequence[Scored], after: Sequence[Scored], j: int
) -> tuple[float, float, float, float]:
    """(loss before, loss after [σ² of the model before], RMS before, RMS after [N·m]) on joint
    ``j`` over the rows scored under both models: the loss with the band centres fitted
    (:func:`_centred_loss`), the RMS of the excess beyond the model's own bands."""
    sums = np.zeros(2)
    count = 0
    both_b, both_a = [], []
    for b, a in zip(before, after, strict=True):
        m = b.use[:, j] & a.use[:, j]
        use = np.zeros_like(b.use)
        use[:, j] = m
        both_b.append(replace(b, use=use))
        both_a.append(replace(a, use=use))
        xb, xa = b.excess()[m, j], a.excess()[m, j]
        sums += [np.sum(xb**2), np.sum(xa**2)]
        count += int(m.sum())
    n = max(count, 1)
    sigma = stack_rows(both_b, j).s
    return (
        _centred_loss(both_b, j),
        _centred_loss(both_a, j, sigma),
        math.sqrt(sums[0] / n),
        math.sqrt(sums[1] / n),
    )


def delivery(
    effect: str,
    promise: tuple[float, list[float] | None],
    joints: Sequence[int],
    scs: tuple[Sequence[Scored], Sequence[Scored], Sequence[Scored]],
) -> Delivery:
    """The :class:`Delivery` of ``effect`` on ``joints`` (0-based) promised ``promise``
    (:func:`promised`), from the recordings scored under the model before, with the effect and
    the bands before, and as written (``scs``, three lists over the same recordings)."""
    first = [_loss_rms(scs[0], scs[1], j) for j in joints]
    last = [_loss_rms(scs[0], scs[2], j) for j in joints]
    loss = [(a[0], a[1], b[1]) for a, b in zip(first, last, strict=True)]
    rms = ([x[2] for x in last], [x[3] for x in last])
    return Delivery(effect, list(joints), promise[0], loss, rms, promise[1])


@dataclass
class ForceChange:
    """The force error RMS per axis [N, N·m] before and after, the axes where it grew beyond
    its sampling uncertainty, and the growth of its mean square in standard errors ``z``."""

    before: list[float]
    after: list[float]
    grew: list[str]
    z: list[float]

    def text(self, effect: str) -> str:
        """One line naming the axes whose force error grew, '' when none did."""
        if not self.grew:
            return ""
        parts = [
            f"{a} {self.before[k]:.3g} -> {self.after[k]:.3g} ({self.z[k]:.1f} standard errors)"
            for k, a in enumerate(WRENCH_COLUMNS)
            if a in self.grew
        ]
        return (
            f"adding {effect} makes the force error (estimate - sensor, RMS) grow on "
            + ", ".join(parts)
            + " [N, N·m]: the torque fits better but the force estimate is worse"
        )

    def to_dict(self) -> dict[str, Any]:
        """The force error before and after and the axes it grew on, for the history row."""
        return {
            "force_rms_before": [round(v, 6) for v in self.before],
            "force_rms_after": [round(v, 6) for v in self.after],
            "force_grew": list(self.grew),
        }


def force_change(
    before: TorqueModel,
    after: TorqueModel,
    sb: Sequence[Scored],
    sa: Sequence[Scored],
) -> ForceChange | None:
    """Force error of the sensorless estimate under ``before`` and ``after`` on the recordings
    with an F/T sensor (scored under each: ``sb``, ``sa``), per axis, and where it grew beyond
    its sampling uncertainty: the mean square's paired difference by more than :data:`FORCE_Z`
    standard errors over blocks of :data:`BLOCK_S` seconds, and the RMS by more than
    :data:`FORCE_GROWTH`; None without a sensor."""
    e2 = [[], []]
    blocks = []
    for b, a in zip(sb, sa, strict=True):
        rec = b.sig.rec
        if not rec.has_wrench:
            continue
        for k, (m, s) in enumerate(((before, b), (after, a))):
            F, Fs = force_inputs(m, s)[5:]
            e2[k].append((F - Fs) ** 2)
        size = max(int(round(BLOCK_S * rec.sample_rate)), 1)
        blocks.append(np.arange(len(rec)) // size + (blocks[-1].max() + 1 if blocks else 0))
    if not blocks:
        return None
    x0, x1, blk = np.concatenate(e2[0]), np.concatenate(e2[1]), np.concatenate(blocks)
    _, b = np.unique(blk, return_inverse=True)
    nb = int(b.max()) + 1
    cnt = np.bincount(b, minlength=nb)[:, None]
    dx = x1 - x0
    d = np.stack([np.bincount(b, weights=dx[:, c], minlength=nb) for c in range(6)], 1) / cnt
    mean = dx.mean(axis=0)
    se = d.std(axis=0, ddof=1) * np.sqrt(np.sum(cnt**2)) / len(x0) if nb > 1 else np.inf
    z = np.where(se > 0, mean / np.where(se > 0, se, 1.0), np.where(mean > 0, np.inf, 0.0))
    rms0, rms1 = np.sqrt(x0.mean(axis=0)), np.sqrt(x1.mean(axis=0))
    grew = [
        a
        for c, a in enumerate(WRENCH_COLUMNS)
        if mean[c] > 0 and z[c] > FORCE_Z and rms1[c] > (1 + FORCE_GROWTH) * rms0[c]
    ]
    return ForceChange(rms0.tolist(), rms1.tolist(), grew, [float(v) for v in z])

"""Rest stretches of a log without a force sensor, and the pushes that interrupt them.

Without an F/T sensor identify has no reference for the external force: every force in the log
goes into the friction bands. :func:`scan_rest` finds where the robot rests (no joint moving,
:func:`ditherlab.data.recording.regimes`) and where, inside those stretches, the torque residual
``rho = tau - gravity - effects`` (N, n) [N·m] departs from its rest distribution: a push by hand,
a contact, a load put down. Those stretches are what identify leaves out.

The rule, stated so that its false alarms are known:

1. The residual is averaged over blocks of :data:`BLOCK` s (a block mean per joint; blocks with
   fewer than half their samples at rest are not tested, nor a log with fewer than
   :data:`MIN_BLOCKS` rest blocks).
2. Steps: the difference of consecutive block means is a step when it exceeds
   ``z * s_j`` on some joint, ``s_j`` being 1.4826 x the median absolute deviation of that
   joint's differences (a normal standard deviation of the quiet majority; the few push edges
   do not move it) and ``z = Phi^-1(1 - alpha / (2 M))`` over the M tested (difference, joint)
   pairs. The steps and the blocks not at rest cut the rest time into segments.
3. Each segment's level is the median of its block means. The rest location of a joint is the
   duration-weighted median of the segment levels, its scale 1.4826 x their duration-weighted
   median absolute deviation (the static friction holds the residual at a different point after
   each push: that spread is part of rest), floored at the block mean's noise ``s_j / sqrt 2``.
4. A segment departs when ``|level - location| > z' * scale`` on some joint, with
   ``z' = Phi^-1(1 - alpha / (2 S n))`` over the S segments and n joints: the probability of
   one false departure anywhere in the log is at most :data:`ALPHA` when the rest levels are
   normal (Bonferroni). Location and scale are re-estimated without the departing segments
   until that set stops changing (at most :data:`ROUNDS` rounds): the first round's scale
   still holds the largest pushes.
5. An event is a run of departing segments that touch; its joints are those whose block means
   depart by more than ``z' * scale``. Identify leaves it out one block wider on each side (the
   push's rise and fall, :meth:`RestScan.spans`).

The rule assumes that the log rests more than it is pushed (the quiet majority, the median's
breakdown point): :func:`quiet_majority` says when the events cover more than half the rest
time, and identify then refuses and asks for ``--window`` (the rest stretches named by the
user).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.core.names import MOVING
from ditherlab.data.recording import Recording, regimes
from ditherlab.data.torque_model import TorqueModel
from ditherlab.estimator.formulation import normal_quantile
from ditherlab.physics.effects import effects_torque

__all__ = [
    "ALPHA",
    "BLOCK",
    "Event",
    "RestScan",
    "kept_rows",
    "parse_span",
    "quiet_majority",
    "scan_rest",
]

#: block length [s] of the block means
BLOCK = 0.25
#: probability of one false alarm in a whole log (quiet block means normal)
ALPHA = 0.01
#: rounds of re-estimating location and scale without the departing segments
ROUNDS = 20
#: fewer rest blocks than this are not tested (too few for a median and its deviation)
MIN_BLOCKS = 20
#: MAD -> standard deviation of a normal distribution
MAD_SD = 1.4826


@dataclass(frozen=True)
class Event:
    """One departure from rest: a push, a contact, a load.

    Attributes
    ----------
    start, end : [s] in the log's time (its ``t`` column)
    joints : 1-based joints whose residual departed
    peak : the largest departure [N·m] of each of ``joints`` from its rest location (signed)
    """

    start: float
    end: float
    joints: tuple[int, ...]
    peak: tuple[float, ...]

    def text(self) -> str:
        """``336.85-339.35 s (2.5 s): joint 2 -24.3 N·m, joint 5 +4.9 N·m``."""
        js = ", ".join(
            f"joint {j} {p:+.1f} N·m" for j, p in zip(self.joints, self.peak, strict=True)
        )
        return f"{self.start:.2f}-{self.end:.2f} s ({self.end - self.start:.1f} s): {js}"


@dataclass
class RestScan:
    """What :func:`scan_rest` found in one recording.

    Attributes
    ----------
    name : the recording's name
    t0, t1 : its first and last time [s]
    events : the departures from rest, in time order
    scale : (n,) [N·m] the rest levels' robust standard deviation per joint (NaN: no test)
    z : the departure threshold in units of ``scale`` (step 4 of the rule)
    rest_s : time at rest that was tested [s] (the blocks with enough rest samples)
    """

    name: str
    t0: float
    t1: float
    events: list[Event] = field(default_factory=list)
    scale: np.ndarray = field(default_factory=lambda: np.zeros(0))
    z: float = float("nan")
    rest_s: float = 0.0

    @property
    def event_s(self) -> float:
        """Time [s] the events cover."""
        return float(sum(e.end - e.start for e in self.events))

    def spans(self) -> list[tuple[float, float]]:
        """The time spans [s] left out: each event one block wider on each side (its rise and
        fall)."""
        return [(e.start - BLOCK, e.end + BLOCK) for e in self.events]

    def lines(self) -> list[str]:
        """What identify prints: the rule, then one line per event."""
        head = f"{self.name}: {self.rest_s:.1f} s at rest tested"
        if not self.rest_s:
            return [
                f"{self.name}: less than {MIN_BLOCKS * BLOCK:.0f} s at rest in the stretches "
                "considered, no push test: a force there, or during motion, cannot be told from "
                "friction without a sensor, and the bands hold whatever force acted"
            ]
        rule = (
            f"(levels between steps of the {BLOCK} s block means departing from the rest "
            f"levels by > {self.z:.2f} x their robust scale: false-alarm probability "
            f"{ALPHA:.0%} per log)"
        )
        if not self.events:
            return [f"{head}, no departure from rest {rule}"]
        out = [f"{head}; left out {len(self.events)} departures from rest {rule}:"]
        return out + [f"  {e.text()}" for e in self.events]


def parse_span(text: str, where: str) -> tuple[float, float]:
    """``"START:END"`` [s] -> ``(start, end)``; ConfigError naming ``where`` (the option) unless
    both are numbers with ``start < end``."""
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(
            f"{where} {text!r}: expected START:END in seconds of the log's time, e.g. 12.5:40"
        ) from None
    if not (np.isfinite(a) and np.isfinite(b) and a < b):
        raise ConfigError(f"{where} {text!r}: expected finite START < END in seconds")
    return a, b


def kept_rows(
    t: np.ndarray,
    windows: Sequence[tuple[float, float]] = (),
    excludes: Sequence[tuple[float, float]] = (),
) -> np.ndarray:
    """(N,) bool: inside one of ``windows`` (all rows when there are none) and outside every
    one of ``excludes``; ``t`` (N,) [s], spans ``(start, end)`` [s], ends included."""
    keep = np.zeros(len(t), bool) if windows else np.ones(len(t), bool)
    for a, b in windows:
        keep |= (t >= a) & (t <= b)
    for a, b in excludes:
        keep &= ~((t >= a) & (t <= b))
    return keep


def scan_rest(
    rec: Recording,
    model: TorqueModel | None = None,
    keep: np.ndarray | None = None,
    *,
    alpha: float = ALPHA,
) -> RestScan:
    """Find the rest stretches of ``rec`` and the departures from rest in them (the module's
    rule).

    Parameters
    ----------
    rec : a recording without a force sensor (the residual takes the external force as zero)
    model : the model whose effects are subtracted (None: gravity only)
    keep : (N,) bool, the rows to consider (:func:`kept_rows`); None: all
    alpha : the probability of one false alarm in the whole log

    Returns
    -------
    RestScan
    """
    t = rec.t
    name = str(rec.name or "recording")
    out = RestScan(name, float(t[0]), float(t[-1]), scale=np.full(rec.n, np.nan))
    rest = (regimes(rec) != MOVING).all(axis=1)
    if keep is not None:
        rest &= keep
    idx = ((t - t[0]) // BLOCK).astype(np.int64)
    means, valid = _block_means(_residual(rec, model), rest, idx)
    if valid.sum() < MIN_BLOCKS:
        return out
    out.rest_s = float(valid.sum() * BLOCK)
    z_step = normal_quantile(1 - alpha / (2 * valid.sum() * rec.n))
    segs, sd = _segments(means, valid, z_step)
    out.z = normal_quantile(1 - alpha / (2 * len(segs) * rec.n))
    loc, out.scale, dep = _departures(means, segs, sd / np.sqrt(2), out.z)
    events = _events(means, segs, dep, loc, out.scale, out.z, float(t[0]))
    out.events = [_clip(e, out.t0, out.t1) for e in events]
    return out


def _residual(rec: Recording, model: TorqueModel | None) -> np.ndarray:
    """``tau - gravity - effects`` (N, n) [N·m]: the external force taken as zero."""
    rho = rec.tau - rec.robot().gravity(rec.q)
    if model is not None and model.effects:
        rho = rho - effects_torque(model, rec)
    return rho


def _block_means(x: np.ndarray, rest: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Block means (K, n) [N·m] of ``x`` (N, n) over the rest rows of each block ``idx`` (N,),
    and (K,) bool: the block has at least half its rows at rest."""
    K = int(idx[-1]) + 1
    rows = np.bincount(idx, minlength=K)
    at_rest = np.bincount(idx, weights=rest.astype(float), minlength=K)
    sums = np.stack(
        [
            np.bincount(idx, weights=np.where(rest, x[:, j], 0.0), minlength=K)
            for j in range(x.shape[1])
        ],
        axis=1,
    )
    valid = (at_rest >= 0.5 * rows) & (at_rest > 0)
    means = np.where(valid[:, None], sums / np.maximum(at_rest, 1)[:, None], np.nan)
    return means, valid


def _segments(
    means: np.ndarray, valid: np.ndarray, z: float
) -> tuple[list[tuple[int, int]], np.ndarray]:
    """Step 2 of the rule: the rest blocks split at the significant steps, as block ranges
    ``(a, b)`` (b exclusive), and the step scale (n,) [N·m]."""
    d = np.diff(means, axis=0)  # NaN where a block is not at rest
    ok = np.isfinite(d).all(axis=1)
    sd = np.array([_mad(d[ok, j]) for j in range(means.shape[1])])
    step = np.zeros(len(means), bool)
    step[1:] = ok & (np.abs(np.where(ok[:, None], d, 0.0)) > z * sd).any(axis=1)
    out: list[tuple[int, int]] = []
    a = None
    for k in range(len(means) + 1):
        cut = k == len(means) or not valid[k] or step[k]
        if cut and a is not None:
            out.append((a, k))
            a = None
        if k < len(means) and valid[k] and a is None:
            a = k
    return out, sd


def _departures(
    means: np.ndarray, segs: list[tuple[int, int]], floor: np.ndarray, z: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 3 and 4 of the rule: the rest location (n,) and scale (n,) [N·m] of the segment
    levels, and which segments depart (S,) bool."""
    levels = np.array([np.median(means[a:b], axis=0) for a, b in segs])
    w = np.array([b - a for a, b in segs], float)
    dep = np.zeros(len(segs), bool)
    for _ in range(ROUNDS):
        q = ~dep
        loc = np.array([_wmedian(levels[q, j], w[q]) for j in range(levels.shape[1])])
        spread = np.array(
            [MAD_SD * _wmedian(np.abs(levels[q, j] - loc[j]), w[q]) for j in range(len(loc))]
        )
        scale = np.maximum(spread, floor)
        new = (np.abs(levels - loc) > z * scale).any(axis=1)
        if np.array_equal(new, dep) or new.all():
            break
        dep = new
    return loc, scale, dep


def _wmedian(x: np.ndarray, w: np.ndarray) -> float:
    """The weighted median of ``x`` with weights ``w`` (the lower one at an even split)."""
    o = np.argsort(x)
    c = np.cumsum(w[o])
    return float(x[o][np.searchsorted(c, 0.5 * c[-1])])


def _mad(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation from the median (a normal SD), floored above 0."""
    if not len(x):
        return float("nan")
    s = MAD_SD * float(np.median(np.abs(x - np.median(x))))
    return max(s, 1e-9)


def _events(
    means: np.ndarray,
    segs: list[tuple[int, int]],
    dep: np.ndarray,
    loc: np.ndarray,
    scale: np.ndarray,
    z: float,
    t0: float,
) -> list[Event]:
    """Step 5: runs of departing segments that touch."""
    out: list[Event] = []
    for (a, b), d in zip(segs, dep, strict=True):
        if not d:
            continue
        if out and abs(out[-1][1] - a) == 0:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    events = []
    for a, b in out:
        dev = means[a:b] - loc
        js = np.flatnonzero((np.abs(dev) > z * scale).any(axis=0))
        if not len(js):
            js = np.array([int(np.argmax(np.abs(dev).max(axis=0) / scale))])
        peaks = tuple(float(dev[np.argmax(np.abs(dev[:, j])), j]) for j in js)
        events.append(Event(t0 + a * BLOCK, t0 + b * BLOCK, tuple(int(j) + 1 for j in js), peaks))
    return events


def _clip(e: Event, t0: float, t1: float) -> Event:
    """``e`` with its span inside the log's ``[t0, t1]`` [s]."""
    return Event(max(e.start, t0), min(e.end, t1), e.joints, e.peak)


def quiet_majority(scan: RestScan) -> bool:
    """The rule's assumption: the events cover at most half the time at rest."""
    return scan.event_s <= 0.5 * scan.rest_s

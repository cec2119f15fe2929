"""Rest stretches of a log without a force sensor, and the pushes that interrupt them.

Without an F/T sensor identify has no reference for the external force: every force in the log
goes into the friction bands. :func:`scan_rest` finds where the robot rests (no joint moving,
:func:`ditherlab.data.recording.regimes`) and where, inside those stretches, the torque residual
``rho = tau - gravity - effects`` (N, n) [N·m] departs from its rest distribution: a push by hand,
a contact, a load put down. Those stretches are what identify leaves out.

The rule, stated so that its false alarms are known:

1. The residual is averaged over blocks of :data:`BLOCK` s of the log's time. Each block has a
   regime: *moving* when a joint moves in more than half its samples, else *dither* when the
   dither is on in at least half, else *still* (the rest level differs between the two standing
   regimes: the dither's centre loop holds the joint elsewhere).
2. Per standing regime with at least :data:`MIN_BLOCKS` blocks, the rest distribution of the
   block means comes from the quiet majority: the median ``m_j`` and the scale
   ``s_j = 1.4826 MAD`` per joint. The static friction holds a standing joint anywhere in its
   band, so the rest level moves after each push: that spread is part of rest and widens
   ``s_j``; a push is larger.
3. A block departs when ``|mean - m_j| > z s_j`` on some joint, with
   ``z = Phi^-1(1 - alpha / (2 K n))`` over the K tested blocks and n joints: one false
   departure anywhere in a clean log has probability at most :data:`ALPHA` when the block means
   are normal (Bonferroni). The test runs :data:`PASSES` times, each against the blocks not yet
   flagged (the largest pushes inflate the first scale and hide smaller ones); a clean log stops
   after the first, so the bound holds. A later pass that would flag more than half the blocks
   is not taken: its scale would come from a minority.
4. A flagged stretch is an event when unflagged blocks of its regime lie on both sides of it
   within one run of that regime: a push starts and ends at rest. A stretch at a run's start or
   end (after motion, at a dither switch, at the log's ends) is a rest level settling and stays.
   In a log that mostly stands, moving blocks do not end a run (a push moves a standing arm
   through its compliance; the moving blocks between flagged ones join the event); in a log
   that mostly moves, they do (that motion is commanded, the moving regime's to fit).
5. Identify leaves each event out one block wider on each side (the push's rise and fall,
   :meth:`RestScan.spans`).

A push the torque does not show (held by static friction without dither) is not found, and
needs not be: it left the torque, and so the bands, as they were. The rule assumes that the log
rests more than it is pushed (the quiet majority, the median's breakdown point):
:func:`quiet_majority` says when the events cover more than half the rest time, and identify
then refuses and asks for ``--window`` (the rest stretches named by the user).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.core.names import DITHER, MOVING, STILL
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
    "kept_stretches",
    "parse_span",
    "quiet_majority",
    "scan_rest",
]

#: block length [s] of the block means
BLOCK = 0.5
#: probability of one false alarm in a whole log (quiet block means normal)
ALPHA = 0.01
#: tests of the blocks, each against the rest distribution of the blocks not yet flagged
PASSES = 2
#: a standing regime with fewer blocks than this is not tested (too few for a median and MAD)
MIN_BLOCKS = 8
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
            f"({BLOCK} s block means departing from their regime's rest median by > "
            f"{self.z:.2f} x its robust scale, with rest on both sides: false-alarm "
            f"probability {ALPHA:.0%} per log)"
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


#: the shortest stretch between departures that diagnose and an added effect's fit use [s]
MIN_STRETCH_S = 2.0


def kept_stretches(
    rec: Recording, spans: Sequence[tuple[float, float]], min_s: float = MIN_STRETCH_S
) -> list[Recording]:
    """``rec`` without the rows in ``spans`` ``(start, end)`` [s] (:func:`kept_rows`): its
    stretches between them at least ``min_s`` [s] long (a shorter one has too little context
    for its derivatives), each a Recording; ``[rec]`` without spans."""
    if not spans:
        return [rec]
    keep = kept_rows(rec.t, (), spans)
    edges = np.flatnonzero(np.diff(np.r_[0, keep.astype(np.int8), 0]))
    return [
        rec.slice(rec.t[a], rec.t[b - 1] + 1e-9)
        for a, b in zip(edges[::2], edges[1::2], strict=True)
        if rec.t[b - 1] - rec.t[a] >= min_s
    ]


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
    blocks = _Blocks.of(rec, _residual(rec, model), keep)
    classes = [c for c in (STILL, DITHER) if (blocks.kind == c).sum() >= MIN_BLOCKS]
    if not classes:
        return out
    tested = np.isin(blocks.kind, classes)
    out.rest_s = float(tested.sum() * BLOCK)
    out.z = normal_quantile(1 - alpha / (2 * int(tested.sum()) * rec.n))
    flagged = np.zeros(blocks.means.shape, dtype=bool)
    dev = np.zeros(blocks.means.shape)
    scales = []
    for c in classes:
        sel = blocks.kind == c
        flagged[sel], dev[sel], scale = _flag(blocks.means[sel], out.z, PASSES)
        scales.append(scale)
    out.scale = np.min(scales, axis=0)
    hit = flagged.any(axis=1) & _bounded(blocks.keys, blocks.kind, flagged.any(axis=1))
    events = _events(blocks, flagged & hit[:, None], dev, float(t[0]))
    out.events = [_clip(e, out.t0, out.t1) for e in events]
    return out


def _residual(rec: Recording, model: TorqueModel | None) -> np.ndarray:
    """``tau - gravity - effects`` (N, n) [N·m]: the external force taken as zero."""
    rho = rec.tau - rec.robot().gravity(rec.q)
    if model is not None and model.effects:
        rho = rho - effects_torque(model, rec)
    return rho


@dataclass
class _Blocks:
    """The log in blocks of :data:`BLOCK` (those holding kept rows): ``keys (K,)`` the block
    numbers from the first time, ``means (K, n) [N·m]`` of the residual over the kept rows,
    ``kind (K,)`` the regime (step 1 of the rule)."""

    keys: np.ndarray
    means: np.ndarray
    kind: np.ndarray

    @classmethod
    def of(cls, rec: Recording, x: np.ndarray, keep: np.ndarray | None) -> _Blocks:
        """The blocks of the residual ``x (N, n)`` of ``rec`` over the rows ``keep (N,)``."""
        reg = regimes(rec)
        use = np.ones(len(x), dtype=bool) if keep is None else keep
        idx = ((rec.t - rec.t[0]) // BLOCK).astype(np.int64)[use]
        if not len(idx):
            return cls(np.zeros(0, np.int64), np.zeros((0, x.shape[1])), np.zeros(0, np.int64))
        keys, inv = np.unique(idx, return_inverse=True)
        rows = np.bincount(inv).astype(float)
        sums = np.stack([np.bincount(inv, weights=x[use, j]) for j in range(x.shape[1])], 1)
        moving = np.bincount(inv, weights=(reg[use] == MOVING).any(axis=1).astype(float))
        dith = np.bincount(inv, weights=(reg[use] == DITHER).any(axis=1).astype(float))
        kind = np.where(2 * moving > rows, MOVING, np.where(2 * dith >= rows, DITHER, STILL))
        return cls(keys, sums / rows[:, None], kind)


def _flag(means: np.ndarray, z: float, passes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2 and 3 for one regime: which blocks ``(K, n)`` depart, every block's departure
    ``(K, n) [N·m]`` from the rest median, and the rest scale ``(n,) [N·m]``."""
    flagged = np.zeros(means.shape, dtype=bool)
    for k in range(passes):
        keep = ~flagged.any(axis=1)
        med = np.median(means[keep], axis=0)
        s = MAD_SD * np.median(np.abs(means[keep] - med), axis=0)
        s = np.where(s > 0, s, np.inf)  # a constant joint: nothing departs
        now = np.abs(means - med) > z * s
        if k == 0:
            dev, scale = means - med, s
        if not (now.any(axis=1) & keep).any():
            break
        if flagged.any() and (flagged | now).any(axis=1).mean() > 0.5:
            break  # a later pass that leaves no quiet majority is not taken
        flagged |= now
        dev, scale = means - med, s
    return flagged, dev, scale


def _bounded(keys: np.ndarray, kind: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Step 4: which flagged blocks ``hit (K,)`` lie between unflagged blocks of their regime
    within one run of it."""
    standing = kind != MOVING
    through = standing.mean() > 0.5
    idx = np.flatnonzero(standing) if through else np.arange(len(keys))
    k, kd = keys[idx], kind[idx]
    gap = np.zeros(len(k) - 1, dtype=bool) if through else np.diff(k) != 1
    starts = np.flatnonzero(np.r_[True, gap | (kd[1:] != kd[:-1])]) if len(k) else []
    out = np.zeros(len(keys), dtype=bool)
    for a, b in zip(starts, np.r_[starts[1:], len(idx)], strict=True):
        h = hit[idx[a:b]]
        quiet = np.flatnonzero(~h)
        if len(quiet) == 0:
            continue
        pos = np.arange(b - a)
        out[idx[a:b]] = h & (pos > quiet[0]) & (pos < quiet[-1])
    return out


def _events(blocks: _Blocks, flagged: np.ndarray, dev: np.ndarray, t0: float) -> list[Event]:
    """Runs of flagged blocks (with the moving blocks between two of them, and gaps of at most
    two blocks) as events, with their joints and peak departures."""
    hit = np.flatnonzero(flagged.any(axis=1))
    runs: list[list[int]] = []
    for i in hit:
        prev = runs[-1][-1] if runs else None
        between = blocks.kind[prev + 1 : i] if prev is not None else None
        if prev is not None and (
            blocks.keys[i] - blocks.keys[prev] <= 3
            or (bool(np.all(between == MOVING)) and blocks.keys[i] - blocks.keys[prev] == i - prev)
        ):
            runs[-1].append(i)
        else:
            runs.append([i])
    events = []
    for run in runs:
        rows = np.array(run)
        js = np.flatnonzero(flagged[rows].any(axis=0))
        peaks = tuple(float(dev[rows, j][np.argmax(np.abs(dev[rows, j]))]) for j in js)
        start = t0 + blocks.keys[rows[0]] * BLOCK
        end = t0 + (blocks.keys[rows[-1]] + 1) * BLOCK
        events.append(Event(start, end, tuple(int(j) + 1 for j in js), peaks))
    return events


def _clip(e: Event, t0: float, t1: float) -> Event:
    """``e`` with its span inside the log's ``[t0, t1]`` [s]."""
    return Event(max(e.start, t0), min(e.end, t1), e.joints, e.peak)


def quiet_majority(scan: RestScan) -> bool:
    """The rule's assumption: the events cover at most half the time at rest."""
    return scan.event_s <= 0.5 * scan.rest_s

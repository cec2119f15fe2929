"""Joint samples as they arrive: from ROS 2 over DDS (:class:`DdsFeed`) or from a recording
played at its own rate (:class:`FileFeed`), checked one message at a time.

A feed hands out :class:`Sample` lists (:meth:`poll`); what it could not use it drops and counts
by reason (:class:`Faults`), with one line for the first of each kind:

- a JointState without every joint of the model (other names), or whose ``position`` /
  ``effort`` (and ``velocity``, when the first sample had it) is not as long as ``name``;
- a value that is not finite;
- a stamp equal to the last one (duplicated) or before it (out of order);
- a joint state whose DitherState (same stamp) did not come within :data:`HOLD_S`, once the
  dither topic is in use;
- samples the estimate did not take in time: the feed's queue holds ``queue`` samples and drops
  the oldest beyond (a slow consumer).

Joints are matched by name, not position: ``JointState.name`` may list them in any order and
list others too. The feed decides from the first joint state (held :data:`HOLD_S` for its
companions) whether the velocity, the dither (``DitherState``) and a sensor's wrench are part of
the stream; the rest of the stream must keep to it.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ditherlab.core.stamps import NS_PER_S, stamp_time, wire_time
from ditherlab.data.recording import Recording
from ditherlab.io.dds import DitherState, JointState, Reader, WrenchStamped, dds_topic, participant

__all__ = ["HOLD_S", "DdsFeed", "Faults", "FileFeed", "Sample"]

#: [s] how long a joint state waits for its companions (DitherState, the sensor's wrench)
HOLD_S = 0.2


class Sample(NamedTuple):
    """One joint sample: ``t`` [s], ``q`` (n,) [rad], ``tau`` (n,) [N·m], ``dq`` (n,) [rad/s]
    or None, ``dither`` bool or None, ``ffw`` (n,) [N·m] or None, ``wrench`` (6,) [N, N·m] or
    None (NaN where the sensor's message did not come)."""

    t: float
    q: np.ndarray
    tau: np.ndarray
    dq: np.ndarray | None = None
    dither: bool | None = None
    ffw: np.ndarray | None = None
    wrench: np.ndarray | None = None


@dataclass
class Faults:
    """Samples dropped, by reason, and the lines not yet shown (one per reason: the first)."""

    counts: collections.Counter = field(default_factory=collections.Counter)
    lines: list[str] = field(default_factory=list)

    def add(self, reason: str, line: str) -> None:
        """Count one drop for ``reason``; the first of a reason queues ``line``."""
        if not self.counts[reason]:
            self.lines.append(line)
        self.counts[reason] += 1

    def news(self) -> list[str]:
        """The lines queued since the last call."""
        out, self.lines = self.lines, []
        return out

    def text(self) -> str:
        """``reason: count`` of every reason, or ``none``."""
        return ", ".join(f"{k}: {v}" for k, v in sorted(self.counts.items())) or "none"


class FileFeed:
    """A recording's samples at its own rate times ``rate`` (0: as fast as they are taken),
    from its first sample on; :meth:`poll` returns ``None`` after the last.

    Parameters
    ----------
    rec : the recording ; rate : playback speed (1: real time)
    """

    def __init__(self, rec: Recording, rate: float = 1.0) -> None:
        self.rec, self.rate = rec, float(rate)
        self.faults = Faults()
        self.meta = rec.meta
        self._i = 0
        self._start: float | None = None

    def poll(self, timeout: float) -> list[Sample] | None:
        """The samples due now (waiting up to ``timeout`` [s] for the next), None at the end."""
        rec, N = self.rec, len(self.rec)
        if self._i >= N:
            return None
        if self._start is None:
            self._start = time.monotonic()
        if self.rate <= 0:
            end = min(self._i + 256, N)
        else:
            due = rec.t[self._i] - rec.t[0]
            wait = due / self.rate - (time.monotonic() - self._start)
            if wait > 0:
                time.sleep(min(wait, timeout))
            now = (time.monotonic() - self._start) * self.rate + rec.t[0]
            end = max(int(np.searchsorted(rec.t, now, side="right")), self._i)
            if end == self._i:
                return []
        out = rows_of(rec, self._i, end)
        self._i = end
        return out

    def close(self) -> None:
        """Nothing to release."""


def rows_of(rec: Recording, a: int, b: int) -> list[Sample]:
    """Rows ``[a, b)`` of ``rec`` as samples (its ``dither`` flag, else its ``tau_ffw``), the
    times as DDS carries them (:func:`ditherlab.core.stamps.wire_time`)."""
    dq = rec.dq if rec.has_dq else None
    ffw = rec.tau_ffw if rec.dither is None else None
    d, w = rec.dither, rec.wrench
    t, q, tau = wire_time(rec.t[a:b]), rec.q, rec.tau
    return [
        Sample(
            float(t[i - a]),
            q[i],
            tau[i],
            None if dq is None else dq[i],
            None if d is None else bool(d[i]),
            None if ffw is None else ffw[i],
            None if w is None else w[i],
        )  # fmt: skip
        for i in range(a, b)
    ]


class _Pending(NamedTuple):
    """A joint state waiting for its companions: its stamp [ns], sample, arrival [s]."""

    ns: int
    sample: Sample
    arrived: float


class DdsFeed:
    """Joint states of a ROS 2 robot over DDS, with their dither and a sensor's wrench (module
    docstring). A thread takes the messages as they come; :meth:`poll` hands out the samples
    ready.

    Parameters
    ----------
    names : the model's joint names, in its order
    topic : the JointState topic ; namespace : the ROS 2 namespace of relative topics
    wrench_topic : a sensor's WrenchStamped topic (copied to the estimates), optional
    dither_topic : the DitherState topic (used when the robot publishes it)
    domain : the DDS domain (:func:`ditherlab.io.dds.domain_id`)
    queue : samples held for the consumer at most; beyond, the oldest are dropped and counted
    """

    def __init__(
        self,
        names: Sequence[str],
        topic: str = "joint_states",
        *,
        namespace: str = "",
        wrench_topic: str | None = None,
        dither_topic: str = "ditherlab/dither",
        domain: int | None = None,
        queue: int = 4096,
    ) -> None:
        self.names, self.n = list(names), len(names)
        self.topic = dds_topic(topic, namespace)
        dp = participant(domain)
        self._dp = dp
        self._joints = Reader(dp, self.topic, JointState)
        self._companions: dict[str, Reader] = {
            "dither": Reader(dp, dds_topic(dither_topic, namespace), DitherState)
        }
        if wrench_topic:
            self._companions["wrench"] = Reader(
                dp, dds_topic(wrench_topic, namespace), WrenchStamped
            )
        self.faults = Faults()
        self.period: float | None = None
        self.queue = int(queue)
        self._seen: dict[str, dict[int, Any]] = {k: {} for k in self._companions}
        self._pending: collections.deque[_Pending] = collections.deque()
        self._ready: collections.deque[Sample] = collections.deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._uses: set[str] | None = None
        self._has_dq: bool | None = None
        self._last_ns: int | None = None
        self._thread = threading.Thread(target=self._run, name="ditherlab-dds", daemon=True)
        self._thread.start()

    def poll(self, timeout: float) -> list[Sample]:
        """The samples ready, waiting up to ``timeout`` [s] for the first ([] if none came)."""
        with self._cond:
            self._cond.wait_for(lambda: bool(self._ready), timeout)
            out = list(self._ready)
            self._ready.clear()
        return out

    def uses(self) -> set[str]:
        """The companions in the stream (``dither``, ``wrench``), once the first sample is out."""
        return set(self._uses or ())

    def close(self) -> None:
        """Stop the thread."""
        self._stop.set()
        self._thread.join(timeout=2.0)

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        while not self._stop.is_set():
            got = self._receive()
            self._release(time.monotonic())
            if not got:
                time.sleep(0.0005)

    def _receive(self) -> int:
        """Take what arrived; the joint states that pass :meth:`_sample` wait in line."""
        now = time.monotonic()
        got = 0
        for msg in self._joints.take():
            got += 1
            if not isinstance(msg, JointState):  # a writer gone (DDS's invalid sample)
                continue
            s = self._sample(msg)
            if s is not None:
                self._pending.append(_Pending(s[0], s[1], now))
        for k, reader in self._companions.items():
            for msg in reader.take():
                got += 1
                if not hasattr(msg, "header"):  # a writer gone (DDS's invalid sample)
                    continue
                self._seen[k][_ns(msg.header.stamp)] = msg
        return got

    def _sample(self, msg: JointState) -> tuple[int, Sample] | None:
        """The model's joints of one JointState, or None (counted in :attr:`faults`)."""
        ns, t = _ns(msg.header.stamp), stamp_time(msg.header.stamp.sec, msg.header.stamp.nanosec)
        where = f"{self.topic} at t = {t:.6f} s"
        pos = {name: i for i, name in enumerate(msg.name)}
        missing = [j for j in self.names if j not in pos]
        if missing:
            self.faults.add(
                "other joint names",
                f"{where}: names {list(msg.name)[:8]} lack the model's {missing[:4]}; dropped",
            )
            return None
        m = len(msg.name)
        nv = len(msg.velocity)
        if self._has_dq is None:
            self._has_dq = nv == m
        if len(msg.position) != m or len(msg.effort) != m or nv != (m if self._has_dq else nv):
            self.faults.add(
                "joint count",
                f"{where}: {m} names but {len(msg.position)} positions, {nv} velocities, "
                f"{len(msg.effort)} efforts; expected one per name; dropped",
            )
            return None
        idx = [pos[j] for j in self.names]
        q, tau = np.asarray(msg.position)[idx], np.asarray(msg.effort)[idx]
        dq = np.asarray(msg.velocity)[idx] if self._has_dq else None
        if not (np.isfinite(q).all() and np.isfinite(tau).all()) or (
            dq is not None and not np.isfinite(dq).all()
        ):
            self.faults.add(
                "not finite", f"{where}: a position, velocity or effort is NaN; dropped"
            )
            return None
        if self._last_ns is not None and ns <= self._last_ns:
            kind = "duplicated stamp" if ns == self._last_ns else "out of order"
            self.faults.add(kind, f"{where}: {kind} (the last was {self._last_ns} ns); dropped")
            return None
        self._last_ns = ns
        return ns, Sample(t, q, tau, dq)

    def _release(self, now: float) -> None:
        """Hand out the joint states whose companions came (or waited :data:`HOLD_S`)."""
        while self._pending:
            p = self._pending[0]
            waited = now - p.arrived >= HOLD_S
            if self._uses is None:  # the first sample decides what the stream holds
                if not waited and not all(p.ns in s for s in self._seen.values()):
                    return
                self._uses = {k for k, s in self._seen.items() if s}
                if "dither" in self._uses:
                    first = self._seen["dither"].get(p.ns) or next(
                        iter(self._seen["dither"].values())
                    )
                    self.period = float(first.period) if first.period > 0 else None
            lacking = [k for k in self._uses if p.ns not in self._seen[k]]
            if lacking and not waited:
                return
            self._pending.popleft()
            if "dither" in lacking:
                self.faults.add(
                    "no dither state",
                    f"{self.topic} at t = {p.sample.t:.6f} s: no DitherState with its stamp "
                    f"within {HOLD_S} s; dropped",
                )
                continue
            self._push(self._complete(p))

    def _complete(self, p: _Pending) -> Sample:
        """``p``'s sample with its dither and wrench (their messages up to it forgotten)."""
        s = p.sample
        if "dither" in (self._uses or ()):
            d = self._seen["dither"][p.ns]
            pos = {name: i for i, name in enumerate(d.name)}
            if (
                len(d.feedforward)
                and len(d.feedforward) == len(d.name)
                and all(j in pos for j in self.names)
            ):
                s = s._replace(ffw=np.asarray(d.feedforward)[[pos[j] for j in self.names]])
            else:
                s = s._replace(dither=bool(d.on))
        if "wrench" in (self._uses or ()):
            w = self._seen["wrench"].get(p.ns)
            f = np.full(6, np.nan) if w is None else _wrench(w)
            s = s._replace(wrench=f)
        for seen in self._seen.values():
            for k in [k for k in seen if k <= p.ns]:
                del seen[k]
        return s

    def _push(self, s: Sample) -> None:
        with self._cond:
            if len(self._ready) >= self.queue:
                self._ready.popleft()
                self.faults.add(
                    "slow consumer",
                    f"the estimate fell {self.queue} samples behind the stream; the oldest are "
                    "dropped",
                )
            self._ready.append(s)
            self._cond.notify()


def _ns(stamp: Any) -> int:
    """A stamp in whole nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def _wrench(w: WrenchStamped) -> np.ndarray:
    """(6,) ``f_x .. m_z`` [N, N·m] of a WrenchStamped."""
    f, m = w.wrench.force, w.wrench.torque
    return np.array([f.x, f.y, f.z, m.x, m.y, m.z], dtype=float)

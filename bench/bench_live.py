"""The live estimate: compute per update and DDS on the loopback interface.

- **Per-update compute**: :class:`ditherlab.analysis.causal.CausalEstimator` fed one sample at a
  time (all four variants, profile intervals) over 8 s of the simulator's dithered push campaign
  (``recordings/sim-push-dither.parquet`` from 6 s, 250 Hz; ``--quick``: 2 s), p50 and p99 of the update's
  wall time. The reference in the same run: the naive live loop, the offline
  :func:`ditherlab.analysis.estimation.replay` of the last 0.5 s at every new sample, keeping its
  last row (every 10th sample, timed alike). The model is identified on the shipped pair (not
  timed); the first second warms the compiled kernels (not timed).
- **DDS loopback at 1 kHz**: one participant publishes 6-joint JointStates every millisecond
  (5000; ``--quick``: 1000), another in the same process takes them in a thread: the latency
  from write to take (p50, p99) and the messages that did not arrive. Cyclone DDS on ``lo`` only
  (``CYCLONEDDS_URI`` set here when it is not).
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LOOPBACK = (
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface name='lo'/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    "<Peer address='127.0.0.1'/></Peers><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex></Discovery></Domain></CycloneDDS>"
)


def _compute(quick: bool) -> list[dict]:
    from ditherlab.analysis.causal import CausalEstimator, block_of, settings_for
    from ditherlab.analysis.estimation import replay
    from ditherlab.analysis.identification import identify
    from ditherlab.io import read

    recs = [read(ROOT / "recordings" / f"sim-push-{k}.parquet") for k in ("no-dither", "dither")]
    model = identify(recs, n_boot=0)
    rec = recs[1]
    n = int((2.0 if quick else 8.0) / rec.dt)
    first = 1500  # from 6 s on: the dither on, pushes
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    warm = int(1.0 / rec.dt)
    est.update(block_of(rec, slice(first - warm, first)))
    blocks = [block_of(rec, slice(i, i + 1)) for i in range(first, first + n)]
    fast = []
    for b in blocks:
        t0 = time.perf_counter()
        est.update(b)
        fast.append(time.perf_counter() - t0)
    back = int(0.5 / rec.dt)
    ref = []
    for i in range(first, first + n, 10):
        piece = rec.with_data(rec.data.iloc[i - back : i + 1].reset_index(drop=True))
        t0 = time.perf_counter()
        replay(piece, model)
        ref.append(time.perf_counter() - t0)
    f, r = np.array(fast) * 1e3, np.array(ref) * 1e3
    rows = []
    for q in (50, 99):
        a, b = float(np.percentile(f, q)), float(np.percentile(r, q))
        rows.append(
            {
                "name": f"live update, one sample, 4 variants, p{q}",
                "value": a,
                "unit": "ms",
                "reference": b,
                "ratio": b / a,
                "target": f"{len(f)} updates; a block of samples costs about one update",
            }
        )
    return rows


def _loopback(quick: bool) -> list[dict]:
    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK)
    from ditherlab.io.dds import Header, JointState, Reader, Time, Writer, participant

    domain = 100 + os.getpid() % 100
    count = 1000 if quick else 5000
    w = Writer(participant(domain), "rt/bench_joint_states", JointState)
    r = Reader(participant(domain), "rt/bench_joint_states", JointState)
    end = time.monotonic() + 10
    while (w.matched() == 0 or r.matched() == 0) and time.monotonic() < end:
        time.sleep(0.01)
    lat: list[float] = []
    done = threading.Event()

    def take() -> None:
        while not done.is_set():
            got = r.take()
            now = time.monotonic_ns()
            for m in got:
                if isinstance(m, JointState):
                    lat.append((now - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)) * 1e-6)
            if not got:
                time.sleep(0.0002)

    th = threading.Thread(target=take)
    th.start()
    names = [f"joint_{j}" for j in range(1, 7)]
    start = time.monotonic()
    for k in range(count):
        due = start + k * 1e-3
        while time.monotonic() < due:
            pass
        ns = time.monotonic_ns()
        stamp = Time(ns // 10**9, ns % 10**9)
        w.write(JointState(Header(stamp, ""), names, [0.1] * 6, [0.0] * 6, [1.0] * 6))
    time.sleep(0.5)
    done.set()
    th.join()
    a = np.array(lat)
    return [
        {"name": "DDS loopback JointState at 1 kHz, latency p50", "value": float(np.median(a)),
         "unit": "ms"},
        {"name": "DDS loopback JointState at 1 kHz, latency p99", "value": float(np.percentile(a, 99)),
         "unit": "ms"},
        {"name": f"DDS loopback JointState at 1 kHz, lost of {count}", "value": float(count - len(a)),
         "unit": "messages"},
    ]  # fmt: skip


def run(quick: bool = False) -> list[dict]:
    return _compute(quick) + _loopback(quick)

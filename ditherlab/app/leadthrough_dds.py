"""The closed loop of ``ditherlab leadthrough --live`` over DDS: a ``ditherlab live`` process
per run and the simulated arm's lock-step link to it (:func:`dds_source`). The arm publishes the
samples of one controller update (``JointState``, and ``DitherState`` with dither) and waits for
the estimate stamped like the update's last sample (``WrenchStamped`` on ``ditherlab/wrench``
and its bounds on ``/lower``, ``/upper``) before it steps on. Needs the ``live`` extra."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ditherlab.app.leadthrough_live import LinkSettings, push_of
from ditherlab.core.errors import DitherlabError
from ditherlab.core.stamps import split_stamp
from ditherlab.io.dds import (
    DitherState,
    Header,
    JointState,
    Reader,
    WrenchStamped,
    Writer,
    dds_topic,
    participant,
    stamp_of,
)
from ditherlab.sim.guidance import EstimateSource, LoggedChunk

__all__ = ["FIRST_WAIT_S", "STEP_TIMEOUT_S", "dds_source"]

#: [s] without an estimate after the first: the estimator is taken as gone
STEP_TIMEOUT_S = 5.0
#: [s] for the estimator process to subscribe and send its first estimate
FIRST_WAIT_S = 300.0


def _live_command(model: Path, link: LinkSettings, ns: str, domain: int | None) -> list[str]:
    """The ``ditherlab live`` command line of one run's estimator process."""
    cmd = [
        sys.executable, "-m", "ditherlab", "live", "--model", str(Path(model).resolve()),
        "--source", "ros2:joint_states", "--namespace", ns, "--sink", "ros2:ditherlab/wrench",
        "--variants", link.variant, "--variant", link.variant, "--components", "fxyz",
        "--interval", link.interval, "--level", repr(link.level),
        "--timeout", "2", "--wait", repr(FIRST_WAIT_S),
    ]  # fmt: skip
    return cmd + (["--domain", str(domain)] if domain is not None else [])


@contextmanager
def dds_source(
    model: Path,
    link: LinkSettings,
    *,
    namespace: str,
    domain: int | None = None,
    timeout: float = STEP_TIMEOUT_S,
) -> Iterator[EstimateSource]:
    """A ``ditherlab live`` process on the run's topics (in ``namespace``, on ``domain``) and
    the lock-step link to it (:class:`_Link`) for the simulated arm; the process is ended when
    the block ends (it stops by itself once the arm stops publishing; a fault ends it at once).

    Raises DitherlabError (one line) when the process ends early or sends no estimate of an
    update within ``timeout`` seconds (the first within :data:`FIRST_WAIT_S`)."""
    env = dict(os.environ)
    proc = subprocess.Popen(
        _live_command(model, link, namespace, domain),
        env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    ok = False
    try:
        yield _Link(proc, link, namespace, domain, timeout)
        ok = True
    finally:
        _end(proc, ok)


def _end(proc: subprocess.Popen, ok: bool) -> None:
    """Let the estimator process stop by itself (``ok``: the run is whole) or end it."""
    if ok:
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            pass
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    proc.communicate()


class _Link:
    """The arm's side of the lock-step link: :meth:`__call__` publishes one update's samples
    (DitherState, then JointState, per sample) and waits for the estimate (WrenchStamped on
    ``ditherlab/wrench``, ``/lower``, ``/upper``) stamped like the update's last sample."""

    def __init__(
        self,
        proc: subprocess.Popen,
        link: LinkSettings,
        ns: str,
        domain: int | None,
        timeout: float,
    ) -> None:
        self.proc, self.link, self.timeout = proc, link, timeout
        dp = participant(domain)
        self.js = Writer(dp, dds_topic("joint_states", ns), JointState)
        dither = link.period is not None
        self.ds = Writer(dp, dds_topic("ditherlab/dither", ns), DitherState) if dither else None
        self.readers = [
            Reader(dp, dds_topic("ditherlab/wrench" + end, ns), WrenchStamped)
            for end in ("", "/lower", "/upper")
        ]
        self.got: list[dict[int, np.ndarray]] = [{}, {}, {}]
        self.first = True

    def __call__(self, chunk: LoggedChunk) -> tuple[np.ndarray, ...]:
        if self.first:
            writers = [w for w in (self.js, self.ds) if w is not None]
            subscribed = lambda: all(w.matched() > 0 for w in writers)  # noqa: E731
            self._await(subscribed, FIRST_WAIT_S, chunk.t[0], "subscribe")
        self._publish(chunk)
        sec, nsec = split_stamp(chunk.t[-1:])
        key = int(sec[0]) * 1_000_000_000 + int(nsec[0])
        wait = FIRST_WAIT_S if self.first else self.timeout
        self._await(lambda: self._take(key), wait, chunk.t[-1], "send its estimate")
        self.first = False
        est, lo, hi = (g.pop(key) for g in self.got)
        for g in self.got:  # an estimate is used once: the older ones are forgotten
            for k in [k for k in g if k < key]:
                del g[k]
        return push_of(est, lo, hi)

    def _publish(self, chunk: LoggedChunk) -> None:
        names = list(self.link.names)
        for i in range(len(chunk.t)):
            header = Header(stamp_of(float(chunk.t[i])), "")
            if self.ds is not None:
                on = bool(chunk.dither[i])
                self.ds.write(DitherState(header, on, float(self.link.period), names, []))
            q, dq, tau = (a[i].tolist() for a in (chunk.q, chunk.dq, chunk.tau))
            self.js.write(JointState(header, names, q, dq, tau))

    def _take(self, key: int) -> bool:
        """Take what arrived; True once the estimate and both bounds stamped ``key`` [ns]
        came."""
        for reader, got in zip(self.readers, self.got, strict=True):
            for m in reader.take():
                if hasattr(m, "header"):
                    st = m.header.stamp
                    f, tq = m.wrench.force, m.wrench.torque
                    got[int(st.sec) * 1_000_000_000 + int(st.nanosec)] = np.array(
                        [f.x, f.y, f.z, tq.x, tq.y, tq.z]
                    )
        return all(key in g for g in self.got)

    def _await(self, done: Callable[[], bool], wait: float, t: float, what: str) -> None:
        """Poll ``done`` until it holds; DitherlabError when the estimator process ended or
        did not ``what`` within ``wait`` seconds (at the arm's time ``t`` [s])."""
        end = time.monotonic() + wait
        while not done():
            code = self.proc.poll()
            if code is not None:
                last = _last_line(self.proc)
                raise DitherlabError(
                    f"leadthrough --live: the estimator process (ditherlab live, pid "
                    f"{self.proc.pid}) ended with status {code} at t = {t:.3f} s of the run"
                    f"{': ' + last if last else ''}; expected it to estimate every update"
                )
            if time.monotonic() > end:
                raise DitherlabError(
                    f"leadthrough --live: the estimator process (ditherlab live, pid "
                    f"{self.proc.pid}) did not {what} for t = {t:.3f} s of the run within "
                    f"{wait:g} s; expected an estimate of every update"
                )
            time.sleep(0.0002)


def _last_line(proc: subprocess.Popen) -> str:
    """The estimator process's last line on stderr (it has ended), without ``error:``."""
    try:
        _, err = proc.communicate(timeout=2.0)
    except (subprocess.TimeoutExpired, ValueError):
        return ""
    lines = [ln.strip() for ln in (err or "").splitlines() if ln.strip()]
    return lines[-1].removeprefix("error: ") if lines else ""

"""``ditherlab leadthrough --live``: the lead-through of ``leadthrough`` in closed loop across
processes. The simulated arm publishes its joint states (and the dither's state) over DDS as a
ROS 2 robot would; a ``ditherlab live`` process, started by the command, estimates the push and
publishes it (``geometry_msgs/WrenchStamped``, with its interval's bounds); the arm subscribes
to that estimate and moves by the admittance law with it.

Lock-step: the arm publishes the samples of one controller update, waits for the estimate of
the update's last sample, and only then steps on; so the run is deterministic and reproducible
from the seed, and equals the same lead-through with the same estimator in one process
(:func:`causal_source`, ``ditherlab leadthrough --model``) float for float. The estimator is
``live``'s (:class:`ditherlab.analysis.causal.CausalEstimator` with a torque model): variant
``dither_band`` with dither, ``nodither_band`` without, forces only; the interval the law's
(``lead_through.interval`` at ``lead_through.level``) with the interval law, ``profile`` with the
dead zone (whose law reads no interval).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.causal import CausalBlock, CausalEstimator, CausalSettings
from ditherlab.analysis.lead_metrics import COMPARED
from ditherlab.core.errors import ConfigError, DitherlabError
from ditherlab.core.stamps import split_stamp, wire_time
from ditherlab.data.torque_model import TorqueModel
from ditherlab.robot import RobotModel
from ditherlab.sim.guidance import EstimateSource, LoggedChunk
from ditherlab.sim.params import load_params

__all__ = [
    "LinkSettings",
    "causal_source",
    "closed_loop_difference",
    "closed_loop_line",
    "dds_source",
    "link_settings",
]

#: [s] without an estimate after the first: the estimator is taken as gone
STEP_TIMEOUT_S = 5.0
#: [s] for the estimator process to subscribe and send its first estimate
FIRST_WAIT_S = 300.0


@dataclass(frozen=True)
class LinkSettings:
    """What the estimate of one lead-through run is computed with (:func:`link_settings`).

    Attributes
    ----------
    variant : the estimator variant that drives the arm ; interval : ``profile`` or
        ``set_membership`` ; level : the interval's confidence level in (0, 1)
    period : [s] the dither period (None: the run has no dither) ; names : the joints, in order
    """

    variant: str
    interval: str
    level: float
    period: float | None
    names: tuple[str, ...]


def link_settings(model: TorqueModel, law: str, dither: bool, config: Any = None) -> LinkSettings:
    """The estimate's settings of a run with ``law`` and ``dither`` (module docstring), from the
    simulator's parameters (``config``: a TOML path or dict); ConfigError when the model's robot
    is not the simulated one (the built-in IRB140)."""
    params = load_params(config, {"lead_through": {"law": law}})
    lt = params["lead_through"]
    sim_names = RobotModel.from_spec("irb140").joint_names
    if not model.same_robot("irb140"):
        raise ConfigError(
            f"--model: its robot {_robot_name(model.robot)!r} is not the simulated arm; "
            "expected a model of the simulator's IRB140 (ditherlab identify on its recordings)"
        )
    interval = str(lt["interval"]) if law == "interval" else "profile"
    period = 2 * np.pi / float(params["dither"]["frequency"]) if dither else None
    variant = "dither_band" if dither else "nodither_band"
    return LinkSettings(variant, interval, float(lt["level"]), period, tuple(sim_names))


def _robot_name(spec: Any) -> str:
    """A model's robot, named: the built-in's name or the URDF's robot."""
    return spec if isinstance(spec, str) else str(spec.get("name") or spec.get("urdf", "")[:40])


def _push_of(est: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """The push on the tool (3,) [N] and its interval from the estimated wrench of the arm on
    its surroundings (the sensor's sign) ``est``, ``lo``, ``hi`` (6,) or (3,) [N, N·m]."""
    return -np.asarray(est[:3], float), -np.asarray(hi[:3], float), -np.asarray(lo[:3], float)


def causal_source(model: TorqueModel, link: LinkSettings, lag: int = 0) -> EstimateSource:
    """The estimate of ``ditherlab live`` computed in this process: the samples of every update
    as they arrive over DDS (stamps in whole nanoseconds, the dither's flag), the settings as
    ``live`` takes them from its first samples; ``lag`` updates late (0: the estimate of the
    update's last sample; 1: the previous update's, as a transport delay of one update would
    give)."""
    state: dict[str, Any] = {"est": None, "past": []}

    def source(chunk: LoggedChunk) -> tuple[np.ndarray, ...]:
        t = wire_time(chunk.t)
        if state["est"] is None:
            dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
            s = CausalSettings(dt, link.period, (link.variant,), link.level, link.interval, "fxyz")
            state["est"] = CausalEstimator(model, {"robot": model.robot}, s)
        dither = chunk.dither.copy() if link.period is not None else None
        rows = state["est"].update(CausalBlock(t, chunk.q, chunk.tau, chunk.dq, dither))
        v = link.variant
        got = [np.array([rows[f"{v}/f_{a}{s}"][-1] for a in "xyz"]) for s in ("", "_lo", "_hi")]
        state["past"].append(_push_of(*got))
        if len(state["past"]) <= lag:
            return np.zeros(3), np.full(3, np.nan), np.full(3, np.nan)
        return state["past"].pop(0)

    return source


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
        from ditherlab.io.dds import (
            DitherState,
            JointState,
            Reader,
            WrenchStamped,
            Writer,
            dds_topic,
            participant,
        )

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
        return _push_of(est, lo, hi)

    def _publish(self, chunk: LoggedChunk) -> None:
        from ditherlab.io.dds import DitherState, Header, JointState, stamp_of

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


def closed_loop_difference(live: Mapping[str, Any], here: Mapping[str, Any]) -> dict[str, Any]:
    """The live runs against the same runs in one process (two :func:`compare_laws` results
    of the same seeds, laws and dither settings): per compared metric the largest difference
    over the runs (NaN in both counts as equal), and the largest difference of the tool's path
    [mm] over the first seed's traces."""
    diff: dict[str, float] = {}
    for a, b in zip(live["runs"], here["runs"], strict=True):
        for key, *_ in COMPARED:
            x, y = float(a["summary"][key]), float(b["summary"][key])
            d = 0.0 if (np.isnan(x) and np.isnan(y)) or x == y else abs(x - y)
            diff[key] = max(diff.get(key, 0.0), d)
    path = max(
        float(np.max(np.abs(np.asarray(p["x"]) - np.asarray(here["paths"][k]["x"]))))
        for k, p in live["paths"].items()
    )
    return {"metrics_max_abs": diff, "path_max_mm": path, "runs": len(live["runs"])}


def closed_loop_line(loop: Mapping[str, Any]) -> str:
    """One line: how far the live runs are from the same runs in one process."""
    worst = max(loop["metrics_max_abs"].items(), key=lambda kv: kv[1])
    return (
        f"closed loop over DDS against the same estimate in one process ({loop['runs']} runs): "
        f"tool path max |difference| {loop['path_max_mm']:.3g} mm, metrics max |difference| "
        f"{worst[1]:.3g} ({worst[0]})"
    )

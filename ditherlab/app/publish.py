"""``ditherlab publish``: a recording's joint states published over DDS in real time, as a ROS 2
robot driver would (``sensor_msgs/JointState`` with the robot's joint names, and
``ditherlab_msgs/DitherState`` with the same stamps when the recording has dither, a sensor's
``geometry_msgs/WrenchStamped`` on request): the robot of ``ditherlab live`` on one machine,
from a log or from ``ditherlab simulate``."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ditherlab.app.workflow import ReadOptions
from ditherlab.core.errors import ConfigError
from ditherlab.core.stamps import split_stamp
from ditherlab.data.recording import Recording
from ditherlab.io import read
from ditherlab.io.dds import (
    DitherState,
    Header,
    JointState,
    Time,
    WrenchStamped,
    Writer,
    dds_topic,
    participant,
    wrench_stamped,
)
from ditherlab.physics.dither import dither_period, has_dither

__all__ = ["PublishOptions", "Published", "run"]


@dataclass(frozen=True)
class PublishOptions:
    """The options of ``ditherlab publish``.

    Attributes
    ----------
    recording : the recording to publish ; read : how to read it
    topic : the JointState topic ; namespace : of relative topics ; domain : the DDS domain
    dither_topic : the DitherState topic (when the recording has dither)
    wrench_topic : publish the recording's F/T sensor as WrenchStamped there (None: not)
    rate : playback speed (1: the recording's own rate)
    wait : [s] to wait for a subscriber before the first sample (0: do not wait)
    frame : the frame of the joint states' and the wrench's headers
    """

    recording: Path
    read: ReadOptions = ReadOptions()
    topic: str = "joint_states"
    namespace: str = ""
    domain: int | None = None
    dither_topic: str = "ditherlab/dither"
    wrench_topic: str | None = None
    rate: float = 1.0
    wait: float = 10.0
    frame: str = ""


@dataclass
class Published:
    """What :func:`run` published: samples, on which topic, over how long [s]."""

    samples: int
    topic: str
    dither: bool
    seconds: float

    def text(self) -> str:
        with_dither = " with its DitherState" if self.dither else ""
        return (
            f"published {self.samples} joint states{with_dither} on {self.topic} "
            f"in {self.seconds:.2f} s"
        )


def run(options: PublishOptions, progress: Callable[[int, int], None] | None = None) -> Published:
    """Publish a recording's samples at their own times (times ``rate``), each as a JointState
    (and DitherState, WrenchStamped) stamped with its time in whole nanoseconds.

    Raises ConfigError for a rate that is not positive, a wrench topic without a sensor in the
    recording, or no subscriber within ``wait`` seconds.
    """
    o = options
    if not (np.isfinite(o.rate) and o.rate > 0):
        raise ConfigError(f"--rate {o.rate!r}; expected a positive playback speed (1: real time)")
    rec = read(o.recording, **o.read.kwargs())
    if o.wrench_topic and not rec.has_wrench:
        raise ConfigError(f"{o.recording}: --wrench-topic needs the F/T columns f_x..m_z")
    dp = participant(o.domain)
    js = Writer(dp, dds_topic(o.topic, o.namespace), JointState)
    ds = (
        Writer(dp, dds_topic(o.dither_topic, o.namespace), DitherState) if has_dither(rec) else None
    )
    ws = (
        Writer(dp, dds_topic(o.wrench_topic, o.namespace), WrenchStamped)
        if o.wrench_topic
        else None
    )
    _await_subscriber(js, o.wait)
    start = time.monotonic()
    _stream(rec, o, (js, ds, ws), progress)
    time.sleep(0.3)  # the reliable protocol delivers the last samples before the writers go
    return Published(len(rec), js.topic, ds is not None, time.monotonic() - start)


def _await_subscriber(js: Writer, wait: float) -> None:
    """Wait up to ``wait`` seconds for a reader of ``js``; ConfigError when none came."""
    if wait <= 0:
        return
    end = time.monotonic() + wait
    while js.matched() == 0:
        if time.monotonic() > end:
            raise ConfigError(
                f"no subscriber on {js.topic} within {wait:g} s; expected ditherlab live (or "
                "another ROS 2 node) listening, or --wait 0 to publish regardless"
            )
        time.sleep(0.02)
    time.sleep(0.2)  # discovery of the other topics of the same participant


def _stream(
    rec: Recording,
    o: PublishOptions,
    writers: tuple[Writer, Writer | None, Writer | None],
    progress: Callable[[int, int], None] | None,
) -> None:
    """Write every sample at its time: the DitherState first, then the wrench, then the
    JointState (a subscriber has the companions when the joint state comes)."""
    js, ds, ws = writers
    names = list(rec.robot().joint_names)
    sec, ns = split_stamp(rec.t)
    q, tau = rec.q, rec.tau
    dq = rec.dq if rec.has_dq else None
    flag, ffw = rec.dither, (rec.tau_ffw if rec.dither is None else None)
    period = dither_period(rec) if ds is not None else 0.0
    start, t0 = time.monotonic(), rec.t[0]
    for i in range(len(rec)):
        wait = (rec.t[i] - t0) / o.rate - (time.monotonic() - start)
        if wait > 0:
            time.sleep(wait)
        header = Header(Time(int(sec[i]), int(ns[i])), o.frame)
        if ds is not None:
            on = bool(flag[i]) if flag is not None else True
            feed = [] if ffw is None else [float(x) for x in ffw[i]]
            ds.write(DitherState(header, on, float(period), names, feed))
        if ws is not None:
            ws.write(wrench_stamped(float(rec.t[i]), o.frame, rec.wrench[i]))
        velocity = [] if dq is None else [float(x) for x in dq[i]]
        js.write(
            JointState(
                header, names, [float(x) for x in q[i]], velocity, [float(x) for x in tau[i]]
            )
        )
        if progress and (i % 250 == 0 or i == len(rec) - 1):
            progress(i + 1, len(rec))

"""``ditherlab live``: the force estimate of a running robot, sample by sample as its joint
states arrive, from the past alone (:class:`ditherlab.analysis.causal.CausalEstimator`, the same
update as ``replay --causal``).

Sources (``--source``): ``ros2:TOPIC`` (``sensor_msgs/JointState`` over DDS,
:class:`ditherlab.io.live_feed.DdsFeed`) or ``file:RECORDING`` (a recording played at its own
rate times ``--rate``, :class:`ditherlab.io.live_feed.FileFeed`). Sinks (``--sink``, repeatable):
``parquet:OUT.parquet`` (the estimates file of ``replay``), ``ros2:TOPIC`` (the estimate as
``geometry_msgs/WrenchStamped`` on TOPIC, the interval's lower and upper bounds as
WrenchStamped on ``TOPIC/lower`` and ``TOPIC/upper``), ``rerun`` (a viewer) or
``rerun:FILE.rrd``.

The estimate ends when the source ends (a file), when no sample came for ``--timeout`` seconds
(the publisher stopped), after ``--duration`` seconds of stream, or on Ctrl-C (SIGINT); in every
case the files are closed whole, with every row estimated up to then.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.causal import CausalBlock, CausalEstimator, CausalSettings, settings_for
from ditherlab.app.replay import ESTIMATES_FILE, Tally, error_lines
from ditherlab.app.view import RRD_FILE
from ditherlab.app.workflow import ReadOptions, guard
from ditherlab.core.errors import ConfigError, DitherlabError
from ditherlab.core.files import plain
from ditherlab.data.estimates import VARIANTS, EstimatesWriter
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io import read
from ditherlab.io.dds import WrenchStamped, Writer, dds_topic, participant, wrench_stamped
from ditherlab.io.live_feed import DdsFeed, FileFeed, Sample
from ditherlab.output.rerun.live_view import LiveView
from ditherlab.robot import RobotModel

__all__ = ["LiveOptions", "LiveResult", "run"]


@dataclass(frozen=True)
class LiveOptions:
    """The options of ``ditherlab live``.

    Attributes
    ----------
    model : the torque model (TOML) ; source : ``ros2:TOPIC`` or ``file:RECORDING``
    sinks : ``parquet:OUT``, ``ros2:TOPIC``, ``rerun``, ``rerun:FILE.rrd``
    rate : a file source's playback speed (1: its own rate; 0: as fast as it is estimated)
    namespace : the ROS 2 namespace of relative topics ; domain : the DDS domain
    wrench_topic : a sensor's WrenchStamped topic, copied beside the estimate
    dither_topic : the ``ditherlab_msgs/DitherState`` topic
    timeout : [s] without a sample after the first: the publisher stopped, the estimate ends
    wait : [s] for the first sample ; duration : [s] of stream to estimate (None: no limit)
    queue : samples waiting for the estimate at most (beyond: dropped, counted)
    variant : the variant published on ``ros2:`` and shown in Rerun (default: ``dither_band``
        with dither, else ``nodither_band``)
    variants, level, interval, components : as for ``replay``
    frame : the WrenchStamped frame (default: the robot's tool frame)
    read : how to read a file source ; force : replace existing output files
    """

    model: Path
    source: str
    sinks: tuple[str, ...]
    rate: float = 1.0
    namespace: str = ""
    domain: int | None = None
    wrench_topic: str | None = None
    dither_topic: str = "ditherlab/dither"
    timeout: float = 1.0
    wait: float = 10.0
    duration: float | None = None
    queue: int = 4096
    variant: str | None = None
    variants: tuple[str, ...] | None = None
    level: float = 0.95
    interval: str = "profile"
    components: str = "all"
    frame: str | None = None
    read: ReadOptions = ReadOptions()
    force: bool = False


@dataclass
class LiveResult:
    """What a live estimate did: samples estimated, the stream's first and last time [s], why
    it ended, the faults' counts, gaps, per-block compute times [s], the files written."""

    samples: int
    t_first: float
    t_last: float
    stopped: str
    faults: str
    gaps: int
    compute: list[float] = field(default_factory=list)
    wrote: list[Path] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def text(self) -> str:
        """A few lines: the stream, why it ended, what was dropped, compute time, files."""
        c = np.asarray(self.compute) * 1e3
        per = (
            f"; compute per update p50 {np.percentile(c, 50):.2f} ms, p99 "
            f"{np.percentile(c, 99):.2f} ms"
            if len(c)
            else ""
        )
        lines = [
            f"{self.samples} samples estimated, t = {self.t_first:.3f} .. {self.t_last:.3f} s{per}",
            f"stopped: {self.stopped}",
            f"dropped: {self.faults}; gaps: {self.gaps}",
            *self.errors,
        ]
        lines += [f"wrote {p}" for p in self.wrote]
        return "\n".join(lines)


def run(options: LiveOptions, echo: Callable[[str], None] | None = None) -> LiveResult:
    """Estimate the force of a robot live (module docstring).

    Parameters
    ----------
    options : :class:`LiveOptions`
    echo : where the one-line fault reports go as they happen (default: nowhere)

    Returns
    -------
    LiveResult

    Raises
    ------
    ConfigError
        A source or sink that does not parse, an existing output without ``force``, no sample
        within ``wait`` seconds, a first sample without the model's joints.
    """
    o, say = options, echo or (lambda line: None)
    kind, where = _split(o.source, "--source", ("ros2", "file"))
    sinks = [_split(s, "--sink", ("parquet", "ros2", "rerun"), bare=("rerun",)) for s in o.sinks]
    if not sinks:
        raise ConfigError("live needs at least one --sink: parquet:OUT, ros2:TOPIC or rerun")
    inputs = [o.model, where if kind == "file" else None]
    outs = _guard_sinks(sinks, inputs, o)
    model = TorqueModel.load(o.model)
    with _interrupt() as stop:
        return _run(kind, where, model, sinks, outs, o, say, stop)


def _run(
    kind: str,
    where: str,
    model: TorqueModel,
    sinks: list[tuple[str, str]],
    outs: list[Path | None],
    o: LiveOptions,
    say: Callable[[str], None],
    stop: threading.Event,
) -> LiveResult:
    """:func:`run` once the options are checked, with Ctrl-C setting ``stop``."""
    feed, meta, settings_of = _open_feed(kind, where, model, o)
    try:
        label = o.source if kind == "file" else f"{o.source} (DDS topic {feed.topic})"
        first = _first_samples(feed, o.wait, label, stop)
        settings = settings_of(first)
        est = CausalEstimator(model, meta, settings)
        out = _Sinks(sinks, outs, _variant(o.variant, settings), est, o)
        say(
            f"estimating {', '.join(settings.variants)} from {o.source} at "
            f"{1 / settings.dt:.4g} Hz; Ctrl-C stops"
        )
        return _estimate(feed, est, first, out, o, say, stop)
    finally:
        feed.close()


def _split(
    spec: str, option: str, kinds: Sequence[str], bare: Sequence[str] = ()
) -> tuple[str, str]:
    """``KIND:ARG`` -> (kind, arg); ConfigError naming ``option`` for anything else."""
    kind, sep, arg = spec.partition(":")
    if spec in bare:
        return spec, ""
    if not sep or kind not in kinds or not arg:
        forms = ", ".join(f"{k}:..." for k in kinds) + "".join(f", {b}" for b in bare)
        raise ConfigError(f"{option} {spec!r} is not one of {forms}")
    return kind, arg


def _guard_sinks(sinks: list[tuple[str, str]], inputs: list[Any], o: LiveOptions) -> list:
    """The output file of every sink (None for a topic or a viewer), checked before any work."""
    outs: list[Path | None] = []
    for kind, arg in sinks:
        if kind == "parquet":
            outs.append(guard(arg, inputs, read=o.read, kind=ESTIMATES_FILE, force=o.force))
        elif kind == "rerun" and arg:
            outs.append(guard(arg, inputs, read=o.read, kind=RRD_FILE, force=o.force))
        else:
            if kind == "ros2":
                dds_topic(arg, o.namespace)
            outs.append(None)
    files = [p for p in outs if p is not None]
    if len({p.resolve() for p in files}) < len(files):
        raise ConfigError("two --sink options name the same file; expected one file per sink")
    return outs


def _open_feed(kind: str, where: str, model: TorqueModel, o: LiveOptions):
    """The feed, the stream's recording metadata, and how the settings follow from the first
    samples."""
    pick = {"variants": o.variants, "level": o.level, "interval": o.interval}
    pick["components"] = o.components
    if kind == "file":
        rec = read(where, **o.read.kwargs())
        model.check_robot(rec)
        settings = settings_for(rec, **pick)
        return FileFeed(rec, o.rate), plain(rec.meta), lambda first: settings
    meta = {"robot": model.robot}
    robot = RobotModel.from_recording_meta({"schema": 1, **meta}, n_expected=model.n)
    feed = DdsFeed(
        robot.joint_names, where, namespace=o.namespace, wrench_topic=o.wrench_topic,
        dither_topic=o.dither_topic, domain=o.domain, queue=o.queue,
    )  # fmt: skip

    def settings_of(first: list[Sample]) -> CausalSettings:
        t = np.array([s.t for s in first])
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        if not dt > 0:
            raise ConfigError(f"{feed.topic}: the first samples' stamps do not advance: {t[:4]}")
        dither = feed.period is not None
        allowed = [v for v in VARIANTS if dither or not v.startswith("dither")]
        asked = list(o.variants) if o.variants else allowed
        for v in asked:
            if v in VARIANTS and v not in allowed:
                raise ConfigError(
                    f"variant {v} needs the dither: no {o.dither_topic} DitherState with a period "
                    f"came with the joint states of {feed.topic}"
                )
        return CausalSettings(dt, feed.period, tuple(asked), o.level, o.interval, o.components)

    return feed, meta, settings_of


def _first_samples(feed: Any, wait: float, where: str, stop: threading.Event) -> list[Sample]:
    """The first samples (at least 16, or all that came within half a second of the first), or
    a ConfigError when none came within ``wait`` seconds (with the faults seen); a
    DitherlabError when Ctrl-C comes first."""
    start = time.monotonic()
    got: list[Sample] = []
    first_at = None
    while True:
        if stop.is_set():
            raise DitherlabError(f"{where}: interrupted (Ctrl-C) before the first sample")
        batch = feed.poll(0.05)
        if batch is None:
            if got:
                return got
            raise ConfigError(f"{where}: the recording has no samples")
        got += batch
        now = time.monotonic()
        if got and first_at is None:
            first_at = now
        if len(got) >= 16 or (first_at is not None and now - first_at > 0.5):
            return got
        if not got and now - start > wait:
            seen = feed.faults.text()
            raise ConfigError(
                f"{where}: no joint state with the model's joints within {wait:g} s "
                f"(dropped: {seen}); expected a publisher on that topic"
            )


def _variant(variant: str | None, s: CausalSettings) -> str:
    """The variant shown and published: ``variant``, else ``dither_band`` with dither, else
    ``nodither_band``; ConfigError when it is not estimated."""
    v = variant or ("dither_band" if "dither_band" in s.variants else s.variants[0])
    if v not in s.variants:
        raise ConfigError(
            f"--variant {v} is not estimated; expected one of {', '.join(s.variants)}"
        )
    return v


class _Sinks:
    """Every sink of one live estimate: :meth:`write` a block of rows, :meth:`close` them all
    (the files whole, with the metadata; the Parquet rows buffered up to :data:`FLUSH_ROWS`)."""

    FLUSH_ROWS = 2048

    def __init__(
        self,
        sinks: list[tuple[str, str]],
        outs: list[Path | None],
        variant: str,
        est: CausalEstimator,
        o: LiveOptions,
    ) -> None:
        self.variant, self.est, self.outs = variant, est, [p for p in outs if p is not None]
        self.parquet: list[EstimatesWriter] = []
        self.views: list[LiveView] = []
        self.topics: list[tuple[Writer, Writer, Writer]] = []
        self._buf: list[dict[str, np.ndarray]] = []
        self._dp = None
        frame = o.frame or est.robot.tool_frame or "tool0"
        self.frame = str(frame)
        # viewers and topics first: one that cannot start fails before a file is opened
        rank = {"rerun": 0, "ros2": 1, "parquet": 2}
        order = sorted(zip(sinks, outs, strict=True), key=lambda s: rank[s[0][0]])
        for (kind, arg), out in order:
            if kind == "parquet":
                w = EstimatesWriter(out)  # type: ignore[arg-type]
                w.__enter__()
                self.parquet.append(w)
            elif kind == "rerun":
                self.views.append(LiveView(variant, out))
            else:
                self._dp = self._dp or participant(o.domain)
                topic = dds_topic(arg, o.namespace)
                self.topics.append(
                    tuple(
                        Writer(self._dp, topic + end, WrenchStamped)
                        for end in ("", "/lower", "/upper")
                    )  # type: ignore[arg-type]
                )

    def write(self, rows: dict[str, np.ndarray]) -> None:
        """Send one block of rows to every sink."""
        for view in self.views:
            view.write(rows)
        if self.topics:
            self._publish(rows)
        if self.parquet:
            self._buf.append(rows)
            if sum(len(r["t"]) for r in self._buf) >= self.FLUSH_ROWS:
                self._flush()

    def _publish(self, rows: dict[str, np.ndarray]) -> None:
        v, t = self.variant, rows["t"]
        comps = ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")
        est, lo, hi = (
            np.column_stack([rows[f"{v}/{c}{s}"] for c in comps]) for s in ("", "_lo", "_hi")
        )
        for i in range(len(t)):
            for trio in self.topics:
                for writer, w in zip(trio, (est[i], lo[i], hi[i]), strict=True):
                    writer.write(wrench_stamped(float(t[i]), self.frame, w))

    def _flush(self) -> None:
        if not self._buf:
            return
        rows = {k: np.concatenate([r[k] for r in self._buf]) for k in self._buf[0]}
        self._buf = []
        for w in self.parquet:
            w.write(rows)

    def close(self, extra: dict[str, Any], ok: bool = True) -> list[Path]:
        """Close every sink: the Parquet files with the estimator's metadata and ``extra``."""
        if ok:
            self._flush()
        for w in self.parquet:
            w.meta = plain({**self.est.metadata(), "live": extra})
            if ok and w.rows:
                w.__exit__(None, None, None)
            else:
                w.__exit__(RuntimeError, RuntimeError("live stopped"), None)
        for view in self.views:
            view.close(ok)
        return self.outs if ok else []


@contextmanager
def _interrupt():
    """A flag set by Ctrl-C (SIGINT) while the block runs, instead of KeyboardInterrupt (in the
    main thread; elsewhere the flag is never set)."""
    flag = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return
    old = signal.signal(signal.SIGINT, lambda *_: flag.set())
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, old)


def _estimate(
    feed: Any,
    est: CausalEstimator,
    batch: list[Sample],
    sinks: _Sinks,
    o: LiveOptions,
    say: Callable[[str], None],
    stop: threading.Event,
) -> LiveResult:
    """The live loop: estimate what arrived, send it on, until the stream ends (module
    docstring)."""
    n, compute, tally = 0, [], Tally()
    t_first = batch[0].t
    t_last = t_first
    last_at = time.monotonic()
    ok = False
    ends = isinstance(feed, FileFeed)  # a file ends by itself; its own gaps are no timeout
    why = "error"
    try:
        while True:
            if batch:
                c0 = time.perf_counter()
                rows = est.update(_block(batch))
                compute.append(time.perf_counter() - c0)
                sinks.write(rows)
                tally.add(rows, est.settings.variants)
                n, t_last, last_at = n + len(batch), batch[-1].t, time.monotonic()
            for line in feed.faults.news():
                say(line)
            why = _why_stop(stop.is_set(), batch, t_last - t_first, None if ends else last_at, o)
            if why:
                break
            batch = feed.poll(min(0.05, o.timeout))
        ok = True
    finally:
        extra = {"source": o.source, "stopped": why, "faults": feed.faults.text(), "gaps": est.gaps}
        wrote = sinks.close(extra, ok)
    errors = error_lines(tally.result(), "")
    return LiveResult(n, t_first, t_last, why, feed.faults.text(), est.gaps, compute, wrote, errors)


def _why_stop(
    interrupted: bool,
    batch: list[Sample] | None,
    span: float,
    last_at: float | None,
    o: LiveOptions,
) -> str:
    """Why the loop ends now ("" while it goes on); ``last_at`` None: no timeout (a file)."""
    if interrupted:
        return "interrupted (Ctrl-C)"
    if batch is None:
        return "the end of the recording"
    if o.duration is not None and span >= o.duration:
        return f"{o.duration:g} s of stream estimated (--duration)"
    if not batch and last_at is not None and time.monotonic() - last_at > o.timeout:
        return f"no sample for {o.timeout:g} s: the publisher stopped"
    return ""


def _block(samples: list[Sample]) -> CausalBlock:
    """Samples as one block of arrays, time first."""
    s0 = samples[0]

    def stack(k: str) -> np.ndarray | None:
        if getattr(s0, k) is None:
            return None
        return np.array([getattr(s, k) for s in samples])

    return CausalBlock(
        t=np.array([s.t for s in samples]), q=stack("q"), tau=stack("tau"), dq=stack("dq"),
        dither=stack("dither"), tau_ffw=stack("ffw"), wrench=stack("wrench"),
    )  # fmt: skip

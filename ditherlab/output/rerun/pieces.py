"""The view of a recording logged a piece at a time, for logs longer than memory.

:func:`log_pieces` walks the pieces of a recording (:meth:`ditherlab.io.stream.Source.pieces`:
the rows each piece owns plus 2 s of context, the whole recording's time base) beside the same
rows of its estimates file (:class:`ditherlab.data.estimates.EstimatesSource`), computes each panel
on the piece and sends the owned rows, so the ``.rrd`` file grows as the pieces come and memory
holds one piece. What needs the whole recording is found first, in a pass over a few columns
(:class:`WholeView`): the time stamps (the 3D rate's samples, the band edges' span, the
recording id), the pushes of the F/T sensor, the dither period, and the cap of the interval
boxes. What runs across cuts carries its state: the thinning of constant runs
(:class:`ditherlab.output.rerun.columns.ColumnLogger`), the dither's on/off edges, the pushes' peaks and
the detections (:class:`ditherlab.output.rerun.events.EventLog`). The file holds the same rows and values
whatever the piece size; a recording in memory is logged as one piece.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
import rerun as rr

from ditherlab.analysis.detection import Push, find_pushes_in_blocks
from ditherlab.core.errors import FormatError
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.estimates import Estimates, EstimatesSource
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import Piece, Source
from ditherlab.output.diagnosis_report import DiagnosisLike
from ditherlab.output.rerun.columns import ColumnLogger, ViewSummary, decimate_index
from ditherlab.output.rerun.events import EventLog, log_commanded_pushes, log_diagnosis
from ditherlab.output.rerun.panels import (
    EXTRACT_SIGNALS,
    dither_period,
    external_sensor,
    log_bands,
    log_dither,
    log_forces,
    log_history,
    log_joints,
    log_residuals,
    tau_bar,
)
from ditherlab.output.rerun.robot3d import interval_caps, log_robot
from ditherlab.physics.effects import release, signals

__all__ = ["WholeView", "log_pieces", "recording_markdown"]


@dataclass
class WholeView:
    """What the view needs of the whole recording before its pieces are logged.

    Attributes
    ----------
    name, meta : the recording's ; n : joints ; t : (N,) [s] its time stamps
    has_wrench : F/T sensor columns ; has_flag : a ``dither`` column
    period : [s] the dither period the extraction panels use (:func:`ditherlab.output.rerun.panels.
        dither_period`), None without dither
    pushes : the F/T sensor's pushes (:func:`ditherlab.analysis.detection.find_pushes`)
    idx3d : (M,) the rows logged at the 3D rate (:func:`ditherlab.output.rerun.columns.decimate_index`)
    caps : [N] per variant, where an unbounded interval side is drawn
        (:func:`ditherlab.output.rerun.robot3d.interval_caps`)
    robot_label : the robot's short name ; sample_rate : [Hz] nominal
    """

    name: str | None
    meta: dict[str, Any]
    n: int
    t: np.ndarray
    has_wrench: bool
    has_flag: bool
    period: float | None
    pushes: list[Push]
    idx3d: np.ndarray
    caps: dict[str, float]
    robot_label: str
    sample_rate: float
    variants: list[str] = field(default_factory=list)
    #: [1/s] the time series' envelope bins per second (:func:`ditherlab.output.rerun.columns.
    #: envelope_mask`); None: every sample
    series_rate: float | None = None

    @property
    def duration(self) -> float:
        """t[-1] - t[0] [s]."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    @classmethod
    def of_recording(
        cls, rec: Recording, estimates: Estimates | None, rate_3d: float | None
    ) -> WholeView:
        """The whole-recording facts of a recording in memory (and its estimates)."""
        t = rec.t
        idx3d = decimate_index(t, rate_3d)
        est = EstimatesSource.of(estimates) if estimates is not None else None
        w = rec.wrench if rec.has_wrench else None
        pushes = [] if w is None else find_pushes_in_blocks(t, lambda: iter([w[:, :3]]))
        return cls(
            rec.name,
            rec.meta,
            rec.n,
            t,
            rec.has_wrench,
            rec.dither is not None,
            dither_period(rec, estimates if _has_extraction(est) else None),
            pushes,
            idx3d,
            _caps(est, idx3d, len(t)),
            rec.robot_label,
            rec.sample_rate,
            est.variants if est is not None else [],
        )

    @classmethod
    def of_source(
        cls,
        src: Source,
        first: Recording,
        est: EstimatesSource | None,
        rate_3d: float | None,
        chunk_rows: int,
    ) -> WholeView:
        """The whole-recording facts of a recording read in pieces (``first``: its first piece,
        for the joint count and robot), reading only the columns they need."""
        t = src.times()
        idx3d = decimate_index(t, rate_3d)
        has_wrench = all(c in src.columns for c in WRENCH_COLUMNS)
        cols = list(WRENCH_COLUMNS[:3])
        pushes = (
            find_pushes_in_blocks(
                t, lambda: (f.to_numpy(dtype=float) for f in src.frames(chunk_rows, cols))
            )
            if has_wrench
            else []
        )
        period = src.timebase().dither_period
        if _has_extraction(est):
            assert est is not None
            period = float(est.meta["dither_period"]) if est.meta.get("dither_period") else period
        return cls(
            src.name,
            src.meta,
            first.n,
            t,
            has_wrench,
            "dither" in src.columns,
            period,
            pushes,
            idx3d,
            _caps(est, idx3d, len(t), chunk_rows),
            first.robot_label,
            first.sample_rate,
            est.variants if est is not None else [],
        )


def _has_extraction(est: EstimatesSource | None) -> bool:
    """The estimates file holds the dither extraction replay wrote (``extract/*_1``)."""
    return est is not None and all(f"extract/{s}_1" in est.columns for s in EXTRACT_SIGNALS)


def _caps(
    est: EstimatesSource | None, idx3d: np.ndarray, n_rows: int, rows: int | None = None
) -> dict[str, float]:
    if est is None:
        return {}

    def blocks(cols: list[str]) -> Iterator[pd.DataFrame]:
        return est.blocks(rows or max(n_rows, 1), cols)

    return interval_caps(est.columns, est.variants, blocks, idx3d)


def recording_markdown(whole: WholeView, est: EstimatesSource | Estimates | None) -> str:
    """The ``info/recording`` document: the recording, its robot, sensor, dither, estimates."""
    lines = [
        f"# {whole.name or 'recording'}",
        "",
        f"- robot: {whole.robot_label}, {whole.n} joints",
        f"- {len(whole.t)} samples, {whole.duration:.2f} s, {whole.sample_rate:.1f} Hz",
        f"- F/T sensor: {'yes' if whole.has_wrench else 'no'}; dither flag: "
        f"{'yes' if whole.has_flag else 'no'}",
    ]
    if est is not None:
        iv = est.meta.get("interval", {})
        lines += [
            f"- estimates: {est.name}, variants {', '.join(est.variants)}",
            f"- interval: {iv.get('method', '?')} at level {iv.get('level', '?')}",
        ]
    lines += [
        "",
        "Force signs: the wrench the robot exerts on its environment (a push P shows as -P).",
    ]
    return "\n".join(lines)


def log_pieces(
    stream: rr.RecordingStream,
    whole: WholeView,
    pieces: Iterable[Piece],
    *,
    estimates: EstimatesSource | None = None,
    model: TorqueModel | None = None,
    diagnosis: DiagnosisLike | None = None,
    force_scale: float = 0.005,
    progress: Callable[[int, int], None] | None = None,
) -> ViewSummary:
    """Log a recording piece by piece (module docstring) to a Rerun stream.

    Parameters
    ----------
    stream : an open ``rerun.RecordingStream``
    whole : the whole recording's facts (:class:`WholeView`)
    pieces : the recording's pieces in order (owned rows tiling it)
    estimates : its estimates (same time stamps: checked by the caller), read in blocks of the
        pieces' owned rows
    model, diagnosis, force_scale : as for :func:`ditherlab.output.rerun.rerun_log.log_view`
    progress : ``progress(done, total)`` over the pieces

    Returns
    -------
    ViewSummary
        Row counts per entity as sent.
    """
    t0 = float(whole.t[0]) if len(whole.t) else 0.0
    log = ColumnLogger(stream, whole.t[:0], series_rate=whole.series_rate, t0=t0)
    log.summary.n_joints = whole.n
    log.summary.variants = list(whole.variants)
    stream.log(
        "info/recording",
        rr.TextDocument(recording_markdown(whole, estimates), media_type="text/markdown"),
        static=True,
    )
    if model is not None:
        stream.log(
            "info/model", rr.TextDocument(model.dumps(), media_type="text/plain"), static=True
        )
    span = whole.t[[0, -1]] if len(whole.t) > 1 else whole.t[:1]
    log_bands(log, whole.n, model, span)
    log_history(log, model)
    log_commanded_pushes(log, whole.meta)
    log_diagnosis(log, whole.name, diagnosis)
    events = EventLog(whole.pushes, whole.n)
    est_rows: Iterator[pd.DataFrame] | None = None
    for piece in pieces:
        a, b = piece.owned
        est = None
        if estimates is not None:
            if est_rows is None:  # blocks of the pieces' size: one per piece
                est_rows = estimates.blocks(b - a)
            block = next(est_rows, None)
            if block is None or len(block) != b - a:
                raise FormatError(
                    f"{estimates.name}: fewer rows than the recording {whole.name} "
                    f"(expected {len(whole.t)})"
                )
            est = estimates.estimates(block)
        _log_piece(log, whole, piece, est, model, force_scale, events)
        if piece.count > 1:  # a piece of a long log: its robot quantities go now
            release(piece.rec)
        # wait until the piece is written: the stream's batcher and sink would otherwise
        # queue the pieces as fast as they are computed, and memory grow with the log
        stream.flush()
        if progress is not None:
            progress(piece.index + 1, piece.count)
    events.finish(log)
    return log.summary


def _log_piece(
    log: ColumnLogger,
    whole: WholeView,
    piece: Piece,
    est: Estimates | None,
    model: TorqueModel | None,
    force_scale: float,
    events: EventLog,
) -> None:
    """Every panel of one piece: computed on its rows and context, sent for its owned rows."""
    rec, keep = piece.rec, piece.keep
    a, b = piece.owned
    log.next_piece(rec.t[keep], last=piece.index == piece.count - 1)
    own = whole.idx3d[(whole.idx3d >= a) & (whole.idx3d < b)] - a
    log_robot(log, rec, own + keep.start, est, own, whole.caps, force_scale)
    # gravity (L, n) [N·m], shared by tau_bar and the residuals: the piece's cached signals
    g = signals(rec).gravity
    tb = tau_bar(rec, g, model)
    log_joints(log, rec, keep, tb, external_sensor(rec), model)
    log_dither(log, rec, keep, est, g, tb, model, whole.period)
    log_forces(log, rec, keep, est)
    log_residuals(log, rec, keep, g, model)
    events.add(log, rec, keep, a, est)

"""Log a recording, its estimates, the torque model and a diagnosis to Rerun (``.rrd``).

Everything is sent as columns (``send_columns`` + one ``TimeColumn`` named ``time``, the
recording's ``t`` in seconds), one chunk per entity and piece of the recording; styling is
logged once as static data; the layout comes from :func:`ditherlab.output.rerun.blueprint.make_blueprint`.

This module holds the entry points (:func:`log_view`, :func:`save_view`, :func:`show_view`, and
:func:`save_view_pieces`, :func:`show_view_pieces` for a recording read in pieces;
the ``view`` command's workflow is :mod:`ditherlab.app.view`) and re-exports the public names of the modules that do
the work, each a job of its own:

- :mod:`ditherlab.output.rerun.inputs`: opening and checking the inputs (:func:`load_view_request`,
  :func:`load_estimates`, :func:`open_estimates`, :func:`check_estimates_match`)
- :mod:`ditherlab.output.rerun.pieces`: the loop over a recording's pieces (a long log is read and its
  ``.rrd`` written a piece at a time, ``--chunk ROWS``; a recording in memory is one piece) and
  what it needs of the whole recording first
- :mod:`ditherlab.output.rerun.columns`: sending columns (:class:`~ditherlab.output.rerun.columns.ColumnLogger`,
  :func:`thin_mask`, :func:`decimate_index`, the colours)
- :mod:`ditherlab.output.rerun.robot3d`: the robot, force arrows and interval boxes in 3D
- :mod:`ditherlab.output.rerun.panels`: the time series per joint (torques, bands, dither, residuals) and
  per force axis
- :mod:`ditherlab.output.rerun.events`: dither on/off, pushes, detections and the diagnosis as text logs
- :mod:`ditherlab.output.rerun.rrd`: reading an ``.rrd`` back (:func:`rrd_contents`, :func:`rrd_scalars`)

``rerun`` (about 1.5 s to import) is imported at the top of these modules: only the view loads
them (the CLI imports this module inside its ``view`` command, the demo when it writes its view).

Entity layout (``j`` = 1..n, ``a`` = x, y, z, ``V`` = estimator variant)::

    robot/links/<link>          Transform3D of each URDF link in the base frame   (rate_3d)
    robot/skeleton              line strip through the link origins               (rate_3d)
    robot/force/sensor          arrow of the F/T sensor force at the tool point   (rate_3d)
    robot/force/V               arrow of the estimated force                      (rate_3d)
    robot/force/V/interval      box spanned by the interval [lo, hi] per axis     (rate_3d)
    joints/j/tau                logged motor torque [N·m]
    joints/j/tau_bar            [tau - gravity(q) (- the model's effects), J^T F_sensor] [N·m]
    joints/j/band/<regime>      friction band edges [min, max] of the model [N·m]
    joints/j/dither/ffw         torque feedforward sent (dither square wave + centre) [N·m]
    joints/j/dither/centre/<s>  Fig. 5 centre: recording columns such as ``centre_ref_j``,
                                ``dither_centre_meas_j``
    joints/j/dither/amplitude/<s>  Fig. 5 amplitude: ``extracted`` ((upper - lower) / 2) and the
                                recording's columns such as ``amp_ref_j``
    joints/j/extract            [upper, lower, signal, centre, gravity] (the extraction: the
                                estimates file's columns where present; centre = window mean;
                                gravity = the centre's reference)
    joints/j/fig4/signal_bar    extracted signal - gravity (- effects) [N·m]
    joints/j/band/dither_shrunk the still band shrunk by the extracted amplitude under dither
    joints/j/residual/v<k>      friction residual of model version k [N·m]
    force/a/sensor              sensor force [N]
    force/a/V                   [estimate, lo, hi] of variant V [N]
    force/a/online              the recording's ``fhat_a`` column: an estimate used online [N]
    history/torque_rms/j        bar chart: residual RMS per model version (model history)
    events/dither_flag          the dither flag as a 0/1 series
    events/dither, events/pushes, events/pushes_simulated, events/detections/V, diagnosis
                                text logs (dither on/off; pushes found in the F/T sensor and the
                                simulator's own; detections per variant; worst windows)
    info/recording, info/model, info/history, info/diagnosis    text documents (static)

Forces are the wrench the robot exerts on its environment (``docs/recording-format.md``): a push
P shows as -P.

Series that stay constant over runs of samples (dither extraction, loop outputs, estimates held
at the prior) are thinned losslessly: a sample is dropped only when it equals both neighbours, so
the plotted line (linear or step) is exactly the full-rate one and every logged value is a value
of the input, bit for bit.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ditherlab.core.errors import DitherlabError
from ditherlab.core.files import atomic_path, check_not_input, json_default
from ditherlab.data.estimates import Estimates, EstimatesSource, check_estimates_match
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Piece, Source
from ditherlab.output.diagnosis_report import DiagnosisLike
from ditherlab.output.rerun.blueprint import make_blueprint
from ditherlab.output.rerun.columns import (
    REGIME_COLORS,
    SENSOR_COLOR,
    TIMELINE,
    VARIANT_COLORS,
    ViewSummary,
    decimate_index,
    thin_mask,
)
from ditherlab.output.rerun.events import DETECTION_MERGE_GAP, merge_spans
from ditherlab.output.rerun.inputs import (
    ViewRequest,
    load_estimates,
    load_view_request,
    open_estimates,
)
from ditherlab.output.rerun.panels import dither_period, model_versions, residual, tau_bar
from ditherlab.output.rerun.pieces import WholeView, log_pieces
from ditherlab.output.rerun.rrd import rrd_contents, rrd_rows, rrd_scalars

__all__ = [
    "DETECTION_MERGE_GAP",
    "REGIME_COLORS",
    "SENSOR_COLOR",
    "TIMELINE",
    "VARIANT_COLORS",
    "WEB_PORT",
    "PiecesView",
    "ViewRequest",
    "ViewSummary",
    "check_estimates_match",
    "decimate_index",
    "dither_period",
    "load_estimates",
    "load_view_request",
    "open_estimates",
    "log_view",
    "log_view_pieces",
    "merge_spans",
    "model_versions",
    "new_stream",
    "residual",
    "rrd_contents",
    "rrd_rows",
    "rrd_scalars",
    "save_view",
    "save_view_pieces",
    "show_view",
    "show_view_pieces",
    "tau_bar",
    "thin_mask",
]

WEB_PORT = 9090


def log_view(
    rec: Recording,
    stream: rr.RecordingStream,
    *,
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: DiagnosisLike | None = None,
    rate_3d: float | None = 25.0,
    force_scale: float = 0.005,
    progress: Callable[[int, int], None] | None = None,
    series_rate: float | None = None,
) -> ViewSummary:
    """Log a recording (and optionally estimates, model and diagnosis) to a Rerun stream.

    Parameters
    ----------
    rec : the recording (``t (N,)`` [s], ``q (N, n)`` [rad], ``tau (N, n)`` [N·m], ...)
    stream : an open ``rerun.RecordingStream`` (file sink, memory sink, viewer)
    estimates : estimates of this recording (checked with :func:`check_estimates_match`)
    model : torque model; gives the band edges, the effects in ``tau_bar`` and the residuals
    diagnosis : a diagnosis (candidates at worst windows), optional: ``load_report`` of the
        report.json of ``ditherlab diagnose -o``, or a ``ditherlab.analysis.diagnosis.Diagnosis``
    rate_3d : [Hz] rate of the 3D entities (robot pose, arrows, boxes); None = every sample.
        Time series are logged at full rate unless ``series_rate`` is given.
    force_scale : [m/N] length of a force arrow per newton in the 3D view
    progress : callable(done, total), optional
    series_rate : [1/s] the time series decimated to their envelope in bins of
        ``1 / series_rate`` seconds (:func:`ditherlab.output.rerun.columns.envelope_mask`: per bin its
        first and last samples and each column's extremes, values bit for bit); None = every
        sample (after the lossless thinning)

    Returns
    -------
    ViewSummary
        Row counts per entity as sent (read the file back to verify them).
    """
    if estimates is not None:
        check_estimates_match(rec, estimates)
    if progress is not None:
        progress(0, 1)
    whole = WholeView.of_recording(rec, estimates, rate_3d)
    whole.series_rate = series_rate
    return log_pieces(
        stream,
        whole,
        [Piece(rec, 0, slice(0, len(rec)), 0, 1)],
        estimates=EstimatesSource.of(estimates) if estimates is not None else None,
        model=model,
        diagnosis=diagnosis,
        force_scale=force_scale,
        progress=progress,
    )


@dataclass(frozen=True)
class PiecesView:
    """A recording read in pieces and what its view shows.

    Attributes
    ----------
    src : the recording, read ``chunk_rows`` rows at a time
    head : its first rows with its time base (:func:`ditherlab.output.rerun.inputs.
        load_view_request`)
    estimates : its estimates, read in blocks of the pieces' rows (checked against the
        recording by the caller)
    model, diagnosis : as for :func:`log_view`
    rate_3d : [Hz] rate of the 3D entities; None = every sample
    series_rate : [1/s] the time series' envelope bins per second; None = every sample
    chunk_rows : rows of a piece
    """

    src: Source
    head: Recording
    estimates: EstimatesSource | None = None
    model: TorqueModel | None = None
    diagnosis: DiagnosisLike | None = None
    rate_3d: float | None = 25.0
    series_rate: float | None = None
    chunk_rows: int = CHUNK_ROWS

    def stream(self) -> rr.RecordingStream:
        """A RecordingStream whose id is derived from the inputs (:func:`new_stream`)."""
        return _stream(
            json.dumps(self.src.meta, sort_keys=True), self.src.times(), self.estimates, self.model
        )

    def blueprint(self) -> rrb.Blueprint:
        """The view's layout (:func:`~ditherlab.output.rerun.blueprint.make_blueprint`)."""
        variants = self.estimates.variants if self.estimates else []
        return make_blueprint(self.head.n, variants, has_wrench=self.head.has_wrench)


def log_view_pieces(
    view: PiecesView,
    stream: rr.RecordingStream,
    *,
    force_scale: float = 0.005,
    progress: Callable[[int, int], None] | None = None,
) -> ViewSummary:
    """:func:`log_view` of a recording read in pieces (``view``,
    :func:`ditherlab.output.rerun.pieces.log_pieces`): the same rows and values, memory for one
    piece (and 8 bytes per sample for the time stamps)."""
    if progress is not None:
        progress(0, 1)
    v = view
    whole = WholeView.of_source(v.src, v.head, v.estimates, v.rate_3d, v.chunk_rows)
    whole.series_rate = v.series_rate
    return log_pieces(
        stream,
        whole,
        v.src.pieces(v.chunk_rows),
        estimates=v.estimates,
        model=v.model,
        diagnosis=v.diagnosis,
        force_scale=force_scale,
        progress=progress,
    )


# ---------------------------------------------------------------------- entry points
def new_stream(
    rec: Recording,
    estimates: Estimates | EstimatesSource | None = None,
    model: TorqueModel | None = None,
    application_id: str = "ditherlab",
) -> rr.RecordingStream:
    """A RecordingStream whose recording id is derived from its inputs.

    The same recording, estimates and model give the same id (the viewer shows a re-written file
    in place of the old one); another recording or other estimates of it give another id (the
    viewer keeps them apart instead of merging them).
    """
    return _stream(rec.meta_json(), rec.t, estimates, model, application_id)


def _stream(
    meta_json: str,
    t: np.ndarray,
    estimates: Estimates | EstimatesSource | None,
    model: TorqueModel | None,
    application_id: str = "ditherlab",
) -> rr.RecordingStream:
    """:func:`new_stream` from the recording's metadata (JSON) and time stamps (N,) [s]."""
    h = hashlib.sha256()
    h.update(meta_json.encode())
    h.update(np.asarray(t).tobytes())
    if estimates is not None:
        h.update(json.dumps(estimates.meta, sort_keys=True, default=json_default).encode())
    if model is not None:
        h.update(model.dumps().encode())
    return rr.RecordingStream(application_id, recording_id=h.hexdigest()[:32])


def save_view(
    rec: Recording,
    path: str | Path,
    *,
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: DiagnosisLike | None = None,
    inputs: Sequence[str | Path] = (),
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
    series_rate: float | None = None,
) -> ViewSummary:
    """Write the view of ``rec`` to an ``.rrd`` file atomically; see :func:`log_view`.

    Raises DitherlabError when ``path`` is one of ``inputs``.
    """
    out = _check_out(path, [*inputs, *([rec.name] if rec.name else [])])
    if estimates is not None:
        check_estimates_match(rec, estimates)
    stream = new_stream(rec, estimates, model)
    bp = make_blueprint(rec.n, estimates.variants if estimates else [], has_wrench=rec.has_wrench)
    kw = {"estimates": estimates, "model": model, "diagnosis": diagnosis, "rate_3d": rate_3d}
    kw["series_rate"] = series_rate
    return _save(out, stream, bp, lambda: log_view(rec, stream, progress=progress, **kw))


def save_view_pieces(
    view: PiecesView,
    path: str | Path,
    *,
    inputs: Sequence[str | Path] = (),
    progress: Callable[[int, int], None] | None = None,
) -> ViewSummary:
    """Write the view of a recording read in pieces to an ``.rrd`` file as the pieces come
    (Rerun's file sink streams; the file is renamed into place at the end); see
    :func:`log_view_pieces`. Raises DitherlabError when ``path`` is one of ``inputs``."""
    out = _check_out(path, [*inputs, view.src.name])
    stream = view.stream()
    return _save(
        out, stream, view.blueprint(), lambda: log_view_pieces(view, stream, progress=progress)
    )


def _check_out(path: str | Path, inputs: Sequence[str | Path]) -> Path:
    out = Path(path)
    if out.suffix != ".rrd":
        raise DitherlabError(f"{out}: a Rerun recording must end in .rrd")
    check_not_input(out, inputs)
    return out


def _save(
    out: Path, stream: rr.RecordingStream, bp: rrb.Blueprint, log: Callable[[], ViewSummary]
) -> ViewSummary:
    """Run ``log`` with ``stream`` saving to a temporary file renamed onto ``out``."""
    with atomic_path(out) as tmp:
        stream.save(tmp, default_blueprint=bp)
        try:
            summary = log()
        finally:
            stream.flush()
            stream.disconnect()
    return summary


def show_view(
    rec: Recording,
    *,
    mode: str = "spawn",
    estimates: Estimates | None = None,
    model: TorqueModel | None = None,
    diagnosis: DiagnosisLike | None = None,
    rate_3d: float | None = 25.0,
    progress: Callable[[int, int], None] | None = None,
) -> str | None:
    """Send the view to a viewer: ``mode="spawn"`` starts the native viewer (``rr.spawn``),
    ``mode="serve"`` serves it over gRPC and a web viewer (``rr.serve_grpc`` +
    ``rr.serve_web_viewer``) and returns the web viewer's URL; the servers live as long as this
    process (see :func:`ditherlab.app.view.wait_until_interrupted`).
    """
    stream = new_stream(rec, estimates, model)
    bp = make_blueprint(rec.n, estimates.variants if estimates else [], has_wrench=rec.has_wrench)
    url = _connect(stream, bp, mode)
    log_view(
        rec,
        stream,
        estimates=estimates,
        model=model,
        diagnosis=diagnosis,
        rate_3d=rate_3d,
        progress=progress,
    )
    stream.flush()
    return url


def show_view_pieces(
    view: PiecesView,
    *,
    mode: str = "spawn",
    progress: Callable[[int, int], None] | None = None,
) -> tuple[ViewSummary, str | None]:
    """:func:`show_view` of a recording read in pieces (:func:`log_view_pieces`); returns what
    was logged and the web viewer's URL (``mode="serve"``)."""
    stream = view.stream()
    url = _connect(stream, view.blueprint(), mode)
    summary = log_view_pieces(view, stream, progress=progress)
    stream.flush()
    return summary, url


def _connect(stream: rr.RecordingStream, bp: rrb.Blueprint, mode: str) -> str | None:
    """Start the viewer of ``mode`` for ``stream``; the web viewer's URL for ``"serve"``."""
    if mode == "spawn":
        rr.spawn(recording=stream, default_blueprint=bp)
        return None
    if mode == "serve":
        grpc = rr.serve_grpc(recording=stream, default_blueprint=bp)
        rr.serve_web_viewer(web_port=WEB_PORT, connect_to=grpc, open_browser=False)
        return f"http://localhost:{WEB_PORT}/?url={grpc}"
    raise DitherlabError(f"view mode is {mode!r}, expected 'spawn' or 'serve'")

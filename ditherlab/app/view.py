"""``ditherlab view``: open and check a recording, its estimates, model and diagnosis, then write
the Rerun view to an ``.rrd`` file or show it in a viewer (:mod:`ditherlab.output.rerun`).

Files are read in pieces (:func:`run`); recordings, estimates and models already in memory are
viewed whole (:func:`view`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from ditherlab.analysis.diagnosis import Diagnosis
from ditherlab.app.workflow import Progress, ReadOptions, as_model, as_recording, guard
from ditherlab.core.errors import ConfigError
from ditherlab.core.files import FileKind
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS
from ditherlab.output.diagnosis_report import DiagnosisReport, load_report
from ditherlab.output.rerun.columns import ViewSummary
from ditherlab.output.rerun.inputs import load_estimates, load_view_request
from ditherlab.output.rerun.rerun_log import (
    PiecesView,
    save_view,
    save_view_pieces,
    show_view,
    show_view_pieces,
)

__all__ = [
    "RRD_FILE",
    "ViewOptions",
    "ViewResult",
    "run",
    "save_view_files",
    "view",
    "view_mode",
    "wait_until_interrupted",
]

#: the file that ``view --save`` writes
RRD_FILE = FileKind("a Rerun recording", (".rrd",), "view.rrd")


@dataclass(frozen=True)
class ViewOptions:
    """The options of ``ditherlab view``.

    Attributes
    ----------
    recording : the recording (any readable format)
    estimates : the estimates of this recording (``ditherlab replay``)
    model : the torque model (bands, residuals)
    diagnosis : the ``report.json`` of ``ditherlab diagnose -o``
    save : the ``.rrd`` file to write; or None with a ``mode``
    mode : ``"spawn"`` (open the Rerun viewer) or ``"serve"`` (serve to a web viewer); or None
        with ``save``
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read and logged at a time
    rate_3d : [Hz] rate of the 3D entities (robot pose, arrows); None: every sample
    series_rate : [1/s] the time series decimated to their envelope in bins of
        ``1 / series_rate`` seconds; None: every sample
    force : replace an existing ``.rrd`` file
    """

    recording: Path
    estimates: Path | None = None
    model: Path | None = None
    diagnosis: Path | None = None
    save: str | Path | None = None
    mode: str | None = None
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS
    rate_3d: float | None = 25.0
    series_rate: float | None = None
    force: bool = False


@dataclass
class ViewResult:
    """What a view did: the file written (or the URL served) and what was logged (row counts
    per entity; None for a view of a recording in memory sent to a viewer)."""

    summary: ViewSummary | None
    path: Path | None = None
    url: str | None = None

    def text(self) -> str:
        """Where the view went (what the CLI prints)."""
        if self.path is not None:
            rows = sum(self.summary.rows.values()) if self.summary is not None else 0
            return f"wrote {self.path} ({rows} rows); open it with: rerun {self.path}"
        if self.url:
            return f"serving the view at {self.url} (Ctrl-C stops)"
        return "sent the view to the Rerun viewer"


def view_mode(spawn: bool, serve: bool) -> str | None:
    """``"spawn"``, ``"serve"`` or None from the two switches; ConfigError for both."""
    if spawn and serve:
        raise ConfigError("view: choose one of --spawn and --serve")
    return "spawn" if spawn else "serve" if serve else None


def run(options: ViewOptions, progress: Progress | None = None) -> ViewResult:
    """Check every input (:func:`ditherlab.output.rerun.inputs.load_view_request`) and the
    output, then write or show the view, the recording and its estimates read in pieces.

    Parameters
    ----------
    options : :class:`ViewOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    ViewResult
    """
    o = options
    inputs = [o.recording, o.estimates, o.model, o.diagnosis]
    if o.save is not None:
        guard(o.save, inputs, read=o.read, kind=RRD_FILE, force=o.force)
    req = load_view_request(
        o.recording,
        estimates=o.estimates,
        model=o.model,
        diagnosis=o.diagnosis,
        save=o.save,
        mode=o.mode,
        read_options=o.read.kwargs(),
    )
    pv = PiecesView(
        req.src,
        req.head,
        estimates=req.estimates,
        model=req.model,
        diagnosis=req.diagnosis,
        rate_3d=o.rate_3d,
        series_rate=o.series_rate,
        chunk_rows=o.chunk_rows,
    )
    if req.save is not None:
        summary = save_view_pieces(pv, req.save, inputs=req.inputs, progress=progress)
        return ViewResult(summary, path=req.save)
    summary, url = show_view_pieces(pv, mode=str(req.mode), progress=progress)
    return ViewResult(summary, url=url)


def view(
    recording: Recording | str | Path,
    *,
    estimates: Estimates | str | Path | None = None,
    model: TorqueModel | str | Path | None = None,
    diagnosis: Diagnosis | DiagnosisReport | str | Path | None = None,
    save: str | Path | None = None,
    mode: str | None = None,
    force: bool = False,
    progress: Progress | None = None,
) -> ViewResult:
    """The view of inputs given as objects or paths: files only are read in pieces
    (:func:`run`); with any object in memory, everything is read whole and viewed at once."""
    given = (recording, estimates, model, diagnosis)
    if all(x is None or isinstance(x, str | Path) for x in given):
        opts = ViewOptions(
            Path(recording), *(None if x is None else Path(x) for x in given[1:]),
            save=save, mode=mode, force=force,
        )  # fmt: skip
        return run(opts, progress)
    if (save is None) == (mode is None):
        raise ConfigError("view needs exactly one output: --save out.rrd, --spawn or --serve")
    rec = as_recording(recording)
    est = load_estimates(estimates) if isinstance(estimates, str | Path) else estimates
    mdl = as_model(model) if model is not None else None
    diag = load_report(diagnosis) if isinstance(diagnosis, str | Path) else diagnosis
    kw = {"estimates": est, "model": mdl, "diagnosis": diag, "progress": progress}
    if save is not None:
        files = [x for x in given if isinstance(x, str | Path)]
        out = guard(save, [*files, rec.name], kind=RRD_FILE, force=force)
        return ViewResult(save_view(rec, out, inputs=files, **kw), path=out)
    return ViewResult(None, url=show_view(rec, mode=mode, **kw))


def save_view_files(
    recording: str | Path,
    out: str | Path,
    *,
    estimates: str | Path | None = None,
    model: str | Path | None = None,
    diagnosis: str | Path | None = None,
    rate_3d: float | None = 25.0,
    series_rate: float | None = None,
    progress: Progress | None = None,
) -> Path:
    """Open the files, check them and write (or replace) the view in ``out`` (``.rrd``),
    reading the recording in pieces; returns ``out``. The one call a script (``make demo``)
    needs; ``rate_3d`` and ``series_rate`` as in :class:`ViewOptions`."""
    o = ViewOptions(
        Path(recording),
        estimates=None if estimates is None else Path(estimates),
        model=None if model is None else Path(model),
        diagnosis=None if diagnosis is None else Path(diagnosis),
        save=out,
        rate_3d=rate_3d,
        series_rate=series_rate,
        force=True,
    )
    run(o, progress)
    return Path(out)


def wait_until_interrupted() -> None:
    """Block until Ctrl-C (keeps the servers of a served view alive)."""
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        return

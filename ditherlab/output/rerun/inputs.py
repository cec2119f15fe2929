"""The view's inputs, opened and checked before anything is logged or written: the recording
(read in pieces later), the estimates file (and that it comes from the recording), the model
(for the recording's robot), the diagnosis (:func:`ditherlab.output.diagnosis_report.load_report`), and
the one output.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ditherlab.core.errors import ConfigError, FormatError, RecordingError
from ditherlab.core.files import check_not_input
from ditherlab.data.estimates import VARIANTS, Estimates, EstimatesSource, check_times_match
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import Source, open_source
from ditherlab.output.diagnosis_report import DiagnosisReport, load_report


# ---------------------------------------------------------------------- estimates file
def load_estimates(path: str | Path) -> Estimates:
    """Read an estimates file whole (:meth:`ditherlab.data.estimates.Estimates.load`) and check its
    columns (:func:`open_estimates`)."""
    open_estimates(path)
    return Estimates.load(path)


def open_estimates(path: str | Path) -> EstimatesSource:
    """Open an estimates file to be read a block of rows at a time and check its columns.

    Raises
    ------
    FormatError
        Missing or unreadable file, not an estimates file, or a listed variant without columns.
    """
    est = EstimatesSource(path)
    if "t" not in est.columns:
        raise FormatError(f"{path}: required column t is missing")
    for v in est.variants:
        if v not in VARIANTS:
            raise FormatError(f"{path}: metadata lists variant {v!r}, expected one of {VARIANTS}")
        missing = [c for c in (f"{v}/f_x", f"{v}/f_y", f"{v}/f_z") if c not in est.columns]
        if missing:
            raise FormatError(f"{path}: column {missing[0]} is missing (variant {v} is listed)")
    return est


# ---------------------------------------------------------------------- the request
@dataclass
class ViewRequest:
    """Inputs of ``ditherlab view``, opened and checked: see :func:`load_view_request`.

    ``src`` is the recording read in pieces, ``head`` its first rows (robot, joints, rate) with
    the whole recording's time base, ``estimates`` the estimates file read in blocks."""

    src: Source
    head: Recording
    estimates: EstimatesSource | None = None
    model: TorqueModel | None = None
    save: Path | None = None
    mode: str | None = None
    inputs: list[Path] = field(default_factory=list)
    diagnosis: DiagnosisReport | None = None


def load_view_request(
    recording: str | Path,
    *,
    estimates: str | Path | None = None,
    model: str | Path | None = None,
    diagnosis: str | Path | None = None,
    save: str | Path | None = None,
    mode: str | None = None,
    read_options: Mapping[str, Any] | None = None,
) -> ViewRequest:
    """Open and check every input of a view before anything is logged or written.

    Exactly one of ``save`` (an ``.rrd`` path) and ``mode`` (``"spawn"`` or ``"serve"``) must be
    given; the estimates must come from the recording (the same time stamps, read a column at a
    time, and recording metadata); the model must be for its robot. ``read_options`` go to
    :func:`ditherlab.io.stream.open_source` (``mapping``, ``robot`` for foreign logs). The
    recording and the estimates are read in pieces when the view is logged.

    Raises
    ------
    DitherlabError
        Missing or unreadable files, estimates from another recording, no or two outputs.
    """
    if (save is None) == (mode is None):
        raise ConfigError("view needs exactly one output: --save out.rrd, --spawn or --serve")
    if mode is not None and mode not in ("spawn", "serve"):
        raise ConfigError(f"view mode is {mode!r}, expected 'spawn' or 'serve'")
    if save is not None and Path(save).suffix != ".rrd":
        raise ConfigError(f"{save}: a Rerun recording must end in .rrd")
    src = open_source(recording, **dict(read_options or {}))
    head = _head(src)
    est = open_estimates(estimates) if estimates is not None else None
    if est is not None:
        check_times_match(
            src.times(), src.meta, src.name, est.column("t").astype(float), est.meta, est.name
        )
    mdl = TorqueModel.load(model) if model is not None else None
    if mdl is not None:
        mdl.check_robot(head)
    diag = load_report(diagnosis) if diagnosis is not None else None
    inputs = [Path(p) for p in (recording, estimates, model, diagnosis) if p is not None]
    if save is not None:
        check_not_input(save, inputs)
    out = Path(save) if save is not None else None
    return ViewRequest(src, head, est, mdl, out, mode, inputs, diag)


def _head(src: Source) -> Recording:
    """The first rows of a recording (at most 256) with its whole time base: its robot, joint
    count and sample rate."""
    data = next(src.frames(256), None)
    if data is None or not len(data):
        raise RecordingError(f"{src.name}: the recording has no rows")
    return Recording(data.iloc[:256].reset_index(drop=True), src.meta, src.name, src.timebase())

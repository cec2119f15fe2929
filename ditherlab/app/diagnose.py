"""``ditherlab diagnose``: read recordings and a model, diagnose, write the report folder and the
model with its history row.

The model file given is an input and keeps its bytes: the history row (what this diagnosis
found, and on which recordings) goes into a copy of the model written into the report folder,
``DIR/model.toml`` (:data:`HISTORY_MODEL`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ditherlab.analysis.diagnosis import Diagnosis, diagnose, with_history_row
from ditherlab.analysis.rest import kept_stretches, scan_rest
from ditherlab.app.workflow import Progress, ReadOptions, guard
from ditherlab.core.files import all_or_nothing
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Source, open_source
from ditherlab.output.diagnosis_report import write_report

__all__ = ["HISTORY_MODEL", "DiagnoseOptions", "Diagnosed", "run", "with_history_row"]

#: the model with the diagnosis's history row, in the report folder
HISTORY_MODEL = "model.toml"


@dataclass(frozen=True)
class DiagnoseOptions:
    """The options of ``ditherlab diagnose``.

    Attributes
    ----------
    recordings : recordings of the model's robot (with an F/T sensor for the force error)
    model : the torque model (TOML); read only
    out : the report folder (``report.md``, ``report.json``, PNG figures and
        :data:`HISTORY_MODEL`, the model with the history row), or None: nothing is written
    history : write the model with the diagnosis's history row into ``out``
    regimes : score only these regimes (``still``, ``dither``, ``moving``); None: all
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read and processed at a time
    force : write into an existing non-empty folder
    """

    recordings: tuple[Path, ...]
    model: Path
    out: str | Path | None = None
    history: bool = True
    regimes: tuple[str, ...] | None = None
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS
    force: bool = False


@dataclass
class Diagnosed:
    """What :func:`run` found and wrote: the diagnosis (its ``model`` carries the history row
    when one was written), the report folder, and the model file with the row."""

    diagnosis: Diagnosis
    out: Path | None = None
    model_path: Path | None = None

    def text(self) -> str:
        """The plain-words summary (what the CLI prints)."""
        return self.diagnosis.summary()

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output: :meth:`ditherlab.analysis.diagnosis.Diagnosis.to_dict`."""
        return self.diagnosis.to_dict()


def run(options: DiagnoseOptions, progress: Progress | None = None) -> Diagnosed:
    """Diagnose the recordings (read in pieces of ``chunk_rows`` rows) against the model; with
    ``out``, write the report and (``history``) the model with its new history row into it,
    all or nothing.

    Parameters
    ----------
    options : :class:`DiagnoseOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    Diagnosed
    """
    o = options
    if o.out is None:
        return Diagnosed(_diagnose(o, progress))
    out = guard(o.out, [*o.recordings, o.model], read=o.read, folder=True, force=o.force)
    with all_or_nothing(out):
        d = _diagnose(o, progress)
        path: Path | None = None
        if o.history:
            d.model = d.recorded()
            path = d.model.save(out / HISTORY_MODEL)
        write_report(d, out)
    return Diagnosed(d, out, path)


def _diagnose(o: DiagnoseOptions, progress: Progress | None) -> Diagnosis:
    model = TorqueModel.load(o.model)
    recs: list[Recording | Source] = []
    notes: list[str] = []
    for p in o.recordings:
        src = open_source(p, **o.read.kwargs())
        parts, note = _without_departures(src, model)
        recs += parts
        notes += note
    d = diagnose(recs, model, regimes=o.regimes or None, progress=progress, chunk_rows=o.chunk_rows)
    # a log cut in stretches: named and noted once
    d.notes[:] = list(dict.fromkeys([*notes, *d.notes]))
    d.recordings[:] = list(dict.fromkeys(d.recordings))
    return d


def _without_departures(
    src: Source, model: TorqueModel
) -> tuple[list[Recording | Source], list[str]]:
    """A log without an F/T sensor as the stretches between its departures from rest
    (:func:`ditherlab.analysis.rest.scan_rest`, the pushes identify leaves out too: forces, not
    a model error), each at least :data:`~ditherlab.analysis.rest.MIN_STRETCH_S` long, with a
    note; any other log as it is."""
    if "f_x" in src.columns:
        return [src], []
    rec = src.read()
    found = scan_rest(rec, model)
    if not found.events:
        return [rec], []
    parts: list[Recording | Source] = list(kept_stretches(rec, found.spans()))
    spans = ", ".join(f"{e.start:.1f}-{e.end:.1f} s" for e in found.events)
    note = (
        f"{src.name}: no F/T sensor: {len(found.events)} departures from rest (pushes: {spans}) "
        f"not scored, as identify leaves them out"
    )
    return parts, [note]

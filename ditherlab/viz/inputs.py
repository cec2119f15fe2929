"""The view's inputs, read and checked before anything is logged or written: the estimates
file (and that it comes from the recording), the model (for the recording's robot), the
diagnosis (:func:`ditherlab.viz.diagnosis.load_report`), and the one output.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.errors import ConfigError, FormatError, RecordingError
from ditherlab.estimates import VARIANTS, Estimates
from ditherlab.io import read
from ditherlab.io.atomic import check_not_input, plain
from ditherlab.model import TorqueModel
from ditherlab.recording import Recording
from ditherlab.viz.diagnosis import DiagnosisReport, load_report


# ---------------------------------------------------------------------- estimates file
def load_estimates(path: str | Path) -> Estimates:
    """Read an estimates file with :meth:`ditherlab.replay.Estimates.load` and check its columns.

    Raises
    ------
    FormatError
        Missing or unreadable file, not an estimates file, or a listed variant without columns.
    """
    est = Estimates.load(path)
    if "t" not in est.data.columns:
        raise FormatError(f"{path}: required column t is missing")
    for v in est.variants:
        if v not in VARIANTS:
            raise FormatError(f"{path}: metadata lists variant {v!r}, expected one of {VARIANTS}")
        missing = [c for c in (f"{v}/f_x", f"{v}/f_y", f"{v}/f_z") if c not in est.data.columns]
        if missing:
            raise FormatError(f"{path}: column {missing[0]} is missing (variant {v} is listed)")
    return est


def check_estimates_match(rec: Recording, est: Estimates) -> None:
    """Raise RecordingError unless ``est`` was computed from ``rec``.

    The time stamps must be identical (same count, same values) and the recording metadata stored
    in the estimates file must equal ``rec.meta``.

    Raises
    ------
    RecordingError
        One sentence naming both files and the first difference.
    """
    ename = est.name or "estimates"
    rname = rec.name or "the recording"
    t_rec, t_est = rec.t, est.data["t"].to_numpy(dtype=float)
    if len(t_rec) != len(t_est):
        raise RecordingError(
            f"{ename}: the estimates come from another recording: column t has {len(t_est)} "
            f"samples, {rname} has {len(t_rec)}"
        )
    diff = np.flatnonzero(t_rec != t_est)
    if diff.size:
        i = int(diff[0])
        raise RecordingError(
            f"{ename}: the estimates come from another recording: t in row {i + 1} is "
            f"{t_est[i]!r} s, {rname} has {t_rec[i]!r} s"
        )
    stored = est.meta.get("recording")
    if stored is None:
        raise RecordingError(f"{ename}: metadata key 'recording' is missing")
    # both as plain JSON values (tuples as lists, numpy values as Python ones); a recording's
    # metadata is JSON by contract (Recording.meta_json), so no other conversion is needed
    a, b = plain(stored), plain(rec.meta)
    if a != b:
        key = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
        raise RecordingError(
            f"{ename}: the estimates come from another recording: metadata key {key!r} is "
            f"{_short(a.get(key))}, {rname} has {_short(b.get(key))}"
        )


def _short(v: Any, width: int = 60) -> str:
    s = repr(v)
    return s if len(s) <= width else s[: width - 3] + "..."


# ---------------------------------------------------------------------- the request
@dataclass
class ViewRequest:
    """Inputs of ``ditherlab view``, read and checked: see :func:`load_view_request`."""

    rec: Recording
    estimates: Estimates | None = None
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
    """Read and check every input of a view before anything is logged or written.

    Exactly one of ``save`` (an ``.rrd`` path) and ``mode`` (``"spawn"`` or ``"serve"``) must be
    given; the estimates must come from the recording; the model must be for its robot.
    ``read_options`` go to :func:`ditherlab.io.read` (``mapping``, ``robot`` for foreign logs).

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
    rec = read(recording, **dict(read_options or {}))
    est = load_estimates(estimates) if estimates is not None else None
    if est is not None:
        check_estimates_match(rec, est)
    mdl = TorqueModel.load(model) if model is not None else None
    if mdl is not None:
        mdl.check_robot(rec)
    diag = load_report(diagnosis) if diagnosis is not None else None
    inputs = [Path(p) for p in (recording, estimates, model, diagnosis) if p is not None]
    if save is not None:
        check_not_input(save, inputs)
    return ViewRequest(rec, est, mdl, Path(save) if save is not None else None, mode, inputs, diag)

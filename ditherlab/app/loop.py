"""The diagnosis loop's workflow: add an effect to a model, re-fit, and the file-level commands.

``identify --add NAME`` and the library call :func:`add_effect`: the joints are chosen by
diagnosis (:func:`ditherlab.analysis.scoring.select_joints`; an effect of the measurement pipeline,
:attr:`~ditherlab.physics.effects.Effect.on_every_joint`, goes on every joint where it acts), the
effect is fitted on the band-aware residual (:mod:`ditherlab.physics.effect_fit`), refused when the bands
could take it (:func:`ditherlab.physics.effect_fit.identifiability`), and the bands re-identified with it in
place (:func:`ditherlab.analysis.identification.identify`). This module sits above both identify and diagnose, so
neither has to know the other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from ditherlab.analysis.diagnosis import Diagnosis, append_history, diagnose
from ditherlab.analysis.identification import identify
from ditherlab.analysis.scoring import select_joints
from ditherlab.core.errors import ModelError
from ditherlab.core.files import check_not_input
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, open_source
from ditherlab.output.diagnosis_report import write_report
from ditherlab.physics.dither import has_dither
from ditherlab.physics.effect_fit import fit_effect, not_identifiable, pool_weak_joints, pooled_note
from ditherlab.physics.effects import clean_none, get_effect, make_spec, signals
from ditherlab.physics.residual import scored

__all__ = ["add_effect", "diagnose_files", "identify_files"]


def add_effect(
    model: TorqueModel,
    recs: Sequence[Recording],
    name: str,
    joints: Sequence[int] | None = None,
    *,
    refit: bool = True,
    assume_no_force: bool = False,
    executor: Executor | None = None,
) -> TorqueModel:
    """Fit one more effect on the current residual and return the new model (version + 1).

    Parameters
    ----------
    model : TorqueModel
    recs : recordings to fit on (with an F/T sensor for ``attenuation_lag`` and ``ft_bias``)
    name : effect name (see :data:`EFFECTS`)
    joints : 1-based joints for a per-joint effect; None chooses the joints where diagnosis finds
        the effect (the best joint when none passes the test), or for an effect with
        :attr:`~ditherlab.physics.effects.Effect.on_every_joint` every joint where its design acts
        (:func:`ditherlab.analysis.scoring.acting_joints`)
    refit : re-fit the bands and noise with :func:`ditherlab.analysis.identification.identify` afterwards
        (recordings with an F/T sensor, or without one with ``assume_no_force``)
    assume_no_force : the recordings have no sensor and no external force acts (as stated to
        identify): the re-fit treats the external force as zero
    executor : runs the re-fit's band fits (:func:`ditherlab.analysis.identification.identify`'s
        ``executor``; the same model)

    Returns
    -------
    TorqueModel with the effect appended (an existing one of the same name is replaced).

    Raises
    ------
    ModelError
        Unknown effect name, a joint out of range, or a column the effect needs is missing.
    """
    e = get_effect(name)
    recs = list(recs)
    if not recs:
        raise ModelError("add_effect needs at least one recording")
    for r in recs:
        e.check(signals(r))
    if e.needs_dither and not any(has_dither(r) for r in recs):
        names = ", ".join(str(r.name) for r in recs)
        raise ModelError(
            f"{names}: effect {name!r} acts only where the dither is on, and no recording here "
            "has the dither on (column 'dither'); add it with a dithered recording"
        )
    if joints is not None:
        bad = [j for j in joints if not 1 <= int(j) <= model.n]
        if bad:
            raise ModelError(
                f"effect {name!r}: joint {bad[0]} is out of range, expected 1..{model.n}"
            )
    base = model.copy()
    base.effects = [s for s in base.effects if s.name != name]
    sc = [scored(base, r) for r in recs]
    if e.shared:
        fits = {-1: fit_effect(e, sc, None)}
    else:
        if joints is None:
            js = select_joints(base, recs, name, scored_recs=sc)
        else:
            js = [int(j) - 1 for j in joints]
        fits = {j: fit_effect(e, sc, j) for j in js}
    # joints with too little evidence take values shared over the others (dither_extraction)
    fits, weak = pool_weak_joints(e, sc, fits) if not e.shared else (fits, {})
    for j, f in fits.items():
        why = not_identifiable(e, sc, None if j == -1 else j, f)
        if why is not None:
            raise ModelError(why)
    spec = clean_none(make_spec(e, fits))
    if weak:  # the model file says which joints took the shared values
        spec.params["pooled"] = [1.0 if j - 1 in weak else 0.0 for j in spec.joints]
    new = base.copy()
    new.effects.append(spec)
    new.version = model.version + 1
    if refit:
        new = _refit(new, recs, assume_no_force=assume_no_force, executor=executor)
    if weak:
        new.notes = "; ".join(x for x in (new.notes, pooled_note(e, fits, weak)) if x)
    return new


def _refit(
    model: TorqueModel,
    recs: Sequence[Recording],
    n_boot: int = 20,
    *,
    assume_no_force: bool = False,
    executor: Executor | None = None,
) -> TorqueModel:
    """Re-fit bands and noise with the effects in place (identify), keeping version/history.
    Without a sensor the bands are re-fitted only when the user stated that no force acts."""
    if not assume_no_force and not all(r.has_wrench for r in recs):
        return model
    out = identify(
        list(recs), base=model, n_boot=n_boot, assume_no_force=assume_no_force, executor=executor
    )
    out.effects = list(model.effects)
    out.version = model.version
    out.history = list(model.history)
    return out


def identify_files(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    base: str | Path | None = None,
    add: Sequence[str] = (),
    assume_no_force: bool = False,
    n_boot: int = 30,
    seed: int = 0,
    read_options: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
    chunk_rows: int = CHUNK_ROWS,
) -> TorqueModel:
    """Read recordings, :func:`~ditherlab.analysis.identification.identify`, add effects (:func:`add_effect`),
    save.

    The bands are identified from the recordings read in pieces of ``chunk_rows`` rows
    (:mod:`ditherlab.io.stream`: memory does not grow with the logs' length); effects named in
    ``add`` are fitted on the whole recordings, read into memory.

    Parameters
    ----------
    paths : recording files
    out : model file to write (TOML, atomic; never one of the inputs)
    base : a model file to start from
    add : effect names to fit after the bands, in order
    assume_no_force, n_boot, seed, progress : as in :func:`ditherlab.analysis.identification.identify`
    read_options : options for :func:`ditherlab.io.read` (``mapping``, ``robot``)
    chunk_rows : rows per piece

    Returns
    -------
    The written TorqueModel.
    """
    inputs = [Path(p) for p in paths] + ([Path(base)] if base is not None else [])
    check_not_input(out, inputs)
    sources = [open_source(p, **(read_options or {})) for p in paths]
    base_model = TorqueModel.load(base) if base is not None else None
    model = identify(
        sources,
        base=base_model,
        assume_no_force=assume_no_force,
        n_boot=n_boot,
        seed=seed,
        progress=progress,
        chunk_rows=chunk_rows,
    )
    if add:
        recs = [s.read() for s in sources]
        for name in add:
            model = add_effect(model, recs, name, assume_no_force=assume_no_force)
    model.source = None
    model.save(out)
    return model


def diagnose_files(
    recordings: Sequence[str | Path],
    model_path: str | Path,
    *,
    out_dir: str | Path | None = None,
    read_options: dict[str, Any] | None = None,
    history: bool = True,
    regimes: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    chunk_rows: int = CHUNK_ROWS,
) -> Diagnosis:
    """The ``ditherlab diagnose`` command: read, diagnose, append the history, write the report.

    Parameters
    ----------
    recordings : recording files (any format :func:`ditherlab.io.read` knows)
    model_path : the model TOML; its history gets one row (atomically) unless ``history=False``
    out_dir : folder for ``report.md``, ``report.json`` and the PNG figures (optional)
    read_options : passed to :func:`ditherlab.io.read` (``mapping``, ``robot``)
    chunk_rows : rows per piece (recordings are read in pieces: :func:`ditherlab.analysis.diagnosis.diagnose`)
    """
    model = TorqueModel.load(model_path)
    recs = [open_source(p, **(read_options or {})) for p in recordings]
    if out_dir is not None:
        for name in ("report.md", "report.json"):
            check_not_input(Path(out_dir) / name, [*recordings, model_path])
    d = diagnose(model, recs, regimes=regimes or None, progress=progress, chunk_rows=chunk_rows)
    if history:
        d.model = append_history(model_path, d.history_entry())
    if out_dir is not None:
        write_report(d, out_dir)
    return d

"""``ditherlab identify``: read recordings, fit the bands, add effects, save the model.

``identify --add NAME`` and the library call :func:`add_effect`: the joints are chosen by
diagnosis (:func:`ditherlab.analysis.scoring.select_joints`; an effect of the measurement
pipeline, :attr:`~ditherlab.physics.effects.Effect.on_every_joint`, goes on every joint where it
acts), the effect is fitted on the band-aware residual (:mod:`ditherlab.physics.effect_fit`),
refused when the bands could take it (:func:`ditherlab.physics.effect_fit.identifiability`), and
the bands re-identified with it in place (:func:`ditherlab.analysis.identification.identify`).
This module sits above both identification and diagnosis, so neither has to know the other.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.delivery import delivery, force_change, promised
from ditherlab.analysis.diagnosis import demote_below_floor, quiet_joints
from ditherlab.analysis.diagnosis_sums import ResidualSums
from ditherlab.analysis.identification import identify, summary
from ditherlab.analysis.rest import (
    RestScan,
    kept_rows,
    kept_stretches,
    parse_span,
    quiet_majority,
    scan_rest,
)
from ditherlab.analysis.scoring import Candidate, candidates, rescored, select_joints, thinned
from ditherlab.app.workflow import Progress, ReadOptions, guard
from ditherlab.core.errors import ConfigError, ModelError, RecordingError
from ditherlab.core.files import FileKind
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Source, open_source
from ditherlab.physics.dither import has_dither
from ditherlab.physics.effect_fit import (
    fit_effect,
    held_lines,
    not_identifiable,
    out_of_range,
    physical_fits,
    pooled_note,
    recentre,
)
from ditherlab.physics.effects import Effect, FitResult, clean_none, get_effect, make_spec, signals
from ditherlab.physics.effects.ranges import OutOfRange
from ditherlab.physics.residual import Scored, scored

__all__ = ["MODEL_FILE", "IdentifyOptions", "Identified", "add_effect", "identify_model", "run"]

#: the model file that identify writes
MODEL_FILE = FileKind("a torque model", (".toml",), "model.toml")


@dataclass(frozen=True)
class IdentifyOptions:
    """The options of ``ditherlab identify``.

    Attributes
    ----------
    recordings : recordings with an F/T sensor (``f_x..m_z``), or without one with
        ``assume_no_force``; any readable format
    out : the model file to write (``.toml``; as text, a trailing ``/`` names a folder: refused)
    model : a model file to start from: its prior and effects are kept, its bands re-fitted
    add : effects to fit after the bands, in order (names of :data:`ditherlab.physics.effects.EFFECTS`)
    assume_no_force : no F/T sensor: the external force is taken as zero where the log rests
        and does not depart from rest (:func:`ditherlab.analysis.rest.scan_rest` finds the
        departures, and identify leaves them out and says so)
    windows : ``"START:END"`` or ``(start, end)`` [s] in the logs' time: only these stretches
        are fitted on (none: the whole logs)
    excludes : ``"START:END"`` or ``(start, end)`` [s]: stretches left out
    n_boot : bootstrap replicates for the standard errors
    seed : the bootstrap's seed
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read and processed at a time
    force : replace an existing model file
    """

    recordings: tuple[Path, ...]
    out: str | Path
    model: Path | None = None
    add: tuple[str, ...] = ()
    assume_no_force: bool = False
    windows: tuple[str | tuple[float, float], ...] = ()
    excludes: tuple[str | tuple[float, float], ...] = ()
    n_boot: int = 30
    seed: int = 0
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS
    force: bool = False


@dataclass
class Identified:
    """What :func:`run` wrote: the model and its file, and without a sensor what the rest scan
    of each recording found (:class:`~ditherlab.analysis.rest.RestScan`)."""

    model: TorqueModel
    path: Path
    scans: list[RestScan] = field(default_factory=list)
    #: one line each: what the added effects did that the user must know (a force error that
    #: grew), also in the model's history rows
    warnings: list[str] = field(default_factory=list)

    def text(self) -> str:
        """The rest scans, the bands per regime and joint, and where the model went (what the
        CLI prints)."""
        scans = [line for s in self.scans for line in s.lines()]
        return "\n".join([*scans, summary(self.model), f"wrote {self.path}"])


def run(options: IdentifyOptions, progress: Progress | None = None) -> Identified:
    """Read the recordings (in pieces of ``chunk_rows`` rows: memory does not grow with the
    logs' length), identify the bands, add the effects (on the whole recordings, read into
    memory) and save the model (atomically; never over an input).

    Parameters
    ----------
    options : :class:`IdentifyOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    Identified
    """
    o = options
    out = guard(o.out, [*o.recordings, o.model], read=o.read, kind=MODEL_FILE, force=o.force)
    sources = [open_source(p, **o.read.kwargs()) for p in o.recordings]
    base = TorqueModel.load(o.model) if o.model is not None else None
    windows = [as_span(w, "--window") for w in o.windows]
    excludes = [as_span(w, "--exclude") for w in o.excludes]
    recs, drop, scans = left_out(sources, base, windows, excludes, scan=o.assume_no_force)
    model = identify_model(
        recs,
        model=base,
        add=o.add,
        assume_no_force=o.assume_no_force,
        n_boot=o.n_boot,
        seed=o.seed,
        progress=progress,
        chunk_rows=o.chunk_rows,
        drop=drop,
    )
    model.source = None
    note_left_out(model, scans)
    model.save(out)
    known = len(base.history) if base is not None else 0
    warnings = [h["warning"] for h in model.history[known:] if h.get("warning")]
    return Identified(model, out, scans, warnings)


def left_out(
    recordings: Sequence[Recording | Source],
    base: TorqueModel | None,
    windows: Sequence[tuple[float, float]] = (),
    excludes: Sequence[tuple[float, float]] = (),
    *,
    scan: bool,
) -> tuple[list[Recording | Source], list[list[tuple[float, float]]], list[RestScan]]:
    """The recordings to identify on, per recording the spans [s] identify leaves out
    (:func:`rest_spans`), and the rest scans of those without a sensor when ``scan``
    (``assume_no_force``). A recording the scan read whole is handed on in memory, not read a
    second time."""
    recs, drop, scans = [], [], []
    for r in recordings:
        spans, found, rec = rest_spans(r, base, windows, excludes, scan=scan)
        recs.append(rec)
        drop.append(spans)
        scans += [found] if found is not None else []
    return recs, drop, scans


def note_left_out(model: TorqueModel, scans: Sequence[RestScan]) -> None:
    """Add to ``model``'s notes the stretches its bands do not hold (the departures from rest)."""
    left = [f"{s.name} {a:.2f}-{b:.2f} s" for s in scans for a, b in s.spans()]
    if left:
        note = "departures from rest left out (no sensor): " + ", ".join(left)
        model.notes = "; ".join(x for x in (model.notes, note) if x)


def as_span(value: str | tuple[float, float], option: str) -> tuple[float, float]:
    """A ``--window`` / ``--exclude`` value as ``(start, end)`` [s]."""
    if isinstance(value, str):
        return parse_span(value, option)
    return parse_span(f"{value[0]}:{value[1]}", option)


def rest_spans(
    src: Source | Recording,
    base: TorqueModel | None,
    windows: Sequence[tuple[float, float]],
    excludes: Sequence[tuple[float, float]],
    *,
    scan: bool,
) -> tuple[list[tuple[float, float]], RestScan | None, Recording | Source]:
    """The time spans [s] of ``src`` that identify leaves out: outside ``windows``, inside
    ``excludes`` and, with ``scan`` (no sensor), the departures from rest that
    :func:`~ditherlab.analysis.rest.scan_rest` finds in the rest. ConfigError when a window or
    exclusion lies outside the log; RecordingError when the departures cover half the rest
    time or more (the rule's quiet majority fails: the user names the rest with ``--window``).
    Also returns what to identify on: the recording the scan read whole, or ``src``."""
    t = src.t if isinstance(src, Recording) else src.times()
    t0, t1 = float(t[0]), float(t[-1])
    for opt, spans in (("--window", windows), ("--exclude", excludes)):
        for a, b in spans:
            if b < t0 or a > t1:
                raise ConfigError(
                    f"{src.name}: {opt} {a:g}:{b:g} lies outside the log's time "
                    f"{t0:.2f}..{t1:.2f} s; expected START:END in the log's own seconds"
                )
    drop = _outside(windows, t0, t1) + list(excludes)
    if not scan:
        return drop, None, src
    rec = src if isinstance(src, Recording) else src.read()
    found = scan_rest(rec, base, kept_rows(t, windows, excludes))
    if found.rest_s and not quiet_majority(found):
        raise RecordingError(
            f"{src.name}: departures from rest cover {found.event_s:.1f} of the "
            f"{found.rest_s:.1f} s at rest, so the rest cannot be told from the pushes; name the "
            "stretches where no force acts with --window START:END (or leave pushes out with "
            "--exclude START:END)"
        )
    return drop + found.spans(), found, rec


def _outside(
    windows: Sequence[tuple[float, float]], t0: float, t1: float
) -> list[tuple[float, float]]:
    """The spans [s] of ``[t0, t1]`` outside every window (none when there are no windows)."""
    if not windows:
        return []
    out, at = [], t0 - 1.0
    for a, b in sorted(windows):
        if a > at:
            out.append((at, float(np.nextafter(a, -np.inf))))
        at = max(at, float(np.nextafter(b, np.inf)))
    if at <= t1:
        out.append((at, t1 + 1.0))
    return out


def identify_model(
    recordings: Sequence[Recording | Source],
    *,
    model: TorqueModel | None = None,
    add: Sequence[str] = (),
    assume_no_force: bool = False,
    n_boot: int = 30,
    seed: int = 0,
    progress: Progress | None = None,
    chunk_rows: int = CHUNK_ROWS,
    drop: Sequence[Sequence[tuple[float, float]]] = (),
) -> TorqueModel:
    """:func:`~ditherlab.analysis.identification.identify` the bands, then :func:`add_effect`
    each of ``add`` in order (recordings read in pieces are read whole for these).

    Parameters
    ----------
    recordings : in memory or :class:`~ditherlab.io.stream.Source` s read in pieces
    model : the model to start from (its prior and effects kept), or None
    add : effect names
    assume_no_force, n_boot, seed, progress, chunk_rows, drop : as
        :func:`~ditherlab.analysis.identification.identify` (``drop``: the spans [s] left out
        per recording; the effects are fitted, and the bands re-fitted after each, on the
        stretches between them, :func:`~ditherlab.analysis.rest.kept_stretches`)

    Returns
    -------
    TorqueModel
    """
    new = identify(
        recordings,
        base=model,
        assume_no_force=assume_no_force,
        n_boot=n_boot,
        seed=seed,
        progress=progress,
        chunk_rows=chunk_rows,
        drop=drop,
    )
    if add:
        recs = [r.read() if isinstance(r, Source) else r for r in recordings]
        if any(drop):  # the effects are fitted, and the bands re-fitted, between the spans
            recs = [x for r, sp in zip(recs, drop, strict=True) for x in kept_stretches(r, sp)]
        for name in add:
            new = add_effect(recs, new, name, assume_no_force=assume_no_force)
    return new


def add_effect(
    recordings: Sequence[Recording],
    model: TorqueModel,
    effect: str,
    joints: Sequence[int] | None = None,
    *,
    refit: bool = True,
    assume_no_force: bool = False,
    executor: Executor | None = None,
) -> TorqueModel:
    """Fit one more effect on the current residual and return the new model (version + 1).

    Parameters
    ----------
    recordings : recordings to fit on (with an F/T sensor for ``attenuation_lag`` and
        ``ft_bias``)
    model : the model the effect is added to
    effect : effect name (see :data:`ditherlab.physics.effects.EFFECTS`)
    joints : 1-based joints for a per-joint effect; None chooses the joints where diagnosis finds
        the effect (the best joint when none passes the test), or for an effect with
        :attr:`~ditherlab.physics.effects.Effect.on_every_joint` every joint where its design acts
        (:func:`ditherlab.analysis.scoring.acting_joints`)
    refit : re-fit the bands and noise with :func:`ditherlab.analysis.identification.identify`
        afterwards (recordings with an F/T sensor, or without one with ``assume_no_force``);
        otherwise the bands and the sliding line move by what the effect's fit moved them
        (:func:`ditherlab.physics.effect_fit.recentre`)
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
    e = get_effect(effect)
    recs = list(recordings)
    _check_effect_inputs(recs, model, effect, joints)
    base = model.copy()
    base.effects = [s for s in base.effects if s.name != effect]
    sc = [scored(base, r) for r in recs]
    cand = _candidate(base, recs, effect, sc)
    every = not e.shared and joints is None and e.on_every_joint
    if e.shared:
        fits = {-1: fit_effect(e, sc, None)}
    else:
        if joints is not None:
            js = [int(j) - 1 for j in joints]
        elif e.on_every_joint:
            js = select_joints(base, recs, effect, scored_recs=sc)
        else:
            js = [j - 1 for j in cand.joints]
        fits = {j: fit_effect(e, sc, j) for j in js}
    # joints with too little evidence take values shared over the others (dither_extraction),
    # a parameter the data cannot move is held at its nominal value (inertia's scale on a
    # wrist's last link) and a value just outside its range held at the edge where the data
    # allow it
    free = dict(fits)
    fits, weak = physical_fits(e, sc, fits)
    held = held_lines(e, sc, free, fits, weak)
    unfit, bad = _unwritable(e, sc, fits)
    left: dict[int, str] = {}
    if every and len(unfit) + len(bad) < len(fits):  # leave those joints out, say why
        left = {**{j: b.text() for j, b in bad.items()}, **unfit}
        fits = {j: f for j, f in fits.items() if j not in left}
    elif unfit:
        raise ModelError(unfit[min(unfit)])
    elif bad:
        why = "; ".join(b.text() for b in bad.values())
        raise ModelError(f"identify --add {effect}: {why}; the model is not written")
    cand = _promise_as_written(e, cand, sc, {j: f for j, f in fits.items() if f is not free[j]})
    spec = clean_none(make_spec(e, fits))
    if weak:  # the model file says which joints took the shared values
        spec.params["pooled"] = [1.0 if j - 1 in weak else 0.0 for j in spec.joints]
    new = base.copy()
    new.effects.append(spec)
    new.version = model.version + 1
    fitted = new
    if refit and _can_refit(recs, assume_no_force):
        new = _refit(recs, new, assume_no_force=assume_no_force, executor=executor)
    else:  # the bands keep their fit: they move by what the effect's fit moved them
        new = recentre(new, [scored(new, r) for r in recs])
    row = _delivered(base, (fitted, new), cand, sorted(fits), recs, sc)
    told = held + [f"{why}: not fitted there" for why in left.values()]
    if told:
        row["warning"] = "; ".join(x for x in (row.get("warning"), *told) if x)
    new.history = [*new.history, row]
    new.notes = "; ".join(x for x in (new.notes, pooled_note(e, fits, weak), *told) if x)
    return new


def _unwritable(
    e: Effect, sc: Sequence[Scored], fits: dict[int, FitResult]
) -> tuple[dict[int, str], dict[int, OutOfRange]]:
    """The fits ``identify --add`` cannot write, by joint (0-based; -1 shared): those the bands
    could take instead (:func:`not_identifiable`, its sentence) and, among the others, those
    outside a physical range (:func:`out_of_range`). An effect fitted on every joint where it
    acts (:attr:`~ditherlab.physics.effects.Effect.on_every_joint`, no joints given) leaves
    such joints out; any other add is refused."""
    unfit = {
        j: w for j, f in fits.items() if (w := not_identifiable(e, sc, None if j < 0 else j, f))
    }
    bad = out_of_range(e, sc, {j: f for j, f in fits.items() if j not in unfit})
    return unfit, bad


def _candidate(
    base: TorqueModel, recs: Sequence[Recording], effect: str, sc: Sequence[Scored]
) -> Candidate:
    """Diagnosis's evidence for ``effect`` on the model ``base`` (its joints, the held-out
    share it promises, and whether diagnosis suggests it: the same rules, the below-floor one
    included); ModelError when the effect cannot be tried on these recordings."""
    res = ResidualSums(base.n)
    for s in sc:
        res.add(s)
    ratio = res.result()["ratio"]
    cands, skipped = candidates(
        base, recs, effects=[effect], scored_recs=sc, quiet=quiet_joints(ratio)
    )
    if effect in skipped:
        raise ModelError(skipped[effect])
    demote_below_floor(cands, ratio, [])
    return cands[0]


def _promise_as_written(
    e: Effect, cand: Candidate, sc: Sequence[Scored], changed: dict[int, FitResult]
) -> Candidate:
    """``cand`` with the held-out gain of each joint whose fit ``identify --add`` changes before
    writing it (0-based joint -> the fit written: held at a range's edge, or shared over the
    joints) measured for that fit (:func:`~ditherlab.analysis.scoring.rescored`, on the samples
    and folds diagnosis scores): the promise of what is written, not of a value outside its
    range."""
    by = {s.joint: s for s in cand.scores}
    todo = {j: f for j, f in changed.items() if j in by}
    if not todo:
        return cand
    th = thinned(sc)
    scores = [
        rescored(e, th, s, todo[s.joint], 5, 0.25) if s.joint in todo else s for s in cand.scores
    ]
    return replace(cand, scores=scores)


def _delivered(
    base: TorqueModel,
    new: tuple[TorqueModel, TorqueModel],
    cand: Candidate,
    fitted: Sequence[int],
    recs: Sequence[Recording],
    sc: Sequence[Scored],
) -> dict[str, Any]:
    """The history row of an added effect: the model ``new[1]`` (as written; ``new[0]`` with the
    bands of ``base``) delivers at least half of the held-out share ``cand`` promised on the
    joints fitted (0-based; -1 shared: all joints), else ModelError saying why when diagnosis
    suggests the effect (its promise), or a ``warning`` line when it does not (the user asked
    for it; what it did is said); and where the recordings have an F/T sensor, the force error
    before and after (a ``warning`` line when it grew beyond its sampling uncertainty).
    ``sc``: the recordings scored under ``base``. Delivery fits the band centres on both sides
    (:mod:`ditherlab.analysis.delivery`): what recentring the bands alone lowers is not
    credited to the effect."""
    js = list(range(base.n)) if list(fitted) == [-1] else list(fitted)
    after = [scored(new[1], r) for r in recs]
    scs = (sc, [scored(new[0], r) for r in recs], after)
    d = delivery(cand.effect, promised(cand, js), js, scs)
    if not d.ok and cand.suggested:
        raise ModelError(f"identify --add {cand.effect}: {d.text()}; the model is not written")
    row: dict[str, Any] = {
        "version": new[1].version,
        "effects": [s.name for s in new[1].effects],
        "added": cand.effect,
        **d.to_dict(),
    }
    warnings = [] if d.ok else [f"not suggested by diagnosis: {d.text()}"]
    fc = force_change(base, new[1], sc, after)
    if fc is not None:
        row.update(fc.to_dict())
        if fc.grew:
            warnings.append(fc.text(cand.effect))
    if warnings:
        row["warning"] = "; ".join(warnings)
    return row


def _check_effect_inputs(
    recs: list[Recording], model: TorqueModel, effect: str, joints: Sequence[int] | None
) -> None:
    """ModelError unless the recordings can carry ``effect`` on ``joints`` of ``model``."""
    e = get_effect(effect)
    if not recs:
        raise ModelError("add_effect needs at least one recording")
    for r in recs:
        e.check(signals(r))
    if e.needs_dither and not any(has_dither(r) for r in recs):
        names = ", ".join(str(r.name) for r in recs)
        raise ModelError(
            f"{names}: effect {effect!r} acts only where the dither is on, and no recording here "
            "has the dither on (column 'dither'); add it with a dithered recording"
        )
    if joints is not None:
        bad = [j for j in joints if not 1 <= int(j) <= model.n]
        if bad:
            raise ModelError(
                f"effect {effect!r}: joint {bad[0]} is out of range, expected 1..{model.n}"
            )


def _can_refit(recs: Sequence[Recording], assume_no_force: bool) -> bool:
    """The bands can be re-identified on these recordings: all have the F/T sensor, or the user
    stated that no force acts."""
    return assume_no_force or all(r.has_wrench for r in recs)


def _refit(
    recs: Sequence[Recording],
    model: TorqueModel,
    n_boot: int = 20,
    *,
    assume_no_force: bool = False,
    executor: Executor | None = None,
) -> TorqueModel:
    """Re-fit bands and noise with the effects in place (identify), keeping version/history
    (recordings :func:`_can_refit`)."""
    out = identify(
        list(recs),
        base=model,
        n_boot=n_boot,
        assume_no_force=assume_no_force,
        executor=executor,
    )
    out.effects = list(model.effects)
    out.version = model.version
    out.history = list(model.history)
    return out

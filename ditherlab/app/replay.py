"""``ditherlab replay``: replay the estimator of eq. (3) over a recording read in pieces, writing
the estimates file as it goes (:func:`replay_stream`), and tally the force error and interval
coverage against the F/T sensor on the way (:class:`Tally`, :func:`describe`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.causal import CausalEstimator, block_of, settings_for
from ditherlab.analysis.estimation import RampCarry, replay_columns
from ditherlab.analysis.known_load import (
    KNOWN_PREFIX,
    ReferenceSums,
    known_load_of,
    known_load_text,
)
from ditherlab.app.workflow import Progress, ReadOptions, guard
from ditherlab.core.files import FileKind, plain
from ditherlab.data.estimates import Estimates, EstimatesWriter
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Source, open_source
from ditherlab.physics.effects import release

__all__ = [
    "ESTIMATES_FILE",
    "ReplayOptions",
    "Replayed",
    "Tally",
    "describe",
    "error_lines",
    "replay_causal",
    "replay_stream",
    "run",
]

#: the estimates file that replay writes
ESTIMATES_FILE = FileKind("estimates", (".parquet",), "estimates.parquet")


@dataclass(frozen=True)
class ReplayOptions:
    """The options of ``ditherlab replay``.

    Attributes
    ----------
    recording : the recording to replay the estimator over
    model : the torque model (TOML) from ``ditherlab identify``
    out : the estimates file to write (``.parquet``)
    level : the intervals' confidence level, in (0, 1)
    interval : the interval method, ``profile`` or ``set_membership``
    components : the estimated wrench components: ``all``, ``fxyz``, or a list like ``f_x,f_z``
    variants : the estimator variants (:data:`ditherlab.data.estimates.VARIANTS`); None: all the
        recording allows
    read : how to read a foreign log (``--mapping``, ``--robot``)
    chunk_rows : rows read and processed at a time
    force : replace an existing estimates file
    causal : estimate every sample from the past alone (:mod:`ditherlab.analysis.causal`),
        as ``ditherlab live`` does
    """

    recording: Path
    model: Path
    out: str | Path
    level: float = 0.95
    interval: str = "profile"
    components: str = "all"
    variants: tuple[str, ...] | None = None
    read: ReadOptions = ReadOptions()
    chunk_rows: int = CHUNK_ROWS
    force: bool = False
    causal: bool = False


def run(options: ReplayOptions, progress: Progress | None = None) -> Replayed:
    """Read a recording and a model, replay the estimator piece by piece
    (:func:`replay_stream`) and save the estimates (atomic, never over an input).

    Parameters
    ----------
    options : :class:`ReplayOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    Replayed
    """
    o = options
    out = guard(o.out, [o.recording, o.model], read=o.read, kind=ESTIMATES_FILE, force=o.force)
    model = TorqueModel.load(o.model)
    src = open_source(o.recording, **o.read.kwargs())
    stream = replay_causal if o.causal else replay_stream
    return stream(
        src,
        model,
        out,
        chunk_rows=o.chunk_rows,
        progress=progress,
        level=o.level,
        interval=o.interval,
        components=o.components,
        variants=list(o.variants) if o.variants else None,
    )


def replay_stream(
    src: Source,
    model: TorqueModel,
    out: str | Path,
    *,
    chunk_rows: int = CHUNK_ROWS,
    progress: Progress | None = None,
    **options: Any,
) -> Replayed:
    """:func:`~ditherlab.analysis.estimation.replay` over a recording read in pieces
    (:class:`ditherlab.io.stream.Source`), writing the estimates file as it goes: memory holds
    one piece, whatever the length.

    Every piece is replayed with its 2 s of context on either side and keeps the rows it owns;
    the file equals ``replay(src.read(), model, **options).save(out)`` (tested on logs cut inside
    a dither period, a push and a stick). ``moving_spans`` are joined across pieces, and the
    dither's ramp-in, which can outlast the context, is carried from piece to piece
    (:class:`~ditherlab.analysis.estimation.RampCarry`).

    Parameters
    ----------
    src : the recording ; model : as for :func:`~ditherlab.analysis.estimation.replay`
    out : the estimates file to write
    chunk_rows : rows per piece (:data:`ditherlab.io.stream.CHUNK_ROWS`)
    progress : ``progress(done, total)`` over the pieces
    **options : those of :func:`~ditherlab.analysis.estimation.replay` (not ``progress``)

    Returns
    -------
    Replayed: the file, its metadata and the force error / coverage tally
    """
    spans: list[list[float]] = []
    meta: dict[str, Any] | None = None
    last = None
    tally, known = Tally(), ReferenceSums(KNOWN_PREFIX, plus_sensor=True)
    with EstimatesWriter(out) as writer:
        carry = RampCarry()  # a dither's ramp-in can outlast a piece's context
        for piece in src.pieces(chunk_rows):
            carry.at(piece.start, piece.keep)
            cols, pmeta = replay_columns(piece.rec, model, carry=carry, **options)
            rows = {k: v[piece.keep] for k, v in cols.items()}
            writer.write(rows)
            tally.add(rows, pmeta["variants"])
            known.add(rows, pmeta["variants"])
            t = rows["t"]
            for a, b in pmeta["moving_spans"]:
                a, b = max(a, t[0]), min(b, t[-1])
                if a > b:
                    continue
                if spans and a == t[0] and spans[-1][1] == last:
                    spans[-1][1] = b  # a motion across the cut continues
                else:
                    spans.append([a, b])
            last = float(t[-1])
            if meta is None:  # the recording's own is the source's, converted once below
                meta = plain({**pmeta, "recording": None})
            if piece.count > 1:  # a piece of a long log: its robot quantities go now
                release(piece.rec)
            if progress:
                progress(piece.index + 1, piece.count)
        assert meta is not None
        meta = {**meta, "recording": plain(src.meta), "recording_name": src.name}
        meta["moving_spans"] = spans
        writer.meta = meta
    return Replayed(Path(out), meta, tally, known)


def replay_causal(
    src: Source,
    model: TorqueModel,
    out: str | Path,
    *,
    chunk_rows: int = CHUNK_ROWS,
    progress: Progress | None = None,
    variants: Sequence[str] | None = None,
    **options: Any,
) -> Replayed:
    """The causal estimate (:class:`ditherlab.analysis.causal.CausalEstimator`) of every sample
    of a recording read in pieces, written as the estimates file: what ``ditherlab live`` writes
    for the same recording streamed over DDS (times in whole nanoseconds,
    :func:`ditherlab.analysis.causal.block_of`).

    Parameters
    ----------
    src, model, out, chunk_rows, progress : as for :func:`replay_stream`
    variants : the estimator variants (default: all the recording allows)
    **options : ``level``, ``interval``, ``components`` (:class:`CausalSettings`)

    Returns
    -------
    Replayed
    """
    est: CausalEstimator | None = None
    tally, known = Tally(), ReferenceSums(KNOWN_PREFIX)
    with EstimatesWriter(out) as writer:
        for piece in src.pieces(chunk_rows, halo_s=0.0):
            if est is None:
                model.check_robot(piece.rec)
                settings = settings_for(piece.rec, variants=variants, **options)
                est = CausalEstimator(model, plain(src.meta), settings, piece.rec.robot())
            rows = est.update(block_of(piece.rec, piece.keep))
            writer.write(rows)
            tally.add(rows, est.settings.variants)
            known.add(rows, est.settings.variants)
            if progress:
                progress(piece.index + 1, piece.count)
        assert est is not None
        meta = plain(est.metadata(src.name))
        writer.meta = meta
    return Replayed(Path(out), meta, tally, known)


@dataclass
class Replayed:
    """What :func:`replay_stream` wrote: the estimates file, its metadata, and the running
    force error / coverage over all its rows (:class:`Tally`)."""

    path: Path
    meta: dict[str, Any]
    tally: Tally
    known: ReferenceSums | None = None

    @property
    def variants(self) -> list[str]:
        return list(self.meta["variants"])

    def text(self) -> str:
        """:func:`describe` and where the estimates went (what the CLI prints)."""
        return f"{describe(self)}\nwrote {self.path}"


class Tally(ReferenceSums):
    """Running force error and interval coverage against the F/T sensor, per variant, over
    pieces of estimates (what :func:`describe` prints): :class:`ReferenceSums` of the sensor's
    columns, and ``rows``, every row counted."""

    def __init__(self) -> None:
        super().__init__("")
        self.rows = 0

    def add(self, cols: Mapping[str, Any], variants: Sequence[str]) -> None:
        """Count the rows of ``cols`` (a DataFrame or a dict of (N,) arrays) of ``variants``."""
        self.rows += len(cols["t"])
        super().add(cols, variants)

    def add_estimates(self, est: Estimates) -> None:
        """Count the rows of ``est`` (a whole file or one piece of it)."""
        self.add(est.data, est.variants)


def describe(est: Estimates | Replayed) -> str:
    """A few lines: samples, variants, interval method, and per variant the force RMS error and
    interval coverage against the F/T sensor when it is there, and against the known load when
    the recording declares one (over the whole file for what :func:`replay_stream` wrote)."""
    if isinstance(est, Replayed):
        tally, known = est.tally, est.known
    else:
        tally, known = Tally(), ReferenceSums(KNOWN_PREFIX, plus_sensor=True)
        tally.add_estimates(est)
        known.add(est.data, est.variants)
    lines = [
        f"{tally.rows} samples, variants: {', '.join(est.variants)}; intervals "
        f"{est.meta['interval']['method']} at {est.meta['interval']['level']:.0%}"
    ]
    lines += error_lines(tally.result(), "")
    load = known_load_of(est.meta.get("recording"))
    res = known.result() if known is not None else None
    if load is not None and res is not None:
        mean = res["reference_mean"]
        lines.append(
            f"  known load {known_load_text(load)}: mean wrench "
            f"{mean[0]:.1f}/{mean[1]:.1f}/{mean[2]:.1f} N; the estimate against it:"
        )
        lines += error_lines(res, "  ")
    return "\n".join(lines)


def error_lines(res: dict[str, Any] | None, indent: str) -> list[str]:
    """Per variant (and the vendor's own estimate): the force error RMS and bias x/y/z [N] and
    the interval coverage of the force axes, of a :meth:`ReferenceSums.result` (none for None)."""
    if res is None:
        return []
    out = []
    for v, r in res["variants"].items():
        rms, bias = r["rms"], r["bias"]
        cov = (
            "no interval (the vendor's own estimate)"
            if r["coverage"] is None
            else f"interval coverage {float(np.mean(r['coverage'][:3])):.1%}"
        )
        out.append(
            f"{indent}  {v:<16} force error RMS x/y/z {rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f} N,"
            f" bias {bias[0]:.1f}/{bias[1]:.1f}/{bias[2]:.1f} N, {cov}"
        )
    return out

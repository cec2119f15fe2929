"""Events as text logs: the dither switching on and off, the pushes found in the F/T sensor and
the simulator's own, the detections of each estimator variant, and the diagnosis at its worst
windows."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr

from ditherlab.analysis.detection import Push
from ditherlab.core.names import FORCE_AXES
from ditherlab.core.timeseries import merge_runs, runs
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording
from ditherlab.output.diagnosis_report import DiagnosisLike, as_report
from ditherlab.output.rerun.columns import ColumnLogger


class EventLog:
    """The events of a recording logged a piece at a time, as the whole recording gives them:
    the dither switching on and off (the flag before a cut carried over), the pushes found in
    the F/T sensor (``pushes``: :func:`ditherlab.analysis.detection.find_pushes` of the whole recording;
    their peaks followed across pieces, logged at :meth:`finish`), and each variant's detections
    (runs of joints outside their band merged across gaps shorter than
    :data:`DETECTION_MERGE_GAP`, a run or a gap going on across a cut).

    Call :meth:`add` for every piece in order, then :meth:`finish`.
    """

    def __init__(self, pushes: Sequence[Push], n: int):
        self.pushes = list(pushes)
        self.n = n
        # per push: (largest |F| along its axis so far [N], its time [s])
        self.peaks: list[tuple[float, float]] = [(-np.inf, np.nan)] * len(self.pushes)
        self.prev_flag = False
        self.open: dict[str, _Span | None] = {}

    def add(
        self,
        log: ColumnLogger,
        rec: Recording,
        keep: slice,
        start: int,
        estimates: Estimates | None,
    ) -> None:
        """The piece ``rec`` whose rows ``keep`` are the whole recording's rows from ``start``;
        ``estimates``: those rows' estimates."""
        t = rec.t[keep]
        d = rec.dither
        if d is not None:
            d = d[keep]
            e = np.diff(np.r_[np.int8(self.prev_flag), d.astype(np.int8)])
            on, off = np.flatnonzero(e == 1), np.flatnonzero(e == -1)
            times = np.concatenate([t[on], t[off]])
            texts = ["dither on"] * len(on) + ["dither off"] * len(off)
            order = np.argsort(times, kind="stable")
            log.text_log(
                "events/dither", times[order], [texts[i] for i in order], ["INFO"] * len(order)
            )
            log.series(
                "events/dither_flag",
                d.astype(float),
                names="dither on",
                colors=[[150, 90, 200]],
                step=True,
            )
            if len(d):
                self.prev_flag = bool(d[-1])
        if rec.has_wrench:
            self._peaks(rec.wrench[keep], t, start)
        if estimates is None:
            return
        for v in estimates.variants:
            col = f"{v}/active"
            if col not in estimates.data.columns:
                continue
            bits = estimates.data[col].to_numpy().astype(np.int64)
            F = estimates.data[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)
            closed = self._detections(v, t, bits, F, start)
            log.text_log(
                f"events/detections/{v}",
                np.array([sp.t_a for sp in closed]),
                [self._text(v, sp) for sp in closed],
                ["WARN"] * len(closed),
            )

    def _peaks(self, w: np.ndarray, t: np.ndarray, start: int) -> None:
        """Follow each push's peak over the rows ``[start, start + len(t))``."""
        end = start + len(t)
        for k, p in enumerate(self.pushes):
            if p.i1 <= start or p.i0 >= end:
                continue
            a, b = max(p.i0, start) - start, min(p.i1, end) - start
            x = np.abs(w[a:b, "xyz".index(p.axis)])
            i = int(np.argmax(x))
            if x[i] > self.peaks[k][0]:  # the first largest, as argmax over the push
                self.peaks[k] = (float(x[i]), float(t[a + i]))

    def _detections(
        self, v: str, t: np.ndarray, bits: np.ndarray, F: np.ndarray, start: int
    ) -> list[_Span]:
        """Fold one piece's detection bits (M,) and estimates (M, 3) [N] of variant ``v`` into
        its spans; the spans that closed."""
        mag = np.sqrt(F[:, 0] ** 2 + F[:, 1] ** 2 + F[:, 2] ** 2)

        def best(a: int, b: int) -> tuple[float, float, np.ndarray]:
            i = a + int(np.argmax(mag[a:b]))
            return float(mag[i]), float(t[i]), F[i]

        closed = []
        starts, ends = runs(bits != 0)
        for s, e in zip(starts, ends, strict=True):
            sp = self.open.get(v)
            or_bits = int(np.bitwise_or.reduce(bits[s:e]))
            if sp is not None and (start + s == sp.b or t[s] - sp.t_last < DETECTION_MERGE_GAP):
                g0 = max(sp.b - start, 0)
                if s > g0:  # the gap's rows are in the span
                    sp.gap = _first_max(sp.gap, best(g0, s))
                sp.best = _first_max(_first_max(sp.best, sp.gap), best(s, e))
                sp.gap, sp.b, sp.t_last, sp.bits = (
                    None,
                    start + e,
                    float(t[e - 1]),
                    sp.bits | or_bits,
                )
            else:
                if sp is not None:
                    closed.append(sp)
                self.open[v] = _Span(
                    start + s, float(t[s]), start + e, float(t[e - 1]), or_bits, best(s, e)
                )
        sp = self.open.get(v)
        if sp is not None and len(t) > max(sp.b - start, 0):
            sp.gap = _first_max(sp.gap, best(max(sp.b - start, 0), len(t)))
        return closed

    def _text(self, v: str, sp: _Span) -> str:
        joints = ",".join(str(j + 1) for j in range(self.n) if sp.bits >> j & 1)
        mag, ti, Fi = sp.best
        return (
            f"{v}: detection for {sp.t_last - sp.t_a:.2f} s, joints {joints} outside band; "
            f"peak F=({', '.join(f'{x:+.1f}' for x in Fi)}) N at t={ti:.2f} s"
        )

    def finish(self, log: ColumnLogger) -> None:
        """Log the pushes and the detections still open at the recording's end."""
        times, texts = [], []
        for k, (p, (_, t_peak)) in enumerate(zip(self.pushes, self.peaks, strict=True), 1):
            applied = f"{'+' if p.sign > 0 else '-'}{p.axis}"
            times += [p.start, t_peak, p.end]
            texts += [
                f"push {k} start ({applied})",
                f"push {k} peak: {p.peak:.1f} N applied along {applied}",
                f"push {k} end ({p.end - p.start:.2f} s)",
            ]
        log.text_log("events/pushes", np.array(times), texts, ["INFO"] * len(times))
        for v, sp in self.open.items():
            if sp is not None:
                log.text_log(
                    f"events/detections/{v}", np.array([sp.t_a]), [self._text(v, sp)], ["WARN"]
                )
        self.open = {}


@dataclass
class _Span:
    """A detection being followed: rows ``[a, b)`` from its first run's start to its last run's
    end, their OR of joint bits, and the largest ``|F|`` (value [N], time [s], F (3,) [N]) over
    the span's rows and over the rows after it seen so far (``gap``: part of the span if
    another run follows within the merge gap)."""

    a: int
    t_a: float
    b: int
    t_last: float
    bits: int
    best: tuple[float, float, np.ndarray]
    gap: tuple[float, float, np.ndarray] | None = None


def _first_max(
    cur: tuple[float, float, np.ndarray] | None, new: tuple[float, float, np.ndarray] | None
) -> tuple[float, float, np.ndarray] | None:
    """The larger of two maxima of consecutive stretches, the earlier one on a tie (and a NaN
    first), as ``np.argmax`` over both stretches picks."""
    if cur is None:
        return new
    if new is None or np.isnan(cur[0]):
        return cur
    return new if np.isnan(new[0]) or new[0] > cur[0] else cur


#: Detections closer than this [s] are one event (a joint flickering at its band edge).
DETECTION_MERGE_GAP = 0.25


def merge_spans(t: np.ndarray, flag: np.ndarray, gap: float) -> list[tuple[int, int]]:
    """Runs of ``flag`` as ``[start, end)`` index pairs, runs less than ``gap`` [s] apart merged.

    Parameters
    ----------
    t : (N,) [s]
    flag : (N,) bool
    gap : [s]

    Returns
    -------
    list of (start, end) sample indices, in time order
    """
    return merge_runs(t, *runs(flag), gap)


def log_commanded_pushes(log: ColumnLogger, meta: dict) -> None:
    """The simulator's pushes (``meta["sim"]["pushes"]``: t0, duration, axis, sign, magnitude)."""
    pushes = (meta.get("sim") or {}).get("pushes") or []
    times, texts = [], []
    for k, p in enumerate(pushes, 1):
        try:
            t0, dur = float(p["t0"]), float(p["duration"])
            what = f"{'+' if p['sign'] > 0 else '-'}{p['axis']} {float(p['magnitude']):.1f} N"
        except (KeyError, TypeError, ValueError):
            continue
        times += [t0, t0 + dur / 2, t0 + dur]
        texts += [
            f"push {k} (simulated) start: {what} for {dur:.2f} s",
            f"push {k} (simulated) peak: {what}",
            f"push {k} (simulated) end",
        ]
    if times:
        order = np.argsort(times, kind="stable")
        log.text_log(
            "events/pushes_simulated",
            np.array(times)[order],
            [texts[i] for i in order],
            ["DEBUG"] * len(order),
        )


# ---------------------------------------------------------------------- diagnosis
def log_diagnosis(log: ColumnLogger, name: str | None, diagnosis: DiagnosisLike | None) -> None:
    """Diagnosis at its worst windows: one entry per window naming the worst joint and the
    suggested effects that act on it; the ranked candidates as a document.

    ``diagnosis`` is a :class:`ditherlab.output.diagnosis_report.DiagnosisReport` (:func:`load_report` of a
    report.json), a :class:`ditherlab.analysis.diagnosis.Diagnosis` or its ``to_dict()``. Windows of other
    recordings (by name: ``name`` is the recording's) are skipped.
    """
    if diagnosis is None:
        return
    d = as_report(diagnosis)
    cands = d.candidates
    recs = d.recordings
    mine = [
        w
        for w in d.worst_windows
        if len(recs) <= 1 or w["recording"] in (name, Path(name or "").name)
    ]
    times, texts = [], []
    for w in mine:
        j = int(w["worst_joint"])
        sugg = [c for c in cands if c["suggested"] and (not c["joints"] or j in c["joints"])]
        text = (
            f"worst window t={w['t0']:.1f}..{w['t1']:.1f} s: joint {j} at "
            f"{w['worst_joint_ratio']:.2g}x the noise floor"
        )
        text += (
            ("; suggested: " + "; ".join(c["text"] for c in sugg))
            if sugg
            else ("; no suggested effect acts on this joint")
        )
        times.append(float(w["t0"]))
        texts.append(text)
    order = np.argsort(times, kind="stable")
    log.text_log(
        "diagnosis", np.array(times)[order], [texts[i] for i in order], ["WARN"] * len(order)
    )
    ranked = [f"{i}. {c['text']}" for i, c in enumerate(cands, 1)]
    doc = "# Diagnosis\n\n" + ("\n".join(ranked) if ranked else "no candidates")
    log.stream.log("info/diagnosis", rr.TextDocument(doc, media_type="text/markdown"), static=True)

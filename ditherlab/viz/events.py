"""Events as text logs: the dither switching on and off, the pushes found in the F/T sensor and
the simulator's own, the detections of each estimator variant, and the diagnosis at its worst
windows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from ditherlab.estimates import Estimates
from ditherlab.recording import FORCE_AXES, Recording
from ditherlab.signal import merge_runs, runs
from ditherlab.thresholds import find_pushes
from ditherlab.viz.diagnosis import DiagnosisLike, as_report
from ditherlab.viz.stream import ColumnLogger


def log_events(log: ColumnLogger, rec: Recording, estimates: Estimates | None) -> None:
    t = rec.t
    d = rec.dither
    if d is not None:
        on, off = runs(d)
        off = off[off < len(t)]  # a run to the end has no falling edge
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
    if rec.has_wrench:
        w = rec.wrench
        times, texts = [], []
        for k, p in enumerate(find_pushes(t, w), 1):
            ax = "xyz".index(p.axis)
            i = p.i0 + int(np.argmax(np.abs(w[p.i0 : p.i1, ax])))
            applied = f"{'+' if p.sign > 0 else '-'}{p.axis}"
            times += [p.start, float(t[i]), p.end]
            texts += [
                f"push {k} start ({applied})",
                f"push {k} peak: {p.peak:.1f} N applied along {applied}",
                f"push {k} end ({p.end - p.start:.2f} s)",
            ]
        log.text_log("events/pushes", np.array(times), texts, ["INFO"] * len(times))
    _log_commanded_pushes(log, rec)
    if estimates is None:
        return
    for v in estimates.variants:
        col = f"{v}/active"
        if col not in estimates.data.columns:
            continue
        bits = estimates.data[col].to_numpy().astype(np.int64)
        F = estimates.data[[f"{v}/f_{a}" for a in FORCE_AXES]].to_numpy(dtype=float)
        mag = np.linalg.norm(F, axis=1)
        spans = merge_spans(t, bits != 0, DETECTION_MERGE_GAP)
        texts = []
        for a, b in spans:
            i = a + int(np.argmax(mag[a:b]))
            joints = ",".join(str(j + 1) for j in range(rec.n) if np.any(bits[a:b] >> j & 1))
            texts.append(
                f"{v}: detection for {t[b - 1] - t[a]:.2f} s, joints {joints} outside band; "
                f"peak F=({', '.join(f'{x:+.1f}' for x in F[i])}) N at t={t[i]:.2f} s"
            )
        starts = np.array([t[a] for a, _ in spans])
        log.text_log(f"events/detections/{v}", starts, texts, ["WARN"] * len(spans))


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


def _log_commanded_pushes(log: ColumnLogger, rec: Recording) -> None:
    """The simulator's pushes (``meta["sim"]["pushes"]``: t0, duration, axis, sign, magnitude)."""
    pushes = (rec.meta.get("sim") or {}).get("pushes") or []
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
def log_diagnosis(log: ColumnLogger, rec: Recording, diagnosis: DiagnosisLike | None) -> None:
    """Diagnosis at its worst windows: one entry per window naming the worst joint and the
    suggested effects that act on it; the ranked candidates as a document.

    ``diagnosis`` is a :class:`ditherlab.viz.diagnosis.DiagnosisReport` (:func:`load_report` of a
    report.json), a :class:`ditherlab.diagnose.Diagnosis` or its ``to_dict()``. Windows of other
    recordings (by name) are skipped.
    """
    if diagnosis is None:
        return
    d = as_report(diagnosis)
    cands = d.candidates
    recs = d.recordings
    mine = [
        w
        for w in d.worst_windows
        if len(recs) <= 1 or w["recording"] in (rec.name, Path(rec.name or "").name)
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

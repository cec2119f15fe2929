"""The report: the paper's §VI-C table beside ours, detection statistics, figures (Markdown + HTML).

:func:`write_pages` writes the report of an analysis of estimates files
(:func:`ditherlab.analysis.detection.analyse`; the workflow is
:func:`ditherlab.app.report.make_report`) into one folder: ``report.md``, ``report.html``,
``report.json`` (the same numbers) and PNG figures (:mod:`ditherlab.output.figures`): the forces
of the paper's Fig. 6, the response against applied force with the detection curves, and — when
the recordings are given (:func:`open_logs`) — the torques of Fig. 2, the extraction of Fig. 4
and the dither control of Fig. 5.
"""

from __future__ import annotations

import hashlib
import html
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.analysis.detection import AXES, PAPER, find_pushes_in_blocks
from ditherlab.analysis.no_sensor import variant_label
from ditherlab.core.errors import RecordingError
from ditherlab.core.files import atomic_write_json, atomic_write_text, plain
from ditherlab.core.names import DITHER, STILL
from ditherlab.data.estimates import COMPONENTS, Estimates, EstimatesSource, check_times_match
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, HALO_S, open_source
from ditherlab.output import figures as figs
from ditherlab.output.vendor_page import vendor_blocks
from ditherlab.physics.dither import dither_waveform, extract, extract_dither
from ditherlab.physics.effects import signals


def _fmt(x: Any, unit: str = "N", nd: int = 1) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{nd}f} {unit}".strip()


def _ci(c: dict, key: str) -> str:
    if c.get("bound"):
        sign = "<" if c["bound"] == "below" else ">"
        return f"{sign} {c['bound_force']:.1f} N ({'all' if sign == '<' else 'none'} seen)"
    v = c.get(key)
    lo, hi = c.get(f"{key}_ci", [None, None])
    if v is None or not math.isfinite(v):
        return "–"
    if lo is None or not math.isfinite(lo):
        return f"{v:.1f} N"
    return f"{v:.1f} N [{lo:.1f}, {hi:.1f}]"


def paper_table(analysis: dict) -> tuple[list[str], list[list[str]]]:
    """Rows: direction; columns: the paper's and our two statistics, without and with dither."""
    head = [
        "direction",
        "no dither: paper response / >10 N",
        "no dither: ours (nodither_band)",
        "dither: paper response / >10 N",
        "dither: ours (dither_band)",
        "dither, no uniform term: ours (dither_noband)",
    ]
    rows = []
    cond = analysis["conditions"]
    for a in AXES:
        row = [a]
        for label, key in (("no dither", "nodither_band"), ("dither", "dither_band")):
            p = PAPER[label]
            row.append(f"{p['response'][a]:.0f} N / {p['above10'][a]:.0f} N")
            d = cond.get(key, {}).get("directions", {}).get(a)
            row.append(_ours(d))
        d = cond.get("dither_noband", {}).get("directions", {}).get(a)
        row.append(_ours(d))
        rows.append(row)
    return head, rows


def own_table(analysis: dict) -> tuple[list[str], list[list[str]]]:
    """Rows: direction; columns: the user's own estimator variants, named for people
    (:func:`ditherlab.analysis.no_sensor.variant_label`), each cell as in :func:`paper_table`."""
    conds = sorted(analysis["conditions"])
    head = ["direction"] + [_condition_label(c) for c in conds]
    rows = []
    for a in AXES:
        rows.append([a] + [_ours(analysis["conditions"][c]["directions"].get(a)) for c in conds])
    return head, rows


def _condition_label(condition: str) -> str:
    """``nodither_band (dither on)`` -> ``without dither (estimator ignores ...)``."""
    return variant_label(condition.split(" ")[0], condition.endswith("(dither on)"))


def comparison(analysis: dict) -> tuple[str, str, tuple[list[str], list[list[str]]]]:
    """The report's main table: the paper's IRB140 numbers beside ours when
    ``analysis["paper_comparison"]`` (the IRB140, or ``report --paper``), else the user's own
    variants side by side; as (heading, caption, table)."""
    if analysis.get("paper_comparison", True):
        return (
            "The paper's §VI-C statistics beside ours",
            "Each cell: smallest applied force whose estimate rose above the noise "
            "level / smallest applied force beyond which every estimate exceeded 10 N. "
            "Paper: Stolt et al., ABB IRB140, about 50 pushes per direction.",
            paper_table(analysis),
        )
    return (
        "Detection per push direction, estimator against estimator",
        "Each cell: smallest applied force whose estimate rose above the noise level / smallest "
        "applied force beyond which every estimate exceeded 10 N. The paper's IRB140 numbers "
        "are not shown for this robot (report --paper adds them).",
        own_table(analysis),
    )


def _ours(d: dict | None) -> str:
    if not d:
        return "no pushes"
    r = d["response_min"]
    b = d["above10_from"]
    rs = f"{r:.0f} N" if r is not None else f"none (≤ {d['peak_range'][1]:.0f} N)"
    bs = f"{b:.0f} N" if b is not None else f"not reached (≤ {d['peak_range'][1]:.0f} N)"
    return f"{rs} / {bs}"


def detail_table(analysis: dict) -> tuple[list[str], list[list[str]]]:
    """Per condition and direction: every statistic of the analysis."""
    head = [
        "condition",
        "dir",
        "pushes",
        "peak range",
        "noise level",
        "smallest response",
        "> 10 N from",
        "> 10 N smallest",
        "F50 [90 % CI]",
        "F90 [90 % CI]",
        "error RMS",
        "interval width",
        "coverage (push)",
    ]
    rows = []
    for name, c in analysis["conditions"].items():
        for a in AXES:
            d = c["directions"].get(a)
            if not d:
                continue
            rows.append(
                [
                    name,
                    a,
                    str(d["pushes"]),
                    f"{d['peak_range'][0]:.0f}–{d['peak_range'][1]:.0f} N",
                    _fmt(c["noise_level"][a]),
                    _fmt(d["response_min"], nd=1),
                    _fmt(d["above10_from"], nd=1),
                    _fmt(d["above10_min"], nd=1),
                    _ci(d["curve"], "F50"),
                    _ci(d["curve"], "F90"),
                    _fmt(d["error_rms"]),
                    _fmt(d["width"]),
                    f"{d['coverage']:.1%}",
                ]
            )
    return head, rows


def coverage_table(analysis: dict, level: str) -> tuple[list[str], list[list[str]]]:
    """Per condition: interval coverage of the F/T force over all samples, per axis during
    pushes (the push axis' component, the push's samples) and per axis at rest, and the mean
    interval width at rest per axis [N]; "–" where the analysis has no such number."""
    head = [
        "condition",
        f"coverage, all samples (nominal {level})",
        "coverage during pushes x / y / z",
        "coverage at rest x / y / z",
        "mean width at rest x / y / z",
    ]
    rows = []
    for n, c in analysis["conditions"].items():
        push = [(c["directions"].get(a) or {}).get("coverage") for a in AXES]
        rest = [(c.get("coverage_rest_axes") or {}).get(a) for a in AXES]
        width = [(c.get("width_rest_axes") or {}).get(a) for a in AXES]
        rows.append(
            [
                n,
                f"{c['coverage_all']:.1%}",
                " / ".join(_pct(x) for x in push),
                " / ".join(_pct(x) for x in rest),
                " / ".join(_fmt(x) for x in width),
            ]
        )
    return head, rows


def _pct(x: float | None) -> str:
    """A fraction as a percentage with one decimal, "–" for None or NaN."""
    return "–" if x is None or not np.isfinite(x) else f"{x:.1%}"


# ------------------------------------------------------------------------------ rendering
def _md_table(head: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _html_table(head: list[str], rows: list[list[str]]) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in r) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def render(blocks: list[tuple], fmt: str) -> str:
    """Blocks ``("h1"|"h2"|"p", text)``, ``("table", head, rows)``, ``("img", file, caption)``."""
    parts = []
    for b in blocks:
        kind = b[0]
        if fmt == "md":
            if kind == "h1":
                parts.append(f"# {b[1]}")
            elif kind == "h2":
                parts.append(f"## {b[1]}")
            elif kind == "p":
                parts.append(b[1])
            elif kind == "table":
                parts.append(_md_table(b[1], b[2]))
            elif kind == "img":
                parts.append(f"![{b[2]}]({b[1]})\n\n*{b[2]}*")
        else:
            if kind in ("h1", "h2"):
                parts.append(f"<{kind}>{html.escape(b[1])}</{kind}>")
            elif kind == "p":
                parts.append(f"<p>{html.escape(b[1])}</p>")
            elif kind == "table":
                parts.append(_html_table(b[1], b[2]))
            elif kind == "img":
                parts.append(
                    f'<figure><img src="{html.escape(b[1])}" alt="{html.escape(b[2])}">'
                    f"<figcaption>{html.escape(b[2])}</figcaption></figure>"
                )
    if fmt == "md":
        return "\n\n".join(parts) + "\n"
    style = (
        "body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
        "table{border-collapse:collapse;margin:1em 0;font-size:90%;}"
        "td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;}"
        "th{background:#eee;}img{max-width:100%;}"
    )
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>ditherlab report</title>"
        f"<style>{style}</style></head><body>" + "\n".join(parts) + "</body></html>\n"
    )


# ------------------------------------------------------------------------------ the pages
def open_logs(
    recordings: Sequence[Any], ests: Sequence[EstimatesSource], chunk_rows: int = CHUNK_ROWS
) -> list[RecordingLog]:
    """The recordings behind the estimates (Recording objects or paths), opened to be read
    ``chunk_rows`` rows at a time (only what the torque figures need is kept), each checked to
    be behind one of ``ests`` (as ``view --estimates`` requires): RecordingError otherwise."""
    logs = [RecordingLog(r, chunk_rows) for r in recordings]
    for k, log in enumerate(logs):
        log.check_behind(ests, k)
    return logs


def write_pages(
    ests: Sequence[EstimatesSource],
    analysis: dict[str, Any],
    logs: Sequence[RecordingLog],
    out: Path,
    *,
    figures: bool = True,
    chunk_rows: int = CHUNK_ROWS,
    tick: Callable[[], None] = lambda: None,
    extra: Sequence[tuple] = (),
) -> list[str]:
    """Write the report of an analysis (:func:`ditherlab.analysis.detection.analyse` of
    ``ests``) into ``out``: ``report.md``, ``report.html``, ``report.json`` (the analysis, with
    ``files`` listing what was written) and, with ``figures``, the PNG figures (those of the
    recordings ``logs`` too: :func:`open_logs`). ``tick()`` is called after the
    text, after each of the figures' 4 steps and after the pages (6 calls; 2 without
    figures); ``extra`` blocks (another section, e.g. a known load's) follow the text's; returns
    the files' names."""
    level = ests[0].meta.get("interval", {})
    level_txt = f"{level.get('level', 0.95):.0%} {level.get('method', '')}".strip()
    blocks = _blocks(ests, analysis, level_txt) + list(extra)
    tick()
    written: list[str] = []
    if figures:
        out.mkdir(parents=True, exist_ok=True)
        written += _figures(list(ests), analysis, list(logs), out, blocks, tick, chunk_rows)
    analysis["files"] = written + ["report.md", "report.html", "report.json"]
    atomic_write_text(out / "report.md", render(blocks, "md"))
    atomic_write_text(out / "report.html", render(blocks, "html"))
    atomic_write_json(out / "report.json", analysis)
    tick()
    return analysis["files"]


def _blocks(ests: Sequence[EstimatesSource], analysis: dict, level_txt: str) -> list[tuple]:
    """The report's text blocks before the figures: the paper's table beside ours, the
    definitions, every condition and direction, the coverage and the pushes found."""
    blocks: list[tuple] = [("h1", "ditherlab report: force detection with and without dither")]
    files = [("estimates", e.name or "<memory>") for e in ests]
    blocks.append(
        ("p", "Estimates: " + ", ".join(f for _, f in files) + ". Intervals: " + level_txt + ".")
    )
    title, caption, (h, r) = comparison(analysis)
    blocks += [("h2", title), ("p", caption), ("table", h, r)]
    blocks.append(("h2", "Definitions"))
    for k, v in analysis["definitions"].items():
        blocks.append(("p", f"{k}: {v}."))
    blocks.append(("h2", "All conditions and directions"))
    h, r = detail_table(analysis)
    blocks.append(("table", h, r))
    blocks.append(("h2", "Interval coverage against the F/T sensor (forces)"))
    h, r = coverage_table(analysis, level_txt)
    blocks.append(("table", h, r))
    blocks += vendor_blocks(analysis)
    blocks.append(("h2", "Pushes found"))
    blocks.append(("table", ["file", "dither", "pushes", "x", "y", "z"], _push_rows(analysis)))
    return blocks


def _push_rows(analysis: dict) -> list[list[str]]:
    """Per recording: its file, dither, pushes found, and per axis their count and range."""
    prow = []
    for rec in analysis["recordings"]:
        ps = rec["pushes"]
        by = {a: [p for p in ps if p["axis"] == a] for a in AXES}
        prow.append(
            [Path(rec["file"]).name, "yes" if rec["dithered"] else "no", str(len(ps))]
            + [
                f"{len(by[a])} ({min((p['peak'] for p in by[a]), default=0):.0f}–"
                f"{max((p['peak'] for p in by[a]), default=0):.0f} N)"
                for a in AXES
            ]
        )
    return prow


def _figures(
    ests: list[EstimatesSource],
    analysis: dict,
    logs: list[RecordingLog],
    out: Path,
    blocks: list[tuple],
    tick: Callable[[], None],
    chunk_rows: int,
) -> list[str]:
    written = []
    blocks.append(("h2", "Figures"))
    panels = []
    for label, variant, want_dither in (
        ("no dither", "nodither_band", False),
        ("dither", "dither_band", True),
        ("dither, no uniform term", "dither_noband", True),
    ):
        for e, rinfo in zip(ests, analysis["recordings"], strict=True):
            if variant in e.variants and rinfo["dithered"] == want_dither and rinfo["pushes"]:
                panels.append((f"{variant} ({label})", *_fig6_rows(e, variant, rinfo, chunk_rows)))
                break
    if panels:
        figs.fig6_estimates(panels, out / "fig6_estimates.png")
        written.append("fig6_estimates.png")
        blocks.append(
            (
                "img",
                "fig6_estimates.png",
                "Fig. 6: applied force measured by the F/T sensor (black), estimate (blue) "
                "and interval (shaded), per direction; columns as in the paper.",
            )
        )
    tick()
    figs.detection_curves(analysis, out / "detection.png")
    written.append("detection.png")
    blocks.append(
        (
            "img",
            "detection.png",
            "Largest estimate against applied force per push (top; dashed: 10 N) and the "
            "fitted detection probability (bottom).",
        )
    )
    tick()
    if logs:
        written += _torque_figures(ests, logs, out, blocks)
    tick()
    tick()
    return written


def _fig6_rows(
    src: EstimatesSource, variant: str, rinfo: dict, chunk_rows: int
) -> tuple[Estimates, dict, tuple[float, float]]:
    """The rows of one estimates file that Fig. 6 shows (:func:`ditherlab.output.figures.fig6_windows`)
    as Estimates, its analysis row and the file's first and last time [s]."""
    t = src.column("t").astype(float)
    span = (float(t[0]), float(t[-1]))
    show = np.zeros(len(t), dtype=bool)
    for t0, t1 in figs.fig6_windows(*span, rinfo):
        show |= (t >= t0) & (t <= t1)
    del t
    cols = ["t", *COMPONENTS] + [
        f"{variant}/{c}{x}" for x in ("", "_lo", "_hi") for c in COMPONENTS
    ]
    return _rows_of(src, show, cols, chunk_rows), rinfo, span


def _rows_of(src: EstimatesSource, take: np.ndarray, cols: list[str], rows: int) -> Estimates:
    """The rows ``take`` (N,) bool of some columns of an estimates file, as Estimates."""
    parts, a = [], 0
    for block in src.blocks(rows, cols):
        b = a + len(block)
        if take[a:b].any():
            parts.append(block[take[a:b]])
        a = b
    data = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=cols)
    return src.estimates(data)


# ------------------------------------------------------------------------------ recordings
class RecordingLog:
    """A recording behind the torque figures: a Recording in memory, or a file read a piece
    at a time (:class:`ditherlab.io.stream.Source`) of which only what the figures need is kept:
    its time stamps, dither flag, pushes and the windows the figures show."""

    def __init__(self, r: Any, chunk_rows: int):
        self.rec = r if isinstance(r, Recording) else None
        self.src = None if self.rec is not None else open_source(r)
        self.chunk = chunk_rows
        if self.rec is not None:
            self.name, self.meta = self.rec.name, self.rec.meta
            self.columns = [str(c) for c in self.rec.data.columns]
            self.t, self.dither = self.rec.t, self.rec.dither
        else:
            assert self.src is not None
            self.name, self.meta, self.columns = self.src.name, self.src.meta, self.src.columns
            self.t = self.src.times()
            self.dither = (
                self.src.column("dither").astype(bool) if "dither" in self.columns else None
            )
        self.has_wrench = all(c in self.columns for c in COMPONENTS)
        self.dithered = self.dither is not None and bool(self.dither.any())
        self._pushes: list | None = None
        self._fp: tuple[int, str, str | None, str | None] | None = None

    def blocks(self, cols: list[str]) -> Iterator[pd.DataFrame]:
        """Some columns in consecutive blocks of rows."""
        if self.rec is not None:
            yield self.rec.data[cols]
        else:
            assert self.src is not None
            yield from self.src.frames(self.chunk, cols)

    @property
    def pushes(self) -> list:
        """:func:`ditherlab.analysis.detection.find_pushes` of the recording's F/T sensor."""
        if self._pushes is None:
            cols = list(COMPONENTS[:3])
            self._pushes = (
                find_pushes_in_blocks(
                    self.t, lambda: (b.to_numpy(dtype=float) for b in self.blocks(cols))
                )
                if self.has_wrench
                else []
            )
        return self._pushes

    def from_first_push(self, length: float) -> tuple[int, int]:
        """Rows ``[i0, i1)``: ``length`` [s] from 1 s before the first push (or the start)."""
        ps = self.pushes
        t0 = ps[0].start - 1.0 if ps else self.t[0]
        return _span(self.t, t0, t0 + length)

    def window(self, i0: int, i1: int, context: int = 0) -> tuple[Recording, slice]:
        """A Recording holding the rows ``[i0, i1)`` and ``context`` rows on either side (a
        :class:`ditherlab.io.stream.Piece` of them, with the whole recording's time base) and
        where ``[i0, i1)`` are in it; the whole Recording when in memory."""
        if self.rec is not None:
            return self.rec, slice(i0, i1)
        assert self.src is not None
        halo = int(np.ceil(HALO_S / self.src.timebase().dt)) if len(self.t) > 1 else 1
        lo, hi = max(i0 - halo - context, 0), min(i1 + halo + context, len(self.t))
        parts, a = [], 0
        for f in self.blocks(self.columns):
            b = a + len(f)
            if b > lo and a < hi:
                parts.append(f.iloc[max(lo - a, 0) : hi - a])
            a = b
            if a >= hi:
                break
        data = pd.concat(parts, ignore_index=True)
        rec = Recording(data, self.meta, name=self.name, timebase=self.src.timebase())
        return rec, slice(i0 - lo, i1 - lo)

    def fingerprint(self) -> tuple[int, str, str | None, str | None]:
        """(rows, and digests of ``t``, the dither flag and the F/T columns) to match estimates."""
        if self._fp is None:
            self._fp = _fingerprint(self.blocks, self.columns, len(self.t))
        return self._fp

    def check_behind(self, ests: Sequence[EstimatesSource], k: int) -> None:
        """Raise RecordingError unless one of ``ests`` was computed from this recording
        (:meth:`estimates_of`). The message is :func:`ditherlab.data.estimates.check_times_match`'s
        (the one ``view --estimates`` gives) against the ``k``-th estimates (the only ones, or
        those given in the same place), else one naming both files."""
        if self.estimates_of(ests) is not None:
            return
        e = ests[k] if len(ests) > 1 and k < len(ests) else ests[0]
        rname, ename = self.name or "the recording", e.name or "estimates"
        check_times_match(self.t, self.meta, rname, e.column("t").astype(float), e.meta, ename)
        raise RecordingError(
            f"{ename}: the estimates come from another recording: the dither flag or the F/T "
            f"columns differ from those of {rname}"
        )

    def estimates_of(self, ests: Sequence[EstimatesSource]) -> EstimatesSource | None:
        """The estimates computed from this recording, or None: the same time stamps and
        recording metadata (:func:`ditherlab.data.estimates.check_times_match`) and the same copies of
        its dither flag and F/T columns (two recordings of one campaign can share time stamps and
        metadata), compared by digest, a block at a time."""
        mine = self.fingerprint()
        for e in ests:
            if e.n_rows != len(self.t) or plain(e.meta.get("recording")) != plain(self.meta):
                continue
            cols = [str(c) for c in e.columns]
            if _fingerprint(lambda c, e=e: e.blocks(self.chunk, c), cols, e.n_rows) == mine:
                return e
        return None


def _fingerprint(
    blocks: Callable[[list[str]], Iterator[pd.DataFrame]], columns: list[str], n: int
) -> tuple[int, str, str | None, str | None]:
    """(rows, sha256 of ``t`` as float64, of the dither flag as bool, of ``f_x..m_z`` as
    float64 row by row); None for a column family the table lacks."""
    has_d = "dither" in columns
    has_w = all(c in columns for c in COMPONENTS)
    ht, hd, hw = hashlib.sha256(), hashlib.sha256(), hashlib.sha256()
    cols = ["t"] + (["dither"] if has_d else []) + (list(COMPONENTS) if has_w else [])
    for f in blocks(cols):
        ht.update(np.ascontiguousarray(f["t"].to_numpy(dtype=float)).tobytes())
        if has_d:
            hd.update(np.ascontiguousarray(f["dither"].to_numpy(dtype=bool)).tobytes())
        if has_w:
            hw.update(np.ascontiguousarray(f[list(COMPONENTS)].to_numpy(dtype=float)).tobytes())
    return n, ht.hexdigest(), hd.hexdigest() if has_d else None, hw.hexdigest() if has_w else None


def _span(t: np.ndarray, t0: float, t1: float) -> tuple[int, int]:
    """Rows ``[i0, i1)`` of the increasing ``t`` with ``t0 <= t <= t1``."""
    return int(np.searchsorted(t, t0, "left")), int(np.searchsorted(t, t1, "right"))


def _gravity_and_sensor_torque(r: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Gravity and ``J^T F`` of the F/T sensor (zero without one), each (N, n) [N·m]: the
    recording's cached :func:`ditherlab.physics.effects.signals`."""
    sig = signals(r)
    g = sig.gravity
    if not r.has_wrench:
        return g, np.zeros_like(g)
    return g, sig.jtf(r.wrench)


def _extraction(
    log: RecordingLog, est: EstimatesSource | None, i0: int, i1: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """``upper, lower, signal`` (i1 - i0, n) [N·m] on the rows ``[i0, i1)`` and the period [s]
    of the dither extraction.

    Read from the estimates file (its ``extract/*_j`` columns and ``dither_period``: what replay
    extracted and used); only for a recording given without its estimates is the extraction done
    here (:func:`ditherlab.physics.dither.extract_dither`, the same one, on the rows with 2 s of context).
    None without dither.
    """
    n = sum(1 for c in log.columns if c.startswith("tau_") and c[4:].isdigit())
    names = ("upper", "lower", "signal")
    cols = [f"extract/{s}_{j}" for s in names for j in range(1, n + 1)]
    if est is not None and est.meta.get("dither_period") and all(c in est.columns for c in cols):
        take = np.zeros(est.n_rows, dtype=bool)
        take[i0:i1] = True
        d = _rows_of(est, take, cols, log.chunk).data
        u, lo, sg = (d[cols[k * n : (k + 1) * n]].to_numpy(dtype=float) for k in range(3))
        return u, lo, sg, float(est.meta["dither_period"])
    rec, sl = log.window(i0, i1)
    ext = extract_dither(rec)
    if ext is None:
        return None
    return ext.upper[sl], ext.lower[sl], ext.signal[sl], ext.period


def _torque_figures(
    ests: list[EstimatesSource], logs: list[RecordingLog], out: Path, blocks: list[tuple]
) -> list[str]:
    """Figs. 2, 4, 5 from the recordings (with the model stored in the estimates)."""
    model = TorqueModel.from_dict(ests[0].meta["model"])
    still = model.regimes.get(STILL.label)
    plain_log = next((r for r in logs if not r.dithered), None)
    dith = next((r for r in logs if r.dithered), None)
    written = []
    # joint 2 carries x and z pushes in the paper's pose; pick the joint most loaded by the pushes
    joint = 2
    j = joint - 1
    panels = []
    for title, r in (("without dither", plain_log), ("with dither", dith)):
        if r is None or not r.has_wrench or still is None:
            continue
        rec, m = r.window(*r.from_first_push(25.0))
        g, ext = _gravity_and_sensor_torque(rec)
        panels.append(
            (
                title,
                rec.t[m],
                (rec.tau - g)[m, j],
                ext[m, j],
                (float(still.tau_min[j]), float(still.tau_max[j])),
            )
        )
    if panels:
        figs.fig2_torques(panels, out / "fig2_torques.png", joint)
        written.append("fig2_torques.png")
        blocks.append(
            (
                "img",
                "fig2_torques.png",
                f"Fig. 2: torque of joint {joint} minus gravity, J^T F of the sensor and the "
                "identified still band, without and with dither.",
            )
        )
    if dith is not None and still is not None:
        written += _dither_figures(dith, dith.estimates_of(ests), model, joint, out, blocks)
    return written


def _dither_figures(
    dith: RecordingLog,
    est: EstimatesSource | None,
    model: TorqueModel,
    joint: int,
    out: Path,
    blocks: list[tuple],
) -> list[str]:
    """Figs. 4 and 5 of the dithered recording, their blocks appended to ``blocks``; the files
    written."""
    i0, i1 = dith.from_first_push(6.0)
    ext_sig = _extraction(dith, est, i0, i1)
    if ext_sig is None:
        return []
    _fig4(dith, ext_sig, (i0, i1), model, joint, out / "fig4_extraction.png")
    blocks.append(
        (
            "img",
            "fig4_extraction.png",
            "Fig. 4: upper and lower one-period means, the extracted signal against "
            "J^T F of the sensor, the still band and the band used with dither.",
        )
    )
    _fig5(dith, ext_sig[3], model, joint, out / "fig5_dither_control.png")
    blocks.append(
        (
            "img",
            "fig5_dither_control.png",
            "Fig. 5: centre and amplitude of the logged torque (five-period means), "
            "the feedforward, and the torque with the band around gravity.",
        )
    )
    return ["fig4_extraction.png", "fig5_dither_control.png"]


def _fig4(
    dith: RecordingLog,
    ext_sig: tuple[np.ndarray, np.ndarray, np.ndarray, float],
    rows: tuple[int, int],
    model: TorqueModel,
    joint: int,
    path: Path,
) -> None:
    """Fig. 4 of the rows ``rows`` of the dithered recording: the extraction ``ext_sig``
    (upper, lower, signal [N·m], period [s]) of the 1-based ``joint`` against J^T F and the
    model's bands."""
    upper, lower, signal, _ = ext_sig
    still = model.regimes[STILL.label]
    j = joint - 1
    rec, m = dith.window(*rows)
    g, ext = _gravity_and_sensor_torque(rec)
    g, ext, gm = g[m], ext[m], g[m, j]
    db = model.regimes.get(DITHER.label)
    nb = (float(db.tau_min[j]), float(db.tau_max[j])) if db is not None else (0.0, 0.0)
    figs.fig4_extraction(
        rec.t[m],
        upper[:, j] - gm,
        lower[:, j] - gm,
        signal[:, j] - gm,
        rec.tau[m, j] - gm,
        ext[:, j],
        (float(still.tau_min[j]), float(still.tau_max[j])),
        nb,
        path,
        joint,
    )


def _fig5(dith: RecordingLog, period: float, model: TorqueModel, joint: int, path: Path) -> None:
    """Fig. 5 of the dithered recording around the dither's start (dither ``period`` [s]) for
    the 1-based ``joint``: five-period means, which replay does not write, extracted here on the
    rows shown with five periods of history before them."""
    assert dith.dither is not None
    still = model.regimes[STILL.label]
    j = joint - 1
    on = np.flatnonzero(dith.dither)
    t_on = dith.t[on[0]] if len(on) else dith.t[0]
    i0, i1 = _span(dith.t, t_on - 1.0, t_on + 6.0)
    five_w = int(np.ceil(5 * period / _step(dith.t))) + 1
    rec, m = dith.window(i0, i1, context=five_w)
    g = _gravity_and_sensor_torque(rec)[0]
    five = extract(
        rec.tau, rec.t, period, periods=5, dt=_step(dith.t), waveform=dither_waveform(dith.meta)
    )
    ffw = rec.tau_ffw[m, j] if rec.tau_ffw is not None else None
    figs.fig5_dither_control(
        rec.t[m],
        five.centre[m, j],
        five.amplitude[m, j],
        ffw,
        rec.tau[m, j],
        g[m, j],
        (float(still.tau_min[j]), float(still.tau_max[j])),
        _amplitude_reference(dith.meta, j),
        path,
        joint,
    )


def _amplitude_reference(meta: dict, j: int) -> float | None:
    """The simulator's dither amplitude set point [N·m] of 0-based joint ``j`` (its
    ``amplitude_fraction`` of the static friction), None for a log without them."""
    sim = meta.get("sim", {})
    frac = (sim.get("params", {}).get("dither", {}) or {}).get("amplitude_fraction")
    stat = (sim.get("bands", {}) or {}).get("static")
    if frac is not None and stat is not None:
        fr = frac[j] if isinstance(frac, list) else frac
        return float(fr) * float(stat[j])
    return None


def _step(t: np.ndarray) -> float:
    """The median sample step [s] of the whole recording (what ``extract`` takes by default)."""
    return float(np.median(np.diff(t))) if len(t) > 1 else 1.0


def summary_text(analysis: dict) -> str:
    """The main table (:func:`comparison`) as plain text (what the CLI and the demo print)."""
    head, rows = comparison(analysis)[2]
    widths = [max(len(head[i]), *(len(r[i]) for r in rows)) for i in range(len(head))]
    line = "  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))
    out = [line, "-" * len(line)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(out)

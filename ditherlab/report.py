"""The report: the paper's §VI-C table beside ours, detection statistics, figures (Markdown + HTML).

:func:`make_report` analyses estimates files (:func:`ditherlab.thresholds.analyse`), then writes
into one folder ``report.md``, ``report.html``, ``report.json`` (the same numbers) and PNG figures
(:mod:`ditherlab.viz.figures`): the forces of the paper's Fig. 6, the response against applied
force with the detection curves, and — when the recordings are given — the torques of Fig. 2,
the extraction of Fig. 4 and the dither control of Fig. 5. Nothing is written when the analysis
fails (no F/T columns, no pushes).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.dither import extract, extract_dither
from ditherlab.effects import signals
from ditherlab.errors import RecordingError
from ditherlab.estimates import Estimates, check_estimates_match
from ditherlab.io import read
from ditherlab.io.atomic import atomic_write_json, atomic_write_text, check_not_input
from ditherlab.model import TorqueModel
from ditherlab.recording import DITHER, STILL, Recording
from ditherlab.thresholds import AXES, PAPER, analyse, find_pushes
from ditherlab.viz import figures as figs


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
                    _ci(d["curve"], "F50"),
                    _ci(d["curve"], "F90"),
                    _fmt(d["error_rms"]),
                    _fmt(d["width"]),
                    f"{d['coverage']:.1%}",
                ]
            )
    return head, rows


def coverage_table(analysis: dict, level: str) -> tuple[list[str], list[list[str]]]:
    """Per condition: interval coverage of the F/T force over all samples and at rest."""
    head = [
        "condition",
        f"coverage, all samples (nominal {level})",
        "coverage at rest",
        "mean width at rest",
    ]
    rows = [
        [n, f"{c['coverage_all']:.1%}", f"{c['coverage_rest']:.1%}", _fmt(c["width_rest"])]
        for n, c in analysis["conditions"].items()
    ]
    return head, rows


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


# ------------------------------------------------------------------------------ main entry
def make_report(
    estimates: Sequence[str | Path | Estimates],
    out_dir: str | Path,
    *,
    recordings: Sequence[Any] = (),
    n_boot: int = 200,
    seed: int = 0,
    figures: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Analyse estimates and write the report folder.

    Parameters
    ----------
    estimates : estimates files (or loaded :class:`~ditherlab.replay.Estimates`)
    out_dir : folder to write (created; files written atomically)
    recordings : the recordings (Recording objects or paths) behind the estimates, optional:
        with them the torque figures (Figs. 2, 4, 5) are drawn too
    n_boot, seed : bootstrap of the detection curves
    figures : draw the PNG figures
    progress : ``progress(done, total)``

    Returns
    -------
    The analysis dict (as written to ``report.json``), with ``files`` listing what was written.

    Raises
    ------
    NoPushesError
        No F/T columns or no pushes: nothing is written.
    """
    out = Path(out_dir)
    ests = [e if isinstance(e, Estimates) else Estimates.load(e) for e in estimates]
    for e in estimates:
        if not isinstance(e, Estimates):
            check_not_input(out / "report.json", [e])
    steps = 3 + (4 if figures else 0)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    analysis = analyse(ests, n_boot=n_boot, seed=seed)
    tick()
    level = ests[0].meta.get("interval", {})
    level_txt = f"{level.get('level', 0.95):.0%} {level.get('method', '')}".strip()
    blocks: list[tuple] = [("h1", "ditherlab report: force detection with and without dither")]
    files = [("estimates", e.name or "<memory>") for e in ests]
    blocks.append(
        ("p", "Estimates: " + ", ".join(f for _, f in files) + ". Intervals: " + level_txt + ".")
    )
    blocks.append(("h2", "The paper's §VI-C statistics beside ours"))
    blocks.append(
        (
            "p",
            "Each cell: smallest applied force whose estimate rose above the noise "
            "level / smallest applied force beyond which every estimate exceeded 10 N. "
            "Paper: Stolt et al., ABB IRB140, about 50 pushes per direction.",
        )
    )
    h, r = paper_table(analysis)
    blocks.append(("table", h, r))
    blocks.append(("h2", "Definitions"))
    for k, v in analysis["definitions"].items():
        blocks.append(("p", f"{k}: {v}."))
    blocks.append(("h2", "All conditions and directions"))
    h, r = detail_table(analysis)
    blocks.append(("table", h, r))
    blocks.append(("h2", "Interval coverage against the F/T sensor (forces)"))
    h, r = coverage_table(analysis, level_txt)
    blocks.append(("table", h, r))
    blocks.append(("h2", "Pushes found"))
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
    blocks.append(("table", ["file", "dither", "pushes", "x", "y", "z"], prow))
    tick()
    written: list[str] = []
    if figures:
        out.mkdir(parents=True, exist_ok=True)
        written += _figures(ests, analysis, recordings, out, blocks, tick)
    analysis["files"] = written + ["report.md", "report.html", "report.json"]
    atomic_write_text(out / "report.md", render(blocks, "md"))
    atomic_write_text(out / "report.html", render(blocks, "html"))
    atomic_write_json(out / "report.json", analysis)
    tick()
    return analysis


def _figures(
    ests: list[Estimates],
    analysis: dict,
    recordings: Sequence[Any],
    out: Path,
    blocks: list[tuple],
    tick: Callable[[], None],
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
                panels.append((f"{variant} ({label})", e, rinfo))
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
    recs = [_as_recording(r) for r in recordings]
    if recs:
        written += _torque_figures(ests, recs, out, blocks)
    tick()
    tick()
    return written


def _as_recording(r: Any) -> Recording:
    return r if isinstance(r, Recording) else read(r)


def _gravity_and_sensor_torque(r: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Gravity and ``J^T F`` of the F/T sensor (zero without one), each (N, n) [N·m]: the
    recording's cached :func:`ditherlab.effects.signals`."""
    sig = signals(r)
    g = sig.gravity
    if not r.has_wrench:
        return g, np.zeros_like(g)
    return g, sig.jtf(r.wrench)


def _estimates_of(rec: Recording, ests: Sequence[Estimates]) -> Estimates | None:
    """The estimates computed from ``rec``, or None: the same time stamps and recording metadata
    (:func:`ditherlab.estimates.check_estimates_match`) and the same copies of its dither flag
    and F/T columns (two recordings of one campaign can share time stamps and metadata)."""
    for e in ests:
        try:
            check_estimates_match(rec, e)
        except RecordingError:
            continue
        if _same_or_none(rec.dither, e.dither) and _same_or_none(rec.wrench, e.wrench):
            return e
    return None


def _same_or_none(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def _extraction(
    rec: Recording, est: Estimates | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """``upper, lower, signal`` (N, n) [N·m] and the period [s] of the dither extraction.

    Read from the estimates file (its ``extract/*_j`` columns and ``dither_period``: what replay
    extracted and used); only for a recording given without its estimates is the extraction done
    here (:func:`ditherlab.dither.extract_dither`, the same one). None without dither.
    """
    cols = {
        s: [f"extract/{s}_{j}" for j in range(1, rec.n + 1)] for s in ("upper", "lower", "signal")
    }
    if (
        est is not None
        and est.meta.get("dither_period")
        and all(c in est.data.columns for cs in cols.values() for c in cs)
    ):
        u, lo, sg = (est.data[cs].to_numpy(dtype=float) for cs in cols.values())
        return u, lo, sg, float(est.meta["dither_period"])
    ext = extract_dither(rec)
    if ext is None:
        return None
    return ext.upper, ext.lower, ext.signal, ext.period


def _from_first_push(r: Recording, length: float) -> np.ndarray:
    """(N,) bool: ``length`` [s] from 1 s before the first push of the F/T sensor (or the start)."""
    ps = find_pushes(r.t, r.wrench) if r.has_wrench else []
    t0 = ps[0].start - 1.0 if ps else r.t[0]
    return (r.t >= t0) & (r.t <= t0 + length)


def _torque_figures(
    ests: list[Estimates], recs: list[Recording], out: Path, blocks: list[tuple]
) -> list[str]:
    """Figs. 2, 4, 5 from the recordings (with the model stored in the estimates)."""
    model = TorqueModel.from_dict(ests[0].meta["model"])
    still = model.regimes.get(STILL.label)
    plain = next((r for r in recs if r.dither is None or not r.dither.any()), None)
    dith = next((r for r in recs if r.dither is not None and r.dither.any()), None)
    written = []
    # joint 2 carries x and z pushes in the paper's pose; pick the joint most loaded by the pushes
    joint = 2
    panels = []
    for title, r in (("without dither", plain), ("with dither", dith)):
        if r is None or not r.has_wrench or still is None:
            continue
        g, ext = _gravity_and_sensor_torque(r)
        m = _from_first_push(r, 25.0)
        j = joint - 1
        panels.append(
            (
                title,
                r.t[m],
                (r.tau - g)[m, j],
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
        ext_sig = _extraction(dith, _estimates_of(dith, ests))
        if ext_sig is not None:
            upper, lower, signal, period = ext_sig
            g, ext = _gravity_and_sensor_torque(dith)
            m = _from_first_push(dith, 6.0)
            j = joint - 1
            db = model.regimes.get(DITHER.label)
            nb = (float(db.tau_min[j]), float(db.tau_max[j])) if db is not None else (0.0, 0.0)
            figs.fig4_extraction(
                dith.t[m],
                (upper - g)[m, j],
                (lower - g)[m, j],
                (signal - g)[m, j],
                (dith.tau - g)[m, j],
                ext[m, j],
                (float(still.tau_min[j]), float(still.tau_max[j])),
                nb,
                out / "fig4_extraction.png",
                joint,
            )
            written.append("fig4_extraction.png")
            blocks.append(
                (
                    "img",
                    "fig4_extraction.png",
                    "Fig. 4: upper and lower one-period means, the extracted signal against "
                    "J^T F of the sensor, the still band and the band used with dither.",
                )
            )
            # Fig. 5 shows five-period means, which replay does not write: extracted here.
            five = extract(dith.tau, dith.t, period, periods=5)
            on = np.flatnonzero(dith.dither)
            t_on = dith.t[on[0]] if len(on) else dith.t[0]
            m = (dith.t >= t_on - 1.0) & (dith.t <= t_on + 6.0)
            ffw = dith.tau_ffw[m, j] if dith.tau_ffw is not None else None
            amp_ref = None
            sim = dith.meta.get("sim", {})
            frac = (sim.get("params", {}).get("dither", {}) or {}).get("amplitude_fraction")
            stat = (sim.get("bands", {}) or {}).get("static")
            if frac is not None and stat is not None:
                fr = frac[j] if isinstance(frac, list) else frac
                amp_ref = float(fr) * float(stat[j])
            figs.fig5_dither_control(
                dith.t[m],
                five.centre[m, j],
                five.amplitude[m, j],
                ffw,
                dith.tau[m, j],
                g[m, j],
                (float(still.tau_min[j]), float(still.tau_max[j])),
                amp_ref,
                out / "fig5_dither_control.png",
                joint,
            )
            written.append("fig5_dither_control.png")
            blocks.append(
                (
                    "img",
                    "fig5_dither_control.png",
                    "Fig. 5: centre and amplitude of the logged torque (five-period means), "
                    "the feedforward, and the torque with the band around gravity.",
                )
            )
    return written


def summary_text(analysis: dict) -> str:
    """The paper's table as plain text (what the CLI and the demo print)."""
    head, rows = paper_table(analysis)
    widths = [max(len(head[i]), *(len(r[i]) for r in rows)) for i in range(len(head))]
    line = "  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))
    out = [line, "-" * len(line)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(out)

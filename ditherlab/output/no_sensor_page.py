"""The report's pages for estimates without a force sensor
(:func:`ditherlab.analysis.no_sensor.no_sensor_analysis`): the estimate over time with its events
shaded (one PNG per file), the events, the noise level at rest and the predicted thresholds,
written as ``report.md``, ``report.html`` and ``report.json`` with
:func:`ditherlab.output.report_page.render`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.no_sensor import AXES
from ditherlab.core.files import atomic_path, atomic_write_json, atomic_write_text
from ditherlab.data.estimates import EstimatesSource
from ditherlab.output import figures as figs
from ditherlab.output.report_page import render

__all__ = ["no_sensor_blocks", "no_sensor_lines", "write_no_sensor_pages"]


def _n(x: float | None, unit: str = " N") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if math.isinf(x):
        return "never"
    return f"{x:.1f}{unit}"


def events_table(variant: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """One variant's events: interval [s], duration [s], largest |F̂| [N] and its components."""
    head = ["start [s]", "end [s]", "duration [s]", "largest |F̂|", "at [s]", "F̂ x / y / z there"]
    rows = [
        [
            f"{e['start']:.2f}",
            f"{e['end']:.2f}",
            f"{e['end'] - e['start']:.2f}",
            _n(e["peak"]),
            f"{e['at']:.2f}",
            " / ".join(f"{e['peak_axes'][a]:+.1f}" for a in AXES) + " N",
        ]
        for e in variant["events"]
    ]
    return head, rows


def variants_table(entry: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The user's own variants side by side: events, largest event, noise level at rest."""
    head = ["estimator", "events", "largest event", "largest |F̂|", "noise level at rest x/y/z"]
    rows = []
    for v in entry["variants"].values():
        big = max((e["peak"] for e in v["events"]), default=None)
        nl = " / ".join(_n(v["noise_level"][a], "") for a in AXES) + " N"
        rows.append([v["label"], str(len(v["events"])), _n(big), _n(v["largest"]), nl])
    return head, rows


def thresholds_table(th: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Predicted F50 / F90 per push direction."""
    head = ["direction", "F50", "F90", "joints that carry it"]
    rows = [
        [k, _n(d["f50"]), _n(d["f90"]), ", ".join(str(j) for j in d["joints"]) or "-"]
        for k, d in th["directions"].items()
    ]
    return head, rows


def no_sensor_blocks(analysis: dict[str, Any], level_txt: str) -> list[tuple]:
    """The report's blocks: per file the variants compared, each variant's events and the
    predicted thresholds, then the definitions."""
    blocks: list[tuple] = [
        ("h1", "ditherlab report: estimates without a force sensor"),
        (
            "p",
            "No F/T columns: no pushes of known size to score. Shown: what the estimator "
            f"detected (its {level_txt} interval excludes zero), the noise level at rest, and "
            "the thresholds predicted for this robot at its rest pose.",
        ),
    ]
    for f in analysis["files"]:
        blocks += [("h2", f"{f['file']} ({f['duration']:.1f} s)"), ("table", *variants_table(f))]
        for v in f["variants"].values():
            blocks.append(("p", f"Events, {v['label']}: {len(v['events'])}."))
            if v["events"]:
                blocks.append(("table", *events_table(v)))
            if "thresholds" in v:
                q = ", ".join(f"{math.degrees(x):.1f}" for x in v["thresholds"]["q"])
                blocks.append(("p", f"Predicted thresholds, {v['label']}, at q = ({q}) deg:"))
                blocks.append(("table", *thresholds_table(v["thresholds"])))
        if f.get("figure"):
            blocks.append(
                ("img", f["figure"], f"{f['file']}: the estimate over time, events shaded")
            )
    blocks.append(("h2", "Definitions"))
    blocks += [("p", f"{k}: {v}.") for k, v in analysis["definitions"].items()]
    return blocks


def no_sensor_lines(analysis: dict[str, Any]) -> list[str]:
    """What the CLI prints: per file and variant, the events and the noise level at rest."""
    out = []
    for f in analysis["files"]:
        out.append(f"{f['file']} ({f['duration']:.1f} s), no F/T sensor:")
        for v in f["variants"].values():
            nl = " / ".join(_n(v["noise_level"][a], "") for a in AXES)
            out.append(f"  {v['label']}: {len(v['events'])} events; noise at rest x/y/z {nl} N")
            for e in v["events"]:
                out.append(
                    f"    {e['start']:.2f}-{e['end']:.2f} s ({e['end'] - e['start']:.1f} s), "
                    f"largest |F̂| {e['peak']:.1f} N"
                )
            th = v.get("thresholds")
            if th:
                out.append(
                    "    predicted F50 / F90 at the rest pose: "
                    + "  ".join(
                        f"{k} {_n(d['f50'], '')}/{_n(d['f90'], '')}"
                        for k, d in th["directions"].items()
                    )
                    + " N"
                )
    return out


def _figure(src: EstimatesSource, entry: dict[str, Any], path: Path) -> Path:
    """|F̂| of every variant over time, its events shaded."""
    plt = figs.pyplot()
    t = src.column("t").astype(float)
    n = max(len(entry["variants"]), 1)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n), sharex=True, squeeze=False)
    for ax, (v, row) in zip(axes[:, 0], entry["variants"].items(), strict=False):
        F = np.stack([src.column(f"{v}/f_{a}").astype(float) for a in AXES], axis=1)
        ax.plot(t, np.linalg.norm(F, axis=1), lw=0.7, color="tab:blue", label="|F̂|")
        for e in row["events"]:
            ax.axvspan(e["start"], e["end"], color="tab:orange", alpha=0.25, lw=0)
        ax.set_ylabel("|F̂| [N]")
        ax.set_title(row["label"], fontsize=9)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def write_no_sensor_pages(
    ests: Sequence[EstimatesSource], analysis: dict[str, Any], level_txt: str, out: Path
) -> list[str]:
    """Write the figures, ``report.md``, ``report.html`` and ``report.json`` into ``out``
    (atomically each); returns the files' names."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for k, (src, entry) in enumerate(zip(ests, analysis["files"], strict=True)):
        name = f"estimate_{k + 1}.png"
        _figure(src, entry, out / name)
        entry["figure"] = name
        written.append(name)
    blocks = no_sensor_blocks(analysis, level_txt)
    analysis["files_written"] = written + ["report.md", "report.html", "report.json"]
    atomic_write_text(out / "report.md", render(blocks, "md"))
    atomic_write_text(out / "report.html", render(blocks, "html"))
    atomic_write_json(out / "report.json", analysis)
    return analysis["files_written"]

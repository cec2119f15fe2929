"""The report's section on a known load: the estimate against the known wrench
(:func:`ditherlab.analysis.known_load.known_load_analysis`), as text blocks of
:func:`ditherlab.output.report_page.render`, as the pages of a report that has no pushes, and as
the lines the CLI prints."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ditherlab.analysis.known_load import known_load_text
from ditherlab.core.files import atomic_write_json, atomic_write_text
from ditherlab.core.names import FORCE_AXES
from ditherlab.output.report_page import render

__all__ = ["known_load_blocks", "known_load_lines", "known_load_table", "write_known_load_pages"]

_HEAD = ["variant", "axis", "known mean", "estimated mean", "error RMS", "bias", "coverage"]


def known_load_table(entry: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """One file's table: per variant and force axis the known and estimated mean force [N], the
    error RMS and bias [N] and the interval coverage of the known force."""
    rows = []
    ref = entry["reference_mean"]
    for v, r in entry["variants"].items():
        for k, ax in enumerate(FORCE_AXES):
            rows.append(
                [
                    v,
                    ax,
                    f"{ref[k]:.2f} N",
                    f"{ref[k] + r['bias'][k]:.2f} N",
                    f"{r['rms'][k]:.2f} N",
                    f"{r['bias'][k]:+.2f} N",
                    _share(r["coverage"], k),
                ]
            )
    return _HEAD, rows


def _share(coverage: list[float] | None, k: int | None) -> str:
    """Axis ``k``'s coverage (the force axes' mean for None) as a percentage; "no interval" for
    the vendor's own estimate, which has none."""
    if coverage is None:
        return "no interval"
    return f"{(coverage[k] if k is not None else sum(coverage[:3]) / 3):.1%}"


def known_load_blocks(known: dict[str, Any], level_txt: str) -> list[tuple]:
    """The section's blocks (``("h2" | "p", text)``, ``("table", head, rows)``)."""
    blocks: list[tuple] = [("h2", "Estimated against the known load")]
    blocks.append(
        (
            "p",
            "The wrench the arm exerts on the declared load (its weight, and its inertia while "
            "the arm moves), plus the F/T sensor's reading where the log has one (a contact "
            "beside the load), is the reference: error = estimate - known, over every sample; "
            f"coverage = share of samples whose {level_txt} interval holds the known force.",
        )
    )
    for entry in known["files"]:
        blocks.append(("p", f"{entry['file']}: load {known_load_text(entry['load'])}."))
        h, r = known_load_table(entry)
        blocks.append(("table", h, r))
    return blocks


def known_load_lines(known: dict[str, Any]) -> list[str]:
    """Per file and variant one line: known and estimated mean force x/y/z [N], error RMS."""
    out = []
    for entry in known["files"]:
        ref = entry["reference_mean"]
        out.append(
            f"{entry['file']}: known load {known_load_text(entry['load'])}, known mean force "
            f"x/y/z {ref[0]:.1f}/{ref[1]:.1f}/{ref[2]:.1f} N"
        )
        for v, r in entry["variants"].items():
            est = [ref[k] + r["bias"][k] for k in range(3)]
            rms = r["rms"]
            out.append(
                f"  {v:<16} estimated mean {est[0]:.1f}/{est[1]:.1f}/{est[2]:.1f} N, error RMS "
                f"{rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f} N, coverage "
                f"{_share(r['coverage'], None)}"
            )
    if "no_table" in known:
        out.append(f"no detection table: {known['no_table']}")
    return out


def write_known_load_pages(
    names: Sequence[str], analysis: dict[str, Any], level_txt: str, out: Path
) -> list[str]:
    """A report of estimates without pushes whose recordings declare a known load:
    ``report.md``, ``report.html`` and ``report.json`` (the analysis, with ``files``) in
    ``out``; returns the files' names."""
    blocks: list[tuple] = [("h1", "ditherlab report: the estimate against a known load")]
    why = analysis["known_load"].get("no_table", "no pushes")
    blocks.append(("p", "Estimates: " + ", ".join(names) + f". No detection table: {why}."))
    blocks += known_load_blocks(analysis["known_load"], level_txt)
    analysis["files"] = ["report.md", "report.html", "report.json"]
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "report.md", render(blocks, "md"))
    atomic_write_text(out / "report.html", render(blocks, "html"))
    atomic_write_json(out / "report.json", analysis)
    return analysis["files"]

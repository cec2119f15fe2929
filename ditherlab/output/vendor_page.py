"""The report's section on the vendor's own estimate beside ditherlab's
(:func:`ditherlab.analysis.vendor.compare`, stored as ``analysis["vendor"]``): one table per
metric family, as blocks of :func:`ditherlab.output.report_page.render`, and the lines the CLI
prints."""

from __future__ import annotations

from typing import Any

import numpy as np

from ditherlab.core.names import FORCE_AXES

__all__ = ["vendor_blocks", "vendor_text"]


def _n(x: Any, nd: int = 1) -> str:
    """A number [N] with ``nd`` decimals, "–" for None or NaN."""
    return "–" if x is None or not np.isfinite(x) else f"{x:.{nd}f}"


def _axes(d: dict[str, Any] | None, nd: int = 1) -> str:
    """``x / y / z`` of a per-axis dict."""
    d = d or {}
    return " / ".join(_n(d.get(a), nd) for a in FORCE_AXES)


def _direction(row: dict[str, Any], key: str) -> str:
    return " / ".join(_n(row["directions"].get(a, {}).get(key)) for a in FORCE_AXES)


def vendor_table(vendor: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """Per estimator (ditherlab's conditions, then ``vendor``): error RMS, bias at rest, noise
    level, the detection thresholds per direction [N] and the interval coverage at rest."""
    head = [
        "estimator",
        "error RMS x/y/z [N]",
        "bias at rest x/y/z [N]",
        "noise level x/y/z [N]",
        "response from x/y/z [N]",
        ">10 N from x/y/z [N]",
        "F50 x/y/z [N]",
        "coverage at rest",
    ]
    rows = []
    for name, r in vendor["estimators"].items():
        cov = r["coverage"]
        rows.append(
            [
                name,
                _axes(r["error_rms"]),
                _axes(r["bias_rest"], 2),
                _axes(r["noise_level"]),
                _direction(r, "response_min"),
                _direction(r, "above10_from"),
                _direction(r, "F50"),
                "no interval" if cov is None else f"{cov:.1%}",
            ]
        )
    return head, rows


def vendor_blocks(analysis: dict[str, Any]) -> list[tuple]:
    """The report's blocks on the vendor's estimate; none when the estimates hold none."""
    vendor = analysis.get("vendor")
    if not vendor:
        return []
    sources = ", ".join(f"{f}: from its {s}" for f, s in vendor["sources"].items())
    head, rows = vendor_table(vendor)
    return [
        ("h2", "The vendor's estimate beside ditherlab's"),
        (
            "p",
            f"Both against the {vendor['reference']}, with the same functions: the error RMS "
            "over all samples, the mean error on the rest samples (bias), the noise level and "
            "the detection thresholds of the table above, the interval coverage at rest "
            f"(ditherlab's only; the vendor gives no interval). The vendor's estimate: {sources}.",
        ),
        ("table", head, rows),
    ]


def vendor_text(analysis: dict[str, Any]) -> str:
    """A few plain lines: per estimator its error RMS and bias at rest (what the CLI prints);
    empty without the vendor's estimate."""
    vendor = analysis.get("vendor")
    if not vendor:
        return ""
    lines = [f"the vendor's estimate beside ditherlab's, against the {vendor['reference']}:"]
    for name, r in vendor["estimators"].items():
        lines.append(
            f"  {name:<26} error RMS x/y/z {_axes(r['error_rms'])} N,"
            f" bias at rest {_axes(r['bias_rest'], 2)} N,"
            f" response from {_direction(r, 'response_min')} N"
        )
    return "\n".join(lines)

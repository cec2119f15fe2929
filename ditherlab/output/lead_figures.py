"""The lead-through comparison's outputs (:func:`ditherlab.app.leadthrough.compare_laws`): a Markdown
table, the JSON of every run, and a figure of the tool's path over time under each law.

Nothing is recomputed here: the numbers are the analysis's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.lead_metrics import COMPARED, means_table
from ditherlab.core.files import atomic_write_json, atomic_write_text
from ditherlab.output.figures import _save, legend, pyplot

LAW_STYLE = {"dead-zone": "-", "interval": "--"}


def _no_nan(x: Any) -> Any:
    """NaN -> None (JSON null), recursively."""
    if isinstance(x, dict):
        return {k: _no_nan(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_no_nan(v) for v in x]
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def paths_figure(result: Mapping[str, Any], path: Path) -> Path:
    """One column per dither setting of the first seed: the operator's push and the estimate
    [N] above, the tool's displacement from its start [mm] below (and the intended one: the
    admittance driven by the true push), per base axis, each law in its line style. Returns
    the path."""
    plt = pyplot()
    dithers = result["dithers"]
    fig, axes = plt.subplots(2, len(dithers), figsize=(7 * len(dithers), 6.5), squeeze=False)
    for j, dither in enumerate(dithers):
        top, bottom = axes[0, j], axes[1, j]
        for law in result["laws"]:
            tr = result["paths"].get(f"{law}|{dither}")
            if tr is None:
                continue
            t = np.asarray(tr["t"])
            x, fhat = np.asarray(tr["x"]), np.asarray(tr["fhat"])
            for i, a in enumerate("xyz"):
                ls = LAW_STYLE.get(law, ":")
                bottom.plot(t, x[:, i], ls, color=f"C{i}", lw=1.2, label=f"{a}, {law}")
                top.plot(t, fhat[:, i], ls, color=f"C{i}", lw=0.6, alpha=0.7, label=f"F̂{a}, {law}")
            push = np.asarray(tr["push"])
        intended = np.asarray(tr["intended"])
        for i in range(3):
            top.plot(t, push[:, i], color="black", lw=0.8, label="operator" if i == 0 else None)
            bottom.plot(
                t,
                intended[:, i],
                ":",
                color="black",
                lw=0.8,
                label="intended (true push)" if i == 0 else None,
            )
        top.set_ylabel("push [N]")
        top.set_ylim(-60, 60)
        top.set_title(f"seed {result['seeds'][0]}, dither {'on' if dither else 'off'}")
        bottom.set_ylabel("tool displacement [mm]")
        bottom.set_xlabel("t [s]")
        legend(bottom, fontsize=7, ncol=2)
        legend(top, fontsize=6, ncol=3)
    fig.tight_layout()
    return _save(fig, path)


def comparison_markdown(result: Mapping[str, Any]) -> str:
    """The comparison as Markdown: the means table, then every run's summary."""
    lines = [
        "# Lead-through: dead zone or interval",
        "",
        f"Seeds {', '.join(str(s) for s in result['seeds'])}; means over the seeds "
        "(metrics defined in `ditherlab.analysis.lead_metrics`).",
        "",
        means_table(result),
        "",
        "Better: " + "; ".join(f"{h}: {b}" for _, h, _, b in COMPARED) + ".",
        "",
        "## Runs",
        "",
        "| dither | law | seed | " + " | ".join(h for _, h, _, _ in COMPARED) + " |",
        "|" + "---|" * (3 + len(COMPARED)),
    ]
    for r in result["runs"]:
        s = r["summary"]
        cells = ["on" if r["dither"] else "off", r["law"], str(r["seed"])]
        cells += [fmt.format(s[key]) for key, _, fmt, _ in COMPARED]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_comparison(result: Mapping[str, Any], out: Path) -> list[Path]:
    """Write ``leadthrough.md``, ``leadthrough.json`` (every run, without the traces) and
    ``leadthrough.png`` into the folder ``out``, each atomically; returns their paths."""
    out = Path(out)
    data = {k: v for k, v in result.items() if k != "paths"}
    return [
        atomic_write_text(out / "leadthrough.md", comparison_markdown(result)),
        atomic_write_json(out / "leadthrough.json", _no_nan(data)),
        paths_figure(result, out / "leadthrough.png"),
    ]

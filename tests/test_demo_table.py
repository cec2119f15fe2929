"""The demo's count of the paper's §VI-C numbers matched within ±30 %."""

from __future__ import annotations

from ditherlab.analysis.detection import PAPER
from ditherlab.app.demo import paper_agreement


def _analysis(scale: float, missing: str | None = None) -> dict:
    """Every statistic at ``scale`` times the paper's; one axis of the dither condition absent."""
    conds = {}
    for cond, label in (("nodither_band", "no dither"), ("dither_band", "dither")):
        dirs = {}
        for a in "xyz":
            if cond == "dither_band" and a == missing:
                continue
            dirs[a] = {
                "response_min": scale * PAPER[label]["response"][a],
                "above10_from": scale * PAPER[label]["above10"][a],
            }
        conds[cond] = {"directions": dirs}
    return {"conditions": conds}


def test_all_cells_within_and_outside():
    assert paper_agreement(_analysis(1.29)) == (12, 12, [])
    within, total, misses = paper_agreement(_analysis(1.31))
    assert (within, total) == (0, 12) and len(misses) == 12
    assert misses[0] == "nodither_band x response: 42 N vs 32 N"


def test_a_missing_direction_counts_as_outside():
    within, total, misses = paper_agreement(_analysis(1.0, missing="y"))
    assert (within, total) == (10, 12)
    assert misses == ["dither_band y response: none vs 10 N", "dither_band y above10: none vs 20 N"]


def test_the_needed_reading_reads_the_smallest_force_above_10_n():
    """The second reading compares ``above10_min``, the first ``above10_from``: an analysis
    whose every-push statistic is 1.5x the paper's and whose smallest-above-10-N statistic is
    the paper's gives 6 and 12 cells."""
    a = _analysis(1.0)
    for cond in a["conditions"].values():
        for d in cond["directions"].values():
            d["above10_min"] = d["above10_from"]
            d["above10_from"] = 1.5 * d["above10_from"]
    assert paper_agreement(a)[:2] == (6, 12)
    assert paper_agreement(a, reading="needed") == (12, 12, [])
    within, _, misses = paper_agreement(_analysis(1.0), reading="needed")
    assert within == 6 and misses[0] == "nodither_band x above10: none vs 40 N"

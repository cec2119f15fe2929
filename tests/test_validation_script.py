"""scripts/validation.py: its paper section end to end at the smallest sizes, and its page writer.

The end-to-end run goes through the CLI as the script does (simulate, identify, replay,
report --json) for two seeds with one push per axis and sign; the checks recompute from the
JSON what the page says (the paper's numbers, the medians, the ±30 % counts) and compare with the
report's own report.json, so a script that mislabels a column, drops a seed or misreads the
report fails here.
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "validation.py"
MARKER = "<!-- generated below by scripts/validation.py -->"
#: Stolt et al. 2015, §VI-C [N], typed from the paper, not from ditherlab
PAPER = {
    ("no dither", "response_min"): (32, 22, 22),
    ("no dither", "above10_min"): (40, 30, 30),
    ("no dither", "above10_from"): (40, 30, 30),
    ("dither", "response_min"): (10, 10, 10),
    ("dither", "above10_min"): (20, 20, 20),
    ("dither", "above10_from"): (20, 20, 20),
}
CONDITION = {"no dither": "nodither_band", "dither": "dither_band"}
SEEDS = 2
HISTORY = re.compile(
    r"\bsessions? \d+|\bissues? #?\d+|\b(?:was|were) tried\b|\bpreviously\b|\bno longer\b", re.I
)


def load_script():
    spec = importlib.util.spec_from_file_location("validation_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def rows_of(page: str, first_header: str) -> list[list[str]]:
    """The body rows of the Markdown table whose header starts with ``first_header``."""
    lines = page.splitlines()
    start = next(i for i, x in enumerate(lines) if x.startswith(f"| {first_header} |"))
    out = []
    for x in lines[start + 2 :]:
        if not x.startswith("|"):
            break
        out.append([c.strip() for c in x.strip("|").split(" | ")])
    return out


def f1(v) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.1f}"


def within(v, paper) -> bool:
    return v is not None and math.isfinite(v) and abs(v - paper) <= 0.3 * paper


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("validation")
    out = d / "validation.md"
    out.write_text(f"# Validation\n\nA hand-written introduction.\n\n{MARKER}\n\nold text\n")
    work = d / "work"
    r = subprocess.run(
        [
            sys.executable, str(SCRIPT), "--quick", "--only", "paper", "--seeds", str(SEEDS),
            "--pushes", "1", "--identify-bootstrap", "0", "--report-bootstrap", "10",
            "--jobs", "2", "--out", str(out), "--work", str(work),
        ],
        capture_output=True,
        text=True,
        timeout=1200,
        check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-4000:]
    page = out.read_text()
    data = json.loads(out.with_suffix(".json").read_text())
    return page, data, work


@pytest.mark.slow
def test_the_page_keeps_its_introduction_and_replaces_what_follows_the_marker(run):
    page, _, _ = run
    assert page.startswith("# Validation\n\nA hand-written introduction.\n")
    assert page.count(MARKER) == 1
    assert "old text" not in page
    after = page.split(MARKER)[1]
    assert "## 1. The paper's table over seeds" in after
    assert "**Quick run**" in after  # a quick run says so
    assert not [x for x in page.splitlines() if HISTORY.search(x)]


@pytest.mark.slow
def test_the_paper_column_holds_the_papers_numbers(run):
    page, data, _ = run
    rows = rows_of(page, "condition")  # the per-cell table comes first
    seen = {}
    for cond, stat, axis, paper, *_ in rows:
        seen[(cond, stat.strip("`"), axis)] = float(paper)
    expected = {
        (cond, stat, a): float(v)
        for (cond, stat), vals in PAPER.items()
        for a, v in zip("xyz", vals, strict=True)
    }
    assert seen == expected
    # the per-seed table's paper row, x / y / z per statistic
    per_seed = rows_of(page, "seed")
    assert per_seed[0][0] == "paper"
    assert per_seed[0][1:7] == [
        " / ".join(map(str, PAPER[(c, s)]))
        for c in ("no dither", "dither")
        for s in ("response_min", "above10_min", "above10_from")
    ]
    assert data["sections"]["paper"]["data"]["paper_matches_report"] is True


@pytest.mark.slow
def test_every_seed_appears_with_its_numbers(run):
    page, data, _ = run
    d = data["sections"]["paper"]["data"]
    assert d["seeds"] == list(range(SEEDS))
    assert d["identification_seeds"] == [s + 1 for s in range(SEEDS)]
    per_seed = {r[0]: r for r in rows_of(page, "seed")[1:]}
    assert sorted(per_seed) == [str(s) for s in range(SEEDS)]
    cells = {(c["condition"], c["statistic"], c["axis"]): c for c in d["cells"]}
    for s in range(SEEDS):
        assert d["per_seed"][str(s)]["status"] == "ok"
        row = per_seed[str(s)]
        k = 1
        for label in ("no dither", "dither"):
            for stat in ("response_min", "above10_min", "above10_from"):
                want = " / ".join(
                    f1(cells[(CONDITION[label], stat, a)]["values"][str(s)]) for a in "xyz"
                )
                assert row[k] == want, (s, label, stat)
                k += 1


@pytest.mark.slow
def test_the_json_reads_each_seeds_report(run):
    """The cells' per-seed values are the report's own report.json numbers."""
    _, data, work = run
    d = data["sections"]["paper"]["data"]
    for s in range(SEEDS):
        rep = json.loads((work / "paper" / f"seed{s}" / "report" / "report.json").read_text())
        for c in d["cells"]:
            got = rep["conditions"][c["condition"]]["directions"][c["axis"]][c["statistic"]]
            assert c["values"][str(s)] == got, (s, c["condition"], c["statistic"], c["axis"])


@pytest.mark.slow
def test_medians_and_the_30_percent_counts_agree_between_json_and_page(run):
    page, data, _ = run
    d = data["sections"]["paper"]["data"]
    rows = {(r[0], r[1].strip("`"), r[2]): r for r in rows_of(page, "condition")}
    for c in d["cells"]:
        vals = [v for v in c["values"].values() if v is not None]
        med = statistics.median(vals) if vals else None
        assert c["median"] == med
        n_within = sum(within(v, c["paper"]) for v in vals)
        assert c["seeds_within"] == n_within
        row = rows[(c["paper_row"], c["statistic"], c["axis"])]
        assert row[4] == f1(med)
        assert row[6] == ("yes" if within(med, c["paper"]) else "no")
        assert row[7] == f"{n_within} of {SEEDS}"
    for reading, key in (("smallest", "above10_min"), ("every", "above10_from")):
        mine = [c for c in d["cells"] if c["statistic"] in ("response_min", key)]
        ag = d["agreement"][reading]
        assert ag["cells"] == 12
        assert ag["median_cells_within"] == sum(within(c["median"], c["paper"]) for c in mine)
        assert ag["seed_cells_within"] == sum(c["seeds_within"] for c in mine)
    sentence = next(x for x in page.splitlines() if x.startswith("**Within ±30 % of the paper**"))
    nums = [int(n) for pair in re.findall(r"(\d+) of (\d+)", sentence) for n in pair]
    ag = d["agreement"]
    assert nums == [
        ag["smallest"]["median_cells_within"], 12, ag["every"]["median_cells_within"], 12,
        ag["smallest"]["seed_cells_within"], 12 * SEEDS,
        ag["every"]["seed_cells_within"], 12 * SEEDS,
    ]  # fmt: skip


# ------------------------------------------------------------------ the page writer, no runs
FUZZ = {
    "cases_requested": 20,
    "seed": 1,
    "cases": 2,
    "wall_seconds": 3.0,
    "slowest_case_seconds": 1.5,
    "per_command": {"info": {"parquet": 2, "with a finding": 1}},
    "classes": {"hang": {"cases": 0, "distinct": 0}, "traceback": {"cases": 1, "distinct": 1}},
    "distinct": [
        {
            "cls": "traceback",
            "cmd": "info",
            "kind": "parquet",
            "n": "1",
            "input": "x",
            "detail": "y",
        }
    ],
    "exit_status": 1,
    "steps": ["python -m tests.fuzz --cases 20 --seed 1 --work DIR --findings FILE"],
}


def test_a_failing_section_writes_its_error_line_and_the_others_still_run(tmp_path, monkeypatch):
    mod = load_script()
    monkeypatch.setenv("PYTHONPATH", "")

    def broken(cfg, work):
        raise mod.StepError("bench bench_io: exit status 1: error: boom")

    monkeypatch.setitem(mod.RUNNERS, "speed", broken)
    monkeypatch.setitem(mod.RUNNERS, "fuzz", lambda cfg, work: FUZZ)
    out = tmp_path / "docs" / "validation.md"  # no page yet: one is created
    code = mod.main(["--only", "speed", "--only", "fuzz", "--out", str(out)])
    assert code == 1
    page = out.read_text()
    assert page.startswith("# Validation\n") and page.count(MARKER) == 1
    speed = page.split("## 4.")[1].split("## 5.")[0]
    assert "**This section's run fails:** bench bench_io: exit status 1: error: boom" in speed
    fuzz = page.split("## 5.")[1]
    assert "| traceback | 1 | 1 |" in fuzz and "| `info` | 2 | 2 | 1 |" in fuzz
    assert "Not run yet" in page.split("## 1.")[1].split("## 2.")[0]
    j = json.loads(out.with_suffix(".json").read_text())["sections"]
    assert j["speed"]["status"] == "error" and j["fuzz"]["status"] == "ok"

    # a later run of one section keeps the other's numbers from the JSON
    monkeypatch.setitem(mod.RUNNERS, "speed", lambda cfg, work: {
        "quick": True, "modules": ["bench_io"], "rows": [
            {"module": "bench_io", "name": "read", "value": 2.0, "unit": "s",
             "reference": 6.0, "ratio": 3.0, "target": "≥ 2×"}],
        "errors": {}, "module_seconds": {"bench_io": 1.0}, "steps": ["python -m bench.run"],
    })  # fmt: skip
    assert mod.main(["--only", "speed", "--out", str(out)]) == 0
    page = out.read_text()
    assert "| io | read | 2 s | 6 s | 3.0× | ≥ 2× |" in page
    assert "| traceback | 1 | 1 |" in page

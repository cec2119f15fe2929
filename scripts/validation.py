"""Write the measured sections of docs/validation.md, and their numbers to docs/validation.json.

Usage (from the repository root, with the project's Python)::

    python scripts/validation.py                      # every section, full sizes (slow)
    python scripts/validation.py --quick              # smoke sizes, minutes
    python scripts/validation.py --only paper --seeds 3 --pushes 10

Every figure on the page comes from a run made by this script; nothing is typed in by hand.
Everything in the page above the line ``<!-- generated below by scripts/validation.py -->`` is
hand-written and kept; everything after it is rewritten from the numbers, which are also
written as JSON beside the page (``--out``'s name with ``.json``). A missing page (or marker) is
created with a short introduction.

Sections (``--only NAME``, repeatable; the sections not run keep their numbers from the JSON
beside the page, each with the date and commit of its own run):

``paper``
    The paper's §VI-C table over seeds: per evaluation seed ``s`` the pipeline of ``make demo``
    through the CLI (paired push campaigns without and with dither, identification on seed
    ``s + 1``, ``identify --add dither_extraction``, ``replay``, ``report --json``); per cell
    the median and range over seeds beside the paper's number, and the cells within ±30 %.
``false-discoveries``
    ``bench/bench_false_discovery.py``'s study (imported): clean simulated recordings through
    ``identify`` and ``diagnose``; a suggestion on one of them is a false discovery.
``real-logs``
    The diagnosis loop on real logs (``convert --mapping ur10e``, ``identify``, ``diagnose``,
    ``identify --add`` of the first suggestion, ``diagnose``): the torque residual per joint
    before and after.
``speed``
    ``python -m bench.run --only MODULE --json FILE`` per bench module (one failing module
    leaves the others), every row with a reference: fast value, reference, ratio, target.
``fuzz``
    ``python -m tests.fuzz``: cases per command and input kind, findings by class.

A section that fails writes its error line into the page; the others still run. Progress goes
to stderr.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import re
import resource
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
MARKER = "<!-- generated below by scripts/validation.py -->"
INTRO = (
    "# Validation\n\n"
    "This page holds the measured evidence: every figure on it is written by "
    "`scripts/validation.py` from the runs that measure it, with the command, seeds, commit and "
    "machine of each run, and is rewritten when they run again.\n"
)
SECTIONS = ("paper", "false-discoveries", "real-logs", "speed", "fuzz")
TITLES = {
    "paper": "The paper's table over seeds",
    "false-discoveries": "False discoveries on clean recordings",
    "real-logs": "The diagnosis loop on real logs",
    "speed": "Speed: fast paths against their references",
    "fuzz": "The fuzz campaign",
}
#: Stolt et al. 2015, §VI-C [N]: the smallest force that gave a response, and the force needed
#: for an estimate above 10 N, without and with dither, per direction
PAPER = {
    "no dither": {
        "response": {"x": 32.0, "y": 22.0, "z": 22.0},
        "above10": {"x": 40.0, "y": 30.0, "z": 30.0},
    },
    "dither": {
        "response": {"x": 10.0, "y": 10.0, "z": 10.0},
        "above10": {"x": 20.0, "y": 20.0, "z": 20.0},
    },
}
AXES = ("x", "y", "z")
#: the two conditions the paper compares: the report's variant and the paper's row
PAPER_CONDITIONS = (("nodither_band", "no dither"), ("dither_band", "dither"))
#: every estimator variant on its own recording (no dither on the no-dither campaign, dither on
#: the dithered one)
CONDITIONS = ("nodither_band", "nodither_noband", "dither_band", "dither_noband")
#: the report's statistics: key, the paper's statistic it is compared with, the page's words
STATS = (
    ("response_min", "response", "smallest push with a response"),
    ("above10_min", "above10", "smallest push estimated above 10 N"),
    ("above10_from", "above10", "force beyond which every push is estimated above 10 N"),
)
#: the two readings of the paper's "force needed for an estimate above 10 N"
READINGS = (("smallest", "above10_min"), ("every", "above10_from"))
TOLERANCE = 0.3
#: words of a history, which no page of the repository holds (the page is checked before it is
#: written; a hit is reported on stderr)
HISTORY = re.compile(
    r"\bsessions? \d+|\bissues? #?\d+|\b(?:was|were) tried\b|\bnot kept\b|\bpreviously\b|"
    r"\bno longer\b",
    re.IGNORECASE,
)

T0 = time.perf_counter()


# ------------------------------------------------------------------------------ plumbing
def log(msg: str) -> None:
    """One progress line on stderr."""
    print(f"[{time.perf_counter() - T0:7.1f} s] {msg}", file=sys.stderr, flush=True)


class SectionSkipped(Exception):
    """A section that cannot run here (its data is absent): the page says why."""


class StepError(Exception):
    """A command of a section exited with an error: its last stderr line."""

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


def child_env() -> dict[str, str]:
    """The environment of every command: this checkout first on the import path."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def last_line(text: str) -> str:
    lines = [x.strip() for x in text.splitlines() if x.strip()]
    return lines[-1] if lines else ""


def run(
    args: Sequence[Any], *, cwd: Path, what: str, ok: Sequence[int] = (0,), timeout: float = None
) -> subprocess.CompletedProcess:
    """Run ``python ARGS`` (this interpreter, this checkout); StepError unless its exit status is
    in ``ok``."""
    argv = [sys.executable, *map(str, args)]
    r = subprocess.run(
        argv,
        cwd=cwd,
        env=child_env(),
        capture_output=True,
        text=True,
        check=False,
        timeout=timeout,
    )
    if r.returncode not in ok:
        raise StepError(
            f"{what}: exit status {r.returncode}: {last_line(r.stderr) or last_line(r.stdout)}",
            r.returncode,
        )
    return r


def ditherlab(*args: Any, cwd: Path, what: str, ok: Sequence[int] = (0,)):
    """``python -m ditherlab ARGS`` (see :func:`run`)."""
    return run(["-m", "ditherlab", *args], cwd=cwd, what=what, ok=ok)


def git(*args: str) -> str:
    r = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=False)
    return r.stdout.strip() if r.returncode == 0 else ""


def commit(exclude: Sequence[Path]) -> str:
    """The checkout's commit, and whether tracked files differ from it (the generated page and
    its JSON aside)."""
    head = git("rev-parse", "--short=12", "HEAD") or "unknown"
    specs = []
    for p in exclude:
        try:
            specs.append(f":(exclude){p.resolve().relative_to(REPO)}")
        except ValueError:
            pass
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", ".", *specs)
    return head + (" with uncommitted changes" if dirty else "")


def machine() -> dict[str, Any]:
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "load_average": load,
        "platform": platform.platform(),
        "python": platform.python_version(),
    }


def now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def spread(values: Sequence[Any]) -> dict[str, Any]:
    """Median, smallest and largest of the finite values, and how many there are."""
    v = [float(x) for x in values if finite(x)]
    if not v:
        return {"median": None, "min": None, "max": None, "n": 0}
    return {"median": median(v), "min": min(v), "max": max(v), "n": len(v)}


def within(ours: Any, paper: float) -> bool:
    return finite(ours) and abs(ours - paper) <= TOLERANCE * paper


def f1(v: Any, unit: str = "") -> str:
    return "–" if not finite(v) else f"{v:.1f}{unit}"


def pct(v: Any) -> str:
    return "–" if not finite(v) else f"{100 * v:.1f} %"


def cell(text: Any) -> str:
    """``text`` as one Markdown table cell."""
    text = " ".join(str(text).split())
    return text.replace("|", "\\|") or "–"


def table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    out = ["| " + " | ".join(cell(h) for h in head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def parallel(fn: Callable[[Any], Any], items: Sequence[Any], jobs: int) -> list[Any]:
    """``fn`` over ``items`` in ``jobs`` threads (each runs its own process); results in order,
    an exception as the result of its item."""

    def safe(x):
        try:
            return fn(x)
        except Exception as exc:  # noqa: BLE001 - reported per item
            return exc

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        return list(pool.map(safe, items))


def error_text(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    first = text.splitlines()[0]
    return (
        first if isinstance(exc, StepError | SectionSkipped) else f"{type(exc).__name__}: {first}"
    )


# ------------------------------------------------------------------------------ 1. paper
def section_paper(cfg: argparse.Namespace, work: Path) -> dict[str, Any]:
    seeds = list(range(cfg.seeds))
    P = cfg.pushes
    sims = work / "campaigns"
    sims.mkdir(parents=True)

    def sim_path(seed: int, dither: bool) -> Path:
        return sims / f"seed{seed}-{'dither' if dither else 'nodither'}.parquet"

    # the campaigns of seeds 0..S (evaluation s, identification s + 1), each simulated once
    needed = sorted({(s + k, d) for s in seeds for k in (0, 1) for d in (False, True)})

    def simulate(item):
        seed, dither = item
        log(f"paper: simulate seed {seed} {'with' if dither else 'without'} dither")
        ditherlab(
            "simulate", "push-campaign", "-o", sim_path(seed, dither), "--seed", seed,
            "--dither" if dither else "--no-dither", "--pushes-per-direction", P, "-q",
            cwd=work, what=f"simulate seed {seed}",
        )  # fmt: skip
        return True

    done = dict(zip(needed, parallel(simulate, needed, cfg.jobs), strict=True))

    def one_seed(s: int) -> dict[str, Any]:
        for key in ((s, False), (s, True), (s + 1, False), (s + 1, True)):
            if isinstance(done[key], Exception):
                raise StepError(error_text(done[key]))
        d = work / f"seed{s}"
        d.mkdir()
        t0 = time.perf_counter()
        ident = [sim_path(s + 1, False), sim_path(s + 1, True)]
        model = d / "model.toml"
        log(f"paper: seed {s}: identify (seed {s + 1}'s campaigns)")
        common = ["-o", model, "--bootstrap", cfg.identify_bootstrap, "--seed", s, "-q"]
        try:
            ditherlab("identify", *ident, "--add", "dither_extraction", *common, cwd=d,
                      what="identify --add dither_extraction")  # fmt: skip
            extraction = True
        except StepError as exc:
            # as the demo: where the effect is refused (exit status 2: the campaigns cannot
            # tell it apart from the bands) the model goes without it
            if exc.code != 2:
                raise
            ditherlab("identify", *ident, *common, cwd=d, what="identify")
            extraction = str(exc)
        ests = []
        for dither in (False, True):
            name = "dither" if dither else "nodither"
            log(f"paper: seed {s}: replay {name}")
            est = d / f"estimates-{name}.parquet"
            ditherlab("replay", sim_path(s, dither), "--model", model, "-o", est, "-q",
                      cwd=d, what=f"replay {name}")  # fmt: skip
            ests.append(est)
        log(f"paper: seed {s}: report")
        r = ditherlab("report", *ests, "-o", d / "report", "--bootstrap", cfg.report_bootstrap,
                      "--seed", s, "--json", "-q", cwd=d, what="report")  # fmt: skip
        try:
            analysis = json.loads(r.stdout)
        except json.JSONDecodeError:
            analysis = json.loads((d / "report" / "report.json").read_text())
        return {
            "status": "ok",
            "seconds": round(time.perf_counter() - t0, 1),
            "dither_extraction": extraction,
            **trim_analysis(analysis),
        }

    per_seed: dict[str, dict[str, Any]] = {}
    for s, res in zip(seeds, parallel(one_seed, seeds, cfg.jobs), strict=True):
        if isinstance(res, Exception):
            log(f"paper: seed {s} failed: {error_text(res)}")
            per_seed[str(s)] = {"status": "error", "error": error_text(res)}
        else:
            per_seed[str(s)] = res
    ok = [per_seed[str(s)] for s in seeds if per_seed[str(s)]["status"] == "ok"]
    if not ok:
        raise StepError("every seed failed; seed 0: " + per_seed[str(seeds[0])]["error"])
    paper_from_report = ok[0].get("paper")
    return {
        "seeds": seeds,
        "identification_seeds": [s + 1 for s in seeds],
        "pushes_per_direction": P,
        "identify_bootstrap": cfg.identify_bootstrap,
        "report_bootstrap": cfg.report_bootstrap,
        "paper": PAPER,
        "paper_matches_report": paper_from_report == PAPER,
        "tolerance": TOLERANCE,
        "per_seed": per_seed,
        **aggregate(per_seed, seeds),
        "steps": [
            f"python -m ditherlab simulate push-campaign -o SEED-nodither.parquet --seed SEED "
            f"--no-dither --pushes-per-direction {P} (and --dither; SEED = s and s + 1)",
            "python -m ditherlab identify (s+1)-nodither.parquet (s+1)-dither.parquet "
            f"--add dither_extraction --bootstrap {cfg.identify_bootstrap} --seed s -o model.toml"
            " (without --add where the extraction cannot be told apart from the bands)",
            "python -m ditherlab replay s-nodither.parquet --model model.toml -o "
            "estimates-nodither.parquet (and s-dither.parquet)",
            "python -m ditherlab report estimates-nodither.parquet estimates-dither.parquet "
            f"--bootstrap {cfg.report_bootstrap} --seed s --json -o report",
        ],
    }


def trim_analysis(a: dict[str, Any]) -> dict[str, Any]:
    """What the page needs from a report's JSON: per condition the noise level, coverage and the
    per-direction statistics (without the per-push lists), the pushes found per file."""
    conds = {}
    for name in CONDITIONS:
        c = a["conditions"].get(name)
        if c is None:
            continue
        conds[name] = {
            k: c.get(k)
            for k in ("noise_level", "coverage_all", "coverage_rest", "coverage_rest_axes")
        }
        conds[name]["directions"] = c.get("directions", {})
    return {
        "pushes_found": {Path(r["file"]).name: len(r["pushes"]) for r in a.get("recordings", [])},
        "conditions": conds,
        "paper": a.get("paper"),
    }


def stat_of(seed_res: dict[str, Any], cond: str, axis: str, key: str) -> Any:
    d = seed_res.get("conditions", {}).get(cond, {}).get("directions", {}).get(axis) or {}
    return d.get(key)


def seed_within(seed_res: dict[str, Any]) -> dict[str, int]:
    """Per reading: the cells of one seed within ±30 % of the paper's (of 12)."""
    out = {}
    for reading, key10 in READINGS:
        n = 0
        for cond, label in PAPER_CONDITIONS:
            for a in AXES:
                n += within(stat_of(seed_res, cond, a, "response_min"), PAPER[label]["response"][a])
                n += within(stat_of(seed_res, cond, a, key10), PAPER[label]["above10"][a])
        out[reading] = n
    return out


def aggregate(per_seed: dict[str, dict[str, Any]], seeds: Sequence[int]) -> dict[str, Any]:
    """Cells over seeds (median, range, within ±30 %), the agreement counts, the detection
    curves and the coverage per condition."""
    ok = {s: per_seed[str(s)] for s in seeds if per_seed[str(s)]["status"] == "ok"}
    for r in ok.values():
        r["within"] = seed_within(r)
    cells = []
    for cond, label in PAPER_CONDITIONS:
        for key, pstat, _ in STATS:
            for a in AXES:
                paper = PAPER[label][pstat][a]
                values = {str(s): stat_of(r, cond, a, key) for s, r in ok.items()}
                sp = spread(values.values())
                cells.append(
                    {
                        "condition": cond,
                        "paper_row": label,
                        "statistic": key,
                        "axis": a,
                        "paper": paper,
                        "values": values,
                        **sp,
                        "median_within": within(sp["median"], paper),
                        "seeds_within": sum(within(v, paper) for v in values.values()),
                    }
                )
    agreement = {}
    for reading, key10 in READINGS:
        mine = [c for c in cells if c["statistic"] in ("response_min", key10)]
        agreement[reading] = {
            "statistic": key10,
            "median_cells_within": sum(c["median_within"] for c in mine),
            "cells": len(mine),
            "seed_cells_within": sum(c["seeds_within"] for c in mine),
            "seed_cells": len(mine) * len(ok),
        }
    curves = []
    coverage = []
    for cond in CONDITIONS:
        for a in AXES:
            dirs = [
                (r.get("conditions", {}).get(cond, {}).get("directions", {}).get(a))
                for r in ok.values()
            ]
            dirs = [d for d in dirs if d]
            if not dirs:
                continue
            cv = [d.get("curve") or {} for d in dirs]
            curves.append(
                {
                    "condition": cond,
                    "axis": a,
                    "F50": spread([c.get("F50") for c in cv]),
                    "F90": spread([c.get("F90") for c in cv]),
                    "every_push_seen": sum(c.get("bound") == "below" for c in cv),
                    "no_push_seen": sum(c.get("bound") == "above" for c in cv),
                    "seeds": len(cv),
                }
            )
            conds = [r["conditions"][cond] for r in ok.values() if cond in r.get("conditions", {})]
            coverage.append(
                {
                    "condition": cond,
                    "axis": a,
                    "noise_level": spread([(c.get("noise_level") or {}).get(a) for c in conds]),
                    "coverage_pushes": spread([d.get("coverage") for d in dirs]),
                    "coverage_rest": spread(
                        [(c.get("coverage_rest_axes") or {}).get(a) for c in conds]
                    ),
                    "error_rms": spread([d.get("error_rms") for d in dirs]),
                }
            )
    return {"cells": cells, "agreement": agreement, "curves": curves, "coverage": coverage}


def render_paper(d: dict[str, Any]) -> list[str]:
    seeds = d["seeds"]
    ok = [s for s in seeds if d["per_seed"][str(s)]["status"] == "ok"]
    P = d["pushes_per_direction"]
    out = [
        f"The pipeline of `make demo` on {len(seeds)} evaluation seed{'s' if len(seeds) > 1 else ''} "
        f"({', '.join(map(str, seeds))}): for seed s, paired push campaigns without and with "
        f"dither ({P} pushes per axis and sign, so {2 * P} per direction), a model identified "
        "on the campaigns of seed s + 1 (with the dither's extraction where the campaigns can "
        "tell it apart), the estimators replayed over seed s's campaigns, and the report's "
        "statistics. Seed s's evaluation campaigns are the identification campaigns of seed "
        "s − 1; no model is scored on the campaigns it is fitted to. The statistics, per "
        "direction with both signs pooled:",
        "",
    ]
    for key, _, words in STATS:
        out.append(f"- `{key}`: {words};")
    out[-1] = out[-1][:-1] + "."
    out += [
        "",
        'The paper reports the second statistic once ("an applied force of 40 N was needed"); '
        "`above10_min` and `above10_from` are its two readings, each compared with the same "
        "paper number. No dither is the `nodither_band` estimator on the campaign without "
        "dither, dither the `dither_band` estimator on the dithered one.",
        "",
    ]
    failed = [s for s in seeds if s not in ok]
    for s in failed:
        out.append(f"- Seed {s} fails: {d['per_seed'][str(s)]['error']}")
    if failed:
        out.append("")
    if not d.get("paper_matches_report", True):
        out += ["The report's own copy of the paper's numbers differs from §VI-C's.", ""]
    ag = d["agreement"]
    tol = f"±{100 * d['tolerance']:.0f} %"
    out += [
        f"**Within {tol} of the paper**: the median over seeds lies within {tol} in "
        f"{ag['smallest']['median_cells_within']} of {ag['smallest']['cells']} cells with the "
        f"second statistic read as `above10_min`, and in {ag['every']['median_cells_within']} of "
        f"{ag['every']['cells']} read as `above10_from`; over the single seeds, "
        f"{ag['smallest']['seed_cells_within']} of {ag['smallest']['seed_cells']} and "
        f"{ag['every']['seed_cells_within']} of {ag['every']['seed_cells']} cells.",
        "",
        f"Per cell, over {len(ok)} seed{'s' if len(ok) > 1 else ''} [N]:",
        "",
    ]
    rows = []
    for c in d["cells"]:
        rng = "–" if c["n"] == 0 else f"{f1(c['min'])}–{f1(c['max'])}"
        if 0 < c["n"] < len(ok):
            rng += f" ({c['n']} of {len(ok)} seeds)"
        rows.append(
            [
                c["paper_row"],
                f"`{c['statistic']}`",
                c["axis"],
                f"{c['paper']:.0f}",
                f1(c["median"]),
                rng,
                "yes" if c["median_within"] else "no",
                f"{c['seeds_within']} of {len(ok)}",
            ]
        )
    out.append(
        table(
            [
                "condition",
                "statistic",
                "axis",
                "paper",
                "median",
                "range",
                f"median within {tol}",
                f"seeds within {tol}",
            ],
            rows,
        )  # fmt: skip
    )
    out += ["", "Per seed, x / y / z [N] (identification on seed + 1):", ""]
    head = ["seed"]
    for _, label in PAPER_CONDITIONS:
        head += [f"{label}: {key}" for key, _, _ in STATS]
    head.append(f"within {tol}: `above10_min` / `above10_from` reading")
    prow = ["paper"]
    for _, label in PAPER_CONDITIONS:
        for _, pstat, _ in STATS:
            prow.append(" / ".join(f"{PAPER[label][pstat][a]:.0f}" for a in AXES))
    prow.append("")
    rows = [prow]
    for s in ok:
        r = d["per_seed"][str(s)]
        row = [str(s)]
        for cond, _ in PAPER_CONDITIONS:
            for key, _, _ in STATS:
                row.append(" / ".join(f1(stat_of(r, cond, a, key)) for a in AXES))
        w = r["within"]
        row.append(f"{w['smallest']} / {w['every']} of 12")
        rows.append(row)
    out.append(table(head, rows))
    out += [
        "",
        "Detection curves, P(response | F) = 1 / (1 + exp(−(F − F50) / s)), median over seeds "
        "(range) [N]; a seed where every push gave a response (or none did) has no curve:",
        "",
    ]
    rows = []
    for c in d["curves"]:
        notes = []
        if c["every_push_seen"]:
            notes.append(f"every push seen on {c['every_push_seen']}")
        if c["no_push_seen"]:
            notes.append(f"no push seen on {c['no_push_seen']}")
        rows.append(
            [
                f"`{c['condition']}`",
                c["axis"],
                span(c["F50"]),
                span(c["F90"]),
                f"{c['F50']['n']} of {c['seeds']}" + (f" ({'; '.join(notes)})" if notes else ""),
            ]
        )
    out.append(table(["condition", "axis", "F50", "F90", "seeds with a curve"], rows))
    out += [
        "",
        "Noise level (99.9 % of |F̂| at rest, at least 1 N), force error RMS during pushes and "
        "the interval's coverage, median over seeds (range):",
        "",
    ]
    rows = []
    for c in d["coverage"]:
        rows.append(
            [
                f"`{c['condition']}`",
                c["axis"],
                span(c["noise_level"]),
                span(c["error_rms"]),
                span(c["coverage_pushes"], pct),
                span(c["coverage_rest"], pct),
            ]
        )
    out.append(
        table(
            [
                "condition",
                "axis",
                "noise level [N]",
                "error RMS, pushes [N]",
                "coverage, pushes",
                "coverage, rest",
            ],
            rows,
        )  # fmt: skip
    )
    ex = {s: d["per_seed"][str(s)].get("dither_extraction") for s in ok}
    n_ex = sum(v is True for v in ex.values())
    out += ["", f"The dither's extraction is part of the model on {n_ex} of {len(ok)} seeds."]
    for s, v in ex.items():
        if v is not True:
            out[-1] += f" Seed {s}: {v}."
    out += ["", "Steps per seed s:", ""]
    out += [f"- `{x}`" for x in d["steps"]]
    return out


def span(sp: dict[str, Any], fmt: Callable[[Any], str] = f1) -> str:
    if not sp or sp.get("n", 0) == 0:
        return "–"
    if sp["n"] == 1 or sp["min"] == sp["max"]:
        return fmt(sp["median"])
    return f"{fmt(sp['median'])} ({fmt(sp['min'])}–{fmt(sp['max'])})"


# ------------------------------------------------------------------------------ 2. false discoveries
def section_false_discoveries(cfg: argparse.Namespace, work: Path) -> dict[str, Any]:
    from bench import bench_false_discovery as fd

    n = cfg.fd_recordings
    log(f"false-discoveries: {n} clean recordings, {cfg.jobs} workers")
    rows, wall = fd.study(n, work, workers=cfg.jobs, progress=True)
    s = fd.summary(rows)
    families: dict[str, Counter] = {}
    for r in rows:
        c = families.setdefault(r["family"], Counter())
        c["recordings"] += 1
        if r.get("error"):
            c["errors"] += 1
        elif r.get("false_discovery"):
            c["false"] += 1
    return {
        "recordings": n,
        "master_seed": getattr(fd, "MASTER_SEED", None),
        "families_described": [f for f in getattr(fd, "FAMILIES", ())],
        "summary": s,
        "wall_seconds": round(wall, 1),
        "families": {k: dict(v) for k, v in families.items()},
        "rows": [
            {
                k: r.get(k)
                for k in (
                    "id",
                    "family",
                    "scenario",
                    "seed",
                    "dither",
                    "added",
                    "suggested",
                    "best",
                    "verdict",
                    "false_discovery",
                    "error",
                )  # fmt: skip
            }
            for r in rows
        ],
        "steps": [
            "python -m ditherlab simulate SCENARIO -o rec.parquet --seed SEED --config sim.toml "
            "(settings drawn from the master seed)",
            "python -m ditherlab identify rec.parquet --add inertia [--add dither_extraction] "
            "--bootstrap 0 -o model.toml",
            "python -m ditherlab diagnose rec.parquet --model model.toml --json --no-history",
        ],
    }


def family_order(d: dict[str, Any], family: str) -> tuple[int, str]:
    """The study's order of its families (unknown ones last, by name)."""
    known = d.get("families_described") or []
    return (known.index(family) if family in known else len(known), family)


def render_false_discoveries(d: dict[str, Any]) -> list[str]:
    s = d["summary"]
    out = [
        f"{d['recordings']} simulated recordings with nothing hidden in the plant beyond what "
        "the model holds (the families of `bench/bench_false_discovery.py`, settings drawn from "
        f"the master seed {d['master_seed']}), each through `identify` (with the effects every "
        "simulated arm has: `inertia`, and `dither_extraction` on a dithered log with a sensor, "
        "where the log can identify them) and `diagnose`. A suggestion on such a recording is a "
        "false discovery.",
        "",
        f"**{s['false']} false discoveries in {s['recordings']} recordings** "
        f"(one-sided 95 % upper bound on the rate, Clopper–Pearson: {pct(s['upper95'])}); "
        f"{s['errors']} recordings fail to run; {d['wall_seconds']:.0f} s wall.",
        "",
    ]
    rows = [
        [f, c.get("recordings", 0), c.get("false", 0), c.get("errors", 0)]
        for f, c in sorted(d["families"].items(), key=lambda fc: family_order(d, fc[0]))
    ]
    out.append(table(["family", "recordings", "with a suggestion", "failed"], rows))
    flagged = [r for r in d["rows"] if r.get("error") or r.get("false_discovery")]
    if flagged:
        out += ["", "Recordings with a suggestion or an error:", ""]
        rows = [
            [f"r{r['id']:03d}", r["family"], r["seed"], r.get("error") or r.get("suggested")]
            for r in flagged
        ]
        out.append(table(["recording", "family", "seed", "suggested / error"], rows))
    out += ["", "Steps per recording:", ""] + [f"- `{x}`" for x in d["steps"]]
    return out


# ------------------------------------------------------------------------------ 3. real logs
def data_folder(cfg: argparse.Namespace) -> tuple[Path | None, str]:
    """The folder of the real logs (None: absent) and how it was chosen."""
    if cfg.data is not None:
        return (cfg.data if cfg.data.is_dir() else None), f"--data {cfg.data}"
    shared = REPO.parent / "shared" / "data"
    if shared.is_dir():
        return shared, "the default folder"
    if (REPO / "tests" / "data").is_dir():
        return REPO / "tests" / "data", "the repository's copy; ../shared/data is absent"
    return None, "../shared/data beside the repository"


def real_logs(cfg: argparse.Namespace, data: Path | None) -> list[dict[str, Any]]:
    """The logs of the loop: name, file, whether to convert, identify's options."""
    logs = []
    if data is not None:
        logs.append(
            {
                "name": "UR10e, free motion",
                "file": data / "ur10e" / "no_torque.csv",
                "convert": ["--mapping", "ur10e"],
                "identify": ["--assume-no-force"],
                "about": "5.7 s of free motion up to ~1 rad/s, no F/T sensor",
            }
        )
    logs.append(
        {
            "name": "UR10e, standing, pushed by hand",
            "file": REPO / "recordings" / "ur10e-static.parquet",
            "convert": None,
            "identify": ["--assume-no-force"],
            "about": "45 s holding one pose, pushed by hand four times, no F/T sensor",
        }
    )
    if data is not None:
        logs.append(
            {
                "name": "Hopper leg",
                "file": data / "hopper" / "hopper_long.parquet",
                "convert": None,
                "identify": [],
                "about": "23.4 s of hopping at 1 kHz, an ATI sensor under the foot",
            }
        )
    return logs


def section_real_logs(cfg: argparse.Namespace, work: Path) -> dict[str, Any]:
    data, how = data_folder(cfg)
    shown = os.path.relpath(data, REPO) if data is not None else None
    out: dict[str, Any] = {"data": shown, "data_from": how, "logs": []}
    boot = cfg.identify_bootstrap
    for lg in real_logs(cfg, data):
        entry = {k: v for k, v in lg.items() if k not in ("file", "convert", "identify")}
        entry["file"] = lg["file"].name
        entry["steps"] = []
        out["logs"].append(entry)
        if not lg["file"].exists():
            entry["error"] = f"{lg['file']} is absent (pass --data FOLDER)"
            log(f"real-logs: {entry['name']}: {entry['error']}")
            continue
        d = work / re.sub(r"\W+", "-", lg["name"]).strip("-").lower()
        d.mkdir(parents=True)
        try:
            loop(lg, d, boot, entry)
        except StepError as exc:
            entry["error"] = str(exc)
            log(f"real-logs: {entry['name']}: {exc}")
    if data is None:
        out["skipped_note"] = (
            f"no data folder ({how} is absent): the UR10e free-motion log and the hopper are "
            "skipped; pass --data FOLDER"
        )
    return out


def loop(lg: dict[str, Any], d: Path, boot: int, entry: dict[str, Any]) -> None:
    """convert (if foreign), identify, diagnose, identify --add the first suggestion, diagnose."""
    name = entry["name"]
    rec = lg["file"]
    steps = entry["steps"]
    if lg["convert"] is not None:
        conv = d / "log.parquet"
        log(f"real-logs: {name}: convert")
        ditherlab("convert", rec, conv, *lg["convert"], cwd=d, what="convert")
        steps.append(
            f"python -m ditherlab convert {rec.name} log.parquet {' '.join(lg['convert'])}"
        )
        rec = conv
    shown = str(rec.relative_to(REPO)) if rec.is_relative_to(REPO) else rec.name
    m1, m2 = d / "model1.toml", d / "model2.toml"
    flags = lg["identify"]
    log(f"real-logs: {name}: identify")
    ditherlab("identify", rec, *flags, "--bootstrap", boot, "-o", m1, "-q", cwd=d, what="identify")
    steps.append(
        f"python -m ditherlab identify {shown} {' '.join(flags)} --bootstrap {boot} -o model1.toml".replace(
            "  ", " "
        )
    )
    log(f"real-logs: {name}: diagnose")
    d1 = diagnosis(rec, m1, d)
    steps.append(f"python -m ditherlab diagnose {shown} --model model1.toml --json --no-history")
    entry["before"] = d1
    sug = [c for c in d1["candidates"] if c["suggested"]]
    if not sug:
        return
    first = sug[0]["effect"]
    entry["added"] = first
    log(f"real-logs: {name}: identify --add {first}")
    ditherlab("identify", rec, *flags, "--model", m1, "--add", first, "--bootstrap", boot,
              "-o", m2, "-q", cwd=d, what=f"identify --add {first}")  # fmt: skip
    steps.append(
        f"python -m ditherlab identify {shown} {' '.join(flags)} --model model1.toml --add "
        f"{first} --bootstrap {boot} -o model2.toml".replace("  ", " ")
    )
    log(f"real-logs: {name}: diagnose again")
    entry["after"] = diagnosis(rec, m2, d)
    steps.append(f"python -m ditherlab diagnose {shown} --model model2.toml --json --no-history")


def diagnosis(rec: Path, model: Path, d: Path) -> dict[str, Any]:
    r = ditherlab("diagnose", rec, "--model", model, "--json", "--no-history", "-q", cwd=d,
                  what=f"diagnose with {model.name}")  # fmt: skip
    j = json.loads(r.stdout)
    res = j["residual"]
    cands = sorted(j["candidates"], key=lambda c: -(c.get("explained_fraction") or -9))
    return {
        "torque_rms": res["torque_rms"],
        "noise_floor": res["noise_floor"],
        "ratio": res["ratio"],
        "candidates": [
            {
                k: c.get(k)
                for k in ("effect", "joints", "explained_fraction", "suggested", "not_identifiable")
            }  # fmt: skip
            for c in cands
        ],
        "verdict": (j.get("verdict") or {}).get("text") if j.get("verdict") else None,
        "verdict_status": (j.get("verdict") or {}).get("status") if j.get("verdict") else None,
    }


def describe_candidate(c: dict[str, Any]) -> str:
    joints = c.get("joints") or []
    where = (
        f" on joint{'s' if len(joints) > 1 else ''} {', '.join(map(str, joints))}"
        if joints
        else " (all joints)"
    )
    return f"`{c['effect']}`{where}, explaining {pct(c['explained_fraction'])} of the residual on held-out data"


def residual_cells(d: dict[str, Any], j: int) -> list[str]:
    """Noise floor, residual RMS [N·m] and their ratio of joint ``j`` (0-based)."""

    def at(key: str, fmt: str) -> str:
        v = (d.get(key) or [])[j] if j < len(d.get(key) or []) else None
        return format(v, fmt) if finite(v) else "–"

    return [at("noise_floor", ".3g"), at("torque_rms", ".3g"), at("ratio", ".2f")]


def render_real_logs(d: dict[str, Any]) -> list[str]:
    out = [
        "Each log through the loop a user runs: `identify`, `diagnose`, `identify --add` of "
        "diagnose's first suggestion, `diagnose` again. The residual is the torque RMS per "
        "joint on the scored samples against its noise floor (diagnose's JSON, "
        "`residual`)."
        + (f" Real logs from `{d['data']}` ({d['data_from']})." if d["data"] else ""),
        "",
    ]
    if d.get("skipped_note"):
        out += [f"Skipped here: {d['skipped_note']}.", ""]
    for lg in d["logs"]:
        out += [f"**{lg['name']}** ({lg['about']}; `{Path(lg['file']).name}`).", ""]
        if lg.get("error") and not lg.get("before"):
            out += [f"Not run: {lg['error']}.", ""]
            continue
        b, a = lg.get("before"), lg.get("after")
        if b is None:
            continue
        sug = [c for c in b["candidates"] if c["suggested"]]
        if sug:
            out.append(
                "Suggested after `identify`: "
                + "; ".join(describe_candidate(c) for c in sug)
                + f". Added: `{lg['added']}`."
            )
        else:
            top = b["candidates"][0] if b["candidates"] else None
            out.append(
                "Nothing is suggested after `identify`"
                + (
                    f" (the best candidate, not suggested: {describe_candidate(top)})"
                    if top
                    else ""
                )
                + "; the loop stops there."
            )
        out.append("")
        head = ["joint", "noise floor [N·m]", "residual RMS [N·m]", "ratio"]
        if a is not None:
            head += [f"with `{lg['added']}`: noise floor", "residual RMS", "ratio"]
        rows = []
        for j in range(len(b["torque_rms"])):
            row = [j + 1, *residual_cells(b, j)]
            if a is not None:
                row += residual_cells(a, j)
            rows.append(row)
        out.append(table(head, rows))
        out.append("")
        if a is not None:
            sug2 = [c for c in a["candidates"] if c["suggested"]]
            out.append(
                "Then suggested: "
                + ("; ".join(describe_candidate(c) for c in sug2) if sug2 else "nothing")
                + "."
                + (f" Verdict: {a['verdict']}" if a.get("verdict") else "")
            )
            out.append("")
        elif b.get("verdict"):
            out += [f"Verdict: {b['verdict']}", ""]
        if lg.get("error"):
            out += [f"The loop stops: {lg['error']}.", ""]
        out += [f"- `{x}`" for x in lg["steps"]]
        out.append("")
    return out[:-1] if out and out[-1] == "" else out


# ------------------------------------------------------------------------------ 4. speed
def bench_modules() -> list[str]:
    """The bench modules ``bench.run`` runs, except the false-discovery study (section 2)."""
    return sorted(
        p.stem for p in (REPO / "bench").glob("bench_*.py") if p.stem != "bench_false_discovery"
    )


def demo_timing(work: Path, jobs: int) -> dict[str, Any]:
    """``make demo``'s run (``python -m ditherlab.app.demo``, the install excluded): its wall
    and CPU time [s] and the size of what it wrote [MB]; or the error."""
    out = work / "demo-out"
    log("speed: make demo's run")
    load = round(os.getloadavg()[0], 2)
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        run(["-m", "ditherlab.app.demo", "--out", out, "--jobs", jobs], cwd=work, what="demo")
    except StepError as exc:
        return {"error": error_text(exc)}
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return {
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "written_mb": round(size / 1e6, 1),
        "jobs": jobs,
        "load_before": load,
    }


def section_speed(cfg: argparse.Namespace, work: Path) -> dict[str, Any]:
    modules = bench_modules()
    if not modules:
        raise SectionSkipped("no bench/bench_*.py modules")
    demo = demo_timing(work, cfg.jobs)
    rows, errors, seconds = [], {}, {}
    for mod in modules:
        log(f"speed: {mod}{' (quick)' if cfg.bench_quick else ''}")
        out = work / f"{mod}.json"
        t0 = time.perf_counter()
        try:
            run(["-m", "bench.run", "--only", mod, "--json", out,
                 *(["--quick"] if cfg.bench_quick else [])],
                cwd=work, what=f"bench {mod}")  # fmt: skip
            got = [r for r in json.loads(out.read_text()) if r.get("module", mod) == mod]
            rows += [{k: v for k, v in r.items() if k != "module"} | {"module": mod} for r in got]
        except (StepError, OSError, json.JSONDecodeError) as exc:
            errors[mod] = error_text(exc)
            log(f"speed: {mod} failed: {errors[mod]}")
        seconds[mod] = round(time.perf_counter() - t0, 1)
    return {
        "demo": demo,
        "quick": cfg.bench_quick,
        "modules": modules,
        "rows": rows,
        "errors": errors,
        "module_seconds": seconds,
        "steps": [
            "python -m bench.run --only MODULE --json MODULE.json"
            + (" --quick" if cfg.bench_quick else "")
            + " (per bench/bench_*.py module; bench_false_discovery in its own section)"
        ],
    }


def fmt_value(v: Any) -> str:
    return f"{v:.4g}" if finite(v) else str(v)


def render_speed(d: dict[str, Any]) -> list[str]:
    ref = [r for r in d["rows"] if r.get("reference") is not None]
    other = [r for r in d["rows"] if r.get("reference") is None]
    demo = d.get("demo") or {}
    if "error" in demo:
        head = [f"`make demo` (its run, after the install) fails: {demo['error']}", ""]
    elif demo:
        head = [
            f"`make demo` (its run, after the install; `--jobs {demo['jobs']}`): "
            f"**{demo['wall_s']:.0f} s** wall, {demo['cpu_s']:.0f} s CPU, "
            f"{demo['written_mb']:.0f} MB written (load average {demo['load_before']} "
            "when it started).",
            "",
        ]
    else:
        head = []
    out = head + [
        "Every bench module of `bench/` (the `make bench` runner, one module at a time"
        + (", `--quick` sizes" if d["quick"] else "")
        + "); each fast path is timed beside its slow, plainly right reference in the same run. "
        "The machine is shared: read the ratios, not the wall-clock values.",
        "",
    ]
    for mod, e in d["errors"].items():
        out.append(f"- `{mod}` fails: {e}")
    if d["errors"]:
        out.append("")
    out.append(
        table(
            ["module", "what", "fast", "reference", "ratio", "target"],
            [
                [
                    r["module"].removeprefix("bench_"),
                    r["name"],
                    f"{fmt_value(r['value'])} {r.get('unit', '')}",
                    f"{fmt_value(r['reference'])} {r.get('unit', '')}",
                    f"{r['ratio']:.1f}×" if finite(r.get("ratio")) else "–",
                    r.get("target") or "–",
                ]
                for r in ref
            ],
        )
    )
    if other:
        out += ["", "Rows without a reference:", ""]
        out.append(
            table(
                ["module", "what", "value", "target"],
                [
                    [
                        r["module"].removeprefix("bench_"),
                        r["name"],
                        f"{fmt_value(r['value'])} {r.get('unit', '')}",
                        r.get("target") or "–",
                    ]
                    for r in other
                ],  # fmt: skip
            )
        )
    secs = ", ".join(
        f"{m.removeprefix('bench_')} {s:.0f} s" for m, s in d["module_seconds"].items()
    )
    out += ["", f"Wall time per module: {secs}.", ""] + [f"- `{x}`" for x in d["steps"]]
    return out


# ------------------------------------------------------------------------------ 5. fuzz
def section_fuzz(cfg: argparse.Namespace, work: Path) -> dict[str, Any]:
    fz = work / "campaign"
    findings = work / "findings.md"
    log(f"fuzz: about {cfg.fuzz_cases} cases, seed {cfg.fuzz_seed}")
    t0 = time.perf_counter()
    r = run(["-m", "tests.fuzz", "--cases", cfg.fuzz_cases, "--seed", cfg.fuzz_seed,
             "--work", fz, "--findings", findings],
            cwd=work, what="fuzz", ok=(0, 1))  # fmt: skip
    wall = time.perf_counter() - t0
    cases = [json.loads(x) for x in (fz / "cases.jsonl").read_text().splitlines() if x.strip()]
    per: dict[str, Counter] = {}
    by_class: Counter = Counter()
    for c in cases:
        k = per.setdefault(c["command"], Counter())
        k[c["kind"]] += 1
        k["with a finding"] += bool(c["findings"])
        for cls in c["findings"]:
            by_class[cls] += 1
    classes = fuzz_classes(r.stdout) or {
        k: {"cases": v, "distinct": None} for k, v in by_class.items()
    }
    distinct = []
    if findings.exists():
        for m in re.finditer(
            r"^## \d+\. (?P<cls>.+?): `(?P<cmd>[^`]+)` on (?P<kind>\S+) \((?P<n>\d+) cases\)\n\n"
            r"- input: (?P<input>.*)\n- detail: (?P<detail>.*)\n- reproduce: (?P<repro>.*)$",
            findings.read_text(),
            re.MULTILINE,
        ):
            distinct.append({k: m.group(k) for k in ("cls", "cmd", "kind", "n", "input", "detail")})
    return {
        "cases_requested": cfg.fuzz_cases,
        "seed": cfg.fuzz_seed,
        "cases": len(cases),
        "wall_seconds": round(wall, 1),
        "slowest_case_seconds": max((c.get("s", 0) for c in cases), default=0),
        "per_command": {k: dict(v) for k, v in per.items()},
        "classes": classes,
        "distinct": distinct,
        "exit_status": r.returncode,
        "steps": [
            f"python -m tests.fuzz --cases {cfg.fuzz_cases} --seed {cfg.fuzz_seed} --work DIR "
            "--findings FILE"
        ],
    }


def fuzz_classes(stdout: str) -> dict[str, dict[str, Any]]:
    """The campaign's printed 'findings by class' table: class -> cases, distinct."""
    out = {}
    part = stdout.split("findings by class:")[-1] if "findings by class:" in stdout else ""
    for line in part.splitlines():
        m = re.match(r"^\| (?P<cls>[^|]+?) \| (?P<n>\d+) \| (?P<d>\d+) \|$", line.strip())
        if m:
            out[m["cls"]] = {"cases": int(m["n"]), "distinct": int(m["d"])}
    return out


def render_fuzz(d: dict[str, Any]) -> list[str]:
    n_find = sum(v["cases"] for v in d["classes"].values())
    out = [
        f"{d['cases']} cases (about {d['cases_requested']} asked for, spread evenly over every "
        f"command and input kind; seed {d['seed']}), each in its own process: "
        f"{len(d['distinct'])} distinct findings in {n_find} case findings; "
        f"{d['wall_seconds']:.0f} s wall, slowest case {d['slowest_case_seconds']:.1f} s.",
        "",
    ]
    kinds = list(
        dict.fromkeys(k for v in d["per_command"].values() for k in v if k != "with a finding")
    )
    rows = []
    for cmd, v in d["per_command"].items():
        rows.append([f"`{cmd}`", *[v.get(k, 0) for k in kinds], sum(v.get(k, 0) for k in kinds),
                     v.get("with a finding", 0)])  # fmt: skip
    out.append(table(["command", *kinds, "all", "with a finding"], rows))
    out += ["", "Findings by class:", ""]
    out.append(
        table(
            ["class", "cases", "distinct"],
            [
                [k, v["cases"], "–" if v["distinct"] is None else v["distinct"]]
                for k, v in d["classes"].items()
            ],  # fmt: skip
        )
    )
    if d["distinct"]:
        out += ["", "Distinct findings:", ""]
        out.append(
            table(
                ["class", "command", "input kind", "cases", "detail"],
                [
                    [f["cls"], f"`{f['cmd']}`", f["kind"], f["n"], f["detail"][:200]]
                    for f in d["distinct"]
                ],  # fmt: skip
            )
        )
    out += ["", f"- `{d['steps'][0]}`"]
    return out


# ------------------------------------------------------------------------------ page
RUNNERS: dict[str, Callable[[argparse.Namespace, Path], dict[str, Any]]] = {
    "paper": section_paper,
    "false-discoveries": section_false_discoveries,
    "real-logs": section_real_logs,
    "speed": section_speed,
    "fuzz": section_fuzz,
}
RENDERERS: dict[str, Callable[[dict[str, Any]], list[str]]] = {
    "paper": render_paper,
    "false-discoveries": render_false_discoveries,
    "real-logs": render_real_logs,
    "speed": render_speed,
    "fuzz": render_fuzz,
}


def section_command(name: str, cfg: argparse.Namespace) -> str:
    """The script's command line that runs ``name`` again with the same sizes."""
    args = ["python", "scripts/validation.py", "--only", name]
    if cfg.quick:
        args.append("--quick")
    if name == "paper":
        args += ["--seeds", cfg.seeds, "--pushes", cfg.pushes,
                 "--identify-bootstrap", cfg.identify_bootstrap,
                 "--report-bootstrap", cfg.report_bootstrap]  # fmt: skip
    elif name == "false-discoveries":
        args += ["--fd-recordings", cfg.fd_recordings]
    elif name == "real-logs":
        args += ["--identify-bootstrap", cfg.identify_bootstrap]
        if cfg.data is not None:
            args += ["--data", cfg.data]
    elif name == "fuzz":
        args += ["--fuzz-cases", cfg.fuzz_cases, "--fuzz-seed", cfg.fuzz_seed]
    if name in ("paper", "false-discoveries"):
        args += ["--jobs", cfg.jobs]
    return " ".join(shlex.quote(str(a)) for a in args)


def run_section(name: str, cfg: argparse.Namespace, work: Path, exclude: Sequence[Path]) -> dict:
    """Run one section; its numbers, or its error line, with when, where and how it ran."""
    meta = {
        "date": now(),
        "commit": commit(exclude),
        "machine": machine(),
        "quick": cfg.quick,
        "command": section_command(name, cfg),
    }
    d = work / name
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    log(f"== {name}")
    t0 = time.perf_counter()
    try:
        data = RUNNERS[name](cfg, d)
        status, error = "ok", None
    except SectionSkipped as exc:
        data, status, error = None, "skipped", error_text(exc)
    except Exception as exc:  # noqa: BLE001 - one failing section must not stop the others
        data, status, error = None, "error", error_text(exc)
        traceback.print_exc(file=sys.stderr)
    meta["seconds"] = round(time.perf_counter() - t0, 1)
    log(f"== {name}: {status} in {meta['seconds']:.0f} s" + (f": {error}" if error else ""))
    return {"status": status, "error": error, **meta, "data": data}


def render(results: dict[str, dict[str, Any]]) -> str:
    """The generated part of the page (after the marker), from the sections' numbers."""
    out = [
        "",
        "Everything below is written by `scripts/validation.py` from its runs and their JSON "
        "(`validation.json` beside this page); each section names the run it comes from.",
    ]
    if any(r.get("quick") for r in results.values()):
        quick = ", ".join(k for k in SECTIONS if (results.get(k) or {}).get("quick"))
        out += [
            "",
            f"**Quick run** (smoke sizes) in: {quick}. Those sections check that the runs go "
            "through; their numbers are not the measured evidence.",
        ]
    for i, name in enumerate(SECTIONS, 1):
        r = results.get(name)
        out += ["", f"## {i}. {TITLES[name]}", ""]
        if r is None:
            out.append("Not run yet: `python scripts/validation.py --only " + name + "`.")
            continue
        m = r.get("machine", {})
        load = m.get("load_average")
        out.append(
            f"Run {r['date']}, commit `{r['commit']}`, {m.get('cores')} cores "
            f"({m.get('usable_cores')} usable"
            + (f", load average {load[0]:.1f} at the start" if load else "")
            + f"), Python {m.get('python')}, {r['seconds']:.0f} s"
            + (", **quick sizes**" if r.get("quick") else "")
            + f". Reproduce: `{r['command']}`."
        )
        out.append("")
        if r["status"] != "ok":
            word = "skipped" if r["status"] == "skipped" else "fails"
            out.append(f"**This section's run {word}:** {r['error']}")
            continue
        try:
            out += RENDERERS[name](r["data"])
        except Exception as exc:  # noqa: BLE001 - the page still gets the other sections
            out.append(f"**This section's numbers cannot be written:** {error_text(exc)}")
    return "\n".join(out).rstrip() + "\n"


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, with the usual file mode (the library's writer)."""
    from ditherlab.core.files import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def page_with(path: Path, generated: str) -> str:
    """The page: its text up to and with the marker line kept, the generated part after it; a
    missing page gets an introduction, a page without the marker gets it at its end."""
    head = path.read_text(encoding="utf-8") if path.exists() else INTRO
    if MARKER in head:
        head = head[: head.index(MARKER)]
    head = head.rstrip("\n") + "\n\n"
    return head + MARKER + "\n" + generated


def clean(x: Any) -> Any:
    """``x`` with every non-finite float as None (strict JSON)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean(v) for v in x]
    return x


def load_previous(path: Path) -> dict[str, Any]:
    try:
        j = json.loads(path.read_text(encoding="utf-8"))
        return dict(j.get("sections", {}))
    except (OSError, ValueError, AttributeError):
        return {}


# ------------------------------------------------------------------------------ main
def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python scripts/validation.py",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--seeds", type=int, help="evaluation seeds 0..N-1 (default 7; quick 2)")
    ap.add_argument(
        "--pushes", type=int, help="pushes per axis and sign in each campaign (default 25; quick 3)"
    )
    ap.add_argument(
        "--fd-recordings", type=int, help="clean recordings of the false-discovery study (50; 3)"
    )
    ap.add_argument("--fuzz-cases", type=int, help="about this many fuzz cases (1000; 20)")
    ap.add_argument("--fuzz-seed", type=int, default=1, help="seed of the fuzz campaign (1)")
    ap.add_argument(
        "--identify-bootstrap",
        type=int,
        help="bootstrap replicates of identify (30, the demo's; quick 5)",
    )
    ap.add_argument(
        "--report-bootstrap",
        type=int,
        help="bootstrap replicates of the report's detection curves (200; quick 50)",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="smoke sizes: 2 seeds, 3 pushes, 3 recordings, bench --quick, 20 fuzz cases",
    )
    ap.add_argument(
        "--only",
        action="append",
        choices=SECTIONS,
        metavar="SECTION",
        help=f"run only this section (repeatable): {', '.join(SECTIONS)}",
    )
    ap.add_argument(
        "--data",
        type=Path,
        help="folder of the real logs (ur10e/, hopper/); default ../shared/data beside the "
        "repository, else the repository's tests/data",
    )
    ap.add_argument("--jobs", type=int, default=2, help="commands run at once (2)")
    ap.add_argument("--work", type=Path, help="scratch folder (default: a temporary one)")
    ap.add_argument(
        "--out", type=Path, default=REPO / "docs" / "validation.md", help="the page to write"
    )
    a = ap.parse_args(argv)
    q = a.quick
    for name, full, quick in (
        ("seeds", 7, 2),
        ("pushes", 25, 3),
        ("fd_recordings", 50, 3),
        ("fuzz_cases", 1000, 20),
        ("identify_bootstrap", 30, 5),
        ("report_bootstrap", 200, 50),
    ):
        if getattr(a, name) is None:
            setattr(a, name, quick if q else full)
    a.bench_quick = q
    for name in ("seeds", "pushes", "fd_recordings", "fuzz_cases", "jobs"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1")
    return a


def main(argv: Sequence[str] | None = None) -> int:
    cfg = parse(argv)
    os.environ["PYTHONPATH"] = child_env()["PYTHONPATH"]
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    out = cfg.out.resolve()
    js = out.with_suffix(".json")
    names = [s for s in SECTIONS if not cfg.only or s in cfg.only]
    own = cfg.work is None
    work = Path(tempfile.mkdtemp(prefix="ditherlab-validation-")) if own else cfg.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    log(f"sections: {', '.join(names)}; scratch {work}")
    results = load_previous(js)
    try:
        for name in names:
            results[name] = run_section(name, cfg, work, [out, js])
            # written after every section: an interrupted run keeps what it measured
            write_atomic(
                js,
                json.dumps({"sections": clean(results)}, indent=1, allow_nan=False, default=str)
                + "\n",
            )
            page = page_with(out, render(results))
            write_atomic(out, page)
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    for i, line in enumerate(page.splitlines(), 1):
        if HISTORY.search(line):
            log(f"warning: {out.name} line {i} reads as history: {line[:100]}")
    log(f"wrote {out} and {js}")
    bad = [n for n in names if results[n]["status"] == "error"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

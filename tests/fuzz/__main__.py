"""The fuzz campaign: ``python -m tests.fuzz --cases 1000 --seed 1`` (``make fuzz``).

Cases are spread evenly over every command and input kind; each cell's cases are drawn by
hypothesis from a seed derived from ``--seed``, so a campaign is reproducible. Each case runs in
its own subprocess (60 s timeout). Prints a line per finding as it is met, then a table of cases
per command and input kind and the findings by class; writes the findings, with a command that
reproduces each, to ``--findings`` (rewritten as the campaign goes; text above the line
``<!-- campaign -->`` in an existing file is kept).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hseed

from tests.fuzz.harness import (
    CLASSES,
    TIMEOUT_S,
    Result,
    preload,
    reproduction,
    run_case,
    signature,
)
from tests.fuzz.inputs import COMMANDS, KINDS, cases, prepare_base

MARK = "<!-- campaign -->"


class Campaign:
    """The cases run so far and the distinct findings (by :func:`signature`)."""

    def __init__(self, work: Path, findings: Path | None, seed: int):
        self.work, self.findings, self.seed = work, findings, seed
        self.counts: Counter[tuple[str, str]] = Counter()
        self.failed: Counter[tuple[str, str]] = Counter()
        self.by_class: Counter[str] = Counter()
        self.distinct: dict[str, dict] = {}
        self.n = 0
        self.t0 = time.perf_counter()
        self.slowest = 0.0
        self.log = (work / "cases.jsonl").open("a")

    def record(self, res: Result) -> None:
        c = res.case
        self.n += 1
        self.counts[(c.command, c.kind)] += 1
        self.slowest = max(self.slowest, res.seconds)
        line = {
            "n": self.n,
            "command": c.command,
            "kind": c.kind,
            "label": c.label,
            "code": res.code,
            "s": round(res.seconds, 2),
            "findings": res.findings,
            "error": res.error_line[:300],
        }
        self.log.write(json.dumps(line) + "\n")
        self.log.flush()
        if not res.findings:
            return
        self.failed[(c.command, c.kind)] += 1
        for cls in res.findings:
            self.by_class[cls] += 1
            sig = signature(res, cls)
            if sig in self.distinct:
                self.distinct[sig]["count"] += 1
                continue
            keep = self.work / "findings" / f"f{len(self.distinct) + 1:03d}"
            self.distinct[sig] = {
                "class": cls,
                "command": c.command,
                "kind": c.kind,
                "label": c.label,
                "detail": res.details.get(cls) or res.error_line,
                "stderr": res.err.strip()[-1500:],
                "repro": reproduction(res, keep),
                "count": 1,
            }
            print(
                f"[{self.n}] {cls}: {c.command} {c.kind} {c.label} :: {res.details.get(cls, '')[:200]}",
                flush=True,
            )
            self.write()

    def table(self) -> str:
        kinds = [k for k in KINDS if any(self.counts[(c, k)] for c in COMMANDS)]
        head = "| command | " + " | ".join(kinds) + " | all |"
        rows = [head, "|" + "---|" * (len(kinds) + 2)]
        commands = [c for c in COMMANDS if any(self.counts[(c, k)] for k in kinds)]
        for cmd in commands:
            cells = [f"{self.counts[(cmd, k)]} ({self.failed[(cmd, k)]})" for k in kinds]
            tot = sum(self.counts[(cmd, k)] for k in kinds)
            bad = sum(self.failed[(cmd, k)] for k in kinds)
            rows.append(f"| {cmd} | " + " | ".join(cells) + f" | {tot} ({bad}) |")
        tot = [sum(self.counts[(c, k)] for c in commands) for k in kinds]
        bad = [sum(self.failed[(c, k)] for c in commands) for k in kinds]
        rows.append(
            "| all | "
            + " | ".join(f"{a} ({b})" for a, b in zip(tot, bad, strict=True))
            + f" | {sum(tot)} ({sum(bad)}) |"
        )
        return "\n".join(rows)

    def class_table(self) -> str:
        per: dict[str, int] = defaultdict(int)
        for d in self.distinct.values():
            per[d["class"]] += 1
        rows = ["| class | cases | distinct |", "|---|---|---|"]
        for cls in CLASSES:
            rows.append(f"| {cls} | {self.by_class[cls]} | {per[cls]} |")
        return "\n".join(rows)

    def summary(self) -> str:
        wall = time.perf_counter() - self.t0
        return (
            f"{self.n} cases, seed {self.seed}, {wall:.0f} s wall (slowest case {self.slowest:.1f} s)"
            "\n\ncases per command and input kind (cases with a finding in parentheses):\n\n"
            f"{self.table()}\n\nfindings by class:\n\n{self.class_table()}\n"
        )

    def write(self) -> None:
        if self.findings is None:
            return
        keep = ""
        if self.findings.exists():
            text = self.findings.read_text()
            if MARK in text:
                keep = text.split(MARK)[0]
        parts = [keep + MARK, f"\n# Fuzz campaign (seed {self.seed})\n", self.summary()]
        for i, d in enumerate(self.distinct.values(), 1):
            parts.append(
                f"\n## {i}. {d['class']}: `{d['command']}` on {d['kind']} ({d['count']} cases)\n\n"
                f"- input: {d['label']}\n- detail: `{d['detail'][:400]}`\n"
                f"- reproduce: `{d['repro']}`\n\n```\n{d['stderr'][-800:]}\n```\n"
            )
        self.findings.parent.mkdir(parents=True, exist_ok=True)
        self.findings.write_text("".join(parts))


def run_campaign(
    total: int,
    seed: int,
    work: Path,
    findings: Path | None = None,
    commands: tuple[str, ...] = COMMANDS,
    kinds: tuple[str, ...] = KINDS,
    timeout: float = TIMEOUT_S,
    mode: str = "fork",
) -> Campaign:
    """Run about ``total`` cases spread over ``commands`` x ``kinds``."""
    work.mkdir(parents=True, exist_ok=True)
    base = prepare_base(work / "base")
    camp = Campaign(work, findings, seed)
    if mode == "fork":
        preload()
    cells = [(c, k) for k in kinds for c in commands]
    per = max(1, math.ceil(total / len(cells)))
    scratch = work / "cases"
    for i, (command, kind) in enumerate(cells):

        @hseed(seed * 1_000_003 + i)
        @settings(
            max_examples=per,
            phases=[Phase.generate],
            database=None,
            deadline=None,
            suppress_health_check=list(HealthCheck),
        )
        @given(cases(base, kind, command))
        def one(case):  # noqa: ANN001
            shutil.rmtree(scratch, ignore_errors=True)
            camp.record(run_case(case, base, scratch, mode=mode, timeout=timeout))

        one()
    camp.write()
    return camp


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=1000, help="about this many cases in all")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--work", type=Path, default=Path("/tmp/ditherlab-fuzz"))
    ap.add_argument("--findings", type=Path, default=None, help="markdown file of the findings")
    ap.add_argument("--commands", default=",".join(COMMANDS))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--timeout", type=float, default=TIMEOUT_S)
    ap.add_argument(
        "--mode",
        choices=("fork", "subprocess", "inprocess"),
        default="fork",
        help="each case in a process forked after the imports (default), in a fresh "
        "'python -m ditherlab', or in this process (no hang detection)",
    )
    a = ap.parse_args(argv)
    camp = run_campaign(
        a.cases,
        a.seed,
        a.work,
        a.findings or a.work / "findings.md",
        tuple(a.commands.split(",")),
        tuple(a.kinds.split(",")),
        a.timeout,
        a.mode,
    )
    print(camp.summary())
    sys.exit(1 if camp.distinct else 0)


if __name__ == "__main__":
    main()

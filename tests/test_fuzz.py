"""The fuzz suite (:mod:`tests.fuzz`) on a small budget, as part of ``make test``: a few cases of
every input kind through the commands that only read (info, convert, view --save), each in a
process forked after the imports, checked against the promise (exit 0, or exit 2 with one line
``error: ...``; no traceback, no hang, input unchanged, nothing left behind on failure).

``make fuzz`` runs the large campaign (``python -m tests.fuzz``) over every command.
"""

from __future__ import annotations

import itertools
import shutil

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hseed

from tests.fuzz.harness import preload, run_case
from tests.fuzz.inputs import KINDS, Base, Case, cases, prepare_base

COMMANDS = ("info", "convert", "view")
EXAMPLES = 2  # per command and input kind: 42 cases, about 20 s


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Base:
    preload()
    return prepare_base(tmp_path_factory.mktemp("fuzz-base"), simulate=False)


@pytest.mark.parametrize(("kind", "command"), list(itertools.product(KINDS, COMMANDS)))
def test_fuzz_cases_keep_the_promise(base, tmp_path, kind, command):
    failures: list[str] = []

    @hseed(sum(map(ord, kind + command)))
    @settings(
        max_examples=EXAMPLES,
        phases=[Phase.generate],
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(cases(base, kind, command))
    def one(case: Case) -> None:
        work = tmp_path / "case"
        shutil.rmtree(work, ignore_errors=True)
        res = run_case(case, base, work, mode="fork")
        if res.findings:
            failures.append(f"{res.findings} {case.label}: {' '.join(res.argv)}\n{res.err[-2000:]}")

    one()
    assert not failures, "\n\n".join(failures)

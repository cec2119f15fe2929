"""Shared test fixtures and helpers."""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import pytest

#: real files (ROS 2 bags, UR10e logs): a copy of the team's shared test data, in the repo
DATA = Path(__file__).resolve().parent / "data"


@dataclass
class CliResult:
    code: int
    out: str
    err: str


def run_cli(*args: str) -> CliResult:
    """Run ``ditherlab ARGS`` in-process through main(); returns exit code, stdout, stderr."""
    from ditherlab.cli import main

    out, err = io.StringIO(), io.StringIO()
    code = 0
    with redirect_stdout(out), redirect_stderr(err):
        try:
            main([str(a) for a in args])
        except SystemExit as exc:
            code = int(exc.code or 0)
    return CliResult(code, out.getvalue(), err.getvalue())


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"test data not found at {DATA}")
    return DATA


def one_error(r: CliResult) -> str:
    """The one stderr line of a refused command (exit 2, nothing on stdout, no traceback)."""
    assert r.code == 2, (r.code, r.out, r.err)
    assert r.out == "" and "Traceback" not in r.err
    lines = r.err.splitlines()
    assert len(lines) == 1, r.err
    return lines[0]

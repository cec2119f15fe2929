"""The product speaks of itself only: no file of the repository tells its own history.

Code, comments, docs and config say what is and why; how the project got there lives in git and
in CHANGELOG.md (the one file exempt). The phrases below are the ones a history leaves behind.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: the history's own words (case-insensitive)
HISTORY = re.compile(
    r"\bsessions?[- ]\d+|\bissues?[- ]#?\d+|\b(?:was|were) tried\b|\bnot kept\b|\bearlier (?:wording|"
    r"version|session)s?\b|\bpreviously\b|\bno longer\b|\buntil (?:session|issue|now)\b|"
    r"(?<![\w-])RECORDING\.md\b|(?<![\w-])DESIGN\.md\b",
    re.IGNORECASE,
)
EXEMPT = {"CHANGELOG.md", "tests/test_no_history.py"}
TEXT = {".py", ".md", ".toml", ".txt", ".ipynb", ".yml", ".yaml", ".cfg", ".json", ""}


def tracked_files() -> list[Path]:
    out = subprocess.run(
        ["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=False
    ).stdout.split()
    if not out:  # not a git checkout (an sdist): every file below the repository
        return [p for p in REPO.rglob("*") if p.is_file() and ".venv" not in p.parts]
    return [REPO / f for f in out]


def history_lines(text: str) -> list[tuple[int, str]]:
    return [
        (i, line.strip()) for i, line in enumerate(text.splitlines(), 1) if HISTORY.search(line)
    ]


def test_the_pattern_finds_history():
    """The check can fail: each kind of phrase is found, and plain prose is not."""
    session, issue = "sess" + "ion", "iss" + "ue"  # the file names no history of its own
    for s in (
        f"measured in {session} 15",
        f"the {session}-12 plant",
        f"see {issue} 12",
        "a ripple model was tried",
        "the candidate was not kept",
        "an earlier wording said",
        "RECORDING.md beside this file",
    ):
        assert history_lines(s), s
    assert not history_lines("the loop runs until the band is left; the tries are counted")


@pytest.mark.parametrize("path", tracked_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_no_history_words(path: Path):
    rel = str(path.relative_to(REPO))
    if rel in EXEMPT or path.suffix not in TEXT or not path.is_file():
        return
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return
    found = history_lines(text)
    assert not found, f"{rel}: " + "; ".join(f"line {i}: {s[:90]}" for i, s in found[:5])

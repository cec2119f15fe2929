"""The documentation: the README is a front door, the generated pages are current, and the site
builds strict (no broken link, no dangling reference, every docstring the API page renders)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_the_readme_is_a_front_door():
    """README.md fits on a few screens (≤ 300 lines) and shows the two commands."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300
    assert "make demo" in text and "make test" in text


@pytest.mark.parametrize("script", ["effects_page.py", "cli_page.py"])
def test_generated_pages_are_current(script):
    """The effect table and the command reference match the code (``make docs`` rewrites them)."""
    r = subprocess.run(
        [sys.executable, str(REPO / "scripts" / script), "--check"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_site_builds_strict(tmp_path):
    """``mkdocs build --strict``: any warning (a broken link or anchor, a missing page, an API
    reference that does not resolve) fails the build."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=REPO,
        capture_output=True,
        text=True,
        env=env,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "api" / "index.html").is_file()

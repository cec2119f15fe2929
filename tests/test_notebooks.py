"""The worked examples in notebooks/ run top to bottom without error (executed with nbclient,
from notebooks/ as a reader would run them; they write their outputs to temporary folders)."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

FOLDER = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(FOLDER.glob("*.ipynb"))


def test_there_are_notebooks():
    """The parametrised test below would pass on an empty folder: the three examples exist."""
    assert {p.stem for p in NOTEBOOKS} >= {"diagnosis_loop", "paper_experiment", "your_own_log"}


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path):
    """Every cell of the notebook executes without an error (and its own asserts hold)."""
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(
        nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(FOLDER)}}
    )
    client.execute()
    errors = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.get("output_type") == "error"
    ]
    assert not errors

"""The package's front door, ``import ditherlab as dl``: its names, one argument order
(recordings first, then the model, then keyword-only options), a light import, and a tiny
campaign through it that gives what the command line gives on the same seed."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import ditherlab as dl
from ditherlab.analysis.diagnosis import diagnose
from ditherlab.app.identify import add_effect
from ditherlab.cli import app
from ditherlab.core.files import json_default
from ditherlab.data.estimates import Estimates

REPO = Path(__file__).resolve().parents[1]
NAMES = (
    "read",
    "write",
    "simulate",
    "identify",
    "replay",
    "diagnose",
    "add_effect",
    "report",
    "view",
    "Recording",
    "TorqueModel",
    "DitherlabError",
    "DitherlabWarning",
    "__version__",
)


def test_every_name_is_on_the_package():
    """Each name of the front door is an attribute of ``ditherlab`` and listed in __all__."""
    for name in NAMES:
        assert getattr(dl, name) is not None, name
        assert name in dl.__all__, name
    from ditherlab.core.version import __version__

    assert dl.__version__ == __version__
    assert dl.Recording.__name__ == "Recording" and dl.TorqueModel.__name__ == "TorqueModel"


def _positional(f) -> list[str]:
    return [
        p.name
        for p in inspect.signature(f).parameters.values()
        if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)
    ]


@pytest.mark.parametrize(
    "f, first",
    [
        (dl.simulate, ["scenario"]),
        (dl.identify, ["recordings"]),
        (dl.replay, ["recording", "model"]),
        (dl.diagnose, ["recordings", "model"]),
        (dl.add_effect, ["recordings", "model", "effect"]),
        (dl.report, ["estimates", "out"]),
        (dl.view, ["recording"]),
        (diagnose, ["recs", "model"]),
        (add_effect, ["recordings", "model", "effect", "joints"]),
    ],
)
def test_one_argument_order(f, first):
    """Recordings first, then the model; the front door's options are keyword-only."""
    assert _positional(f) == first
    if f.__module__ == "ditherlab":
        kinds = {p.kind for n, p in inspect.signature(f).parameters.items() if n not in first}
        assert kinds <= {inspect.Parameter.KEYWORD_ONLY}, f.__name__


def test_the_front_door_is_documented():
    """Every function of the front door has a NumPy-style docstring with its parameters."""
    for name in NAMES[:9]:
        doc = inspect.getdoc(getattr(dl, name)) or ""
        assert "Parameters\n----------" in doc or name == "write", name
        for p in _positional(getattr(dl, name)):
            assert p in doc, (name, p)


def _modules_after(code: str) -> set[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys; print(' '.join(sys.modules))"],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout
    return set(out.split())


def test_import_and_help_stay_light():
    """``import ditherlab`` and ``ditherlab --help`` load neither pandas nor pinocchio."""
    heavy = {"pandas", "pinocchio", "numpy"}
    assert not heavy & _modules_after("import ditherlab")
    help_run = (
        "import contextlib, io\n"
        "from ditherlab.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['--help'])"
    )
    assert not heavy & _modules_after(help_run)


def test_version_flag():
    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.stdout == f"ditherlab {dl.__version__}\n"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A short push campaign through the command line: recording, model, estimates, and the
    diagnosis as JSON."""
    d = tmp_path_factory.mktemp("front")
    paths = {
        k: d / f for k, f in (("rec", "rec.parquet"), ("model", "m.toml"), ("est", "e.parquet"))
    }
    runs = [
        ["simulate", "push-campaign", "--seed", "0", "--pushes-per-direction", "2", "-o", paths["rec"]],
        ["identify", paths["rec"], "--bootstrap", "0", "-o", paths["model"]],
        ["replay", paths["rec"], "--model", paths["model"], "-o", paths["est"]],
        ["diagnose", paths["rec"], "--model", paths["model"], "--json"],
    ]  # fmt: skip
    for args in runs:
        res = CliRunner().invoke(app, [*map(str, args), "-q"])
        assert res.exit_code == 0, res.stderr
    paths["diagnosis"] = json.loads(res.stdout)
    return paths


@pytest.mark.slow
def test_front_door_equals_the_command_line(campaign):
    """simulate -> identify -> replay -> diagnose through ``dl`` on the same seed: the same
    recording, model file, estimates and diagnosis as the commands wrote and printed."""
    rec = dl.simulate("push-campaign", seed=0, pushes_per_direction=2)
    assert rec.data.equals(dl.read(campaign["rec"]).data)
    path = campaign["rec"]  # the file: the model's notes and the diagnosis name it
    model = dl.identify([path], n_boot=0)
    assert model.dumps() == campaign["model"].read_text(encoding="utf-8")
    est = dl.replay(path, campaign["model"])
    assert est.data.equals(Estimates.load(campaign["est"]).data)
    d = dl.diagnose(path, model)
    assert json.loads(json.dumps(d.to_dict(), default=json_default)) == campaign["diagnosis"]

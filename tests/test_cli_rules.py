"""The rules every command follows, through ``typer.testing.CliRunner`` (the app itself, as a
user's script or another program would drive it):

- an existing output file is refused without ``--force`` (one line naming it and ``--force``),
  replaced with it, like an existing non-empty output folder;
- a file output named as a folder (``-o DIR/``, an existing folder) is refused, naming the file
  name expected there;
- a suffix the output's writer does not take is refused;
- no command writes into a file it reads: ``diagnose`` leaves ``--model`` byte for byte and
  writes the model with its history row to ``DIR/model.toml``;
- messages speak CLI; flags show as flags; the help lists every command.

The checks themselves live in one place, :func:`ditherlab.core.files.check_output`.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ditherlab.cli import app
from ditherlab.data.torque_model import TorqueModel

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "recordings" / "ur10e-static.parquet"
COMMANDS = (
    "info",
    "convert",
    "simulate",
    "identify",
    "replay",
    "report",
    "diagnose",
    "view",
    "robot",
    "fleet",
    "sweep",
    "leadthrough",
    "live",
    "publish",
)


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def refused(res, pattern: str) -> None:
    """Exit 2, nothing on stdout, one line ``error: ...`` on stderr matching ``pattern``."""
    assert res.exit_code == 2, (res.exit_code, res.stdout, res.stderr)
    assert res.stdout == ""
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert re.search(pattern, lines[0]), lines[0]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """A recording (the standing UR10e, no F/T sensor), its model and its estimates."""
    d = tmp_path_factory.mktemp("inputs")
    rec = d / "rec.parquet"
    shutil.copy(SAMPLE, rec)
    model, est = d / "model.toml", d / "est.parquet"
    res = run("identify", rec, "--assume-no-force", "--bootstrap", "0", "-o", model, "-q")
    assert res.exit_code == 0, res.stderr
    assert run("replay", rec, "--model", model, "-o", est, "-q").exit_code == 0
    return {"rec": rec, "model": model, "est": est}


def writing_commands(f: dict[str, Path], out: Path | str) -> dict[str, list]:
    """Every command that writes a file, writing ``out`` (its suffix chosen by the caller),
    quietly."""
    return {
        "identify": ["identify", f["rec"], "--assume-no-force", "--bootstrap", "0", "-o", out, "-q"],
        "replay": ["replay", f["rec"], "--model", f["model"], "-o", out, "-q"],
        "simulate": ["simulate", "push-campaign", "--pushes-per-direction", "1", "-o", out, "-q"],
        "convert": ["convert", f["rec"], out],
        "view": ["view", f["rec"], "--model", f["model"], "--save", out, "-q"],
        "live": ["live", "--model", f["model"], "--source", f"file:{f['rec']}", "--rate", "0",
                 "--sink", f"parquet:{out}"],
        "robot": ["robot", "irb140", "--sensitivity", "--no-dither", "--map", out,
                  "--grid", "q2=-0.2:0.2:2", "-q"],
    }  # fmt: skip


SUFFIX = {
    "identify": ".toml",
    "replay": ".parquet",
    "simulate": ".parquet",
    "convert": ".csv",
    "view": ".rrd",
    "robot": ".csv",
    "live": ".parquet",
}


@pytest.mark.parametrize("command", list(SUFFIX))
def test_an_existing_output_file_needs_force(inputs, tmp_path, command):
    """Refused without --force (the file keeps its bytes), replaced with it."""
    out = tmp_path / f"out{SUFFIX[command]}"
    out.write_text("mine")
    args = writing_commands(inputs, out)[command]
    refused(run(*args), rf"^error: {re.escape(str(out))}: exists; use --force to replace it$")
    assert out.read_text() == "mine"
    res = run(*args, "--force")
    assert res.exit_code == 0, res.stderr
    assert out.read_bytes() != b"mine"


def test_a_csv_sidecar_or_a_map_figure_in_the_way_needs_force(inputs, tmp_path):
    """The files an output brings along count as outputs: a CSV's sidecar, the map's PNG."""
    side = tmp_path / "out.json"
    side.write_text("{}")
    refused(
        run("convert", inputs["rec"], tmp_path / "out.csv"),
        rf"{re.escape(str(side))}: exists \(the sidecar of .*out\.csv\); use --force",
    )
    png = tmp_path / "map.png"
    png.write_text("mine")
    args = writing_commands(inputs, tmp_path / "map.csv")["robot"]
    refused(run(*args), rf"{re.escape(str(png))}: exists; use --force")
    assert side.read_text() == "{}" and png.read_text() == "mine"
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "map.csv").exists()


DEFAULT_NAME = {
    "identify": "model.toml",
    "replay": "estimates.parquet",
    "view": "view.rrd",
    "robot": "map.csv",
    "live": "estimates.parquet",
}


@pytest.mark.parametrize("command", list(DEFAULT_NAME))
def test_a_file_output_named_as_a_folder(inputs, tmp_path, command):
    """``-o DIR/`` and an existing folder are refused, saying the file name expected there;
    nothing is created (a recording output without suffix is a ROS 2 bag folder instead)."""
    new = tmp_path / "new"
    args = writing_commands(inputs, f"{new}/")[command]
    expected = re.escape(str(new / DEFAULT_NAME[command]))
    refused(
        run(*args),
        rf"new/: ends in a separator, a folder name; expected a file name such as {expected}$",
    )
    assert not new.exists()
    there = tmp_path / "there"
    there.mkdir()
    args = writing_commands(inputs, there)[command]
    expected = re.escape(str(there / DEFAULT_NAME[command]))
    refused(run(*args), rf"there: is a folder; expected a file name such as {expected}$")
    assert list(there.iterdir()) == []


@pytest.mark.parametrize(
    "command, name, expected",
    [
        ("identify", "model.json", r"\.toml \(a torque model\), not \.json"),
        ("replay", "est.csv", r"\.parquet \(estimates\), not \.csv"),
        ("simulate", "rec.txt", r"\.parquet, \.pq, \.csv or \.mcap \(a recording; .*\), not \.txt"),
        ("convert", "rec.json", r"\.parquet, \.pq, \.csv or \.mcap \(a recording; .*\), not \.json"),
        ("view", "view.png", r"\.rrd \(a Rerun recording\), not \.png"),
        ("robot", "map.txt", r"\.csv or \.parquet \(a sensitivity map table\), not \.txt"),
        ("live", "est.csv", r"\.parquet \(estimates\), not \.csv"),
    ],
)  # fmt: skip
def test_a_suffix_that_does_not_match_the_output(inputs, tmp_path, command, name, expected):
    """``identify -o model.json`` wrote TOML: each writer's suffix or one line, nothing
    written."""
    out = tmp_path / name
    refused(
        run(*writing_commands(inputs, out)[command]),
        rf"{re.escape(name)}: expected a file name ending in {expected}$",
    )
    assert not out.exists()


def snapshot(p: Path) -> tuple[bytes, int]:
    return p.read_bytes(), p.stat().st_mtime_ns


def test_diagnose_never_writes_into_its_model(inputs, tmp_path):
    """``--model`` keeps its bytes; ``-o DIR`` holds the model with the history row, which
    names the recordings; without ``-o`` nothing is written; ``-o`` onto the model refused."""
    model = tmp_path / "model.toml"
    shutil.copy(inputs["model"], model)
    before = snapshot(model)
    res = run("diagnose", inputs["rec"], "--model", model, "-q")
    assert res.exit_code == 0, res.stderr
    assert snapshot(model) == before and sorted(tmp_path.iterdir()) == [model]
    out = tmp_path / "diag"
    res = run("diagnose", inputs["rec"], "--model", model, "-o", out, "-q")
    assert res.exit_code == 0, res.stderr
    assert snapshot(model) == before
    written = TorqueModel.load(out / "model.toml")
    original = TorqueModel.load(model)
    assert written.history[:-1] == original.history
    row = written.history[-1]
    assert row["recordings"] == [str(inputs["rec"])]
    assert row["version"] == original.version
    assert (out / "report.json").is_file() and (out / "report.md").is_file()
    refused(
        run("diagnose", inputs["rec"], "--model", model, "-o", tmp_path, "--force", "-q"),
        rf"{re.escape(str(tmp_path))}: refusing to write a folder that holds the input file "
        rf"{re.escape(str(model))}$",
    )
    assert snapshot(model) == before
    nohist = tmp_path / "nohist"
    res = run("diagnose", inputs["rec"], "--model", model, "-o", nohist, "--no-history", "-q")
    assert res.exit_code == 0 and not (nohist / "model.toml").exists()


def test_messages_speak_cli(tmp_path):
    """A log without a robot names the option to give, not a Python keyword."""
    import ditherlab.io as dio

    rec = dio.read(SAMPLE)
    p = tmp_path / "a.csv"
    rec.data[["t", *[f"{f}_{j}" for f in ("q", "tau") for j in range(1, 7)]]].to_csv(p, index=False)
    res = run("info", p)
    refused(res, r"a\.csv: no robot given .*expected --robot with a built-in name \(irb140\)")
    assert "robot=" not in res.stderr


def test_help_lists_every_command():
    """``ditherlab --help``: every command in the header and in the list."""
    res = run("--help")
    assert res.exit_code == 0
    header, _, listing = res.stdout.partition("Commands:")
    for c in COMMANDS:
        assert re.search(rf"\b{c}\b", header), c
        assert re.search(rf"^  {c}\s+\S", listing, re.M), c


@pytest.mark.parametrize("command", COMMANDS)
def test_command_help_reads_well(command):
    """Each command's help: usage, a one-sentence summary, flags without a type, and
    --force on every command that writes."""
    res = run(command, "--help")
    assert res.exit_code == 0, res.stderr
    assert res.stdout.startswith(f"Usage: ditherlab {command} ")
    assert "<bool>" not in res.stdout and "╭" not in res.stdout
    summary = res.stdout.split("\n\n")[1].strip()
    assert summary.endswith(".") and len(summary) <= 60, summary
    if command not in ("info", "publish"):  # publish writes no file
        assert "--force" in res.stdout

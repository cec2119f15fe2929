"""Hostile inputs of the bad-input campaign, each with its exact input: blank lines before a
too-wide first data line, a ROS 2 bag whose SQLite file was cut, and the temporary file (or bag
folder) a killed writer leaves (a CSV of its header only and a 200 000-field line are in
test_fuzz_regressions). Each refused input is one line ``error:
...`` on stderr, exit status 2, nothing written; a stale temporary file is cleared by the next
write into its folder, a live one never."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import one_error

import ditherlab.io as dio
from ditherlab.core.errors import DitherlabWarning, FormatError
from ditherlab.core.files import atomic_path, clear_stale_temporaries
from ditherlab.data.recording import Recording, RecordingArrays

META = {"schema": "ditherlab.recording/1", "robot": "irb140"}
REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def rec() -> Recording:
    """300 rows at 250 Hz of an IRB140 with a wrench, a dither flag and a feedforward."""
    rng = np.random.default_rng(0)
    t = np.arange(300) * 0.004
    q = 0.3 * np.sin(np.outer(t, np.arange(1, 7)) * 0.5)
    r = Recording.from_arrays(RecordingArrays(t, q, rng.normal(0, 1, (300, 6))), META)
    data = r.data.copy()
    for k, c in enumerate(("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")):
        data[c] = rng.normal(0, 1 + k, 300)
    for j in range(1, 7):
        data[f"tau_ffw_{j}"] = 0.0
    data["dither"] = False
    return Recording(data, META)


@pytest.fixture(scope="module")
def model(rec, tmp_path_factory) -> Path:
    from ditherlab.analysis.identification import identify

    p = tmp_path_factory.mktemp("model") / "m.toml"
    identify([rec], n_boot=0).save(p)
    return p


# ------------------------------------------------------------------ a wide first data line
def test_blank_lines_before_the_wide_line_are_counted(tmp_path, rec):
    """The line named is the file's line: blank lines before it (which pandas skips) count."""
    src = tmp_path / "w.csv"
    dio.write(rec, src)
    lines = src.read_text().splitlines()
    src.write_text("\n".join([lines[0], "", "", lines[1] + ",1,2", *lines[2:]]) + "\n")
    with pytest.raises(FormatError) as e:
        dio.read(src)
    assert f"line 4 has {len(lines[0].split(',')) + 2} fields" in str(e.value)


# ------------------------------------------------------------------ a cut SQLite bag
@pytest.fixture(scope="module")
def db3_bag(rec, tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("db3") / "bag"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DitherlabWarning)  # tau_ffw, dither are not stored
        dio.write(rec, bag, storage="sqlite3")
    return bag


@pytest.mark.parametrize("keep", ["one byte short", "one page short", "99 bytes"])
def test_cut_sqlite_bag_is_refused(cli, tmp_path, db3_bag, model, keep):
    """``replay`` of a bag whose .db3 lost its end: one line saying the file is cut, how long
    it is and how long its header says, nothing written (SQLite read the pages left without a
    word and replay exited 0 on the messages that remained)."""
    bag = tmp_path / "bag"
    shutil.copytree(db3_bag, bag)
    db = bag / "bag.db3"
    data = db.read_bytes()
    n = {"one byte short": len(data) - 1, "one page short": len(data) - 4096, "99 bytes": 99}
    db.write_bytes(data[: n[keep]])
    line = one_error(cli("replay", bag, "--model", model, "-o", tmp_path / "e.parquet"))
    assert line.startswith(f"error: {bag}: the SQLite file bag.db3 is cut off ({n[keep]} bytes")
    assert "expected a whole bag" in line
    assert not (tmp_path / "e.parquet").exists()
    assert not any(p.name.startswith(".e.parquet") for p in tmp_path.iterdir())


def test_whole_sqlite_bag_reads_back_with_its_metadata(db3_bag, rec):
    """The uncut bag reads back: its samples, and the metadata stored in custom_data (base64:
    ruamel.yaml's folding of a long quoted string broke the JSON of a simulated recording)."""
    back = dio.read(db3_bag)
    np.testing.assert_array_equal(back.q, rec.q)
    np.testing.assert_array_equal(back.wrench, rec.wrench)
    assert back.meta == rec.meta


def test_bag_metadata_with_quotes_spaces_and_units_round_trips(tmp_path, rec):
    """Metadata holding what ruamel.yaml folds wrongly in a long double-quoted string (quotes,
    backslashes and non-ASCII characters beside spaces) comes back from a bag unchanged."""
    notes = " ".join(f'"q{k}" in N·m \\ {k}' for k in range(60))
    r = Recording(rec.data[["t", *(c for c in rec.data.columns if c[:2] in ("q_", "ta"))]],
                  {**META, "notes": notes})  # fmt: skip
    r = Recording(r.data[[c for c in r.data.columns if not c.startswith("tau_ffw")]], r.meta)
    for storage in ("mcap", "sqlite3"):
        bag = dio.write(r, tmp_path / f"b_{storage}", storage=storage)
        assert dio.read(bag).meta["notes"] == notes


def test_bag_says_which_columns_it_does_not_store(cli, tmp_path, rec):
    """``convert`` to a bag names the columns a bag cannot hold and why (it dropped 12 without a
    word); the columns it holds come back."""
    src = dio.write(rec, tmp_path / "a.parquet")
    with pytest.warns(DitherlabWarning) as got:
        r = cli("convert", src, tmp_path / "bag")
    assert r.code == 0, r.err
    assert [str(w.message) for w in got] == [
        f"{tmp_path / 'bag'}: not stored: tau_ffw_1..6, dither; a ROS 2 bag holds the joint "
        "states (q, dq, tau) and the wrench only (.parquet, .csv or .mcap keep every column)"
    ]
    back = dio.read(tmp_path / "bag")
    np.testing.assert_array_equal(back.tau, rec.tau)
    assert not any(c.startswith("tau_ffw") or c == "dither" for c in back.data.columns)


# ------------------------------------------------------------------ stale temporary files
_KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from ditherlab.core.files import atomic_path
    with atomic_path(sys.argv[1]) as tmp:
        tmp.write_bytes(b"half")
        os.kill(os.getpid(), signal.SIGKILL)
    """
)


def _killed_write(target: Path) -> Path:
    """Run a writer that is killed (SIGKILL) inside atomic_path; returns the file it left."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(target)], env=env, check=False)
    assert r.returncode == -9
    (left,) = [p for p in target.parent.iterdir() if p.name.startswith(f".{target.name}.")]
    return left


def test_stale_temporary_file_of_a_killed_replay_is_cleared(cli, tmp_path, rec, model):
    """The hidden temporary file a killed writer leaves beside its output is removed by the
    next run that writes into that folder; other hidden files stay."""
    out = tmp_path / "out"
    out.mkdir()
    left = _killed_write(out / "est.parquet")
    assert left.name.startswith(".est.parquet.") and left.name.endswith(".parquet")
    mine = out / ".est.parquet.notes"  # a user's file: not of the pattern
    mine.write_text("keep")
    src = dio.write(Recording(rec.data[[c for c in rec.data.columns if c != "dither"]], META),
                    tmp_path / "a.parquet")  # fmt: skip
    r = cli("replay", src, "--model", model, "-o", out / "e2.parquet", "-q",
            "--variants", "nodither_band")  # fmt: skip
    assert r.code == 0, r.err
    assert sorted(p.name for p in out.iterdir()) == [".est.parquet.notes", "e2.parquet"]


def test_live_temporary_file_is_never_cleared(tmp_path):
    """A temporary file whose writer is still writing (its lock held) stays; once the writer
    is done, its file is renamed whatever a clearing did meanwhile."""
    target = tmp_path / "x.parquet"
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"data")
        assert clear_stale_temporaries(tmp_path) == []
        assert tmp.exists()
    assert target.read_bytes() == b"data"
    left = _killed_write(tmp_path / "y.parquet")
    assert clear_stale_temporaries(tmp_path) == [left]
    assert not left.exists()


_KILLED_BAG_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    import numpy as np
    from ditherlab.data.recording import Recording, RecordingArrays
    from ditherlab.io import rosbag

    def killed(bag, plugin, rec, robot, ns):  # the bag half written, then the process killed
        bag.mkdir()
        (bag / (bag.name + ".mcap")).write_bytes(b"half")
        os.kill(os.getpid(), signal.SIGKILL)

    rosbag._write_bag = killed
    t = np.arange(10) * 0.004
    meta = {"schema": "ditherlab.recording/1", "robot": "irb140"}
    rec = Recording.from_arrays(RecordingArrays(t, np.zeros((10, 6)), np.zeros((10, 6))), meta)
    rosbag.write(rec, sys.argv[1])
    """
)


def test_stale_bag_folder_of_a_killed_writer_is_cleared(tmp_path, rec):
    """A bag writer killed half-way leaves its hidden folder ``.NAME.XXXXXXXX``: the next bag
    written into that folder removes it; a hidden folder that holds a replaced bag (``.old``)
    or anything else is left."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-c", _KILLED_BAG_WRITER, str(tmp_path / "run")],
                       env=env, check=False)  # fmt: skip
    assert r.returncode == -9
    (left,) = [p for p in tmp_path.iterdir() if p.name.startswith(".run.")]
    assert (left / "run" / "run.mcap").is_file()
    other = tmp_path / ".cfg.abcdefgh"  # the pattern, but not a bag being written
    (other / ".old").mkdir(parents=True)
    small = Recording(rec.data[["t", *(c for c in rec.data.columns if c[:2] in ("q_", "ta"))]],
                      META)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DitherlabWarning)
        dio.write(small, tmp_path / "second")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".cfg.abcdefgh", "second"]

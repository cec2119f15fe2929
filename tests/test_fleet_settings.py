"""``ditherlab fleet`` on real logs of different kinds at once: each recording's settings from
the manifest (a vendor log through its mapping and without a sensor beside logs with one), an
optional step that fails reported without failing its recording, exit status 1 when a
recording failed, and the robot's identity from the recording's metadata without a manifest."""

from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest

import ditherlab.io as dio
from ditherlab.analysis.fleet_job import robot_identity
from ditherlab.data.recording import Recording


@pytest.fixture(scope="module")
def mixed(tmp_path_factory, shared_data):
    """A UR10e log without torque sensor (mapping ur10e) and the hopper stand with its F/T
    sensor, both named in a manifest; a copy of the hopper log with ``robot_id`` in its
    metadata and one without, given without a manifest; a truncated Parquet file. Run serially
    with thresholds on (the hopper's pushes have no rest around them: that step fails)."""
    from conftest import run_cli

    d = tmp_path_factory.mktemp("mixed")
    shutil.copy(shared_data / "ur10e" / "no_torque.csv", d / "no_torque.csv")
    shutil.copy(shared_data / "hopper" / "hopper_short.parquet", d / "hopper.parquet")
    hop = dio.read(d / "hopper.parquet")
    dio.write(Recording(hop.data, {**hop.meta, "robot_id": "stand-2"}), d / "stand2.parquet")
    dio.write(hop, d / "unnamed.parquet")
    (d / "cut.parquet").write_bytes((d / "hopper.parquet").read_bytes()[:20000])
    (d / "manifest.csv").write_text(
        "file,robot,mapping,sensor\nno_torque.csv,ur-7,ur10e,no\nhopper.parquet,hopper-1,,yes\n"
    )
    out = d / "out"
    r = run_cli("fleet", "--manifest", d / "manifest.csv", d / "stand2.parquet",
                d / "unnamed.parquet", d / "cut.parquet", "-o", out, "--scheduler", "serial",
                "-q")  # fmt: skip
    return d, out, r


def test_failed_recording_gives_status_1_and_one_line(mixed):
    """One of five recordings failed: the report names it, the last stderr line says how many
    failed and what the outputs hold, and the status is 1 (not 0: scripts see it; not 2: the
    outputs were written)."""
    d, out, r = mixed
    assert r.code == 1, (r.out, r.err)
    assert r.err.splitlines() == [
        f"error: fleet: 1 of 5 recordings failed (listed above); {out} holds the other 4"
    ]
    assert f"failed: {d / 'cut.parquet'}: not a readable Parquet file" in r.out
    s = json.loads((out / "fleet.json").read_text())
    assert [f["file"] for f in s["failures"]] == [str(d / "cut.parquet")]


def test_manifest_settings_per_recording(mixed):
    """The UR10e log, read through the manifest's mapping and identified without a sensor
    (sensor = no), sits in the same table as the hopper logs identified with theirs: it has
    rows, with the UR10e's six joints and no force error."""
    _, out, _ = mixed
    t = pd.read_parquet(out / "fleet.parquet")
    ur = t[t["robot"] == "ur-7"]
    assert sorted(ur["joint"].unique()) == [1, 2, 3, 4, 5, 6]
    assert ur["force_rms_x"].isna().all()
    hop = t[t["robot"] == "hopper-1"]
    assert sorted(hop["joint"].unique()) == [1, 2]
    assert hop["force_rms_x"].notna().all()


def test_failed_optional_step_keeps_the_recording(mixed):
    """The thresholds cannot be measured on the hopper's pushes (no rest around them): each
    hopper recording keeps its rows (NaN thresholds) and the step's failure is reported, in the
    output, fleet.json and fleet.md."""
    d, out, r = mixed
    s = json.loads((out / "fleet.json").read_text())
    skipped = {k["file"]: k for k in s["skipped"]}
    hopper_files = [d / f"{n}.parquet" for n in ("hopper", "stand2", "unnamed")]
    assert set(skipped) == {str(p) for p in hopper_files}
    assert all(k["step"] == "thresholds" and "no rest" in k["error"] for k in skipped.values())
    t = pd.read_parquet(out / "fleet.parquet")
    assert set(t["file"]) == {str(p) for p in hopper_files} | {str(d / "no_torque.csv")}
    assert t["f50_x"].isna().all()
    assert f"thresholds not computed: {d / 'hopper.parquet'}: " in r.out
    assert "## Optional steps not done" in (out / "fleet.md").read_text()


def test_robot_identity_from_metadata_without_a_manifest(mixed):
    """Without a manifest a recording is the robot its metadata ``robot_id`` names; one without
    it is named by its file, and the output says so."""
    d, out, r = mixed
    t = pd.read_parquet(out / "fleet.parquet")
    assert set(t["robot"]) == {"ur-7", "hopper-1", "stand-2", "unnamed"}
    s = json.loads((out / "fleet.json").read_text())
    assert s["named_by_file"] == [str(d / "unnamed.parquet")]
    assert "1 recording named by its file (no manifest robot, no metadata robot_id)" in r.out


def test_robot_identity_order():
    """The manifest's robot first, then the metadata's robot_id, then the file's stem."""
    assert robot_identity("a/x.parquet", {"robot": "m"}, {"robot_id": "r"}) == ("m", "manifest")
    assert robot_identity("a/x.parquet", {"robot": None}, {"robot_id": "r"}) == ("r", "metadata")
    assert robot_identity("a/x.parquet", {}, {}) == ("x", "file name")


@pytest.mark.parametrize(
    ("text", "msg"),
    [
        ("file,sensor\nx.csv,maybe\n", "row 2, column 'sensor' is 'maybe'; expected yes"),
        ("file,robots\nx.csv,r\n", "unknown column 'robots'; expected file, robot, date"),
    ],
)
def test_bad_manifest_setting_is_one_line(cli, tmp_path, text, msg):
    """A sensor cell that is neither yes nor no, and a column the manifest does not have: one
    line naming the manifest, exit 2, nothing written."""
    (tmp_path / "x.csv").write_text("t\n0\n")
    m = tmp_path / "m.csv"
    m.write_text(text)
    r = cli("fleet", "--manifest", m, "-o", tmp_path / "out", "-q")
    assert r.code == 2 and r.out == "", (r.out, r.err)
    lines = r.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {m}: ") and msg in lines[0], r.err
    assert not (tmp_path / "out").exists()

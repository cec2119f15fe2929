"""Tests of the ``ditherlab info`` and ``ditherlab convert`` commands."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import ditherlab.io as dio
from ditherlab.data.recording import Recording, RecordingArrays

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "recordings" / "ur10e-static.parquet"


def assert_user_error(res, pattern: str) -> None:
    """Exit 2, nothing on stdout, one line on stderr matching ``pattern``, no traceback."""
    assert res.code == 2, (res.code, res.out, res.err)
    lines = res.err.strip().splitlines()
    assert len(lines) == 1, res.err
    assert lines[0].startswith("error: ")
    assert "Traceback" not in res.err and res.out == ""
    assert re.search(pattern, lines[0]), lines[0]


@pytest.fixture
def sample_copy(tmp_path) -> Path:
    p = tmp_path / "in.parquet"
    shutil.copy(SAMPLE, p)
    return p


def test_info_text(cli):
    """info prints rate with jitter, joints, present and absent columns and regime fractions."""
    res = cli("info", SAMPLE)
    assert res.code == 0, res.err
    assert "rate       100.00 Hz (interval 10.000 ms, jitter 0.944 ms std" in res.out
    assert "robot      ur10e (6 joints: shoulder_pan_joint" in res.out
    assert "columns    t, q, tau, dq; absent: tau_ffw, temp, wrench, dither, vendor" in res.out
    assert "regimes    still 97.9 %, dither 0.0 %, moving 2.1 %" in res.out


def test_info_json(cli):
    """info --json gives the summary as JSON whose regime fractions sum to one."""
    res = cli("info", SAMPLE, "--json")
    assert res.code == 0, res.err
    d = json.loads(res.out)
    assert d["samples"] == 4259 and d["joints"] == 6
    assert d["duration_s"] == pytest.approx(45.438)
    assert sum(d["regimes"].values()) == pytest.approx(1.0)
    assert d["columns"] == {
        "dq": True,
        "tau_ffw": False,
        "temp": False,
        "wrench": False,
        "dither": False,
        "vendor": False,
    }
    assert len(d["q_range_rad"]) == 6


def test_info_with_mapping(cli, shared_data):
    """info reads a foreign log through a mapping file."""
    res = cli("info", shared_data / "ur10e" / "no_torque.csv", "--mapping", "ur10e", "--json")
    assert res.code == 0, res.err
    d = json.loads(res.out)
    assert d["samples"] == 531 and d["robot"] == "ur10e"
    assert d["regimes"]["moving"] > 0.5


def test_info_on_a_ros2_file_without_joint_states(cli, shared_data):
    """A real ROS 2 bag without JointState is one clear line and exit 2."""
    res = cli("info", shared_data / "rosbag2" / "talker.mcap", "--robot", "irb140")
    assert_user_error(
        res,
        r"talker\.mcap: no sensor_msgs/msg/JointState topic .* /rosout "
        r"\[rcl_interfaces/msg/Log\]",
    )


def test_info_missing_file(cli, tmp_path):
    """A file that does not exist is exit 2 with its name."""
    assert_user_error(cli("info", tmp_path / "nope.parquet"), r"nope\.parquet: no such file")


def test_info_unknown_robot(cli, tmp_path):
    """An unknown --robot is exit 2 naming the robot."""
    rec = dio.read(SAMPLE)
    p = tmp_path / "a.csv"
    rec.data[["t", *[f"{f}_{j}" for f in ("q", "tau") for j in range(1, 7)]]].to_csv(p, index=False)
    assert_user_error(cli("info", p), r"a\.csv: no robot given")
    assert_user_error(cli("info", p, "--robot", "ur33"), r"robot 'ur33' is not a built-in robot")
    assert cli("info", p, "--robot", "irb140").code == 0


def test_a_vendor_log_without_a_header_is_sent_to_a_mapping(cli):
    """A headerless vendor CSV (the UR10e log): without options the error offers --mapping and
    names the built-in mappings; with --robot it says the first line is data, not names; with a
    mapping that expects a header it says the file has none; with the right mapping it reads."""
    log = REPO / "tests" / "data" / "ur10e" / "no_torque.csv"
    assert_user_error(cli("info", log), r"no robot given.*--mapping.*ur10e")
    assert_user_error(cli("info", log, "--robot", "ur10e"), r"first line holds numbers .*--mapping")
    assert_user_error(
        cli("info", log, "--mapping", "ur_rtde"), r"holds numbers, not names.*header = false"
    )
    assert cli("info", log, "--mapping", "ur10e").code == 0


def test_info_refuses_degrees(cli, tmp_path):
    """Joint angles in degrees are refused in one line that says so, naming the joint."""
    t = np.arange(100) * 0.004
    q = np.tile([10.0, 80.0, -120.0, 170.0, 95.0, 300.0], (100, 1))
    p = tmp_path / "deg.parquet"
    dio.write(
        Recording.from_arrays(RecordingArrays(t, q, np.zeros_like(q)), {"robot": "irb140"}), p
    )
    assert_user_error(
        cli("info", p), r"deg\.parquet: the joint log looks like degrees: q_6 reaches 300"
    )


@pytest.mark.parametrize("out", ["out.mcap", "out.csv", "out.parquet", "out_bag"])
def test_convert_round_trip(cli, sample_copy, tmp_path, out):
    """convert writes each format and the result reads back to the same recording."""
    dst = tmp_path / out
    res = cli("convert", sample_copy, dst)
    assert res.code == 0, res.err
    assert res.out.strip() == f"wrote {dst}"
    back, orig = dio.read(dst), dio.read(sample_copy)
    if out == "out_bag":
        np.testing.assert_array_equal(back.q, orig.q)
        np.testing.assert_array_equal(back.tau, orig.tau)
    else:
        assert back.equals(orig)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_convert_with_mapping(cli, shared_data, tmp_path):
    """convert --mapping turns a vendor CSV into a Parquet recording with the URDF embedded."""
    dst = tmp_path / "ur.parquet"
    res = cli("convert", shared_data / "ur10e" / "no_torque.csv", dst, "--mapping", "ur10e")
    assert res.code == 0, res.err
    rec = dio.read(dst)
    assert len(rec) == 531 and '<robot name="ur10e">' in rec.meta["robot"]["urdf"]


def test_convert_refuses_to_overwrite_its_input(cli, sample_copy):
    """convert IN IN is refused and the input is untouched."""
    before = sample_copy.read_bytes()
    res = cli("convert", sample_copy, sample_copy)
    assert_user_error(res, r"refusing to write over the input file")
    assert sample_copy.read_bytes() == before


def test_convert_refuses_the_input_through_another_spelling(cli, sample_copy):
    """A relative path with '..' that names the input is refused too."""
    other = sample_copy.parent / "sub" / ".." / sample_copy.name
    (sample_copy.parent / "sub").mkdir()
    assert_user_error(cli("convert", sample_copy, other), r"refusing to write over the input")


def test_convert_bad_input_writes_nothing(cli, tmp_path):
    """A corrupt input is exit 2, and neither the output nor a temporary file appears."""
    bad = tmp_path / "bad.mcap"
    dio.write(dio.read(SAMPLE), bad)
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 3])
    res = cli("convert", bad, tmp_path / "out.parquet")
    assert_user_error(res, r"bad\.mcap: the MCAP file is truncated or corrupt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]


def test_convert_failing_write_leaves_no_temp_file(cli, sample_copy, tmp_path):
    """A folder in the way of the output file: one line (the output guard refuses it before any
    work), no temp file, the folder untouched."""
    blocker = tmp_path / "out.parquet"
    blocker.mkdir()
    (blocker / "keep").write_text("x")
    res = cli("convert", sample_copy, blocker)
    assert_user_error(
        res, r"out\.parquet: is a folder; expected a file name such as .*/recording\.parquet$"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.parquet", "out.parquet"]
    assert (blocker / "keep").read_text() == "x"


def test_convert_replaces_an_existing_output(cli, sample_copy, tmp_path):
    """An existing output (not an input) is refused without --force, replaced whole with it."""
    dst = tmp_path / "out.mcap"
    dst.write_bytes(b"old")
    assert_user_error(cli("convert", sample_copy, dst), r"out\.mcap: exists; use --force")
    assert dst.read_bytes() == b"old"
    assert cli("convert", sample_copy, dst, "--force").code == 0
    assert dio.read(dst).equals(dio.read(sample_copy))


def test_info_bad_urdf_and_nan_are_one_line(cli, tmp_path):
    """A URDF that does not parse and a NaN cell each give one stderr line and exit 2."""
    rec = dio.read(SAMPLE).slice(None, 334.0)
    p = tmp_path / "a.csv"
    cols = ["t", *[f"{f}_{j}" for f in ("q", "tau") for j in range(1, 7)]]
    rec.data[cols].to_csv(p, index=False)
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'>")
    assert_user_error(cli("info", p, "--robot", bad), r"bad\.urdf")
    df = rec.data[cols].copy()
    df.loc[3:5, "tau_4"] = np.nan
    df.to_csv(p, index=False)
    t = df["t"].to_numpy()
    assert_user_error(
        cli("info", p, "--robot", "ur10e"),
        rf"a\.csv: tau_4 has 3 NaN values between t={t[3]:.2f} s and t={t[5]:.2f} s$",
    )


@pytest.mark.parametrize(
    "args, message",
    [
        (["replay", "--bogus"], "error: ditherlab replay: No such option: --bogus"),
        (["replay"], "error: ditherlab replay: Missing argument 'RECORDING'."),
        (["frobnicate"], "error: ditherlab: No such command 'frobnicate'."),
        (
            ["diagnose", "x.parquet", "--chunk", "0"],
            "error: ditherlab diagnose: Invalid value for '--chunk': Input should be greater "
            "than or equal to 1",
        ),
        (["replay", "x.parquet", "--level", "abc"], "error: ditherlab replay: Invalid value"),
    ],
)
def test_usage_errors_are_one_line_exit_2(cli, args, message):
    """A usage error (unknown option or command, missing argument, a value typer refuses) is one
    line on stderr naming the command, with where to look, and exit status 2 (typer's own is a
    usage line, a hint and a framed box: five lines)."""
    r = cli(*args)
    assert r.code == 2, (r.out, r.err)
    assert r.err.count("\n") == 1 and r.err.startswith(message), r.err
    assert r.err.rstrip().endswith("--help')") and r.out == ""


def test_bare_command_prints_the_help(cli):
    r = cli()
    assert r.code == 2 and r.err == ""
    assert "Usage: ditherlab" in r.out and "diagnose" in r.out


def test_logs_of_one_and_two_rows_end_cleanly(cli, tmp_path):
    """A log of one or two rows, shorter than the 0.1 s motion window: moving_mask does not
    broadcast the window into the log, nor does a fit on no rows divide by zero; replay
    estimates them, identify and diagnose say in one line that the log is too short, exit 2."""
    from ditherlab.analysis.identification import identify
    from ditherlab.sim import simulate

    rec = simulate("excitation", seed=4, dither=False, blocks=1, pushes_per_block=1)
    model = tmp_path / "m.toml"
    identify([rec], n_boot=0).save(model)
    for rows in (1, 2):
        short = tmp_path / f"r{rows}.parquet"
        dio.write(Recording(rec.data.iloc[:rows].reset_index(drop=True), rec.meta), short)
        r = cli("replay", short, "--model", model, "-o", tmp_path / f"e{rows}.parquet", "-q")
        assert r.code == 0, r.err
        r = cli("identify", short, "-o", tmp_path / f"m{rows}.toml", "-q")
        assert r.code == 2 and r.err.count("\n") == 1, r.err
        assert "no joint has 200 samples in any regime" in r.err
        r = cli("diagnose", short, "--model", model, "--no-history", "-q")
        assert r.code == 2 and r.err == (
            f"error: {short}: no sample left to score ({rows} rows; stick transitions, velocity "
            "reversals and the first dither period are not scored); expected a longer "
            "recording\n"
        ), r.err

"""Joint logs in degrees (ditherlab.io.units): refused by range or by velocity consistency, with
the word and the evidence; radian logs (simulated, and the real UR10e and hopper logs) pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from synthetic import push_recording

import ditherlab.io as dio
from ditherlab.core.errors import RecordingError
from ditherlab.data.recording import Recording
from ditherlab.io.units import degrees_evidence

REPO = Path(__file__).resolve().parents[1]
DATA = Path("/work/shared/data")


@pytest.fixture(scope="module")
def moving() -> Recording:
    """A simulated IRB140 recording that moves (pushes while the arm holds; dq logged)."""
    rec, _ = push_recording(5, magnitudes=(20.0,))
    return rec


def _scaled(rec: Recording, q: float = 1.0, dq: float = 1.0) -> Recording:
    data = rec.data.copy()
    for j in range(rec.n):
        data[f"q_{j + 1}"] *= q
        if f"dq_{j + 1}" in data:
            data[f"dq_{j + 1}"] *= dq
    return Recording(data, rec.meta, name="log.parquet")


def _with_motion(rec: Recording) -> Recording:
    """``rec`` with a slow sine on every joint (0.2 rad, 0.5 Hz) and dq its exact derivative:
    a log whose velocity test has something to measure, inside the joint limits."""
    data = rec.data.copy()
    w = 2 * np.pi * 0.5
    for j in range(rec.n):
        data[f"q_{j + 1}"] = rec.q[:, j] + 0.2 * np.sin(w * rec.t + j)
        data[f"dq_{j + 1}"] = 0.2 * w * np.cos(w * rec.t + j)
    return Recording(data, rec.meta, name="log.parquet")


def test_radians_pass(moving):
    """The simulator's log in rad and rad/s: no evidence, moving or not."""
    assert degrees_evidence(moving) is None
    assert degrees_evidence(_with_motion(moving)) is None


def test_q_and_dq_in_degrees_are_refused_by_range(moving):
    """q and dq both in degrees: consistent velocities, but q far beyond the limits and within
    them when read as degrees."""
    deg = _scaled(_with_motion(moving), np.degrees(1.0), np.degrees(1.0))
    ev = degrees_evidence(deg)
    assert ev is not None and "more than π beyond its limits" in ev


def test_q_in_degrees_dq_in_rad_is_refused_by_velocity(moving):
    """q in degrees but small (within every limit even so): the derivative of q is 57.3 times
    the logged dq."""
    rec = _with_motion(moving)
    data = rec.data.copy()
    for j in range(rec.n):  # small angles around zero: inside the limits in either unit
        data[f"q_{j + 1}"] = np.degrees(0.02 * np.sin(2 * np.pi * 0.5 * rec.t + j))
        data[f"dq_{j + 1}"] = 0.02 * 2 * np.pi * 0.5 * np.cos(2 * np.pi * 0.5 * rec.t + j)
    ev = degrees_evidence(Recording(data, rec.meta))
    assert ev is not None and "57.3 when q is in degrees" in ev
    assert "derivative of q_* is 57.3 times" in ev or "derivative of q_* is 57.2 times" in ev


def test_dq_in_degrees_per_second_is_refused(moving):
    """q in rad and dq in deg/s: the logged dq is 57.3 times the derivative of q."""
    ev = degrees_evidence(_scaled(_with_motion(moving), 1.0, np.degrees(1.0)))
    assert ev is not None and "dq is in deg/s" in ev


def test_far_outside_but_not_degrees_keeps_the_warning(moving):
    """A joint 400 rad off is beyond its limits in either reading: not called degrees (the
    robot's warning stays with it)."""
    data = moving.data.copy()
    data["q_2"] = data["q_2"] + 400.0
    assert degrees_evidence(Recording(data, moving.meta)) is None


def test_reading_a_degree_file_is_one_line_at_the_cli(cli, tmp_path, moving):
    """info and replay on a Parquet log in degrees: exit 2, one line with the word, nothing
    written."""
    p = tmp_path / "deg.parquet"
    dio.write(_scaled(_with_motion(moving), np.degrees(1.0), np.degrees(1.0)), p)
    for args in (["info", p], ["convert", p, tmp_path / "c.csv"]):
        r = cli(*args)
        assert r.code == 2 and r.out == "", (r.code, r.err)
        (line,) = r.err.strip().splitlines()
        assert line.startswith(f"error: {p}: the joint log looks like degrees: q_")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["deg.parquet"]


@pytest.mark.skipif(not DATA.exists(), reason="the shared real logs are not on this machine")
@pytest.mark.parametrize(
    "name, options",
    [
        ("ur10e/ur-static.csv", {"mapping": "ur10e"}),
        ("ur10e/no_torque.csv", {"mapping": "ur10e"}),
        ("hopper/hopper_short.parquet", {}),
    ],
)
def test_real_radian_logs_pass(name, options):
    """The real logs (rad, rad/s) read without a unit refusal."""
    rec = dio.read(DATA / name, **options)
    assert degrees_evidence(rec) is None


def test_bundled_real_log_in_degrees_is_refused(tmp_path):
    """The bundled UR10e log (tests/data) converted to degrees is refused; as logged it reads."""
    rec = dio.read(REPO / "tests" / "data" / "ur10e" / "no_torque.csv", mapping="ur10e")
    assert degrees_evidence(rec) is None
    p = tmp_path / "ur.parquet"
    dio.write(_scaled(rec, np.degrees(1.0), np.degrees(1.0)), p)
    with pytest.raises(RecordingError, match="looks like degrees"):
        dio.read(p)

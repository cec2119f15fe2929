"""A known load at the tool as the ground truth of the force estimate
(ditherlab.analysis.known_load): its wrench, its declaration, the comparison, the payload's range."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from synthetic import push_recording

from ditherlab.analysis.estimation import replay
from ditherlab.analysis.identification import identify
from ditherlab.analysis.known_load import (
    KNOWN_PREFIX,
    ReferenceSums,
    known_load_analysis,
    known_load_of,
    known_wrench,
    parse_known_load,
)
from ditherlab.core.errors import ConfigError, RecordingError
from ditherlab.core.names import VENDOR
from ditherlab.data.estimates import EstimatesSource
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.io import read, write
from ditherlab.output.known_load_page import known_load_lines, known_load_table
from ditherlab.physics.effects import EFFECTS
from ditherlab.physics.effects.signals import Signals
from ditherlab.robot import RobotModel

LOAD = {"mass": 2.0, "com": [0.02, -0.01, 0.05]}


def _moving(robot: RobotModel, seed: int = 0) -> Recording:
    """A recording of ``robot`` moving smoothly through its joints (4 s at 250 Hz)."""
    t = np.arange(0.0, 4.0, 1 / 250)
    rng = np.random.default_rng(seed)
    amp, w = rng.uniform(0.3, 0.8, robot.n), rng.uniform(1.0, 3.0, robot.n)
    q = 0.3 + amp * np.sin(np.outer(t, w))
    dq = amp * w * np.cos(np.outer(t, w))
    tau = robot.gravity(q)
    meta = {"robot": robot.name, "known_load": LOAD}
    return Recording.from_arrays(RecordingArrays(t, q, tau, dq=dq), meta)


@pytest.mark.parametrize("name", ["irb140", "ur10e"])
def test_known_wrench_is_the_torque_the_load_adds(name):
    """J^T of the known wrench equals the inverse dynamics of the arm with the load less the arm
    without it, moving, on two arms: the wrench is the load's weight and inertia at the tool."""
    robot = RobotModel.from_spec(name)
    rec = _moving(robot)
    W = known_wrench(rec, LOAD)
    dq, ddq = Signals(rec, sensor=False).motion
    loaded = robot.with_payload(LOAD)
    added = loaded.inverse_dynamics(rec.q, dq, ddq) - robot.inverse_dynamics(rec.q, dq, ddq)
    J = robot.jacobian(rec.q)
    assert np.abs(np.einsum("tkj,tk->tj", J, W) - added).max() < 1e-6 * np.abs(added).max()
    assert np.abs(W[:, 2] - 2.0 * 9.81).max() > 0.5  # the inertia shows while moving


def test_known_wrench_standing_is_the_weight_held_up():
    """Standing still the known wrench is (0, 0, m g) with the moment r × f of its lever."""
    robot = RobotModel.from_spec("irb140")
    q = np.tile([0.0, 0.3, -0.2, 0.1, 1.2, 0.4], (50, 1))
    arrays = RecordingArrays(np.arange(50) / 250, q, robot.gravity(q))
    rec = Recording.from_arrays(arrays, {"robot": "irb140", "known_load": LOAD})
    W = known_wrench(rec, LOAD)
    g = -robot.model.gravity.linear
    assert np.allclose(W[:, :3], 2.0 * g)
    R = robot.tool_pose(q)[:, :3, :3]
    r = np.einsum("tij,j->ti", R, LOAD["com"])
    assert np.allclose(W[:, 3:], np.cross(r, W[:, :3]), atol=1e-9)


def test_parse_known_load_and_its_errors():
    """MASS[@X,Y,Z] gives the load; a non-positive mass, two numbers or a word is one error."""
    assert parse_known_load("2.5@0,0,0.1") == {"mass": 2.5, "com": [0.0, 0.0, 0.1]}
    assert parse_known_load("1") == {"mass": 1.0, "com": [0.0, 0.0, 0.0]}
    for bad, words in (("-1", "mass > 0"), ("2@0,0", "3"), ("two", "MASS[@X,Y,Z]")):
        with pytest.raises(ConfigError, match="--known-load") as info:
            parse_known_load(bad)
        assert words in str(info.value)
    assert known_load_of({}) is None
    with pytest.raises(RecordingError, match="known_load"):
        known_load_of({"known_load": {"mass": -2.0}})


def test_reference_sums_give_rms_bias_and_coverage():
    """ReferenceSums over two blocks: the error's RMS and mean and the interval's coverage."""
    n = 100
    ref = np.zeros((n, 6)) + 10.0
    err = np.where(np.arange(n)[:, None] % 2 == 0, 1.0, 3.0) * np.ones((1, 6))
    cols = {
        f"{KNOWN_PREFIX}{c}": ref[:, k]
        for k, c in enumerate(["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"])
    }
    for k, c in enumerate(["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]):
        cols[f"v/{c}"] = ref[:, k] + err[:, k]
        cols[f"v/{c}_lo"] = cols[f"v/{c}"] - 2.0  # holds the reference where the error is 1
        cols[f"v/{c}_hi"] = cols[f"v/{c}"] + 2.0
    df = pd.DataFrame(cols)
    sums = ReferenceSums(KNOWN_PREFIX)
    sums.add(df.iloc[:40], ["v"])
    sums.add(df.iloc[40:], ["v"])
    res = sums.result()["variants"]["v"]
    assert np.allclose(res["bias"], 2.0)
    assert np.allclose(res["rms"], np.sqrt(5.0))
    assert np.allclose(res["coverage"], 0.5)
    assert ReferenceSums("x/").result() is None


def test_the_known_reference_adds_the_sensor_where_the_log_has_one():
    """With F/T columns beside the known load's, the reference is their sum (a push beside the
    load): an estimate equal to load + push has no error, one equal to the load alone has the
    push as its error."""
    n, names = 50, ["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]
    load, push = np.tile([0, 0, 19.6, 0, 0, 0.0], (n, 1)), np.zeros((n, 6))
    push[10:30, 0] = 30.0
    cols = {f"{KNOWN_PREFIX}{c}": load[:, k] for k, c in enumerate(names)}
    cols.update({c: push[:, k] for k, c in enumerate(names)})
    for v, F in (("both", load + push), ("load", load)):
        for k, c in enumerate(names):
            cols[f"{v}/{c}"] = F[:, k]
            cols[f"{v}/{c}_lo"], cols[f"{v}/{c}_hi"] = F[:, k] - 1, F[:, k] + 1
    plus = ReferenceSums(KNOWN_PREFIX, plus_sensor=True)
    plus.add(cols, ["both", "load"])
    res = plus.result()["variants"]
    assert np.allclose(res["both"]["rms"], 0.0) and np.allclose(res["both"]["coverage"], 1.0)
    assert np.isclose(res["load"]["bias"][0], -30.0 * 20 / n)
    alone = ReferenceSums(KNOWN_PREFIX)
    alone.add(cols, ["both", "load"])
    assert np.allclose(alone.result()["variants"]["load"]["rms"], 0.0)


def test_report_of_a_known_load_without_rest_shows_the_load_and_says_why(cli, tmp_path):
    """A loaded run whose pushes leave no rest (the robot always moves): report shows the
    estimate against the known load and says why there is no detection table, exit 0."""
    rec, _ = push_recording(2, magnitudes=(20.0, 40.0))
    model = identify([rec], n_boot=0)
    moving = rec.data.copy()
    moving["q_1"] = moving["q_1"] + 0.2 * np.sin(2 * np.pi * 0.5 * moving["t"])
    moving["dq_1"] = 0.2 * np.pi * np.cos(2 * np.pi * 0.5 * moving["t"])
    loaded = Recording(moving, {**rec.meta, "known_load": LOAD}, name="loaded")
    est = replay(loaded, model, variants=["nodither_band"])
    path = est.save(tmp_path / "est.parquet")
    r = cli("report", path, "-o", tmp_path / "rep", "-q")
    assert r.code == 0, r.err
    assert "known load 2 kg" in r.out
    assert "no detection table: the log has pushes but no rest" in r.out
    assert "No detection table: the log has pushes" in (tmp_path / "rep" / "report.md").read_text()


def test_reference_sums_count_the_vendor_estimate_without_an_interval():
    """The vendor's own estimate is compared with the reference like a variant: its error RMS
    and bias, and no coverage (it has no interval), in the table and in the printed lines."""
    n = 50
    names = ["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]
    cols = {f"{KNOWN_PREFIX}{c}": np.full(n, 5.0) for c in names}
    for c in names:
        cols[f"v/{c}"] = np.full(n, 5.0)
        cols[f"v/{c}_lo"], cols[f"v/{c}_hi"] = np.full(n, 4.0), np.full(n, 6.0)
        cols[f"{VENDOR}/{c}"] = np.full(n, 8.0)  # a bias of +3 everywhere
    sums = ReferenceSums(KNOWN_PREFIX)
    sums.add(pd.DataFrame(cols), ["v"])
    res = sums.result()
    assert list(res["variants"]) == ["v", VENDOR]
    assert np.allclose(res["variants"][VENDOR]["bias"], 3.0)
    assert res["variants"][VENDOR]["coverage"] is None
    assert np.allclose(res["variants"]["v"]["coverage"], 1.0)
    entry = {**res, "file": "a", "load": {"mass": 1.0, "com": [0, 0, 0]}}
    _, rows = known_load_table(entry)
    assert [r[-1] for r in rows if r[0] == VENDOR] == ["no interval"] * 3
    assert "coverage no interval" in known_load_lines({"files": [entry]})[-1]


def test_replay_of_a_loaded_run_estimates_the_load():
    """A standing run with a 10 kg load the model lacks, replayed: the known columns hold m g,
    and the estimate at rest lies near it (the friction band hides a part of it without dither)."""
    load = {"mass": 10.0, "com": [0.0, 0.0, 0.05]}
    rec, _ = push_recording(3, magnitudes=(20.0, 40.0))
    model = identify([rec], n_boot=0)
    W = known_wrench(rec, load)
    J = rec.robot().jacobian(rec.q)
    data = rec.data.copy()
    tau = rec.tau + np.einsum("tkj,tk->tj", J, W)
    for j in range(rec.n):
        data[f"tau_{j + 1}"] = tau[:, j]
    loaded = Recording(data, {**rec.meta, "known_load": load}, name="loaded")
    est = replay(loaded, model, variants=["nodither_band"])
    assert np.allclose(est.data[f"{KNOWN_PREFIX}f_z"], 10.0 * 9.81, atol=0.01)
    known = known_load_analysis([EstimatesSource.of(est)], 1000)
    entry = known["files"][0]
    assert entry["load"] == load
    rest = np.abs(rec.wrench[:, :3]).max(axis=1) < 0.5
    fz = est.F("nodither_band")[rest, 2]
    assert abs(np.median(fz) - 10.0 * 9.81) < 0.25 * 10.0 * 9.81


def test_convert_known_load_writes_the_metadata(cli, tmp_path):
    """convert --known-load stores the load; a bad value is one line, exit 2, nothing written."""
    rec, _ = push_recording(1, magnitudes=(20.0,))
    src = write(rec, tmp_path / "run.parquet")
    r = cli("convert", src, tmp_path / "k.parquet", "--known-load", "1.5@0,0,0.1")
    assert r.code == 0, r.err
    assert read(tmp_path / "k.parquet").meta["known_load"] == {"mass": 1.5, "com": [0, 0, 0.1]}
    r = cli("convert", src, tmp_path / "bad.parquet", "--known-load", "0")
    assert r.code == 2 and "--known-load 0" in r.err and len(r.err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.parquet").exists()


def test_payload_fit_outside_its_range_is_refused():
    """A payload whose centre of mass lies beyond the arm's reach, or whose mass is negative,
    is outside its physical range; a load held at the tool is inside."""
    rec = _moving(RobotModel.from_spec("irb140"))
    sig = [Signals(rec, sensor=False)]
    e = EFFECTS["payload"]
    assert e.outside_range({"mass": 2.0, "mass_com": [0.0, 0.0, 0.1]}, sig) is None
    far = e.outside_range({"mass": 2.0, "mass_com": [0.0, 0.0, 20.0]}, sig)
    assert far is not None and "reach" in far.source and far.param == "centre of mass distance"
    assert e.outside_range({"mass": -1.0, "mass_com": [0.0, 0.0, 0.0]}, sig).param == "mass"

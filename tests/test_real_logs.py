"""The diagnosis loop on real robot logs, through the CLI as a user runs it.

compare (identify, diagnose) -> see where it fails -> add the suggested effect -> diagnose again:
every step exits 0 on the real logs of tests/data, a suggestion can be added and the error falls,
and where nothing of the library explains the residual the verdict says so. Bad input gets one
line and exit status 2, with nothing written.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ditherlab.data.torque_model import TorqueModel

UR = ("--mapping", "ur10e")


@pytest.fixture(scope="module")
def data(shared_data):
    return shared_data


def _diagnose(cli, rec, model, *extra):
    r = cli("diagnose", rec, "--model", model, "--no-history", "--json", *extra)
    assert r.code == 0, r.err
    return json.loads(r.out)


def test_ur10e_free_motion_loop(cli, data, tmp_path):
    """No sensor, 89 % motion: identify covers the regimes, diagnose names inertia, adding it
    cuts joints 1-2's residual by more than half (10.2 -> 3.1, 13.2 -> 4.5 N·m measured)."""
    rec = data / "ur10e" / "no_torque.csv"
    m1, m2 = tmp_path / "m1.toml", tmp_path / "m2.toml"
    r = cli("identify", rec, *UR, "--assume-no-force", "-o", m1, "--bootstrap", "3", "-q")
    assert r.code == 0, r.err
    model = TorqueModel.load(m1)
    assert set(model.regimes) == {"still", "moving"}
    assert "moving regime fitted on all moving samples" in model.notes
    assert "--add inertia" in model.notes
    d1 = _diagnose(cli, rec, m1, *UR)
    top = [c for c in d1["candidates"] if c["suggested"]]
    assert top and top[0]["effect"] == "inertia", [c["text"] for c in d1["candidates"]]
    assert top[0]["explained_fraction"] > 0.5
    r = cli(
        "identify", rec, *UR, "--assume-no-force", "--model", m1, "--add", "inertia", "-o", m2,
        "--bootstrap", "3", "-q",
    )  # fmt: skip
    assert r.code == 0, r.err
    d2 = _diagnose(cli, rec, m2, *UR)
    before = np.array(d1["residual"]["torque_rms"])
    after = np.array(d2["residual"]["torque_rms"])
    assert np.all(after[:2] < 0.5 * before[:2]), (before, after)
    assert np.all(after <= before * 1.02), (before, after)


def test_ur10e_standing_gets_no_false_discovery(cli, data, tmp_path):
    """A robot standing still (0.5 mrad of motion, pushed by hand, no sensor): identify leaves
    the pushes out of the bands, diagnose leaves the same stretches out of its scores (forces,
    not a model error) and says so; nothing is suggested and every joint is at its noise floor."""
    rec = data / "ur10e" / "ur-static.csv"
    m = tmp_path / "m.toml"
    r = cli("identify", rec, *UR, "--assume-no-force", "-o", m, "--bootstrap", "3", "-q")
    assert r.code == 0, r.err
    d = _diagnose(cli, rec, m, *UR)
    assert not [c["effect"] for c in d["candidates"] if c["suggested"]]
    assert any("departures from rest" in n and "not scored" in n for n in d["notes"])
    assert len(d["notes"]) == len(set(d["notes"]))
    assert d["verdict"] is None  # every joint at or below its noise floor


def test_add_of_a_non_identifiable_effect_is_refused(cli, data, tmp_path):
    """identify --add of an effect the recording cannot tell apart from the bands (a payload on
    a robot holding one pose): one line, exit 2, nothing written."""
    rec = data / "ur10e" / "ur-static.csv"
    m, out = tmp_path / "m.toml", tmp_path / "m2.toml"
    assert (
        cli("identify", rec, *UR, "--assume-no-force", "-o", m, "--bootstrap", "0", "-q").code == 0
    )
    r = cli(
        "identify", rec, *UR, "--assume-no-force", "--model", m, "--add", "payload", "-o", out,
        "-q",
    )  # fmt: skip
    assert r.code == 2
    lines = r.err.strip().splitlines()
    assert len(lines) == 1, r.err
    assert lines[0] == (
        "error: effect 'payload' cannot be told apart from the bands in these recordings: its "
        "torque barely changes within a regime (q, dq, ddq (joint-torque regressor of the last "
        "link)); record a varying pose, motion or force"
    )
    assert not out.exists()


def test_assume_no_force_on_a_log_with_a_sensor_is_refused(cli, data, tmp_path):
    """--assume-no-force says no force acts; a log whose sensor measures one is refused (not
    silently ignored: the pushes would become friction)."""
    rec = data / "hopper" / "hopper_short.parquet"
    out = tmp_path / "m.toml"
    r = cli("identify", rec, "--assume-no-force", "-o", out, "-q")
    assert r.code == 2
    assert r.err.strip().splitlines() == [
        f"error: {rec}: --assume-no-force states that no external force acts, but this "
        "recording has F/T sensor columns f_x..m_z that measure it; drop the option to fit the "
        "bands with the sensor"
    ]
    assert not out.exists()


def test_hopper_loop_every_step_exits_0_and_says_what_is_missing(cli, data, tmp_path):
    """The hopper (a leg on a vertical slider, treated as a fixed base; an ATI sensor under the
    foot): the sensor bias is not suggested (not identifiable in these poses), each suggestion
    can be added and the held-out residual falls, and the verdict names the failing joints."""
    rec = data / "hopper" / "hopper_long.parquet"
    m = tmp_path / "m0.toml"
    r = cli("identify", rec, "-o", m, "--bootstrap", "3", "-q")
    assert r.code == 0, r.err
    d = _diagnose(cli, rec, m)
    ft = next(c for c in d["candidates"] if c["effect"] == "ft_bias")
    assert not ft["suggested"] and ft["not_identifiable"]
    assert d["verdict"] is not None
    assert {f["joint"] for f in d["verdict"]["failing"]} == {1, 2}
    suggested = [c for c in d["candidates"] if c["suggested"]]
    if suggested:
        name = suggested[0]["effect"]
        m2 = tmp_path / "m1.toml"
        r = cli("identify", rec, "--model", m, "--add", name, "-o", m2, "--bootstrap", "3", "-q")
        assert r.code == 0, r.err
        d2 = _diagnose(cli, rec, m2)
        j = suggested[0]["joints"][0] - 1
        assert d2["residual"]["torque_rms"][j] < d["residual"]["torque_rms"][j]
    else:
        assert d["verdict"]["status"] == "unexplained"
        assert "outside the library" in d["verdict"]["text"]


def test_hopper_report_with_pushes_along_one_axis_prints_no_warning(cli, data, tmp_path):
    """The hopper is pushed along z only: the report's figures have axes without pushes, which
    once made matplotlib print "No artists with labels found to put in legend" on the user's
    terminal (each figure's legend is drawn only where something is labelled)."""
    import warnings

    rec = data / "hopper" / "hopper_long.parquet"
    m, est = tmp_path / "m.toml", tmp_path / "est.parquet"
    assert cli("identify", rec, "-o", m, "--bootstrap", "0", "-q").code == 0
    assert cli("replay", rec, "--model", m, "-o", est, "-q").code == 0
    with warnings.catch_warnings(record=True) as shown:  # what the CLI prints as "warning: ..."
        warnings.simplefilter("always")  # a warning shown by an earlier test is shown again
        r = cli("report", est, "-o", tmp_path / "rep", "-q")
    assert r.code == 0, r.err
    assert [str(w.message) for w in shown] == []
    assert "warning" not in (r.out + r.err).lower(), r.err
    assert (tmp_path / "rep" / "detection.png").stat().st_size > 0
    d = json.loads((tmp_path / "rep" / "report.json").read_text())
    pushed = {a for c in d["conditions"].values() for a, s in c["directions"].items() if s}
    assert "z" in pushed

"""A known load as ground truth, end to end through the CLI on two simulated arms: the unloaded
run identified (with the links' inertia), the loaded run diagnosed (``payload`` first),
``--add payload`` recovering the mass and centre of mass, replay and report comparing the
estimate with the declared load."""

from __future__ import annotations

import json

import pytest

from ditherlab.data.torque_model import TorqueModel

MASS, COM_Z = 2.0, 0.05


@pytest.mark.study
@pytest.mark.parametrize("robot", ["irb140", "ur10e"])
def test_a_known_load_is_named_recovered_and_reported(cli, tmp_path, robot):
    """diagnose names payload first on the loaded run; the fitted mass is within 10 % and the
    centre of mass within 2 cm of the planted one; replay and report compare with the load."""
    p = {k: tmp_path / k for k in ("un.parquet", "lo.parquet", "lok.parquet", "m.toml")}
    common = ["simulate", "excitation", "--robot", robot, "--seed", "5", "-q"]
    assert cli(*common, "-o", p["un.parquet"]).code == 0
    r = cli(*common, "--hidden", f"payload:{MASS}", "-o", p["lo.parquet"])
    assert r.code == 0, r.err
    r = cli("convert", p["lo.parquet"], p["lok.parquet"], "--known-load", f"{MASS}@0,0,{COM_Z}")
    assert r.code == 0, r.err
    r = cli("identify", p["un.parquet"], "--add", "inertia", "-o", p["m.toml"], "-q")
    assert r.code == 0, r.err
    r = cli("diagnose", p["lok.parquet"], "--model", p["m.toml"], "-o", tmp_path / "d", "-q")
    assert r.code == 0, r.err
    cands = json.loads((tmp_path / "d" / "report.json").read_text())["candidates"]
    assert cands[0]["effect"] == "payload" and cands[0]["suggested"], cands[0]
    out = tmp_path / "m2.toml"
    r = cli("identify", p["lok.parquet"], "--model", p["m.toml"], "--add", "payload", "-o", out)
    assert r.code == 0, r.err
    spec = next(e for e in TorqueModel.load(out).effects if e.name == "payload")
    mass = spec.params["mass"]
    com_z = spec.params["mass_com"][2] / mass  # mass_com is the first moment m·c [kg·m]
    assert abs(mass - MASS) < 0.1 * MASS, mass
    assert abs(com_z - COM_Z) < 0.02, com_z
    est = tmp_path / "est.parquet"
    r = cli("replay", p["lok.parquet"], "--model", p["m.toml"], "-o", est, "-q")
    assert r.code == 0 and "known load 2 kg" in r.out, r.out
    r = cli("report", est, "-o", tmp_path / "rep", "-q")
    assert r.code == 0, r.err
    assert "known mean force" in r.out and "estimated mean" in r.out, r.out

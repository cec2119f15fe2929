"""Physical ranges of fitted effect parameters (``Effect.bounds``), identify's refusal of a fit
outside them, diagnosis's listing of such fits, and identify's delivery and force checks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import DATA, one_error, run_cli

from ditherlab import read
from ditherlab.analysis.delivery import DELIVERY_SHARE, Delivery
from ditherlab.physics.effects import EFFECTS, Signals

NO_TORQUE = DATA / "ur10e" / "no_torque.csv"
UR = ("--mapping", "ur10e")


def test_every_effect_declares_ranges_with_sources():
    """Every effect with fitted parameters declares a physical range for them, each with its
    range in words and the source of the range."""
    for name, e in EFFECTS.items():
        assert e.bounds, name
        for b in e.bounds:
            assert b.text and b.source and b.unit, (name, b)


def test_drive_gain_range_names_parameter_joint_value_and_range():
    """A drive gain k = 423 on joint 6 of the UR10e is outside 0.5..2 and named so; k = 1.1
    is inside."""
    sig = [Signals(read(NO_TORQUE, mapping="ur10e"), sensor=False)]
    e = EFFECTS["drive_gain"]
    out = e.outside_range({"gain_error": 422.0}, sig, 5)
    assert out is not None
    assert (out.param, out.where, out.lo, out.hi) == ("k", "joint 6", 0.5, 2.0)
    assert out.value == pytest.approx(423.0)
    assert "k 423 on joint 6" in out.text() and "0.5..2" in out.text()
    assert e.outside_range({"gain_error": 0.1}, sig, 5) is None


def test_payload_range_is_the_rated_payload():
    """A payload heavier than the UR10e's rated 12.5 kg is outside its range; 10 kg is not."""
    sig = [Signals(read(NO_TORQUE, mapping="ur10e"), sensor=False)]
    e = EFFECTS["payload"]
    assert e.outside_range({"mass": 10.0, "mass_com": [0.0, 0.0, 0.5]}, sig) is None
    out = e.outside_range({"mass": 14.0, "mass_com": [0.0, 0.0, 0.7]}, sig)
    assert out is not None and out.param == "mass" and out.hi == 12.5


@pytest.fixture(scope="module")
def no_torque_model(tmp_path_factory):
    """The bands of no_torque.csv without a sensor (identify --assume-no-force)."""
    d = tmp_path_factory.mktemp("no_torque")
    r = run_cli("identify", NO_TORQUE, *UR, "--assume-no-force", "-o", d / "m.toml", "-q")
    assert r.code == 0, r.err
    return d / "m.toml"


def test_identify_refuses_unphysical_drive_gain_on_no_torque(no_torque_model, tmp_path):
    """identify --add drive_gain on no_torque.csv fits k = 2.37 on joint 1 and 423 on joint 6
    (the wrist's rigid torque is tiny): one line naming effect, parameter, joint, value and
    range, exit 2, no model written."""
    out = tmp_path / "dg.toml"
    args = ("identify", NO_TORQUE, *UR, "--assume-no-force", "--model", no_torque_model)
    line = one_error(run_cli(*args, "--add", "drive_gain", "-o", out, "-q"))
    assert "drive_gain k" in line and "on joint 1" in line and "0.5..2" in line, line
    assert "not written" in line
    assert not out.exists()


def test_diagnose_does_not_suggest_unphysical_drive_gain(no_torque_model, tmp_path):
    """diagnose on no_torque.csv no longer suggests drive_gain (its fits on joints 1 and 6 are
    unphysical) and lists them, in the text and the JSON report."""
    r = run_cli("diagnose", NO_TORQUE, *UR, "--model", no_torque_model, "-o", tmp_path / "d", "-q")
    assert r.code == 0, r.err
    rep = json.loads((tmp_path / "d" / "report.json").read_text())
    dg = next(c for c in rep["candidates"] if c["effect"] == "drive_gain")
    assert not dg["suggested"]
    where = {u["where"]: u for u in dg["unphysical"]}
    assert {"joint 1", "joint 6"} <= set(where)
    assert where["joint 6"]["value"] > 2.0 and where["joint 6"]["hi"] == 2.0
    assert "fits only with an unphysical value" in r.out
    assert "fits only with an unphysical value" in (tmp_path / "d" / "report.md").read_text()


def test_delivery_rule():
    """An effect that lowers the named joints' loss by less than half of its promise fails
    the rule and says whether the bands' re-fit took it back; one that delivers passes."""
    d = Delivery("drive_gain", [1], 0.5, (100.0, 60.0, 99.0), ([2.0], [2.0]))
    assert not d.ok and "re-fitted bands take back" in d.text()
    d = Delivery("drive_gain", [1], 0.5, (100.0, 99.0, 99.0), ([2.0], [2.0]))
    assert not d.ok and "does not lower the residual" in d.text()
    d = Delivery(
        "drive_gain", [1], 0.5, (100.0, 70.0, 100 * (1 - DELIVERY_SHARE * 0.5)), ([2], [1])
    )
    assert d.ok
    assert np.isclose(d.share(), DELIVERY_SHARE * 0.5)

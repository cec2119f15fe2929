"""A suggestion delivers what it promised on the second plant (``simulate --plant lugre``: LuGre
friction, coloured and quantised torque noise, its own sensor), through the CLI: a drive gain of
1.3 planted on joint 2 is suggested there, and ``identify --add drive_gain`` fits it within its
physical range and lowers the held-out residual by at least half of the promise.

Study tier: one simulation, identification and diagnosis of a 90 s excitation (about 2 min).
"""

from __future__ import annotations

import json
import tomllib

import pytest
from conftest import run_cli

from ditherlab.analysis.delivery import DELIVERY_SHARE

pytestmark = pytest.mark.study


def test_a_planted_drive_gain_is_suggested_and_delivers(tmp_path):
    rec, m, m2 = tmp_path / "rec.parquet", tmp_path / "m.toml", tmp_path / "m2.toml"
    r = run_cli("simulate", "excitation", "--plant", "lugre", "--seed", "7", "--no-dither",
                "--hidden", "drive_gain:1.3@2", "-o", str(rec), "-q")  # fmt: skip
    assert r.code == 0, r.err
    r = run_cli("identify", str(rec), "--add", "inertia", "--add", "stribeck",
                "--bootstrap", "0", "-o", str(m), "-q")  # fmt: skip
    assert r.code == 0, r.err
    r = run_cli("diagnose", str(rec), "--model", str(m), "--json", "-o", str(tmp_path / "d"),
                "--no-history", "-q")  # fmt: skip
    assert r.code == 0, r.err
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    cand = next(c for c in report["candidates"] if c["effect"] == "drive_gain")
    assert cand["suggested"] and cand["joints"] == [2], cand
    r = run_cli("identify", str(rec), "--model", str(m), "--add", "drive_gain",
                "--bootstrap", "0", "-o", str(m2), "-q")  # fmt: skip
    assert r.code == 0, r.err
    model = tomllib.loads(m2.read_text())
    row = model["history"][-1]
    assert row["added"] == "drive_gain" and row["delivery_joints"] == [2], row
    assert row["delivered"] >= DELIVERY_SHARE * row["promised"] > 0, row
    spec = next(e for e in model["effects"] if e["name"] == "drive_gain")
    k = 1.0 + spec["params"]["gain_error"][spec["joints"].index(2)]
    assert 1.2 < k < 1.4, k

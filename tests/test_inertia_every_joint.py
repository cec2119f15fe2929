"""``identify --add inertia`` fits every joint the log moves (``Effect.on_every_joint``), and
holds a parameter the data cannot determine at its nominal value (``Bound.nominal``,
:func:`ditherlab.physics.effect_fit.undetermined`).

Every joint of an arm has a rotor and moves links. Fitted only where one log's per-joint
evidence passed, the other joints keep their rotor's torque in the residual, and diagnose on
the same log then suggests ``dynamics`` (whose armature columns take it) on a plant that has
nothing else. On the second plant's UR10e (study recording 7 of ``bench_false_discovery
--plant lugre``: an excitation without dither, nothing planted) the wrist's last link adds
0.01 noise sigmas of dynamic torque at scale 1, so its scale fits 55 ± 35 while its rotor's
term reaches 30 sigma: the scale is held at 1 and said so in one line.
"""

from __future__ import annotations

import json
import tomllib

import pytest
from conftest import run_cli

from ditherlab.analysis.delivery import DELIVERY_SHARE
from ditherlab.io import read


@pytest.mark.slow
def test_inertia_on_every_joint_and_nothing_left_to_suggest(tmp_path):
    rec, m = tmp_path / "rec.parquet", tmp_path / "m.toml"
    r = run_cli("simulate", "excitation", "--plant", "lugre", "--robot", "ur10e",
                "--seed", "74280", "--no-dither", "-o", str(rec), "-q")  # fmt: skip
    assert r.code == 0, r.err
    r = run_cli("identify", str(rec), "--add", "inertia", "--add", "stribeck",
                "--bootstrap", "0", "-o", str(m), "-q")  # fmt: skip
    assert r.code == 0, r.err
    held = [x for x in r.err.splitlines() if "inertia joint 6: scale held at 1, its nominal" in x]
    assert len(held) == 1, r.err
    model = tomllib.loads(m.read_text())
    spec = next(e for e in model["effects"] if e["name"] == "inertia")
    assert spec["joints"] == [1, 2, 3, 4, 5, 6], spec
    scale, rotor = spec["params"]["scale"], spec["params"]["motor_inertia"]
    assert scale[5] == 1.0 and all(0.25 <= s <= 4.0 for s in scale), scale
    # the wrist's rotors, which the plant draws per seed (recorded in the log's metadata)
    jm = read(rec).meta["sim"]["params"]["jm"]
    for j in (3, 4, 5):
        assert jm[j] / 1.5 < rotor[j] < 1.5 * jm[j], (j + 1, rotor[j], jm[j])
    row = next(h for h in model["history"] if h.get("added") == "inertia")
    assert row["delivered"] >= DELIVERY_SHARE * row["promised"] > 0, row
    r = run_cli("diagnose", str(rec), "--model", str(m), "--json", "--no-history", "-q")
    assert r.code == 0, r.err
    sug = [(c["effect"], c["joints"]) for c in json.loads(r.out)["candidates"] if c["suggested"]]
    assert sug == [], sug

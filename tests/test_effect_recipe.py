"""Adding an effect is one class in one file and its test (CONTRIBUTING.md, "Add an effect").

This test is that recipe, followed: a new effect defined here, nowhere else, is tried by
diagnosis, ranked first where it was planted, fitted by ``add_effect``, applied by
``effects_torque``, printed by ``model_text`` and read back from the model file.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_effects import make_recording

from ditherlab.analysis.diagnosis import diagnose
from ditherlab.analysis.identification import identify
from ditherlab.app.identify import add_effect
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.effects import EFFECTS, Design, Effect, effects_torque, fmt, model_text

PLANTED = 0.06  # the logged torque reads 6 % too much gravity on joints 2 and 3


@pytest.fixture
def gravity_gain():
    """The new effect, defined in one class; removed from the library after the test."""

    class GravityGain(Effect):
        name = "test_gravity_gain"
        physics = "the drive reads gravity's torque scaled (a wrong torque constant)"
        driven_by = "tau_grav(q)"
        linear = ("gain",)
        shows_in = ("still", "dither", "moving")

        def design(self, sig, j, h, ref):
            return Design(sig.gravity[:, j : j + 1])

        def driver(self, sig, j, p):
            return sig.gravity[:, j], f"tau_grav_{j + 1} [N·m]"

        def term(self, p, j):
            return f"{fmt(p['gain'])}·tau_grav_{j + 1}"

    yield GravityGain
    EFFECTS.pop("test_gravity_gain", None)


def test_a_new_effect_is_found_fitted_applied_and_printed(gravity_gain, tmp_path):
    assert "test_gravity_gain" in EFFECTS
    rec = make_recording((), seed=21, duration=8.0)
    g = rec.robot().gravity(rec.q)
    tau = rec.tau.copy()
    tau[:, 1:3] += PLANTED * g[:, 1:3]
    rec = rec.with_columns(**{f"tau_{j + 1}": tau[:, j] for j in range(rec.n)})
    m = identify([rec], n_boot=3)
    d = diagnose([rec], m)
    assert d.suggested and d.suggested[0].effect == "test_gravity_gain", d.summary()
    assert d.suggested[0].joints == [2, 3]
    m2 = add_effect([rec], m, "test_gravity_gain")
    spec = m2.effects[-1]
    np.testing.assert_allclose(spec.params["gain"], [PLANTED, PLANTED], rtol=0.1)
    shift = effects_torque(m2, rec)
    np.testing.assert_allclose(shift[:, 1:3], np.array(spec.params["gain"]) * g[:, 1:3])
    assert np.all(shift[:, [0, 3, 4, 5]] == 0)
    assert "·tau_grav_2" in model_text(m2).splitlines()[2]
    m2.save(tmp_path / "m.toml")
    back = TorqueModel.load(tmp_path / "m.toml")
    np.testing.assert_array_equal(effects_torque(back, rec), shift)

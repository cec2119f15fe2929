"""Diagnosis on the built-in simulator: each hidden effect of the plant (written in the plant's own
terms, ``ditherlab/sim/hidden.py``) is ranked first on the ``excitation`` scenario, adding it
brings the torque residual to the noise floor, clean recordings give no candidate, and of two
effects the larger comes first.

Workflow under test: the ``inertia`` effect (links and reflected motor inertia, which the plant
always has) is fitted once on a clean recording; every recording (clean or with a hidden effect,
the same plan) then gets its bands, noise and sliding friction identified on itself with that
inertia kept (``identify(base=...)``), and is diagnosed. The recordings are made without dither:
the dither regime's extracted signal under-reads pushes (the paper's known under-estimate) by
more than the noise floor, which no model effect describes.

Every effect meets every criterion; the fitted parameters are checked against the plant's.
"""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.analysis.diagnosis import diagnose, residual_summary
from ditherlab.analysis.identification import identify
from ditherlab.app.identify import add_effect
from ditherlab.physics.residual import scored
from ditherlab.sim import simulate

#: scenario options: two pose blocks, three pushes in each pose and two during strokes (~65 s)
OPTS = {"blocks": 2, "pushes_per_block": 3}
SEED = 3


def _sim(hidden=(), seed=SEED, **options):
    opts = {**OPTS, **options}
    return simulate("excitation", seed=seed, dither=False, hidden=list(hidden), **opts)


def _baseline(rec):
    return _add(identify([rec], n_boot=0), rec, "inertia", list(range(1, 7)))


def _refit(base, rec):
    """Bands, noise and sliding friction identified on ``rec``, the inertia effect kept."""
    return identify([rec], base=base, n_boot=0)


def _add(m, rec, name, joints=None):
    """``add_effect`` and the bands re-identified with it in place (no bootstrap replicates:
    the standard errors are not under test)."""
    m2 = add_effect([rec], m, name, joints=joints, refit=False)
    out = identify([rec], base=m2, n_boot=0)
    out.effects = list(m2.effects)
    return out


def _rms(m, rec):
    return np.array(residual_summary(m, [scored(m, rec)])["torque_rms"])


@pytest.fixture(scope="module")
def clean():
    """The clean recording, its model (identify + inertia) and the model's diagnosis."""
    rec = _sim()
    m = _baseline(rec)
    return rec, m, diagnose([rec], m)


class _Loops(dict):
    """Per hidden effect: recording, diagnosis (bands identified on it, the clean model's inertia
    kept), torque RMS after adding the top candidate, and that model; computed on first use."""

    def __init__(self, base):
        super().__init__()
        self.base = base

    def __missing__(self, name):
        rec = _sim([name])
        m = _refit(self.base, rec)
        d = diagnose([rec], m)
        after = m2 = None
        if d.suggested:
            c = d.suggested[0]
            m2 = _add(m, rec, c.effect, c.joints)
            after = _rms(m2, rec)
        self[name] = out = (rec, d, after, m2)
        return out


@pytest.fixture(scope="module")
def loops(clean):
    return _Loops(clean[1])


#: hidden effect (with its size) -> joints (1-based) that must be named, or None for the effects
#: shared by all joints. The plant applies load_friction to every joint in proportion to its gear
#: torque; joints 2 and 3 carry most of it (joint 1 turns about the vertical, the wrist carries
#: little), so they must be named and the others may be (see LOAD_MAY).
#: temperature_friction: a 40 °C warm-up (default 20 °C) so that the drift within the 70 s
#: recording is 1.7x the noise floor (with 20 °C it is 1.1x: no 30 % fall is possible).
HIDDEN = {
    "load_friction": [2, 3],
    "temperature_friction:40": [1, 2, 3, 4, 5, 6],
    "position_ripple": [1, 2, 3, 4, 5, 6],
    "payload": None,
    "attenuation_lag": None,
    "stribeck": [1, 2, 3, 4, 5, 6],
    "ft_bias": None,
}
#: load_friction: the joints that may be named besides 2 and 3 (the plant has it on all six)
LOAD_MAY = {1, 2, 3, 4, 5, 6}
#: effects that meet both criteria below on the simulator: ranked first on the joints where they
#: show, and the residual at the noise floor once added (the others: see their tests)
PASSING = [
    "load_friction",
    "temperature_friction:40",
    "position_ripple",
    "payload",
    "attenuation_lag",
    "stribeck",
    "ft_bias",
]
#: checked by ``make test`` (one effect on a joint set, two shared by all joints); the others
#: run in the study tier (``make study``)
CORE = ("load_friction", "payload", "ft_bias")
KEYS = [pytest.param(k, marks=() if k in CORE else pytest.mark.study) for k in PASSING]


def _top(loops, key):
    _, d, _, _ = loops[key]
    assert d.suggested, d.summary()
    return d, d.suggested[0]


def _fall_and_floor(d, after):
    r0 = np.array(d.residual["torque_rms"])
    floor = np.array(d.residual["noise_floor"])
    return r0, np.asarray(after), floor


@pytest.mark.parametrize("key", KEYS)
def test_hidden_effect_ranked_first_on_right_joints(loops, key):
    """The plant's hidden effect is the first suggested candidate, on the joints where it shows,
    and explains most of the part of the residual above the noise on held-out data."""
    d, top = _top(loops, key)
    assert top.effect == key.split(":")[0], d.summary()
    if key == "load_friction":
        assert set(HIDDEN[key]) <= set(top.joints) <= LOAD_MAY, d.summary()
    elif HIDDEN[key] is not None:
        assert top.joints == HIDDEN[key], d.summary()
    # stribeck (0.4 Fc) is small: the residual before is 1.2-1.3x the floor, so at most ~40 %
    # of it is the effect, the rest noise
    assert top.explained_fraction > (0.3 if key == "stribeck" else 0.4), d.summary()


@pytest.mark.parametrize("key", KEYS)
def test_error_falls_to_noise_floor_after_adding(loops, key):
    """Adding the top candidate cuts the worst joint's residual RMS by >= 30 % and brings every
    joint within 25 % of its noise floor."""
    _, d, after, _ = loops[key]
    r0, r1, floor = _fall_and_floor(d, after)
    j = int(np.argmax(r0 / floor))
    assert r1[j] <= 0.7 * r0[j], (r0, r1)
    assert np.all(r1 <= 1.25 * floor), (r1, floor)


def test_payload_and_ft_bias_values_match_the_plant(loops):
    """The fitted payload mass and centre of mass, and the fitted F/T offset, are the plant's."""
    rec, _, _, m2 = loops["payload"]
    p = m2.effects[-1].params
    truth = rec.meta["sim"]["hidden"][0]
    assert abs(p["mass"] - truth["size"]) < 0.15 * truth["size"], p
    assert abs(p["mass_com"][2] / p["mass"] - truth["com"][2]) < 0.02, p
    rec, _, _, m2 = loops["ft_bias"]
    p = m2.effects[-1].params
    bias = np.array(rec.meta["sim"]["hidden"][0]["bias"][:3])
    assert np.allclose([p["f_x"], p["f_y"], p["f_z"]], bias, atol=0.3), (p, bias)


def test_load_friction_values_match_the_plant(loops):
    """The fitted load slope is the plant's Coulomb growth (band growth 0.15 per N·m of gear
    torque, i.e. 0.15 · Fc/Fs = 0.1275 on the Coulomb level: within 0.01 on joints 2 and 3, 0.025
    on the others), and the output-side friction the gear carries on joint 2 at no load is about
    the plant's: the output share ``1 - friction.motor_share`` of the sliding friction Fc = 8.1 N·m
    (-38 % / +50 %)."""
    rec, _, _, m2 = loops["load_friction"]
    spec = m2.effects[-1]
    k = np.array(spec.params["k"])
    assert np.allclose(k, 0.1275, atol=0.025), spec.params
    assert np.allclose(k[[spec.joints.index(2), spec.joints.index(3)]], 0.1275, atol=0.01)
    fr = rec.meta["sim"]["params"]["friction"]
    truth = (1 - fr["motor_share"]) * fr["coulomb_ratio"] * fr["static"][1]
    c2 = spec.params["output_friction"][spec.joints.index(2)]
    assert 0.62 * truth < c2 < 1.5 * truth, (truth, spec.params)


@pytest.mark.study
@pytest.mark.xfail(
    strict=True,
    reason="with the friction band behind the gear spring (motor_share 0.1) the wrists' "
    "Stribeck hump, read through the motor velocity, comes out at 0.67 of the plant's and vs one "
    "grid step high; diagnose does not model the link-side velocity",
)
def test_stribeck_values_match_the_plant(loops):
    """The fitted Stribeck velocity is the plant's (0.02 rad/s) and the hump Fs - Fc is within
    25 % of the plant's 0.4 · Fc on every joint (Fc = 0.85 Fs from the run's parameters)."""
    rec, _, _, m2 = loops["stribeck"]
    p = m2.effects[-1].params
    fr = rec.meta["sim"]["params"]["friction"]
    truth = 0.4 * fr["coulomb_ratio"] * np.array(fr["static"])
    vs = np.array(p["vs"])
    assert np.all((vs > 0.015) & (vs < 0.027)), vs
    np.testing.assert_allclose(p["fs_minus_fc"], truth, rtol=0.25)


@pytest.mark.study
def test_attenuation_lag_values_match_the_plant(loops):
    """The pushes made while the joints slide show the compliant support's physics: 70 % of the
    push reaches the arm through a 0.15 s first-order lag; of a pure delay and a first-order lag
    the lag is chosen, with a time constant of 0.1-0.2 s and a gain of 0.6-0.8, on every joint
    named."""
    rec, _, _, m2 = loops["attenuation_lag"]
    p = m2.effects[-1].params
    assert all(0.6 < g < 0.8 for g in p["gain"]), p
    assert all(d == 0 for d in p["delay"]), p
    assert all(0.1 < lag / rec.sample_rate < 0.2 for lag in p["lag"]), p


@pytest.mark.parametrize("seed", [SEED, 4, 5])
def test_no_candidate_on_clean_recordings(clean, seed):
    """A clean recording (no hidden effect) gives no suggested candidate and a residual at the
    noise floor, over several seeds (the bands identified on each recording)."""
    rec, base, d = clean
    if seed != SEED:
        rec = _sim(seed=seed)
        d = diagnose([rec], _refit(base, rec))
    assert not d.suggested, d.summary()
    r, floor = np.array(d.residual["torque_rms"]), np.array(d.residual["noise_floor"])
    assert np.all(r <= 1.15 * floor), (r, floor)


def test_two_effects_larger_first_then_smaller(clean):
    """With a 2 kg payload and a 0.5 N·m motor ripple in the plant, the payload is suggested
    first, and after adding it the ripple."""
    _, base, _ = clean
    rec = _sim(["payload", "position_ripple:0.5"])
    m = _refit(base, rec)
    d = diagnose([rec], m)
    assert d.suggested[0].effect == "payload", d.summary()
    m2 = _add(m, rec, "payload")
    d2 = diagnose([rec], m2)
    assert d2.suggested and d2.suggested[0].effect == "position_ripple", d2.summary()


def test_excitation_scenario_visits_poses_and_pairs_dither(clean):
    """The excitation scenario pushes in every block's pose (the tool held there within 0.01 rad)
    and its plan (pushes, wrench) is the same with and without dither."""
    rec, _, _ = clean
    sim = rec.meta["sim"]
    poses = np.array(sim["poses"])
    pushes = [p for p in sim["pushes"] if not p["moving"]]
    assert len(pushes) == OPTS["blocks"] * OPTS["pushes_per_block"]
    for i, p in enumerate(pushes):
        k = int(np.searchsorted(rec.t, p["t0"]))
        pose = poses[i // OPTS["pushes_per_block"] % len(poses)]
        assert np.max(np.abs(rec.q[k] - pose)) < 0.01, (i, rec.q[k], pose)
    moving = [p for p in sim["pushes"] if p["moving"]]
    assert len(moving) == OPTS["blocks"] * 2  # moving_pushes = 2 per block
    for p in moving:  # every joint slides through the push
        m = (rec.t >= p["t0"]) & (rec.t < p["t0"] + p["duration"])
        assert np.all(np.abs(rec.dq[m]).min(axis=0) > 1e-3), p
    dith = simulate("excitation", seed=SEED, dither=True, **OPTS)
    assert dith.meta["sim"]["pushes"] == sim["pushes"]
    np.testing.assert_array_equal(dith.wrench, rec.wrench)
    assert dith.dither.any() and not rec.dither.any()

"""Tests of diagnosis: the hidden effect ranked first, the error falling after adding it, no false
discovery on clean data, two effects in turn, the CLI, the history and bad input.

Recordings come from the synthetic plant of ``test_effects.make_recording`` (moving IRB140,
hidden effects in forms that differ from the library's); models from ``identify``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_effects import make_recording

from ditherlab.analysis.diagnosis import diagnose, noise_floor_sq, residual_summary
from ditherlab.analysis.identification import identify
from ditherlab.app.identify import add_effect
from ditherlab.data.torque_model import EffectSpec, TorqueModel
from ditherlab.io import write
from ditherlab.physics.residual import scored

#: hidden effect -> joints (1-based) where the synthetic plant has it
HIDDEN = {
    "stribeck": [2, 3],
    "load_friction": [2, 3],
    "temperature_friction": [1, 2, 3],
    "position_ripple": [2],
    "payload": None,
    "attenuation_lag": None,
    "ft_bias": None,
    "inertia": None,
}


def _identify(rec):
    return identify([rec], n_boot=3)


#: the hidden effects checked by ``make test`` (one per joint set, one shared by all joints); the
#: others run in the study tier (``make study``)
CORE = ("stribeck", "payload")
NAMES = [pytest.param(n, marks=() if n in CORE else pytest.mark.study) for n in HIDDEN]


def _loop(name):
    """Recording, model, diagnosis, RMS after adding the top effect, for one hidden effect."""
    rec = make_recording((name,), seed=7, duration=8.0)
    m = _identify(rec)
    d = diagnose([rec], m)
    after = None
    if d.suggested:
        m2 = add_effect([rec], m, d.suggested[0].effect)
        after = residual_summary(m2, [scored(m2, rec)])
    return rec, m, d, after


class _Loops(dict):
    """Per hidden effect, computed on first use and kept for the module."""

    def __missing__(self, name):
        self[name] = out = _loop(name)
        return out


@pytest.fixture(scope="module")
def loops():
    return _Loops()


@pytest.mark.parametrize("name", NAMES)
def test_hidden_effect_ranked_first_on_right_joints(loops, name):
    """Diagnosis suggests the planted effect first, on the joints where it was planted."""
    _, _, d, _ = loops[name]
    assert d.suggested, d.summary()
    top = d.suggested[0]
    assert top.effect == name, d.summary()
    if HIDDEN[name] is not None:
        assert top.joints == HIDDEN[name]
    assert top.explained_fraction > 0.2


@pytest.mark.parametrize("name", NAMES)
def test_error_falls_to_noise_floor_after_adding(loops, name):
    """Adding the top effect cuts the worst joint's residual RMS by >= 30 % and brings it within
    25 % of the noise floor."""
    _, _, d, after = loops[name]
    r0 = np.array(d.residual["torque_rms"])
    floor = np.array(d.residual["noise_floor"])
    r1 = np.array(after["torque_rms"])
    j = int(np.argmax(r0 / floor))
    assert r1[j] <= 0.7 * r0[j], (r0, r1)
    assert np.all(r1 <= 1.25 * floor), (r1, floor)


def test_a_joint_far_below_its_floor_is_never_named(loops):
    """A per-joint effect is not named on a joint whose residual sits below half its noise
    floor, whatever the other joints do: the planted Stribeck friction, scored again with its
    first joint declared quiet, is named on the others only; with every joint quiet, nothing."""
    from ditherlab.analysis.scoring import candidates

    rec, m, d, _ = loops["stribeck"]
    joints = d.suggested[0].joints
    assert len(joints) >= 2, joints
    sc = [scored(m, rec)]
    (c,), _ = candidates(m, [rec], effects=["stribeck"], scored_recs=sc, quiet=joints[:1])
    assert c.suggested and c.joints == joints[1:], (c.joints, joints)
    (c,), _ = candidates(m, [rec], effects=["stribeck"], scored_recs=sc, quiet=range(1, 7))
    assert not c.suggested, c.joints


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_no_false_discovery_on_clean_data(seed):
    """A recording without hidden effects gives no suggested candidate and a residual at the floor."""
    rec = make_recording((), seed=seed, duration=8.0)
    d = diagnose([rec], _identify(rec))
    assert not d.suggested, d.summary()
    r = np.array(d.residual["torque_rms"])
    assert np.all(r <= 1.15 * np.array(d.residual["noise_floor"]))


def test_two_effects_larger_first_then_smaller():
    """With two effects planted, the larger is suggested first, and after adding it the smaller."""
    rec = make_recording(("load_friction", "position_ripple"), seed=8, duration=10.0)
    m = _identify(rec)
    d = diagnose([rec], m)
    assert d.suggested[0].effect == "load_friction", d.summary()
    m2 = add_effect([rec], m, "load_friction")
    d2 = diagnose([rec], m2)
    assert d2.suggested and d2.suggested[0].effect == "position_ripple", d2.summary()
    assert d2.suggested[0].joints == [2]


def test_noise_floor_formula():
    """The still-regime floor is sigma²/2 for a wide band, sigma² for a zero band, and matches a
    Monte Carlo of a friction at the band edge plus noise."""
    s = np.array([0.3])
    assert noise_floor_sq(s, np.array([100.0]), np.array([False]))[0] == pytest.approx(0.045)
    assert noise_floor_sq(s, np.array([0.0]), np.array([False]))[0] == pytest.approx(0.09)
    h = 0.2
    x = h + np.random.default_rng(0).normal(0, 0.3, 400_000)
    mc = np.mean(np.maximum(np.abs(x) - h, 0) ** 2)
    assert noise_floor_sq(s, np.array([h]), np.array([False]))[0] == pytest.approx(mc, rel=0.02)


def test_family_wise_level():
    """A joint's evidence needs its likelihood-ratio test to reject at 1 % over every effect of
    the library on every joint (Bonferroni), beside ΔBIC <= -10: with two parameters, ΔBIC
    -10.5 on 20 effective samples is a statistic of 16.5 (p 2.6e-4, 0.022 over 84 tests: not
    named); on 200 it is 21.1 (p 2.6e-5, 0.0022: named). The p-value is χ² with k degrees of
    freedom of the statistic the BIC holds."""
    from scipy.stats import chi2

    from ditherlab.analysis.scoring import FAMILY_LEVEL, Candidate, JointScore
    from ditherlab.physics.effects import FitResult

    fit = FitResult(np.zeros(2), None, None, 0.0)
    tests = 14 * 6

    def score(n_eff):
        return JointScore(0, 100.0, 60.0, 5, 5, -10.5, n_eff, fit, k=2, tests=tests)

    few, many = score(20.0), score(200.0)
    assert few.p_value == pytest.approx(chi2.sf(2 * np.log(20.0) + 10.5, 2))
    assert few.p_value * tests > FAMILY_LEVEL and not few.evidence(0.05)
    assert many.p_value * tests < FAMILY_LEVEL and many.evidence(0.05)
    row = Candidate("viscous", [1], 0.4, True, scores=[many]).to_dict()["per_joint"][0]
    assert row["p_value"] == pytest.approx(many.p_value, rel=1e-2)
    assert row["p_family"] == pytest.approx(many.p_value * tests, rel=1e-2)


def _windows_by_scanning(model, sc, width=1.0):
    """The obviously right worst windows: every window's samples found by comparing all times."""
    from ditherlab.analysis.diagnosis_sums import excess_and_floor, nanmean

    ex, fl = excess_and_floor(sc)
    t = sc.sig.t
    r = np.where(np.isfinite(ex), ex**2 / np.where(fl > 0, fl, 1.0), np.nan)
    out, k = [], 0
    while t[0] + k * width / 2 < t[-1]:
        start = t[0] + k * width / 2
        m = (t >= start) & (t < start + width)
        per = nanmean(r[m], axis=0)
        if m.sum() > 3 and np.isfinite(per).any():
            out.append((start, float(nanmean(per)), int(np.nanargmax(per)) + 1))
        k += 1
    return sorted(out, key=lambda w: -w[1])


def test_worst_windows_linear_equal_the_scan():
    """The windows found by one division per sample are those of scanning every window, on
    jittered time stamps (no sample on a window edge)."""
    from ditherlab.analysis.diagnosis import worst_windows
    from ditherlab.data.recording import Recording

    rec = make_recording(("stribeck",), seed=12, duration=8.0)
    data = rec.data.copy()
    data["t"] = data["t"] + 0.3 + np.random.default_rng(3).uniform(0, 1e-4, len(data))
    rec = Recording(data, rec.meta)
    m = _identify(rec)
    sc = scored(m, rec)
    got = worst_windows(m, [sc], count=99)
    ref = _windows_by_scanning(m, sc)
    assert len(got) == len(ref) == 16 and [g["t0"] for g in got] == pytest.approx(
        [w[0] for w in ref]
    )
    assert [g["energy"] for g in got] == pytest.approx([w[1] for w in ref], rel=1e-12)
    assert [g["worst_joint"] for g in got] == [w[2] for w in ref]


def test_solve_kernel_equals_the_numpy_reference():
    """The compiled band-aware least squares reaches the numpy iteration's optimum: with and
    without band widening, bands of zero width (moving samples) and none, 0 to 6 columns."""
    from ditherlab.physics.effect_fit import _solve, _solve_reference

    rng = np.random.default_rng(5)
    cases = 0
    for k in range(7):
        for widen in (False, True):
            M = int(rng.integers(50, 3000))
            C = rng.normal(size=(M, k))
            W = np.abs(rng.normal(size=(M, k))) * 0.1 if widen else np.zeros((M, k))
            w_true = rng.normal(size=k)
            h = np.where(rng.random(M) < 0.4, 0.0, rng.uniform(0, 2, M))
            s = rng.uniform(0.2, 1.0, M)
            o = rng.normal(size=M) * 0.1
            e = o + C @ w_true + rng.normal(size=M) * s + np.sign(rng.normal(size=M)) * h
            w1, L1 = _solve(e, h, s, C, W, o)
            w0, L0 = _solve_reference(e, h, s, C, W, o)
            assert L1 == pytest.approx(L0, rel=1e-10)
            assert w1 == pytest.approx(w0, rel=1e-6, abs=1e-9)
            if k:
                # and it is an optimum: no coordinate step lowers the loss
                for c in range(k):
                    for step in (1e-4, -1e-4):
                        d = np.zeros(k)
                        d[c] = step
                        x = e - o - C @ (w1 + d)
                        Ld = np.sum((np.maximum(np.abs(x) - h - W @ (w1 + d), 0) / s) ** 2)
                        assert Ld >= L1 * (1 - 1e-6)
            cases += 1
    assert cases == 14


def test_designs_at_scored_rows_equal_the_whole_recordings():
    """Diagnosis computes every candidate's design at its scored rows alone
    (``Signals.take``): for each effect of the library, the design there equals the whole
    recording's design at those rows. A time-filter effect not marked ``pointwise = False``
    fails this (its design at a row would be filtered over the thinned rows)."""
    from ditherlab.physics.effects import EFFECTS, design_at, signals

    rec = make_recording(("stribeck",), seed=4, duration=6.0, temp=True)
    sig = signals(rec)
    rows = np.arange(3, len(rec), 7)
    sub = sig.take(rows)
    assert sub.take(np.arange(0, len(rows), 2)).index.tolist() == rows[::2].tolist()
    for e in EFFECTS.values():
        j = None if e.shared else 1
        ref = e.reference([sig], j)
        grid = e.grid([sig], j)
        for h in grid[:: max(1, len(grid) // 3)]:
            whole = e.design(sig, j, h, ref).take(rows)
            part = design_at(e, sub, j, h, ref)
            for a, b in zip(
                (whole.centre, whole.widen, whole.offset),
                (part.centre, part.widen, part.offset),
                strict=True,
            ):
                assert (a is None) == (b is None), e.name
                if a is not None:
                    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12, err_msg=e.name)
    # without the sensor view too: the F/T columns stay hidden at the rows
    assert not sub.without_sensor().has_wrench and sub.without_sensor().rows is rows


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A recording with a hidden ripple and its identified model, on disk."""
    d = tmp_path_factory.mktemp("diag")
    rec = make_recording(("position_ripple",), seed=9, duration=8.0)
    rp = write(rec, d / "rec.parquet")
    mp = _identify(rec).save(d / "model.toml")
    return d, rp, mp, rec


def test_cli_json_report_and_history(files, cli):
    """The CLI prints the JSON contract (best first), writes report + figures and the model
    with its history row (``-o DIR/model.toml``; ``--model`` keeps its bytes), and the history
    gains one row per model version with the torque RMS falling."""
    d, rp, mp, rec = files
    given = mp.read_bytes()
    res = cli("diagnose", rp, "--model", mp, "--json", "-o", d / "report")
    assert res.code == 0, res.err
    out = json.loads(res.out)
    assert set(out) >= {"model", "residual", "candidates"}
    c0 = out["candidates"][0]
    assert c0["effect"] == "position_ripple" and c0["joints"] == [2] and c0["suggested"]
    fr = [c["explained_fraction"] for c in out["candidates"] if c["suggested"]]
    assert fr == sorted(fr, reverse=True)
    assert (d / "report" / "report.md").is_file()
    assert (d / "report" / f"evidence_{c0['effect']}.png").stat().st_size > 1000
    assert mp.read_bytes() == given
    m1 = TorqueModel.load(d / "report" / "model.toml")
    assert len(m1.history) == 1 and m1.history[0]["version"] == 1
    assert m1.history[0]["recordings"] == [str(rp)]
    m2 = add_effect([rec], m1, "position_ripple")
    mp2 = m2.save(d / "model2.toml")
    res = cli("diagnose", rp, "--model", mp2, "-o", d / "report2")
    assert res.code == 0, res.err
    hist = TorqueModel.load(d / "report2" / "model.toml").history
    assert [h["version"] for h in hist] == [1, 2]
    assert hist[1]["torque_rms"][1] < 0.7 * hist[0]["torque_rms"][1]
    assert "| 2 | position_ripple |" in (d / "report2" / "report.md").read_text()


def test_cli_bad_input(files, cli, tmp_path):
    """Unknown effect, a missing column and a model without the recording's regime: one line,
    exit 2."""
    d, rp, mp, rec = files
    m = TorqueModel.load(mp)
    m.effects = [EffectSpec("friction", [1], {})]
    bad = m.save(tmp_path / "bad.toml")
    res = cli("diagnose", rp, "--model", bad, "--no-history", "--quiet")
    assert res.code == 2 and res.err.strip().count("\n") == 0
    assert "unknown effect 'friction', expected one of: viscous, stribeck" in res.err
    nof = write(make_recording((), seed=1, duration=4.0, wrench=False), tmp_path / "nof.parquet")
    m.effects = []
    m2 = add_effect([rec], m, "ft_bias", refit=False)
    p2 = m2.save(tmp_path / "bias.toml")
    res = cli("diagnose", nof, "--model", p2, "--no-history", "--quiet")
    assert res.code == 2 and "needs the F/T sensor column f_x" in res.err
    m3 = TorqueModel.load(mp)
    del m3.regimes["moving"]
    p3 = m3.save(tmp_path / "nomoving.toml")
    res = cli("diagnose", rp, "--model", p3, "--no-history", "--quiet")
    assert res.code == 2
    assert "moving samples but the model has no [regimes.moving]" in res.err


def test_ur10e_free_motion_lacks_inertia(shared_data):
    """On the real UR10e free-motion log, a gravity + Coulomb/viscous model lacks the dynamic
    torque: diagnosis suggests ``inertia`` first (on joints 1 and 2 at least), and adding it cuts
    their residual by more than 40 %."""
    from ditherlab.core.names import MOVING
    from ditherlab.data.recording import regimes
    from ditherlab.data.torque_model import Band
    from ditherlab.io import read
    from ditherlab.physics.band_fit import fit_sliding

    rec = read(shared_data / "ur10e" / "no_torque.csv", mapping="ur10e")
    reg = regimes(rec)
    rho = rec.tau - rec.robot().gravity(rec.q)
    cols = {k: np.zeros(rec.n) for k in ("a", "b", "s", "c", "v")}
    for j in range(rec.n):
        mv = reg[:, j] == MOVING
        c, v, fit, *_ = fit_sliding(rho[mv, j], rec.dq[mv, j], n_boot=0)
        for k, x in zip(("a", "b", "s", "c", "v"), (fit.a, fit.b, fit.sigma, c, v), strict=True):
            cols[k][j] = x
    band = Band(cols["a"], cols["b"], cols["s"], coulomb=cols["c"], viscous=cols["v"])
    m = TorqueModel(rec.meta["robot"], rec.n, regimes={"moving": band})
    d = diagnose([rec], m)
    top = d.suggested[0]
    assert top.effect == "inertia" and {1, 2} <= set(top.joints), d.summary()
    assert top.explained_fraction > 0.5
    m2 = add_effect([rec], m, "inertia", joints=top.joints)
    r0 = np.array(d.residual["torque_rms"])
    r1 = np.array(residual_summary(m2, [scored(m2, rec)])["torque_rms"])
    assert np.all(r1[:2] < 0.6 * r0[:2]), (r0, r1)


# ---------------------------------------------------------------- the built-in simulator
SIM_REGIMES = ("still", "dither")


@pytest.fixture(scope="module")
def sim_runs():
    """Short push campaigns of the built-in simulator, clean and with hidden attenuation_lag."""
    from ditherlab.sim import simulate

    out = {}
    for hidden in ((), (("attenuation_lag", 0.3),)):
        rec = simulate("push-campaign", seed=3, hidden=list(hidden), pushes_per_direction=2)
        m = identify([rec], n_boot=3)
        out[hidden[0][0] if hidden else "clean"] = (rec, m, diagnose([rec], m, regimes=SIM_REGIMES))
    return out


def test_sim_clean_campaign_no_candidate(sim_runs):
    """A simulated push campaign without hidden effects gives no suggested candidate but
    ``dither_extraction``: the campaign pushes with the dither on, and how the extraction shows
    those pushes (late and in part) is physics of every dithered push campaign that the base
    model lacks (tests/test_calibration.py: never on a log without dither or without pushes)."""
    _, _, d = sim_runs["clean"]
    assert all(c.effect == "dither_extraction" for c in d.suggested), d.summary()


def test_sim_attenuation_lag_found_with_its_physics(sim_runs):
    """With the simulator's compliant support (70 % of the push reaches the arm through a 0.15 s
    lag), attenuation_lag is suggested; its gain and delay match the plant, and adding it
    lowers the residual of its joints."""
    rec, m, d = sim_runs["attenuation_lag"]
    # every push of this campaign is made with the dither on, where dither_extraction (the
    # extraction's own lag) explains much of the same residual and may rank first
    found = [c for c in d.suggested if c.effect == "attenuation_lag"]
    assert found, d.summary()
    c = found[0]
    m2 = add_effect([rec], m, c.effect, joints=c.joints, refit=False)
    p = m2.effects[-1].params
    assert all(0.5 < g < 0.85 for g in p["gain"]), p
    late = np.array(p["delay"]) + np.array(p["lag"])  # samples
    # the support's 0.15 s lag plus the dither extraction's own (about 0.1 s to half a step)
    assert np.all((0.08 < late / rec.sample_rate) & (late / rec.sample_rate < 0.35)), p
    js = [j - 1 for j in c.joints]
    r0 = np.array(d.residual["torque_rms"])[js]
    d2 = diagnose([rec], m2, regimes=SIM_REGIMES, effects=[])
    r1 = np.array(d2.residual["torque_rms"])[js]
    # >= 10 % of the squared residual: on seed 3 joint 3's held-out gain (81 %) does not beat
    # twice its best surrogate (64 %: a shift that lays one push on another of the same axis),
    # so joint 5 alone is suggested and falls by 12.5 %
    assert np.all(r1 < r0) and np.sum(r1**2) < 0.9 * np.sum(r0**2), (r0, r1)


def test_sim_fixed_pose_payload_not_identifiable(sim_runs):
    """In a push campaign's single pose a payload is a constant gravity torque the bands absorb:
    add_effect refuses it with one sentence instead of storing arbitrary parameters."""
    from ditherlab.core.errors import ModelError

    rec, m, _ = sim_runs["clean"]
    with pytest.raises(ModelError, match="'payload' cannot be told apart from the bands"):
        add_effect([rec], m, "payload", refit=False)

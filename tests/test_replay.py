"""Tests of ditherlab.analysis.estimation: the four estimator variants and the estimates file."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from synthetic import BAND_HI, BAND_LO, SIGMA, push_recording

from ditherlab.analysis.estimation import available_variants, replay
from ditherlab.analysis.identification import identify
from ditherlab.core.errors import ConfigError, ModelError
from ditherlab.core.timeseries import runs
from ditherlab.data.estimates import COMPONENTS, SCHEMA, Estimates
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.estimator import estimate
from ditherlab.physics.dither import dither_period, extract_dither, meta_dither_period

MAGS = (5.0, 15.0, 30.0, 50.0)


@pytest.fixture(scope="module")
def recs():
    plain, _ = push_recording(2, magnitudes=MAGS)
    dith, truth = push_recording(2, dither=True, magnitudes=MAGS)
    return plain, dith, truth


@pytest.fixture(scope="module")
def model(recs):
    plain, dith, _ = recs
    return identify([plain, dith], n_boot=0)


@pytest.fixture(scope="module")
def estimates(recs, model):
    plain, dith, _ = recs
    return replay(plain, model), replay(dith, model)


def test_variants_follow_the_recording(recs, estimates):
    """Dither variants appear only for a recording with a dither flag or tau_ffw."""
    plain, dith, _ = recs
    assert available_variants(plain) == ["nodither_band", "nodither_noband"]
    assert estimates[0].variants == ["nodither_band", "nodither_noband"]
    assert estimates[1].variants == [
        "nodither_band",
        "nodither_noband",
        "dither_band",
        "dither_noband",
    ]
    with pytest.raises(ConfigError, match="needs a dither column or tau_ffw"):
        replay(plain, identify([plain], n_boot=0), variants=["dither_band"])


def test_columns_and_metadata_follow_the_format(estimates, recs):
    """The estimates table has the brief's columns and metadata keys."""
    est = estimates[1]
    cols = list(est.data.columns)
    assert cols[:7] == ["t", *COMPONENTS] and "dither" in cols
    for v in est.variants:
        for c in COMPONENTS:
            assert {f"{v}/{c}", f"{v}/{c}_lo", f"{v}/{c}_hi"} <= set(cols)
        assert est.data[f"{v}/active"].dtype == np.int64
    for j in range(1, 7):
        assert {f"extract/upper_{j}", f"extract/lower_{j}", f"extract/signal_{j}"} <= set(cols)
    m = est.meta
    assert m["schema"] == SCHEMA and m["recording"]["robot"] == "irb140"
    assert m["interval"] == {"method": "profile", "level": 0.95}
    assert m["components"] == list(COMPONENTS) and m["model"]["schema"] == "ditherlab.model/1"
    assert "extract/upper_1" not in estimates[0].data.columns


def test_nodither_band_equals_direct_estimator_call(recs, model, estimates):
    """nodither_band is eq. (3) on tau - gravity with the still band (no hidden processing)."""
    plain = recs[0]
    r = plain.robot()
    b = model.regimes["still"]
    sol = estimate(
        plain.tau - r.gravity(plain.q),
        r.jacobian(plain.q),
        b.tau_min,
        b.tau_max,
        b.sigma,
        model.prior_mean,
        model.prior_sigma,
    )
    np.testing.assert_array_equal(estimates[0].F("nodither_band"), sol.F)
    bits = (sol.active.astype(np.int64) * (1 << np.arange(6))).sum(axis=1)
    np.testing.assert_array_equal(estimates[0].data["nodither_band/active"].to_numpy(), bits)
    np.testing.assert_array_equal(estimates[0].active("nodither_band"), sol.active)


def test_noband_moves_band_variance_into_noise(recs, model):
    """Without the uniform term the band is its centre and sigma^2 gains (b - a)^2 / 12."""
    plain = recs[0]
    r = plain.robot()
    b = model.regimes["still"]
    c = 0.5 * (b.tau_min + b.tau_max)
    s = np.sqrt(b.sigma**2 + (b.tau_max - b.tau_min) ** 2 / 12)
    sol = estimate(
        plain.tau - r.gravity(plain.q),
        r.jacobian(plain.q),
        c,
        c,
        s,
        model.prior_mean,
        model.prior_sigma,
    )
    est = replay(plain, model, variants=["nodither_noband"])
    np.testing.assert_allclose(est.F("nodither_noband"), sol.F, atol=1e-9)


def test_dither_detects_smaller_pushes_than_no_dither(recs, estimates):
    """On the synthetic pair the dither variant follows a 15 N push the plain one misses."""
    plain, dith, truth = recs
    for est, variant, expect in (
        (estimates[0], "nodither_band", False),
        (estimates[1], "dither_band", True),
    ):
        F = est.wrench
        Fh = est.F(variant)
        hits = []
        for t0, ax, _sg, mag in truth["pushes"]:
            if mag != 15.0:
                continue
            k = "xyz".index(ax)
            m = (est.t >= t0) & (est.t <= t0 + 1.5)
            hits.append(np.max(np.sign(F[m, k]).mean() * Fh[m, k]) > 3.0)
        assert np.mean(hits) > 0.5 if expect else np.mean(hits) < 0.5


def test_intervals_cover_the_sensor_with_the_true_model(recs):
    """With the true bands, the 95 % intervals of the band variants hold the F/T force in more
    than 93 % of the samples (with dither: against the raw sensor, despite the extraction lag)."""
    plain, dith, truth = recs
    lo, hi, _ = truth["dither"]
    true = TorqueModel(
        robot="irb140",
        n=6,
        regimes={
            "still": Band(BAND_LO, BAND_HI, SIGMA),
            "dither": Band(lo, hi, SIGMA / np.sqrt(20)),  # one-period mean of 20 samples
        },
    )
    for rec, variant in ((plain, "nodither_band"), (dith, "dither_band")):
        est = replay(rec, true, variants=[variant])
        ilo, ihi = est.interval(variant)
        F = est.wrench
        cov = ((ilo[:, :3] <= F[:, :3] + 1e-9) & (F[:, :3] <= ihi[:, :3] + 1e-9)).mean()
        assert cov > 0.93, (variant, cov)


def test_dither_period_from_feedforward(recs):
    """The dither period is found from tau_ffw (synthetic square wave of 0.08 s)."""
    dith, truth = recs[1], recs[2]
    assert dither_period(dith) == pytest.approx(truth["period"], rel=0.01)
    ext = extract_dither(dith)
    assert ext is not None and not ext.valid[:5].any() and ext.valid[-1]


def test_meta_dither_period_reads_period_or_omega():
    """The stated period is dither.period [s] or 2 pi / dither.omega, also under sim; else None."""
    assert meta_dither_period({"dither": {"period": 0.05}}) == 0.05
    assert meta_dither_period({"sim": {"dither": {"omega": 80.0}}}) == pytest.approx(2 * np.pi / 80)
    assert meta_dither_period({"dither": {}, "sim": None}) is None


def test_runs_against_a_loop():
    """runs gives [start, end) of every run of True, a run at either end included."""
    rng = np.random.default_rng(5)
    for mask in (rng.random(200) > 0.6, np.ones(7, bool), np.zeros(7, bool), np.array([], bool)):
        ref, k = [], 0
        while k < len(mask):
            if mask[k]:
                e = k
                while e < len(mask) and mask[e]:
                    e += 1
                ref.append((k, e))
                k = e
            else:
                k += 1
        starts, ends = runs(mask)
        assert list(zip(starts.tolist(), ends.tolist(), strict=True)) == ref


def test_save_load_round_trip(tmp_path, estimates):
    """Estimates saved to Parquet load back identical, with the metadata as JSON."""
    est = estimates[1]
    p = est.save(tmp_path / "e.parquet")
    back = Estimates.load(p)
    assert back.meta == est.meta
    assert back.data.equals(est.data)
    kv = pq.read_schema(p).metadata
    assert json.loads(kv[b"ditherlab"])["schema"] == SCHEMA


def test_replay_is_deterministic(recs, model, estimates):
    """Replaying the same recording with the same model gives identical numbers."""
    again = replay(recs[0], model)
    assert again.data.equals(estimates[0].data)


def test_set_membership_and_components(recs, model):
    """Set-membership intervals contain the estimate; held components sit at the prior."""
    est = replay(
        recs[0].slice(0, 20.0), model, interval="set_membership", components="fxyz", level=0.9
    )
    assert est.meta["interval"] == {"method": "set_membership", "level": 0.9}
    F = est.F("nodither_band")
    lo, hi = est.interval("nodither_band")
    ok = np.isfinite(lo[:, :3]) & np.isfinite(hi[:, :3])
    assert np.all((lo[:, :3] <= F[:, :3] + 1e-6)[ok]) and np.all((F[:, :3] <= hi[:, :3] + 1e-6)[ok])
    np.testing.assert_array_equal(F[:, 3:], 0.0)


def test_robot_mismatch_is_a_model_error(recs, model):
    """A model for another robot (joint count) stops replay with one sentence."""
    other = TorqueModel(robot="ur10e", n=6, regimes=model.regimes)
    with pytest.raises(ModelError, match="the recording's robot is irb140 with 6 joints"):
        replay(recs[0], other)


def test_cli_replay_and_bad_inputs(tmp_path, cli, recs, model):
    """`ditherlab replay` writes estimates; a bad model or a robot mismatch: exit 2, no file."""
    from ditherlab.io import write

    src = write(recs[0].slice(0, 15.0), tmp_path / "rec.parquet")
    mp = model.save(tmp_path / "model.toml")
    out = tmp_path / "est.parquet"
    r = cli("replay", src, "--model", mp, "-o", out, "-q")
    assert r.code == 0, r.err
    assert Estimates.load(out).variants == ["nodither_band", "nodither_noband"]

    text = mp.read_text()
    bad = tmp_path / "inverted.toml"
    m2 = model.copy()
    st = m2.regimes["still"]
    m2.regimes["still"] = Band(st.tau_max, st.tau_min, st.sigma)  # no validation on assignment
    bad.write_text(m2.dumps())
    noisy = tmp_path / "noise.toml"
    m3 = model.copy()
    m3.regimes["still"].sigma[2] = 0.0
    noisy.write_text(m3.dumps())
    other = tmp_path / "other.toml"
    other.write_text(text.replace('robot = "irb140"', 'robot = "ur10e"'))
    for path, msg in (
        (bad, "band of joint 1 is inverted"),
        (noisy, "sigma of joint 3 is 0 N·m, expected a positive noise level"),
        (other, "the recording's robot is irb140"),
    ):
        out2 = tmp_path / f"out_{path.stem}.parquet"
        r = cli("replay", src, "--model", path, "-o", out2, "-q")
        assert r.code == 2, (path, r.err)
        assert r.err.count("\n") == 1 and msg in r.err, r.err
        assert not out2.exists()


def test_closed_form_noband_intervals_match_general_profile(recs, model):
    """The closed-form intervals of the no-band variants equal the estimator's general profile
    search to 1e-6 N, for all six components and for a subset."""
    from ditherlab.analysis.estimation import band_as_noise
    from ditherlab.estimator import gaussian_profile_intervals, intervals, problem

    dith = recs[1].slice(0, 30.0)
    r = dith.robot()
    tb = dith.tau - r.gravity(dith.q)
    J = r.jacobian(dith.q)
    b = model.regimes["still"]
    N = len(dith)
    a_, b_, s_ = band_as_noise(
        *(np.broadcast_to(x, (N, 6)) for x in (b.tau_min, b.tau_max, b.sigma))
    )
    for comps in (None, ["f_x", "f_z"]):
        args = (tb, J, a_, b_, s_, model.prior_mean, model.prior_sigma)
        sol = estimate(*args, components=comps)
        prob = problem(*args, components=comps)
        fast = gaussian_profile_intervals(prob, sol.F, level=0.9)
        ref = intervals(prob, F_hat=sol.F, method="profile", level=0.9)
        np.testing.assert_allclose(fast[0], ref[0], atol=1e-6)
        np.testing.assert_allclose(fast[1], ref[1], atol=1e-6)


def test_fast_interval_kernels_match_their_references_on_replay_data(recs, model):
    """On a replayed dithered recording (every variant's inputs), the fast profile kernel and the
    set-membership LPs give their references' bounds (profile: the per-segment refactorisation,
    1e-9; set membership: linprog on a subset, 1e-7)."""
    from ditherlab.analysis.estimation import model_effects, model_seen, variant_inputs
    from ditherlab.data.recording import regimes
    from ditherlab.estimator import estimate, problem, set_membership_reference
    from ditherlab.estimator.interval_methods.profile import _run_profile, profile_reference
    from ditherlab.estimator.interval_methods.set_membership import _set_membership
    from ditherlab.physics.effects import force_gain

    dith = recs[1].slice(0, 60.0)
    r = dith.robot()
    g = r.gravity(dith.q)
    J = r.jacobian(dith.q) * force_gain(model)[None, None, :]
    eff = model_effects(model, dith)
    reg = regimes(dith)
    base = (dith.tau - g - eff, *model.sample_bands(reg, dith.dq))
    ext = extract_dither(dith)
    seen = model_seen(g + eff, max(int(round(ext.period * dith.sample_rate)), 1))
    for v in ("nodither_band", "dither_band", "dither_noband"):
        tb, a, b, s = variant_inputs(v, base, model, reg, seen, ext)
        prob = problem(tb, J, a, b, s, model.prior_mean, model.prior_sigma)
        Fm = estimate(tb, J, a, b, s, model.prior_mean, model.prior_sigma).F[:, prob.free]
        lo, hi, _ = _run_profile(prob, Fm, 0.95)
        rlo, rhi = profile_reference(prob, Fm)
        for got, ref in ((lo, rlo), (hi, rhi)):
            assert np.isfinite(got).all() and np.isfinite(ref).all()
            np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
        slo, shi, _ = _set_membership(prob, 0.95)
        rows = np.arange(0, prob.N, prob.N // 40)
        sub = problem(tb[rows], J[rows], a[rows], b[rows], s[rows], model.prior_mean,
                      model.prior_sigma)  # fmt: skip
        rlo, rhi = set_membership_reference(sub)
        np.testing.assert_allclose(slo[rows], rlo, rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(shi[rows], rhi, rtol=1e-7, atol=1e-7)

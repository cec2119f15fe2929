"""Tests of ditherlab.analysis.identification: the band-plus-noise maximum likelihood and the identify command."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate
from synthetic import moving_recording, push_recording

from ditherlab.analysis.identification import friction_residual, identify
from ditherlab.core.errors import RecordingError
from ditherlab.core.timeseries import causal_mean
from ditherlab.data.torque_model import PAPER_PRIOR_SIGMA, TorqueModel
from ditherlab.physics.band_fit import (
    _nll_mix,
    band_noise_logpdf,
    fit_band,
    fit_sliding,
    sigma_from_differences,
)


@pytest.fixture(scope="module")
def campaign():
    rec, truth = push_recording(0)
    return rec, truth


@pytest.fixture(scope="module")
def dither_campaign():
    return push_recording(1, dither=True, magnitudes=(5.0, 10.0, 20.0, 40.0))


def test_density_integrates_to_one():
    """The uniform-convolved-with-Gaussian density integrates to 1, also in the Gaussian limit."""
    for a, b, s in ((-2.0, 3.0, 0.3), (0.0, 1e-12, 0.5), (-1.0, 1.0, 5.0)):
        val, _ = integrate.quad(
            lambda x, a=a, b=b, s=s: np.exp(band_noise_logpdf(np.array([x]), a, b, s))[0],
            -60,
            60,
            points=[a, b],
            limit=200,
        )
        assert val == pytest.approx(1.0, abs=1e-7)


def test_mixture_gradient_matches_finite_differences():
    """The analytic gradient of the edge-atom likelihood equals central finite differences."""
    rng = np.random.default_rng(0)
    x = np.linspace(-3, 4, 200)
    w = rng.uniform(0, 1, 200)
    th = np.array([0.3, 2.0, np.log(0.4), -1.0, 0.5, -0.7, 1.2])
    _, g = _nll_mix(th, x, w)
    num = np.array(
        [(_nll_mix(th + e, x, w)[0] - _nll_mix(th - e, x, w)[0]) / 2e-6 for e in np.eye(7) * 1e-6]
    )
    np.testing.assert_allclose(g, num, rtol=1e-5, atol=1e-8)


def test_fit_band_recovers_iid_truth_jointly():
    """Joint ML (sigma="ml", no atoms) recovers a, b, sigma of iid draws within 4 standard errors."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-5, 4, 40000) + rng.normal(0, 0.4, 40000)
    fit = fit_band(x, sigma="ml", edges=False, n_boot=30, seed=1)
    for est, se, true in (
        (fit.a, fit.se_a, -5),
        (fit.b, fit.se_b, 4),
        (fit.sigma, fit.se_sigma, 0.4),
    ):
        assert se > 0
        assert abs(est - true) < 4 * se + 1e-3


def test_fit_band_piecewise_constant_friction():
    """Friction held in blocks plus white noise: the default fit recovers edges and noise."""
    rng = np.random.default_rng(5)
    held = np.repeat(rng.uniform(-3.0, 2.0, 400), 125)
    x = held + rng.normal(0, 0.1, held.size)
    fit = fit_band(x, n_boot=30, seed=2, blocks=np.arange(x.size) // 1000)
    assert fit.sigma == pytest.approx(0.1, rel=0.03)
    assert abs(fit.a + 3.0) < 4 * fit.se_a + 0.02
    assert abs(fit.b - 2.0) < 4 * fit.se_b + 0.02


def test_fit_band_is_deterministic():
    """The same data and seed give identical fits and standard errors."""
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, 5000) + rng.normal(0, 0.1, 5000)
    assert fit_band(x, n_boot=10, seed=4) == fit_band(x, n_boot=10, seed=4)


def test_sigma_from_differences_lag():
    """Lagged differences recover the noise of a running mean when the lag is its window."""
    rng = np.random.default_rng(2)
    e = rng.normal(0, 1.0, 100000)
    m = causal_mean(e[:, None], 20)[:, 0]
    assert sigma_from_differences(e) == pytest.approx(1.0, rel=0.02)
    assert sigma_from_differences(m[20:], lag=20) == pytest.approx(1 / np.sqrt(20), rel=0.03)


def test_identify_still_band_against_truth(campaign):
    """On a synthetic push campaign the still bands of the pushed joints match the truth."""
    rec, truth = campaign
    model = identify([rec], n_boot=20, seed=0)
    lo, hi, sig = truth["still"]
    b = model.regimes["still"]
    for j in range(3):  # joints 1-3 are swept across their whole band by the pushes
        assert abs(b.tau_min[j] - lo[j]) < 4 * b.stderr["tau_min"][j] + 0.02 * (hi[j] - lo[j])
        assert abs(b.tau_max[j] - hi[j]) < 4 * b.stderr["tau_max"][j] + 0.02 * (hi[j] - lo[j])
    np.testing.assert_allclose(b.sigma, sig, rtol=0.05)
    assert list(model.prior_sigma) == list(PAPER_PRIOR_SIGMA)
    assert model.robot == "irb140" and model.n == 6


def test_identify_dither_band_is_shrunk_band(dither_campaign):
    """The dither regime, fitted on the extracted signal, is the band shrunk by the amplitude."""
    rec, truth = dither_campaign
    model = identify([rec], n_boot=10, seed=0, dither_band="ml")
    lo, hi, _ = truth["dither"]
    b = model.regimes["dither"]
    for j in range(3):
        assert b.tau_min[j] == pytest.approx(lo[j], abs=0.05)
        assert b.tau_max[j] == pytest.approx(hi[j], abs=0.05)


def test_identify_dither_band_shrunk_rule(dither_campaign, campaign):
    """By default the dither band is the still band shrunk by the measured amplitude (Fig. 4)."""
    rec, truth = dither_campaign
    model = identify([campaign[0], rec], n_boot=0)
    st, d = model.regimes["still"], model.regimes["dither"]
    A = truth["amplitude"]
    np.testing.assert_allclose(d.tau_min[:3], st.tau_min[:3] + A[:3], atol=0.05)
    np.testing.assert_allclose(d.tau_max[:3], st.tau_max[:3] - A[:3], atol=0.05)
    assert "shrunk by the measured dither amplitude" in model.notes


def test_identify_moving_coulomb_viscous():
    """Moving segments give Coulomb and viscous friction and the band around them."""
    rec, truth = moving_recording(0)
    model = identify([rec], n_boot=10, max_accel=np.inf)  # the synthetic joints have no inertia
    b = model.regimes["moving"]
    np.testing.assert_allclose(b.coulomb, truth["coulomb"], rtol=0.05)
    err = np.abs(b.viscous - truth["viscous"])
    assert np.all(err < 4 * b.stderr["viscous"] + 0.05 * truth["viscous"])
    np.testing.assert_allclose(b.sigma, truth["sigma"], rtol=0.05)


def test_identify_model_round_trips(tmp_path, campaign):
    """The identified model saves to TOML and loads back with the same bands and errors."""
    rec, _ = campaign
    model = identify([rec], n_boot=5)
    p = model.save(tmp_path / "m.toml")
    back = TorqueModel.load(p)
    for name, band in model.regimes.items():
        np.testing.assert_allclose(back.regimes[name].tau_min, band.tau_min)
        np.testing.assert_allclose(back.regimes[name].stderr["tau_max"], band.stderr["tau_max"])


def test_identify_without_sensor_names_the_way_out(campaign):
    """Without F/T columns identify stops with one sentence naming --assume-no-force."""
    rec, _ = campaign
    bare = rec.with_data(rec.data.drop(columns=["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]))
    with pytest.raises(RecordingError, match="identify needs a reference F/T sensor"):
        identify([bare])
    m = identify([bare.slice(0.0, 1.9)], assume_no_force=True, n_boot=0)
    assert "still" in m.regimes
    np.testing.assert_allclose(
        friction_residual(bare, assume_no_force=True), bare.tau - bare.robot().gravity(bare.q)
    )


def test_cli_identify_writes_model(tmp_path, cli, campaign):
    """`ditherlab identify` writes a loadable model and prints the bands."""
    from ditherlab.io import write

    rec, _ = campaign
    src = write(rec, tmp_path / "push.parquet")
    out = tmp_path / "model.toml"
    r = cli("identify", src, "-o", out, "--bootstrap", "5", "-q")
    assert r.code == 0, r.err
    assert TorqueModel.load(out).regimes["still"].n == 6
    assert "still" in r.out


def test_cli_identify_without_sensor_exit_2(tmp_path, cli, campaign):
    """identify on a recording without F/T columns: one line, exit 2, nothing written."""
    from ditherlab.io import write

    rec, _ = campaign
    bare = rec.with_data(rec.data.drop(columns=["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]))
    src = write(bare, tmp_path / "bare.parquet")
    out = tmp_path / "model.toml"
    r = cli("identify", src, "-o", out, "-q")
    assert r.code == 2
    assert r.err.count("\n") == 1 and "identify needs a reference F/T sensor" in r.err
    assert not out.exists()


@pytest.fixture(scope="module")
def sim_pair():
    from ditherlab.sim import simulate

    return [
        simulate("push-campaign", seed=3, dither=d, pushes_per_direction=6) for d in (False, True)
    ]


def test_identify_against_simulator_truth(sim_pair):
    """On the simulator's paired campaigns the still band of the pushed joints lies between the
    true sliding (Coulomb) and static friction, the noise matches, and the dither band is the
    still band shrunk by about the simulator's dither amplitude set-point."""
    model = identify(sim_pair, n_boot=5)
    truth = sim_pair[0].meta["sim"]
    fs = np.array(truth["bands"]["static"])
    fc = np.array(truth["bands"]["coulomb"])
    st = model.regimes["still"]
    for j in range(3):  # joints 1-3 carry the x, y, z pushes in the paper's pose
        assert -fs[j] - 0.3 <= st.tau_min[j] <= -fc[j] + 0.3
        assert fc[j] - 0.3 <= st.tau_max[j] <= fs[j] + 0.3
    frac = truth["params"]["noise"]["tau_sigma_fraction"]
    np.testing.assert_allclose(st.sigma[:3], frac * fs[:3], rtol=0.2)
    d = model.regimes["dither"]
    amp = np.array(truth["params"]["dither"]["amplitude_fraction"]) * fs
    width = (st.tau_max - st.tau_min) - (d.tau_max - d.tau_min)
    np.testing.assert_allclose(
        width[:3], np.minimum(2 * amp[:3], st.tau_max[:3] - st.tau_min[:3]), atol=0.15 * fs[0]
    )


def test_cli_identify_add_effect(tmp_path, cli):
    """`identify --model base --add payload` keeps the base prior and adds the effect (v + 1)."""
    from ditherlab.io import write

    rec, _ = moving_recording(1, duration=30.0)
    src = write(rec, tmp_path / "moving.parquet")
    base = identify([rec], n_boot=0, max_accel=np.inf)
    base.prior_sigma = np.array([15.0, 15.0, 15.0, 0.2, 0.2, 0.2])
    bp = base.save(tmp_path / "base.toml")
    out = tmp_path / "model.toml"
    r = cli("identify", src, "--model", bp, "--add", "payload", "-o", out, "--bootstrap", "0", "-q")
    assert r.code == 0, r.err
    m = TorqueModel.load(out)
    assert m.effect_names() == ["payload"] and m.version == 2
    np.testing.assert_allclose(m.prior_sigma, base.prior_sigma)


def test_fit_sliding_band_leaves_out_the_transients():
    """The moving band is fitted on the rows given (not the break-away outliers), the sliding
    friction on all rows: planted Coulomb 5, viscous 2, band [-0.3, 0.3] (an offset constant
    over 200 samples), noise 0.05, and 0.5 %
    of samples off by up to +-10 N·m (break-away transients)."""
    rng = np.random.default_rng(0)
    M = 20000
    dq = rng.choice([-1, 1], M) * rng.uniform(0.05, 0.5, M)
    u = np.repeat(rng.uniform(-0.3, 0.3, M // 200), 200)  # slowly varying, as friction is
    x = 5 * np.sign(dq) + 2 * dq + u + rng.normal(0, 0.05, M)
    bad = rng.random(M) < 0.005
    x[bad] += rng.uniform(-10, 10, bad.sum())
    fc, fv, fit, _, _ = fit_sliding(x, dq, n_boot=0, band_rows=~bad)
    assert abs(fc - 5) < 0.05 and abs(fv - 2) < 0.2, (fc, fv)
    assert -0.4 < fit.a < -0.2 and 0.2 < fit.b < 0.4, (fit.a, fit.b)
    _, _, wide, _, _ = fit_sliding(x, dq, n_boot=0)
    assert wide.b - wide.a > 2 * (fit.b - fit.a), (wide.a, wide.b)


def test_block_members_equal_a_scan_per_block():
    """The bootstrap's blocks found by one stable sort are those of scanning every block."""
    from ditherlab.physics.band_fit import block_members

    inv = np.random.default_rng(4).integers(0, 37, 5000)
    inv[inv == 5] = 6  # a label with no sample
    got = block_members(inv, 37)
    assert len(got) == 37
    for k in range(37):
        np.testing.assert_array_equal(got[k], np.flatnonzero(inv == k))


@pytest.mark.parametrize("lag", [1, 3, 20])
def test_replicate_sigma_by_weights_equals_the_built_replicate(lag):
    """The bootstrap's noise level from the blocks' own differences counted with weights
    (BlockDifferences) equals sigma_from_differences of the replicate built as before (the
    drawn blocks concatenated, each copy its own block) exactly: even and odd counts, ties
    (a quantised residual), blocks shorter than the lag, blocks never drawn, and the
    fallbacks (no differences, a MAD of 0) left to the built replicate."""
    from ditherlab.physics.band_fit import BlockDifferences, block_members

    rng = np.random.default_rng(lag)
    for case in range(40):
        n = int(rng.integers(5, 3000))
        x = rng.normal(0, 1, n) + np.repeat(rng.normal(0, 3, n // 50 + 1), 50)[:n]
        if case % 4 == 1:
            x = np.round(x * 4) / 4  # many equal values
        if case % 4 == 2:
            x[: n // 2] = 0.5  # a MAD that may be 0
        labels = np.sort(rng.integers(0, int(rng.integers(1, 60)), n))
        inv = np.unique(labels, return_inverse=True)[1]
        nb = int(inv.max()) + 1
        members = block_members(inv, nb)
        diffs = BlockDifferences(x, lag, members)
        for _ in range(5):
            pick = rng.integers(0, nb, nb)
            mult = np.bincount(pick, minlength=nb).astype(float)
            xs = np.concatenate([x[members[k]] for k in pick])
            bl = np.concatenate([np.full(len(members[k]), i) for i, k in enumerate(pick)])
            want = sigma_from_differences(xs, lag, bl)
            got = diffs.sigma(mult)
            if got is None:  # a fallback: sigma_from_differences does not use the MAD
                d = xs[lag:] - xs[:-lag]
                d = d[bl[lag:] == bl[:-lag]]
                assert len(xs) <= lag + 2 or len(d) == 0 or np.median(np.abs(d - np.median(d))) == 0
            else:
                assert got == want, (case, got, want)


def test_cli_identify_prints_no_numpy_warnings(tmp_path, cli):
    """A push campaign and an excitation (seeds 58 and 57), on which the band fits' line searches
    and two bootstrap replicates diverge: none of their numpy overflow warnings (35 lines)
    reaches stderr, which stays empty, and the model is the same."""
    p, ex, m = tmp_path / "p.parquet", tmp_path / "ex.parquet", tmp_path / "m.toml"
    r = cli("simulate", "push-campaign", "--seed", "58", "--pushes-per-direction", "3", "-o", p)
    assert r.code == 0, r.err
    r = cli("simulate", "excitation", "--seed", "57", "-o", ex, "-q")
    assert r.code == 0, r.err
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        r = cli("identify", p, ex, "-o", m, "-q")
    assert r.code == 0, r.err
    assert r.err == ""
    assert [str(w.message) for w in seen if issubclass(w.category, RuntimeWarning)] == []
    moving = TorqueModel.load(m).regimes["moving"]
    # joint 5's moving band: no standard error where its replicates diverge (as with half the
    # friction on the motor side), else a finite positive one
    se = moving.stderr["tau_min"][4]
    assert (se == -1.0 or 0 < se < np.inf) and moving.stderr["sigma"][4] > 0


def test_identify_through_a_process_pool_is_the_same_model(campaign, dither_campaign):
    """The joint-regimes' fits run by an executor (the demo's process pool) give the model of
    the serial run, bit for bit: each fit is a pure function of its samples."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    recs = [campaign[0], dither_campaign[0]]
    serial = identify(recs, n_boot=5, seed=3).dumps()
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        assert identify(recs, n_boot=5, seed=3, executor=ex).dumps() == serial

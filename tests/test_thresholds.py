"""Tests of ditherlab.analysis.detection: push detection and the paper's detection statistics."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from synthetic import push_profile

from ditherlab.analysis.detection import (
    NoPushesError,
    analyse,
    find_pushes,
    fit_logistic,
    rest_mask,
)
from ditherlab.data.estimates import COMPONENTS, SCHEMA, Estimates

RATE = 250.0


def campaign(mags, axes="xyz", signs=(1, -1), noise=0.2, seed=0):
    """Sensor wrench of pushes (applied force P, sensor F = -P) and the push list."""
    rng = np.random.default_rng(seed)
    plan = [(a, s, m) for a in axes for s in signs for m in mags]
    t = np.arange(0.0, 2.0 + 3.0 * len(plan), 1 / RATE)
    F = np.zeros((len(t), 6))
    starts = []
    for i, (a, s, m) in enumerate(plan):
        t0 = 2.0 + 3.0 * i
        starts.append(t0)
        F[:, "xyz".index(a)] -= s * push_profile(t, t0, m)
    F[:, :3] += rng.normal(0, noise, (len(t), 3))
    return t, F, plan, starts


def estimates_from(t, F, Fh, width=10.0, dither=None, name="fake.parquet"):
    """An Estimates object with one variant ``nodither_band`` whose estimate is ``Fh``."""
    cols = {"t": t}
    for k, c in enumerate(COMPONENTS):
        cols[c] = F[:, k]
    if dither is not None:
        cols["dither"] = dither
    for k, c in enumerate(COMPONENTS):
        cols[f"nodither_band/{c}"] = Fh[:, k]
    for k, c in enumerate(COMPONENTS):
        cols[f"nodither_band/{c}_lo"] = Fh[:, k] - width / 2
    for k, c in enumerate(COMPONENTS):
        cols[f"nodither_band/{c}_hi"] = Fh[:, k] + width / 2
    cols["nodither_band/active"] = np.zeros(len(t), np.int64)
    meta = {
        "schema": SCHEMA,
        "variants": ["nodither_band"],
        "n_joints": 6,
        "interval": {"method": "profile", "level": 0.95},
        "model": {"n_joints": 6},
    }
    return Estimates(pd.DataFrame(cols), meta, name=name)


def test_find_pushes_recovers_plan():
    """Every push is found once, with its axis, applied-force sign, start and peak."""
    t, F, plan, starts = campaign((5.0, 12.0, 40.0))
    pushes = find_pushes(t, F)
    assert len(pushes) == len(plan)
    for p, (a, s, m), t0 in zip(pushes, plan, starts, strict=True):
        assert p.axis == a and p.sign == s
        assert p.peak == pytest.approx(m, abs=1.0)
        assert t0 - 0.05 < p.start < t0 + 0.3 and p.end < t0 + 1.25


def test_rest_mask_keeps_away_from_pushes():
    """Rest samples are at least the margin away from every push."""
    t, F, _, _ = campaign((20.0,), axes="x")
    pushes = find_pushes(t, F)
    rest = rest_mask(t, pushes, 1.0)
    for p in pushes:
        assert not rest[(t > p.start - 1.0) & (t < p.end + 1.0)].any()
    assert rest[t < pushes[0].start - 1.01].all()


def test_statistics_of_a_known_estimator():
    """An estimator that sees only pushes of 25 N and more, at half their size, gives the
    response threshold 25 N and the >10 N threshold at the first push above 20 N applied."""
    mags = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0)
    t, F, plan, _ = campaign(mags)
    Fh = np.where(np.abs(F) >= 25.0 * 0.999, 0.5 * F, 0.0)
    Fh[:, 3:] = 0.0
    Fh += np.random.default_rng(1).normal(0, 0.05, Fh.shape)  # noise far below 1 N
    a = analyse([estimates_from(t, F, Fh)], n_boot=50)
    c = a["conditions"]["nodither_band"]
    for ax in "xyz":
        d = c["directions"][ax]
        assert d["pushes"] == 2 * len(mags)
        # peaks carry the sensor noise (0.2 N)
        assert d["response_min"] == pytest.approx(25.0, abs=1.0)
        assert d["above10_from"] == pytest.approx(25.0, abs=1.0)  # 25 N -> 12.5 N estimate
        assert d["never_detected_max"] == pytest.approx(20.0, abs=1.0)
        assert 20.0 <= d["curve"]["F50"] <= 25.0
        assert d["coverage"] < 0.8  # the 10 N wide interval misses the 40, 50 N pushes
    assert c["noise_level"]["x"] == pytest.approx(1.0)  # floored at 1 N


def test_wrong_sign_estimate_is_no_response():
    """An estimate of the right size but the wrong sign does not count as a response."""
    t, F, _, _ = campaign((30.0,), axes="y")
    a = analyse([estimates_from(t, F, -F)], n_boot=0)
    assert a["conditions"]["nodither_band"]["directions"]["y"]["detected"] == 0


def test_logistic_fit_recovers_curve():
    """The grid ML of the detection curve recovers F50 and F90 of simulated detections."""
    rng = np.random.default_rng(4)
    f = rng.uniform(0, 60, 400)
    p = 1 / (1 + np.exp(-(f - 25.0) / 4.0))
    hit = rng.uniform(size=f.size) < p
    c = fit_logistic(f, hit, n_boot=100, seed=2)
    assert c["F50"] == pytest.approx(25.0, abs=2.0)
    assert c["F50_ci"][0] < c["F50"] < c["F50_ci"][1] or c["F50_ci"][0] == c["F50_ci"][1]
    assert c["F50_ci"][1] - c["F50_ci"][0] < 5.0
    assert c["F90"] == pytest.approx(25.0 + 4.0 * np.log(9), abs=4.0)
    assert fit_logistic(f, hit, n_boot=20, seed=2) == fit_logistic(f, hit, n_boot=20, seed=2)


def test_no_pushes_raises():
    """Estimates without pushes, or without the F/T columns, give one clear error."""
    t = np.arange(0, 20, 1 / RATE)
    F = np.random.default_rng(0).normal(0, 0.1, (len(t), 6))
    with pytest.raises(NoPushesError, match="no pushes found"):
        analyse([estimates_from(t, F, F)])
    est = estimates_from(t, F, F)
    est.data = est.data.drop(columns=list(COMPONENTS))
    with pytest.raises(NoPushesError, match="no F/T columns f_x..m_z"):
        analyse([est])


def test_logistic_without_transition_reports_a_bound():
    """When every push is seen, F50 is reported as below the smallest force, not a grid edge."""
    f = np.array([6.0, 10.0, 20.0, 40.0])
    c = fit_logistic(f, np.ones(4, bool))
    assert c["bound"] == "below" and c["bound_force"] == 6.0 and np.isnan(c["F50"])
    c = fit_logistic(f, np.zeros(4, bool))
    assert c["bound"] == "above" and c["bound_force"] == 40.0


def test_rest_with_dither_leaves_out_the_ramps():
    """The dither flag covers its ramps (docs/recording-format.md: true while the feedforward is
    on); rest with dither starts when every dithering joint's extracted amplitude has reached
    80 % of its median and ends when it last had: the ramp in and out are left out, a dip inside
    (a joint slipping) is kept, a joint that does not dither (its amplitude the noise's spread)
    is ignored, and a file without extraction columns keeps every dithered sample."""
    from ditherlab.analysis.steady import steady_dither
    from ditherlab.data.estimates import Estimates, EstimatesSource

    t = np.arange(2000) / 250.0
    dith = np.ones(2000, dtype=bool)
    ramp = np.clip(np.minimum(t / 1.0, (t[-1] - t) / 1.0), 0.0, 1.0)  # 1 s in, 1 s out
    dip = (t > 4.0) & (t < 4.2)
    ramp[dip] = 0.3  # a dip inside the stretch: still rest
    rng = np.random.default_rng(3)
    cols = {"t": t, "dither": dith}
    for j, amp in ((1, 8.0 * ramp), (2, 0.2 + 0.05 * rng.random(2000))):  # joint 2: noise only
        centre = rng.normal(size=2000)
        cols[f"extract/upper_{j}"] = centre + amp
        cols[f"extract/lower_{j}"] = centre - amp
    band = {"tau_min": [-10.0, -9.0], "tau_max": [10.0, 9.0], "sigma": [0.3, 0.3]}
    meta = {"model": {"regimes": {"still": band}}, "variants": []}
    src = EstimatesSource.of(Estimates(pd.DataFrame(cols), meta))
    steady = steady_dither(src, dith)
    np.testing.assert_array_equal(steady, (ramp >= 0.8) | dip)  # joint 2 plays no part
    assert steady.sum() == 1600 and not steady[:199].any() and not steady[-199:].any()
    bare = EstimatesSource.of(Estimates(pd.DataFrame({"t": t, "dither": dith}), meta))
    assert steady_dither(bare, dith).all()

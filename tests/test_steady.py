"""Rest with dither starts once the dither's loops have settled (``ditherlab.analysis.steady``).

A short dithered push campaign of the built-in simulator with a long still time after the
dither's ramp (``push_campaign.settle_s`` = 6 s, so the start-up lies in what the report could
count as rest) goes through the CLI: simulate -> identify -> replay -> report. Against the
simulator's truth (the extracted signal less the gravity torque at the logged pose, whose level
before the first push is where the centre loop holds it): rest begins only where every joint's
signal has reached that level within the rule's tolerance — the amplitude ramp alone would
start it 1 s after the dither comes on, with joint 3 still 1-3 N·m off — later pushes and
rests are all kept, and the dithered noise level is the report's 1 N floor. ~25 s.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_cli

from ditherlab.analysis.steady import SETTLE_SIGMAS, steady_dither
from ditherlab.data.estimates import EstimatesSource
from ditherlab.io import read
from ditherlab.physics.dither import extract_dither

SETTLE_S = 6.0  # still time after the dither's ramp before the first push [s]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("startup")
    cfg = d / "cfg.toml"
    cfg.write_text(
        f"[push_campaign]\nsettle_s = {SETTLE_S}\nmagnitude_min = 10.0\nmagnitude_max = 25.0\n"
    )
    runs = [
        ("simulate", "push-campaign", "--seed", "5", "--pushes-per-direction", "2",
         "--no-dither", "--config", cfg, "-o", d / "id-plain.parquet", "-q"),
        ("simulate", "push-campaign", "--seed", "5", "--pushes-per-direction", "2",
         "--dither", "--config", cfg, "-o", d / "id-dither.parquet", "-q"),
        ("simulate", "push-campaign", "--seed", "6", "--pushes-per-direction", "1",
         "--dither", "--config", cfg, "-o", d / "ev.parquet", "-q"),
        ("identify", d / "id-plain.parquet", d / "id-dither.parquet", "--bootstrap", "0",
         "-o", d / "model.toml", "-q"),
        ("replay", d / "ev.parquet", "--model", d / "model.toml", "--variants", "dither_band",
         "--components", "fxyz", "-o", d / "ev-est.parquet", "-q"),
        ("report", d / "ev-est.parquet", "-o", d / "rep", "--bootstrap", "0", "--json", "-q"),
    ]  # fmt: skip
    for args in runs:
        res = run_cli(*args)
        assert res.code == 0, (args[0], res.err)
    return d, json.loads(res.out)


def test_rest_starts_when_the_loops_have_settled(campaign):
    d, report = campaign
    rec = read(d / "ev.parquet")
    src = EstimatesSource(d / "ev-est.parquet")
    t = src.column("t")
    dith = src.column("dither").astype(bool)
    steady = steady_dither(src, dith)
    tl = rec.meta["sim"]["timeline"]
    on, first, off = float(tl["dither_on"]), float(tl["first_push"]), float(tl["dither_off"])
    assert first - on > SETTLE_S  # the log has the long still start-up the test needs

    # the simulator's truth: the extracted signal less the gravity torque at the logged pose,
    # settled where it stands before the first push (the loops have had > 6 s)
    g, _ = rec.robot().gravity_jacobian(rec.q)
    r = extract_dither(rec).signal - g  # (N, 6) [N·m]
    level = np.median(r[(t > first - 1.5) & (t < first - 0.2)], axis=0)
    sigma = np.asarray(src.meta["model"]["regimes"]["dither"]["sigma"])
    k0 = int(np.flatnonzero(steady)[0])
    assert on + 1.0 < t[k0] < first - 1.0  # after the amplitude's ramp, before the push's margin
    # the first second of rest: every joint's mean within the rule's tolerance of its level
    first_s = (t >= t[k0]) & (t < t[k0] + 1.0)
    off_by = np.abs(r[first_s].mean(axis=0) - level)
    assert np.all(off_by <= SETTLE_SIGMAS * sigma), (off_by, SETTLE_SIGMAS * sigma)
    # ... which the amplitude's ramp alone (rest from ~1 s after the dither comes on) is not
    ramp_only = (t >= on + 1.0) & (t < on + 2.0)
    assert np.abs(r[ramp_only].mean(axis=0) - level)[2] > 3 * SETTLE_SIGMAS * sigma[2]

    # only the start is left out: from the first push to the ramp-out every flagged sample stays
    later = dith & (t >= first) & (t < off)
    assert later.sum() > 0.8 * (off - first) / (t[1] - t[0]) and steady[later].all()
    assert not steady[dith & (t > off + 0.5)].any()  # the ramp-out is still left out

    cond = report["conditions"]["dither_band"]
    assert cond["noise_level"] == {"x": 1.0, "y": 1.0, "z": 1.0}  # the report's 1 N floor
    assert cond["coverage_rest"] > 0.95


def test_every_stretch_leaves_out_its_own_start_up():
    """Two stretches of the dither flag, each starting with the centre loop's exponential
    approach (offset 3 N·m, time constant 0.5 s, noise 0.1 N·m) and the second with a 1.5 s
    push-like bump 6 s in: each stretch's rest starts where its offset has fallen to about the
    tolerance (3.29 sigma, read from the model's dithered noise), the bump and the rest after it
    are kept, and a joint whose signal drifts slowly all along (0.05 N·m/s: its medians 2 s
    apart differ by 0.1 N·m, within the tolerance) does not hold rest up."""
    import pandas as pd

    from ditherlab.data.estimates import Estimates

    dt = 0.004
    t = np.arange(int(40 / dt)) * dt
    dith = ((t >= 1.0) & (t < 15.0)) | ((t >= 20.0) & (t < 39.0))
    rng = np.random.default_rng(7)
    sig = 0.1
    sig1 = rng.normal(0.0, sig, len(t))
    for a in (1.0, 20.0):
        on = t >= a
        sig1 += np.where(on, 3.0 * np.exp(-(t - a) / 0.5), 0.0) * (dith & on)
    sig1 += np.where((t > 26.0) & (t < 27.5), 2.0, 0.0)  # a push in the second stretch
    drift = 0.05 * t  # joint 2: 0.05 N·m/s for ever, 0.5 sigma per window
    amp = np.where(dith, 5.0, 0.0)
    cols = {"t": t, "dither": dith}
    for j, c in ((1, sig1), (2, drift + rng.normal(0.0, sig, len(t)))):
        cols[f"extract/upper_{j}"] = c + amp
        cols[f"extract/lower_{j}"] = c - amp
        cols[f"extract/signal_{j}"] = c
    band = {"tau_min": [-10.0, -10.0], "tau_max": [10.0, 10.0], "sigma": [0.3, 0.3]}
    dband = {"tau_min": [-1.0, -1.0], "tau_max": [1.0, 1.0], "sigma": [sig, sig]}
    meta = {"model": {"regimes": {"still": band, "dither": dband}}, "variants": []}
    src = EstimatesSource.of(Estimates(pd.DataFrame(cols), meta))
    steady = steady_dither(src, dith)
    tol = SETTLE_SIGMAS * sig
    for a, b in ((1.0, 15.0), (20.0, 39.0)):
        k = np.flatnonzero(steady & (t >= a) & (t < b))
        start = t[k[0]] - a
        # the offset 3 exp(-s / 0.5) reaches the tolerance at 0.5 ln(3 / tol) = 1.1 s; the
        # last 2 s's median reads it about 1 s later (2.1 s), before it is 0.1 tol (2.3 s)
        assert 0.5 * np.log(3.0 / tol) - 0.2 < start < 0.5 * np.log(3.0 / (0.1 * tol))
        assert steady[k[0] : np.searchsorted(t, b)].all()  # the bump and all later rest kept
    assert not steady[~dith].any()

"""Calibrated intervals with dither: the ``dither_extraction`` effect (docs/method.md, "Where the
estimator reads the extraction"), how replay uses it, and diagnose finding it on a dithered push
log but not on clean controls."""

from __future__ import annotations

import tomllib
from types import SimpleNamespace

import numpy as np
import pytest
from synthetic import push_recording

from ditherlab.analysis.estimation import extraction_lead
from ditherlab.core.names import DITHER
from ditherlab.core.timeseries import causal_mean
from ditherlab.physics.effects import get_effect, signals
from ditherlab.physics.effects.extraction import extraction_mask, extraction_window
from ditherlab.physics.effects.sensor import AttenuationLag


def _raised_cosine(t: np.ndarray, t0: float, length: float, peak: float) -> np.ndarray:
    x = np.zeros_like(t)
    m = (t >= t0) & (t <= t0 + length)
    x[m] = 0.5 * peak * (1.0 - np.cos(2.0 * np.pi * (t[m] - t0) / length))
    return x


def test_lead_reads_a_lagged_mean_at_its_time():
    """A push torque seen through a one-period mean (20 samples) and a first-order lag of 20
    samples is read back at its own time by extraction_lead: its largest error falls at least
    2.5-fold, its RMS threefold (0.5-2 s pushes of 10-25 N·m), and a torque held still is left exactly as it is."""
    rate, W, lag = 250.0, 20, 20.0
    t = np.arange(0.0, 30.0, 1.0 / rate)
    x = np.full(len(t), 3.0)  # friction held inside the band
    for t0, L, P in ((2.0, 0.5, 10.0), (8.0, 1.0, -25.0), (16.0, 2.0, 18.0)):
        x += _raised_cosine(t, t0, L, P)
    sig = SimpleNamespace(rec=None)
    y = AttenuationLag.delayed(sig, causal_mean(x, W), (0, lag))
    tb = np.stack([y, y], axis=1)
    reg = np.full(tb.shape, DITHER, dtype=np.int8)
    ext = SimpleNamespace(valid=np.ones(len(t), bool), on=np.ones(len(t), bool), ramp=None)
    spec = SimpleNamespace(name="dither_extraction", joints=[1], params={"gain": 0.9, "lag": lag})
    model = SimpleNamespace(effects=[spec], n=2)
    out = extraction_lead(tb, model, reg, ext, W)
    push = np.abs(x - 3.0) > 0.5
    before = np.max(np.abs(y - x)[push])
    after = np.max(np.abs(out[:, 0] - x)[push])
    assert before > 5.0 and after < before / 2.5
    rms = [np.sqrt(np.mean((z - x)[push] ** 2)) for z in (y, out[:, 0])]
    assert rms[1] < rms[0] / 3.0
    still = (t > 25.0) & (t < 30.0)
    np.testing.assert_allclose(out[still, 0], 3.0, atol=1e-9)
    np.testing.assert_array_equal(out[:, 1], tb[:, 1])  # a joint the effect does not name
    nothing = SimpleNamespace(effects=[], n=2)
    assert extraction_lead(tb, nothing, reg, ext, W) is tb


def test_design_is_what_the_effect_predicts():
    """On a dithered recording: gain · design + offset equals the external torque minus what
    a model without the effect subtracts (``J^T F`` through the dither's window in the dither
    regime, as the extracted signal is compared with it; ``J^T F`` itself where a joint
    creeps), only on the rows where the dither variants read the extraction; zero design
    without dither."""
    rec, _ = push_recording(2, dither=True, magnitudes=(20.0,), axes=("x",))
    e = get_effect("dither_extraction")
    sig = signals(rec)
    W = extraction_window(sig)
    assert W == round(0.08 * 250.0)
    X = sig.jtf(sig.wrench_lp("t"))[:, 1]
    d = e.design(sig, 1, 8, {})
    pred = e.external(sig, 1, X, np.array([0.8]), 8)
    m = extraction_mask(sig, 1)
    base = np.where(m & (sig.regime[:, 1] == DITHER), causal_mean(X, W), X)
    np.testing.assert_allclose(0.8 * d.centre[:, 0] + d.offset, pred - base, atol=1e-9)
    assert (m & (sig.regime[:, 1] == DITHER)).any() and (np.abs(base - X) > 0.1).any()
    assert m.any() and not m.all()
    np.testing.assert_array_equal(pred[~m], X[~m])
    plain, _ = push_recording(2, magnitudes=(20.0,), axes=("x",))
    dp = e.design(signals(plain), 1, 8, {})
    assert not dp.centre.any() and not dp.offset.any()


@pytest.mark.slow
def test_identified_and_diagnosed_on_a_dithered_push_log_only(tmp_path, cli):
    """Through the CLI on the built-in simulator (seed 31, 3 pushes per axis and sign):
    ``identify --add dither_extraction`` fits a gain below 1 (and a lag, on some joints) on the
    dithered push campaign; on the same campaign without dither it is refused (one line, exit 2: nothing to
    fit); diagnose does not suggest it there."""
    paths = {}
    for d in ("dither", "no-dither"):
        p = tmp_path / f"{d}.parquet"
        r = cli("simulate", "push-campaign", "--seed", "31", f"--{d}", "--pushes-per-direction",
                "3", "-o", p)  # fmt: skip
        assert r.code == 0, r.err
        paths[d] = p
    base = tmp_path / "base.toml"
    r = cli("identify", paths["no-dither"], paths["dither"], "-o", base, "--bootstrap", "0")
    if r.code == 2 and "bootstrap" in r.err:
        r = cli("identify", paths["no-dither"], paths["dither"], "-o", base)
    assert r.code == 0, r.err
    m2 = tmp_path / "ext.toml"
    r = cli("identify", paths["no-dither"], paths["dither"], "--model", base,
            "--add", "dither_extraction", "-o", m2)  # fmt: skip
    assert r.code == 0, r.err
    spec = [s for s in tomllib.loads(m2.read_text())["effects"] if s["name"] == "dither_extraction"]
    assert len(spec) == 1
    gains = np.atleast_1d(spec[0]["params"]["gain"])
    lags = np.atleast_1d(spec[0]["params"]["lag"])
    assert np.all((gains > 0.5) & (gains < 1.0)), gains
    # fitted on every joint a push loads, not only where diagnosis found it: a
    # joint whose extraction is the one-period mean alone fits no extra lag (joint 3 here, 0)
    assert np.all(lags >= 0) and lags.max() >= 1, lags
    r = cli("identify", paths["no-dither"], "--model", base, "--add", "dither_extraction",
            "-o", tmp_path / "no.toml")  # fmt: skip
    errors = [x for x in r.err.splitlines() if x.startswith("error")]
    assert r.code == 2 and len(errors) == 1, r.err
    assert errors[0] == (
        f"error: {paths['no-dither']}: effect 'dither_extraction' acts only where the dither is "
        "on, and no recording here has the dither on (column 'dither'); add it with a dithered "
        "recording"
    )
    out = tmp_path / "diag"
    r = cli("diagnose", paths["no-dither"], "--model", base, "-o", out, "--json")
    assert r.code == 0, r.err
    import json

    cands = json.loads((out / "report.json").read_text())["candidates"]
    ext = [c for c in cands if c["effect"] == "dither_extraction"]
    assert all(not c["suggested"] for c in ext)

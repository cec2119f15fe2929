"""The dither variants read the extracted signal, a mean over the last dither period, and
subtract gravity and the model's effects through the same window
(:func:`ditherlab.analysis.estimation.model_seen`): what the effects compute at the dither's own
frequency (an inertia times the vibration's acceleration) averages out as the dither does in
the extraction. Offline replay, the causal general update and its per-sample path alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_causal import irb140_model

import ditherlab.analysis.estimation as estimation
from ditherlab.analysis.causal import CausalEstimator, block_of, settings_for
from ditherlab.data.torque_model import EffectSpec
from ditherlab.io import read

REC = Path(__file__).resolve().parents[1] / "recordings" / "sim-push-dither.parquet"
DITHER_VARIANTS = ["dither_band", "dither_noband"]
#: an inertia of the size ``ditherlab identify recordings/sim-push-dither.parquet --add inertia
#: --bootstrap 0`` fits on this recording (rounded; within the effect's ranges)
INERTIA = EffectSpec(
    "inertia",
    [1, 2, 3, 4, 6],
    {"scale": [0.35, 1.2, 0.45, 2.5, 4.0], "motor_inertia": [4.5, 1.1, 3.3, 0.08, 0.07]},
)


def with_effects(effects: list[EffectSpec]):
    model = irb140_model()
    model.effects = list(effects)
    return model


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


@pytest.fixture(scope="module")
def rec():
    return read(REC)


@pytest.fixture(scope="module")
def estimates(rec):
    """Per model (``none``, ``inertia``) the replay's dither variants with gravity and the
    effects through the window (``windowed``) and per sample (``raw``: what the dither variants
    would read if the window were left out)."""
    out = {}
    for name, eff in (("none", []), ("inertia", [INERTIA])):
        model = with_effects(eff)
        windowed = estimation.replay(rec, model, variants=DITHER_VARIANTS)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(estimation, "model_seen", lambda m, w: np.asarray(m, dtype=float))
            raw = estimation.replay(rec, model, variants=DITHER_VARIANTS)
        out[name] = {"windowed": windowed, "raw": raw}
    return out


def test_the_window_lowers_the_force_error_with_inertia(rec, estimates):
    """With an inertia in the model, the dither variants' force error in the dithered rows falls
    clearly (by 5 % at least) against the per-sample effects, and is no larger than the model
    without effects gives: the inertia's torque of the dither's vibration averages out."""
    on = rec.dither.astype(bool)
    W = rec.wrench[on, :3]
    for v in DITHER_VARIANTS:
        err = {
            (m, k): rms(est.F(v)[on, :3] - W)
            for m, pair in estimates.items()
            for k, est in pair.items()
        }
        assert err["inertia", "windowed"] < 0.95 * err["inertia", "raw"], (v, err)
        assert err["inertia", "windowed"] <= 1.01 * err["none", "windowed"], (v, err)


def test_without_effects_only_gravitys_window_changes_the_estimate(rec, estimates):
    """Without effects the window changes only gravity, which a standing joint barely moves:
    the dither variants' forces move by under 0.05 N RMS in the dithered rows, a fiftieth of
    what the window does to the inertia; rows without dither are the same bit for bit."""
    on = rec.dither.astype(bool)
    for v in DITHER_VARIANTS:
        moved = {
            m: rms(pair["windowed"].F(v)[on, :3] - pair["raw"].F(v)[on, :3])
            for m, pair in estimates.items()
        }
        assert moved["none"] < 0.05 and moved["none"] < moved["inertia"] / 50, (v, moved)
        for pair in estimates.values():
            np.testing.assert_array_equal(pair["windowed"].F(v)[~on], pair["raw"].F(v)[~on])


def test_causal_general_update_keeps_the_window_across_blocks(rec):
    """The causal general update with effects keeps enough rows of gravity plus the effects for
    the window: fed one sample at a time it gives what it gives on one block (to rounding: the
    solver's sums over a block), and the dither variants' forces differ from the per-sample
    effects' where the dither is on."""
    rows = slice(1000, 1300)  # the dither's start and its first periods of standing
    part = rec.with_data(rec.data.iloc[rows].reset_index(drop=True))
    s = settings_for(part)
    model = with_effects([INERTIA])
    one = CausalEstimator(model, part.meta, s, fast=False).update(block_of(part))
    est = CausalEstimator(model, part.meta, s, fast=False)
    each = [est.update(block_of(part, slice(i, i + 1))) for i in range(len(part))]
    for k, v in one.items():
        got = np.concatenate([e[k] for e in each])
        np.testing.assert_allclose(got, v, rtol=1e-12, atol=1e-9, err_msg=k)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("ditherlab.analysis.causal.model_seen", lambda m, w: np.asarray(m, float))
        raw = CausalEstimator(model, part.meta, s, fast=False).update(block_of(part))
    assert np.abs(one["dither_band/f_x"] - raw["dither_band/f_x"]).max() > 0.5


def test_causal_window_equals_the_offline_one(rec, monkeypatch):
    """Gravity through the window that the causal general update gives its dither variants, fed
    in blocks of 50, equals the offline replay's bit for bit on every row (a model without
    effects: gravity is the same per sample in both)."""
    import ditherlab.analysis.causal as causal
    from ditherlab.core.ticker import Ticker

    part = rec.with_data(rec.data.iloc[1000:1400].reset_index(drop=True))
    model, s = irb140_model(), settings_for(part)
    seen, run = [], causal.variant_estimate

    def spy(v, inp, *args):
        seen.append(inp.seen)
        return run(v, inp, *args)

    monkeypatch.setattr(causal, "variant_estimate", spy)
    est = CausalEstimator(model, part.meta, s, fast=False)
    for a in range(0, len(part), 50):
        est.update(block_of(part, slice(a, a + 50)))
    got = np.concatenate(seen[:: len(s.variants)])
    off = estimation._replay_inputs(part, model, DITHER_VARIANTS, 0.0, Ticker(2, None))
    assert off.w_ext == s.windows()["period"] > 1
    np.testing.assert_array_equal(got, off.seen)

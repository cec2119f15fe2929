"""Tests of ditherlab.analysis.causal_fast: the per-sample path of the causal estimate against
the general update (``CausalEstimator(fast=False)``, which runs the offline replay's functions
on the kept past), over every variant, the ways a stream carries its dither, the waveforms, held
components, priors without a bound, and more samples than its history holds."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from test_causal import extraction_model, irb140_model

from ditherlab.analysis.causal import CausalBlock, CausalEstimator, block_of, settings_for
from ditherlab.core.errors import ConfigError
from ditherlab.data.torque_model import Band, EffectSpec
from ditherlab.io import read

REC = Path(__file__).resolve().parents[1] / "recordings" / "sim-push-dither.parquet"
#: the excitation's end (moving), the dither's start, pushes: 1400 samples, more than the
#: per-sample path's history (2 x kept rows + 1024) holds, so its kept rows move to its front
ROWS = slice(900, 2300)


@pytest.fixture(scope="module")
def rec():
    whole = read(REC)
    return whole.with_data(whole.data.iloc[ROWS].reset_index(drop=True))


def run(est: CausalEstimator, blocks: list[CausalBlock]) -> dict[str, np.ndarray]:
    """Every block through ``est``, the columns joined."""
    out = [est.update(b) for b in blocks]
    return {k: np.concatenate([o[k] for o in out]) for k in out[0]}


def both(rec, model, settings, make=block_of, size: int = 200):
    """The fast and the general estimate of ``rec`` in blocks of ``size`` (``make(rec, rows)``
    the blocks)."""
    blocks = [make(rec, slice(a, min(a + size, len(rec)))) for a in range(0, len(rec), size)]
    fast = CausalEstimator(model, rec.meta, settings)
    general = CausalEstimator(model, rec.meta, settings, fast=False)
    assert fast.fast is not None and general.fast is None
    return run(fast, blocks), run(general, blocks), fast, general


def assert_same(a: dict, b: dict) -> None:
    """The same columns in the same order, and the same numbers to rounding (1e-12 relative;
    infinite bounds alike)."""
    assert list(a) == list(b)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-12, atol=1e-9, err_msg=k)


def test_fast_equals_general_every_variant(rec):
    """All four variants, profile intervals, the dither flag: every column of every sample,
    and the moving spans and gaps alike."""
    model = irb140_model()
    f, g, ef, eg = both(rec, model, settings_for(rec))
    assert {"dither_band/f_x_hi", "dither_noband/active", "extract/signal_6"} <= set(f)
    assert_same(f, g)
    assert ef.moving_spans == eg.moving_spans and len(ef.moving_spans) > 0
    # the variants differ from each other: the comparison is not of constants
    assert np.abs(f["dither_band/f_x"] - f["nodither_noband/f_x"]).max() > 0.1


def test_fast_equals_general_with_dither_extraction(rec):
    """A model with ``dither_extraction`` (the demo's kind) stays on the per-sample path: the
    extraction's gain on the Jacobian and its lead over the kept rows (across the history's
    move to its front) give the general update's every column, and the effect moves the
    dither variants' estimate while the no-dither variants stay as they are bit for bit."""
    model = extraction_model()
    f, g, _, _ = both(rec, model, settings_for(rec))
    assert_same(f, g)
    plain, _, _, _ = both(rec, irb140_model(), settings_for(rec), size=700)
    assert np.abs(f["dither_band/f_x"] - plain["dither_band/f_x"]).max() > 1.0
    np.testing.assert_array_equal(f["nodither_band/f_y"], plain["nodither_band/f_y"])


def test_fast_equals_general_feedforward_sine_held_components(rec):
    """The dither seen from the feedforward's range (no flag), a sine waveform (the period
    mean), the dither band shrunk from the still band (no ``dither`` band), the torques held
    at the prior (``fxyz``), one sample per block."""
    model = irb140_model()
    del model.regimes["dither"]
    s = dataclasses.replace(settings_for(rec, components="fxyz"), waveform="sine")

    def ffw_block(r, rows):
        return block_of(r, rows)._replace(dither=None, tau_ffw=r.tau_ffw[rows])

    short = rec.with_data(rec.data.iloc[:400].reset_index(drop=True))
    f, g, _, _ = both(short, model, s, make=ffw_block, size=1)
    assert "dither" not in f
    assert_same(f, g)
    np.testing.assert_array_equal(f["dither_band/m_x"], model.prior_mean[3])


def test_fast_equals_general_without_prior_and_logged_velocity(rec):
    """Components without a prior (the ridge; the no-band variants leave the closed form), the
    velocity differenced from ``q``, a model without a moving band."""
    model = irb140_model()
    model.prior_sigma = np.full(6, np.inf)
    del model.regimes["moving"]

    def no_dq(r, rows):
        return block_of(r, rows)._replace(dq=None)

    short = rec.with_data(rec.data.iloc[:500].reset_index(drop=True))
    f, g, _, _ = both(short, model, settings_for(short), make=no_dq, size=64)
    assert_same(f, g)
    assert (f["nodither_band/active"] > 0).any()  # joints outside their band: the pushes


def test_a_gap_and_bad_samples(rec):
    """A gap starts afresh in both paths alike; a time not after the last and a NaN are the
    general update's ConfigErrors, and leave the state as it was."""
    model = irb140_model()
    data = rec.data.iloc[:300].copy()
    data.loc[150:, "t"] += 5.0
    gapped = rec.with_data(data.reset_index(drop=True))
    f, g, ef, eg = both(gapped, model, settings_for(gapped), size=100)
    assert_same(f, g)
    assert ef.gaps == eg.gaps == 1
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    first = est.update(block_of(rec, slice(0, 10)))
    with pytest.raises(ConfigError, match="is not after the previous one"):
        est.update(block_of(rec, slice(5, 12)))
    b = block_of(rec, slice(10, 12))
    with pytest.raises(ConfigError, match="tau at t = .* is not finite"):
        est.update(b._replace(tau=np.where(np.arange(6) == 2, np.nan, b.tau)))
    with pytest.raises(ConfigError, match="dq is given for some samples only"):
        est.update(b._replace(dq=None))
    again = CausalEstimator(model, rec.meta, settings_for(rec))
    again.update(block_of(rec, slice(0, 10)))
    np.testing.assert_array_equal(
        est.update(b)["dither_band/f_y"], again.update(b)["dither_band/f_y"]
    )
    assert first["t"][0] == block_of(rec, slice(0, 1)).t[0]


def test_what_the_fast_path_does_not_cover(rec):
    """Set-membership intervals and a model with an effect other than ``dither_extraction``
    take the general update."""
    model = irb140_model()
    assert (
        CausalEstimator(model, rec.meta, settings_for(rec, interval="set_membership")).fast is None
    )
    model.effects = [EffectSpec("temperature_friction", [1], {"coef": [-0.1], "x_ref": [30.0]})]
    assert isinstance(model.regimes["still"], Band)
    assert CausalEstimator(model, rec.meta, settings_for(rec)).fast is None
    model.effects += extraction_model().effects  # with another effect: the general update
    assert CausalEstimator(model, rec.meta, settings_for(rec)).fast is None


def test_read_only_columns_and_an_empty_block():
    """A recording read from Parquet hands read-only arrays (its own type to numba): they are
    copied, not compiled for anew; an empty block returns empty columns and changes nothing."""
    whole = read(REC)
    assert not whole.q.flags.writeable
    model = irb140_model()
    est = CausalEstimator(model, whole.meta, settings_for(whole))
    empty = est.update(block_of(whole, slice(0, 0)))
    assert len(empty["dither_band/f_x"]) == 0 and est.moving_spans == []
    got = run(est, [block_of(whole, slice(a, a + 50)) for a in range(0, 200, 50)])
    general = CausalEstimator(model, whole.meta, settings_for(whole), fast=False)
    assert_same(got, run(general, [block_of(whole, slice(0, 200))]))

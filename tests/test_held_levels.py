"""The held-level test of a band at rest (:func:`ditherlab.physics.band_fit.held_levels`) and
its use by identify: a still band contains every level the friction held for 0.1 s.

A residual at rest is piecewise constant friction (wherever the last push left it, anywhere in
the static band) plus noise. The test compares each whole window's mean with a band edge at a
family-wise level; these tests check the rate of false widenings on bands that hold every
level, that a rare held level beyond the bulk is found, and the noise of a window's mean.
"""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.physics.band_fit import HELD_LEVEL, fit_band, fit_regime, held_levels

RATE = 250.0
W = 25  # 0.1 s at 250 Hz


def _campaign(rng, a, b, n_pushes=60, sigma=0.1, phi=0.0, beyond=()):
    """A residual at rest: ``n_pushes`` held levels drawn uniformly in ``[a, b]`` (and the
    levels ``beyond`` among them, each held 0.4 s), each reached by a 0.3 s linear ramp from the
    last and held for 1-3 s, plus AR(1) noise of standard deviation ``sigma`` and coefficient
    ``phi``. Returns (x, labels): one contiguous run per push."""
    levels = np.r_[rng.uniform(a, b, n_pushes), beyond]
    short = np.r_[np.zeros(n_pushes, bool), np.ones(len(beyond), bool)]
    order = rng.permutation(len(levels))
    parts, labels, last = [], [], 0.0
    for k, (lv, brief) in enumerate(zip(levels[order], short[order], strict=True)):
        ramp = np.linspace(last, lv, int(0.3 * RATE), endpoint=False)
        hold = np.full(int((0.4 if brief else rng.uniform(1.0, 3.0)) * RATE), lv)
        parts.append(np.r_[ramp, hold])
        labels.append(np.full(len(parts[-1]), k))
        last = lv
    f = np.concatenate(parts)
    e = rng.normal(0.0, sigma * np.sqrt(1 - phi**2), len(f))
    for i in range(1, len(e)):
        e[i] += phi * e[i - 1]
    return f + e, np.concatenate(labels)


@pytest.mark.parametrize("phi", [0.0, 0.6])
def test_a_band_that_holds_every_level_is_rarely_widened(phi):
    """Levels all inside ``[-2, 2]``, white or coloured noise (AR(1), 0.6: correlated over a few
    samples, decorrelated within a window): the band's own edges are rejected on at most a few
    of 200 campaigns (family-wise 1 %; 6 of 200 has probability below 0.02 at that rate), and
    the noise of a window's mean is what the noise process gives, or a little more."""
    rng = np.random.default_rng(11)
    rejected = 0
    ratio = []
    for _ in range(200):
        x, lab = _campaign(rng, -2.0, 2.0, phi=phi)
        h = held_levels(x, lab, W)
        assert h is not None and h.windows > 500
        rejected += (h.lo < -2.0) or (h.hi > 2.0)
        # the variance of a W-sample mean of stationary AR(1) noise
        var = 0.01 / W * ((1 + phi) / (1 - phi) - 2 * phi * (1 - phi**W) / (W * (1 - phi) ** 2))
        ratio.append(h.sigma / np.sqrt(var))
    assert rejected <= 6, rejected
    # at or a little above the truth (the ramps, not linear across a window's edge, add some):
    # the test errs towards keeping the fitted band
    assert 0.97 <= np.median(ratio) <= 1.2, np.median(ratio)


def test_a_rare_held_level_beyond_the_bulk_is_found():
    """One push held 0.4 s at 2.6 while 60 others lie in ``[-2, 2]``: the band-plus-noise fit
    puts its upper edge well short of 2.6 (the rare held level reads as noise), the held-level
    test finds it within a few noise sigmas of a window's mean, and the lower edge it gives
    does not reach below the lowest level held."""
    rng = np.random.default_rng(5)
    x, lab = _campaign(rng, -2.0, 2.0, beyond=[2.6])
    fit = fit_band(x, blocks=lab, n_boot=0)
    h = held_levels(x, lab, W)
    assert fit.b < 2.45
    assert 2.6 - 6 * h.sigma < h.hi <= 2.6 + 1e-9 + 2 * h.sigma
    assert h.lo >= -2.0 - 3 * h.sigma


def test_the_margin_is_the_bonferroni_quantile_of_both_edges():
    """z is the one-sided normal quantile at ``HELD_LEVEL / (2 · windows)``; a window never
    spans two labels (a run 99 samples long holds three windows of 25, not four)."""
    from scipy.stats import norm

    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 0.1, 99 * 20)
    lab = np.repeat(np.arange(20), 99)
    h = held_levels(x, lab, W)
    assert h.windows == 60
    assert h.z == pytest.approx(norm.isf(HELD_LEVEL / 120))


def test_too_few_windows_give_no_test():
    """Fewer than 20 whole windows: no level is called held (None), and identify's per-regime
    fit then gives no held levels."""
    x = np.zeros(19 * W) + np.random.default_rng(0).normal(0, 0.1, 19 * W)
    lab = np.zeros(len(x), int)
    assert held_levels(x, lab, W) is None
    f = fit_regime(x, lab, 1, 0, 0, hold=W)
    assert "held_min" not in f and "tau_min" in f


def test_fit_regime_reports_the_held_levels_with_their_noise():
    """fit_regime of a regime at rest with ``hold``: ``held_min``/``held_max`` are the test's
    levels, each with the noise of a window's mean as its standard error; without ``hold``
    none."""
    rng = np.random.default_rng(7)
    x, lab = _campaign(rng, -2.0, 2.0, beyond=[2.6])
    h = held_levels(x, lab, W)
    f = fit_regime(x, lab, 1, 0, 0, hold=W)
    assert f["held_max"] == (h.hi, h.sigma) and f["held_min"] == (h.lo, h.sigma)
    assert "held_max" not in fit_regime(x, lab, 1, 0, 0)

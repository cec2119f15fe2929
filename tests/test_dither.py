"""Tests of ditherlab.physics.dither: square wave, signal extraction, band shrink and band-as-noise."""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.core.errors import ConfigError
from ditherlab.physics import dither as D

FS = 250.0  # [Hz]
OMEGA = 80.0  # [rad/s]
PERIOD = 2 * np.pi / OMEGA  # [s]


def loop_reference(tau, W):
    """The paper's pseudo-code, one sample at a time (history of the last W samples)."""
    N, n = tau.shape
    out = {k: np.empty((N, n)) for k in ("upper", "lower", "centre")}
    for k in range(N):
        hist = tau[max(0, k - W + 1) : k + 1]
        for j in range(n):
            h = hist[:, j]
            c = h.mean()
            out["centre"][k, j] = c
            out["upper"][k, j] = h[h > c].mean() if (h > c).any() else c
            out["lower"][k, j] = h[h < c].mean() if (h < c).any() else c
    return out


def dithered(seed=0, N=2000, n=3, amp=(3.0, 1.0, 0.5), step=1.5, t_step=4.0, noise=0.05):
    """Square-wave dither plus a torque step at t_step plus noise, per joint."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    sq = D.square_wave(t, OMEGA, np.array(amp[:n]))
    ext = np.where(t >= t_step, step, 0.0)[:, None] * np.ones(n)
    return t, sq + ext + rng.normal(size=(N, n)) * noise, sq, ext


def test_square_wave_shape_and_values():
    """The square wave is +-amplitude, positive on the first half period, per joint column."""
    t = np.arange(100) / FS
    s = D.square_wave(t, OMEGA, 2.0)
    assert s.shape == (100,) and set(np.unique(s)) == {-2.0, 2.0}
    np.testing.assert_array_equal(s[t < PERIOD / 2 - 1e-9], 2.0)
    s2 = D.square_wave(t, OMEGA, np.array([1.0, 3.0]))
    assert s2.shape == (100, 2)
    np.testing.assert_array_equal(s2[:, 1], 3.0 * s2[:, 0])


@pytest.mark.parametrize("periods", [1, 2, 3])
def test_extract_matches_loop_reference(periods):
    """The vectorised extraction equals the per-sample loop of the paper's pseudo-code."""
    t, tau, _, _ = dithered(seed=periods, N=700)
    ds = D.extract(tau, t, period=PERIOD, periods=periods)
    ref = loop_reference(tau, ds.window)
    for k in ("upper", "lower", "centre"):
        np.testing.assert_allclose(getattr(ds, k), ref[k], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ds.signal, (ref["upper"] + ref["lower"]) / 2, atol=1e-12)
    np.testing.assert_allclose(ds.amplitude, (ref["upper"] - ref["lower"]) / 2, atol=1e-12)
    assert ds.window == round(periods * PERIOD * FS)


def test_extract_small_chunks_equal_one_chunk():
    """Chunked window statistics do not depend on the chunk size, and the compiled kernel
    equals the numpy reference (constant stretches included: no value above the mean)."""
    _, tau, _, _ = dithered(seed=3, N=500)
    tau[100:160] = 1.25
    a = D._window_stats_reference(tau, 20, chunk=37)
    b = D._window_stats_reference(tau, 20, chunk=10_000)
    c = D._window_stats(tau, 20)
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_allclose(z, x, rtol=1e-13, atol=1e-13)
    assert (c[1][130] == 1.25).all() and (c[2][130] == 1.25).all()


def test_extract_recovers_a_step_under_the_dither():
    """On square wave + step + noise, signal recovers the step and amplitude the dither amplitude."""
    t, tau, _, ext = dithered(seed=4, noise=0.02)
    ds = D.extract(tau, t, period=PERIOD, periods=2)
    before = (t > 1.0) & (t < 3.9)
    after = t > 4.0 + 2 * PERIOD + 0.05  # one window after the step
    for j, amp in enumerate((3.0, 1.0, 0.5)):
        assert abs(ds.signal[before, j].mean()) < 0.02
        assert abs(ds.signal[after, j].mean() - 1.5) < 0.02
        assert abs(np.median(ds.amplitude[before, j]) - amp) < 0.02
    # and the raw torque mean over a window shows the step too, but the signal is cleaner
    assert np.std(ds.signal[after, 0]) < 0.05


def test_ripple_of_non_integer_period_is_small_and_measured():
    """A 19.63-sample period in whole-sample windows: the measured ripple stays within its bounds.

    Clean square wave: upper/lower are exact (signal ripple 0), only the centre ripples by one
    unbalanced sample (2 A / W). Square wave through a 4 ms first-order lag (a servo-like edge):
    signal ripple 3.7 % of A with one period per window, 1.0 % with three.
    """
    from scipy.signal import lfilter

    t = np.arange(5000) / FS
    sq = D.square_wave(t, OMEGA, 3.0)[:, None]
    ds = D.extract(sq, t, period=PERIOD)
    f = ds.full & (t > 1.0)
    assert ds.window == 20
    np.testing.assert_allclose(ds.signal[f], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.ptp(ds.centre[f]) / 2, 3.0 / 10, rtol=1e-9)
    al = np.exp(-1 / (FS * 0.004))
    lag = lfilter([1 - al], [1, -al], sq[:, 0])[:, None]
    for periods, bound in ((1, 0.04), (3, 0.012)):
        ds = D.extract(lag, t, period=PERIOD, periods=periods)
        ripple = np.ptp(ds.signal[f]) / 2  # [N·m]
        assert 0.002 * 3.0 < ripple < bound * 3.0, (periods, ripple)


def test_period_from_feedforward():
    """The period found from the zero crossings of tau_ffw equals the true one to 0.1 %."""
    t = np.arange(3000) / FS
    ffw = D.square_wave(t, OMEGA, np.array([0.0, 2.0])) + 0.3
    ffw[1000:1500] = 0.3  # dither off for two seconds
    p = D.period_from_feedforward(ffw, t)
    assert abs(p - PERIOD) < 1e-3 * PERIOD
    _, tau, _, _ = dithered(seed=6, N=3000, n=2)
    a = D.extract(tau, t, tau_ffw=ffw)
    b = D.extract(tau, t, period=PERIOD)
    assert a.window == b.window == 20


def test_extract_one_dimensional_input():
    """A 1-D torque gives 1-D outputs equal to the first column of the 2-D call."""
    t, tau, _, _ = dithered(seed=7, N=300)
    a = D.extract(tau[:, 0], t, period=PERIOD)
    b = D.extract(tau, t, period=PERIOD)
    assert a.signal.shape == (300,)
    np.testing.assert_allclose(a.signal, b.signal[:, 0], rtol=1e-12, atol=1e-14)


def test_extract_bad_input():
    """Missing period and feedforward, a flat feedforward, and bad periods raise ConfigError."""
    t, tau, _, _ = dithered(seed=8, N=100)
    with pytest.raises(ConfigError, match="neither period nor tau_ffw given"):
        D.extract(tau, t)
    with pytest.raises(ConfigError, match="tau_ffw has 0 sign changes"):
        D.extract(tau, t, tau_ffw=np.ones(100))
    with pytest.raises(ConfigError, match="periods is 0; expected a positive integer"):
        D.extract(tau, t, period=PERIOD, periods=0)


def test_dithered_band_shrinks_and_never_inverts():
    """The band moves in by the amplitude on each side and collapses to its midpoint beyond half."""
    a, b = np.array([-4.0, -4.0, -1.0]), np.array([6.0, 6.0, 3.0])
    lo, hi = D.dithered_band(a, b, np.array([1.0, 7.0, 2.0]))
    np.testing.assert_allclose(lo, [-3.0, 1.0, 1.0])
    np.testing.assert_allclose(hi, [5.0, 1.0, 1.0])
    amp = np.abs(np.random.default_rng(0).normal(size=(50, 3))) * 4
    lo, hi = D.dithered_band(a, b, amp)
    assert lo.shape == (50, 3) and np.all(lo <= hi)
    np.testing.assert_allclose(np.maximum(hi - lo, 0), np.maximum(b - a - 2 * amp, 0))


def test_band_as_noise_has_the_variance_of_uniform_plus_gaussian():
    """sigma' squared is the variance of a uniform band plus the Gaussian noise (Monte Carlo)."""
    rng = np.random.default_rng(9)
    a, b, s = -3.0, 5.0, 0.7
    x = rng.uniform(a, b, 400_000) + rng.normal(size=400_000) * s
    sp = D.band_as_noise(a, b, s)
    assert abs(x.var() - sp**2) < 0.01 * sp**2
    np.testing.assert_allclose(D.band_as_noise([0.0, -1.0], [0.0, 1.0], [2.0, 0.0]),
                               [2.0, np.sqrt(4 / 12)])  # fmt: skip


def test_full_window_against_a_loop():
    """full_window is True exactly where the flag held over the whole last window."""
    rng = np.random.default_rng(3)
    on = rng.random(300) > 0.1
    for W in (1, 2, 7, 20):
        ref = [k >= W - 1 and bool(on[k - W + 1 : k + 1].all()) for k in range(len(on))]
        np.testing.assert_array_equal(D.full_window(on, W), ref)


def test_dithered_band_applies_only_where_on():
    """With ``on`` the band is shrunk where on holds and unchanged elsewhere."""
    a, b = np.array([-5.0, -1.0]), np.array([4.0, 1.0])
    amp = np.array([[1.0, 2.0], [1.0, 2.0], [3.0, 0.5]])
    on = np.array([True, False, True])
    lo, hi = D.dithered_band(a, b, amp, on=on[:, None])
    slo, shi = D.dithered_band(a, b, amp)
    np.testing.assert_array_equal(lo[on], slo[on])
    np.testing.assert_array_equal(hi[on], shi[on])
    np.testing.assert_array_equal(lo[~on], a[None].repeat(1, 0))
    np.testing.assert_array_equal(hi[~on], b[None].repeat(1, 0))

"""ditherlab's own versions of the scipy functions it keeps out of its start-up, each against
scipy itself: the Savitzky–Golay filter, the first-order lag, the rotation vector's matrix and
the normal and chi-square quantiles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter, savgol_filter
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm

from ditherlab.core.timeseries import savgol
from ditherlab.estimator.formulation import chi2_1_quantile, normal_quantile
from ditherlab.physics.effects.sensor import _first_order_lag, rotvec_matrix


@pytest.mark.parametrize("shape", [(9,), (50,), (400, 3), (2000, 6)])
@pytest.mark.parametrize("w", [5, 9, 41])
@pytest.mark.parametrize(("deriv", "delta"), [(0, 1.0), (1, 0.004), (2, 0.01)])
def test_savgol_is_scipys(shape, w, deriv, delta):
    """Interior and both edges (scipy's "interp"), values and derivatives, 1-D and 2-D."""
    if w > shape[0]:
        pytest.skip("window longer than the signal")
    x = np.random.default_rng(w + deriv).normal(size=shape).cumsum(axis=0)
    got = savgol(x, w, deriv=deriv, delta=delta)
    ref = savgol_filter(x, w, 2, deriv=deriv, delta=delta, axis=0)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize(("w", "deriv"), [(6, 0), (11, 0), (5, 3)])
def test_savgol_refuses_an_even_or_too_long_window_or_a_high_derivative(w, deriv):
    with pytest.raises(ValueError, match=f"window {w} must be odd, above 2 and at most 10, "
                       f"and the derivative {deriv} at most 2"):  # fmt: skip
        savgol(np.zeros(10), w, deriv=deriv)


@pytest.mark.parametrize("lag", [0.5, 3.0, 75.0])
def test_first_order_lag_is_lfilter_bit_for_bit(lag):
    x = np.random.default_rng(1).normal(size=3000).cumsum()
    a = 1.0 / (lag + 1.0)
    ref, _ = lfilter([a], [1.0, a - 1.0], x, zi=[x[0] * (1.0 - a)])
    np.testing.assert_array_equal(_first_order_lag(x, a), ref)


@pytest.mark.parametrize("seed", range(6))
def test_rotvec_matrix_is_scipys(seed):
    rng = np.random.default_rng(seed)
    for r in (rng.normal(size=3) * 10.0 ** rng.uniform(-6, 0.5), np.zeros(3)):
        np.testing.assert_allclose(
            rotvec_matrix(r), Rotation.from_rotvec(r).as_matrix(), rtol=0, atol=1e-15
        )


@pytest.mark.parametrize("p", [1e-9, 0.01, 0.5, 0.975, 0.997916, 1 - 1e-9])
def test_normal_quantile_is_scipys(p):
    assert normal_quantile(p) == pytest.approx(norm.ppf(p), rel=1e-13, abs=1e-15)


@pytest.mark.parametrize("level", [0.5, 0.9, 0.95, 0.99])
def test_chi2_1_quantile_is_scipys(level):
    assert chi2_1_quantile(level) == pytest.approx(chi2.ppf(level, 1), rel=1e-13)

"""The torque coordinates' set-membership path (``sm_square``) after issue 14's speed work: the
kernel without numba's reference counts, Gauss-Jordan ``J^-T`` and Bland's rule against cycling,
checked against the general kernel and linprog, including the samples it must refuse."""

from __future__ import annotations

import numpy as np
import pytest

from bench.bench_estimator import push_data
from ditherlab import estimator as E
from ditherlab.estimator.intervals.set_membership import (
    BIG_BOX,
    _halfbox,
    _set_membership,
    interval_k,
)
from ditherlab.estimator.intervals.sm_square import square_block, square_state


def _sub(args: dict, rows) -> dict:
    out = dict(args)
    for key in ("tau_bar", "J"):
        out[key] = args[key][rows]
    return out


def _square_only(prob, level=0.95):
    """``square_block`` alone on a whole problem: ``lo, hi (N, m)`` and the status per sample."""
    ridge = prob.p_true == 0.0
    kk = interval_k(level, prob.n, int((~ridge).sum()))
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, _halfbox(prob, kk))
    lo, hi = np.full((prob.N, prob.m), np.nan), np.full((prob.N, prob.m), np.nan)
    st = np.zeros(prob.N, np.int64)
    square_block(prob.tau_bar, prob.J, prob.tau_min, prob.tau_max, sig, kk, prob.prior_mean, half,
                 ridge, BIG_BOX, square_state(prob.m), lo, hi, st)  # fmt: skip
    return lo, hi, st


@pytest.fixture(scope="module")
def bench_args():
    """The first 400 samples of the estimator bench's 100 000 (a pushed IRB140, bands
    (10, 9, 8, 2.5, 2.5, 1.5) N·m, the tight moment prior)."""
    args, _ = push_data(100_000)
    return _sub(args, slice(0, 400))


def test_the_degenerate_cold_start_no_longer_cycles(bench_args):
    """At the bench's first samples the cold start of max F_4 reaches a working set holding the
    objective's own box row (every other multiplier zero): the largest-violation rule cycled
    between six working sets until the iteration limit and the general kernel took the sample
    (7.7 % of the bench). With Bland's rule after m iterations every sample takes the torque
    coordinates and the bounds are linprog's."""
    prob = E.problem(**bench_args)
    lo, hi, st = _square_only(prob)
    assert (st == 5).all(), np.bincount(st + 1)
    sel = np.arange(0, 40, 3)  # the first 20 samples cycled before
    rlo, rhi = E.set_membership_reference(E.problem(**_sub(bench_args, sel)))
    np.testing.assert_allclose(lo[sel], rlo, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hi[sel], rhi, rtol=1e-9, atol=1e-9)
    # the moments' LPs end on the prior box (+-k 0.3 N·m): the degenerate case itself
    kk = interval_k(0.95, 6, 6)
    np.testing.assert_allclose(hi[:20, 3], kk * 0.3, rtol=1e-12)


def test_the_bench_data_equal_the_general_kernel(bench_args):
    """All 400 samples (warm starts from sample to sample, pivots when a vertex moves): the fast
    path's bounds are the general kernel's, which solves every sample by itself."""
    prob = E.problem(**bench_args)
    lo, hi, st = _set_membership(prob, 0.95)
    rlo, rhi, rst = _set_membership(prob, 0.95, square=False)
    assert (st == 5).all() and (rst < 5).all()
    np.testing.assert_allclose(lo, rlo, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(hi, rhi, rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("case", ["inf_band_edge", "ill_conditioned", "singular"])
def test_the_samples_it_must_refuse(bench_args, case):
    """An infinite band edge, a Jacobian beyond the condition limit (1e8) and a singular one:
    the torque coordinates refuse those samples (status -1, nothing written), the others around
    them are still solved there, and the general kernel's bounds come out for all."""
    args = _sub(bench_args, slice(0, 60))
    bad = np.array([10, 11, 30])
    if case == "inf_band_edge":
        tmax = np.tile(args["tau_max"], (60, 1))
        tmax[bad, 2] = np.inf
        args["tau_max"] = tmax
    else:
        J = args["J"].copy()
        J[bad, :, 5] *= 1e-9 if case == "ill_conditioned" else 0.0
        args["J"] = J
    prob = E.problem(**args)
    lo, hi, st = _square_only(prob)
    assert (st[bad] == -1).all() and np.isnan(lo[bad]).all() and np.isnan(hi[bad]).all()
    ok = np.setdiff1d(np.arange(60), bad)
    assert (st[ok] == 5).all(), st
    glo, ghi, gst = _set_membership(prob, 0.95)
    rlo, rhi, rst = _set_membership(prob, 0.95, square=False)
    assert (gst[bad] < 5).all() and (gst[ok] == 5).all()
    for got, ref in ((glo, rlo), (ghi, rhi)):
        np.testing.assert_array_equal(np.isinf(got), np.isinf(ref))
        fin = np.isfinite(ref)
        np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(lo[ok], glo[ok], rtol=0, atol=0)  # the same path, bit for bit

"""The torque coordinates' set-membership path (``sm_square``): the kernel without numba's
reference counts, Gauss-Jordan ``J^-T`` and Bland's rule against cycling, the lockstep passes
(``sm_lockstep``: a block's ``J^-T`` and each LP's working set checked for many samples at
once), checked against the per-sample path, the general kernel and linprog, including the
samples it must refuse or leave to the per-sample code."""

from __future__ import annotations

import numpy as np
import pytest

from bench.bench_estimator import push_data
from ditherlab import estimator as E
from ditherlab.estimator.interval_methods.set_membership import (
    BIG_BOX,
    _halfbox,
    _set_membership,
    interval_k,
    set_membership_reference,
)
from ditherlab.estimator.interval_methods.sm_arrays import (
    Bounds,
    SMProblem,
    block_work,
    square_state,
)
from ditherlab.estimator.interval_methods.sm_lockstep import lockstep_inverse
from ditherlab.estimator.interval_methods.sm_square import BLOCK, MAX_CONDITION, square_block


def _sub(args: dict, rows) -> dict:
    out = dict(args)
    for key in ("tau_bar", "J"):
        out[key] = args[key][rows]
    return out


def _square_only(prob, level=0.95, lockstep=True):
    """``square_block`` alone on a whole problem: ``lo, hi (N, m)`` and the status per sample
    (``lockstep=False``: the per-sample path)."""
    ridge = prob.p_true == 0.0
    kk = interval_k(level, prob.n, int((~ridge).sum()))
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, _halfbox(prob, kk))
    lo, hi = np.full((prob.N, prob.m), np.nan), np.full((prob.N, prob.m), np.nan)
    st = np.zeros(prob.N, np.int64)
    P = SMProblem(prob.tau_bar, prob.J, prob.tau_min, prob.tau_max, sig, kk, prob.prior_mean, half,
                  ridge, BIG_BOX)  # fmt: skip
    square_block(P, square_state(prob.m), Bounds(lo, hi, st), lockstep)
    return lo, hi, st


@pytest.fixture(scope="module")
def bench_args():
    """The first 400 samples of the estimator bench's 100 000 (a pushed IRB140, bands
    (10, 9, 8, 2.5, 2.5, 1.5) N·m, the tight moment prior)."""
    args, _ = push_data(100_000)
    return _sub(args, slice(0, 400))


def test_the_degenerate_cold_start_does_not_cycle(bench_args):
    """At the bench's first samples the cold start of max F_4 reaches a working set holding the
    objective's own box row (every other multiplier zero): the largest-violation rule alone
    cycles there between six working sets until the iteration limit, which would leave the
    sample to the general kernel (7.7 % of the bench). With Bland's rule after m iterations
    every sample takes the torque coordinates and the bounds are linprog's."""
    prob = E.problem(**bench_args)
    lo, hi, st = _square_only(prob)
    assert (st == 5).all(), np.bincount(st + 1)
    # samples 0-39: the first 20 cycle under the largest-violation rule alone
    sel = np.arange(0, 40, 3)
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
    slo, shi, sst = _square_only(prob, lockstep=False)  # the per-sample path refuses the same
    np.testing.assert_array_equal(st, sst)
    np.testing.assert_allclose(lo[ok], slo[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hi[ok], shi[ok], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("seed", [3, 11])
def test_lockstep_equals_the_per_sample_path(seed):
    """Bench-like data on seeds the lockstep passes were not tuned on (3000 samples: 24 blocks,
    working sets that change inside and across blocks): the same status and bounds (to 1e-9) as
    the per-sample dual simplex, and linprog's (to 1e-7) on samples spread over the run."""
    args, _ = push_data(3000, seed)
    prob = E.problem(**args)
    lo, hi, st = _square_only(prob)
    slo, shi, sst = _square_only(prob, lockstep=False)
    np.testing.assert_array_equal(st, sst)
    assert (st == 5).mean() > 0.99
    ok = st == 5
    np.testing.assert_allclose(lo[ok], slo[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hi[ok], shi[ok], rtol=1e-9, atol=1e-9)
    sel = np.arange(5, 3000, 97)
    rlo, rhi = E.set_membership_reference(E.problem(**_sub(args, sel)))
    # 1e-7: on seed 11 every numba kernel (lockstep, per sample, general) is 4.0e-8 N from HiGHS
    # at one sample (1848, min F_1), the others within 3e-14
    np.testing.assert_allclose(lo[sel], rlo, rtol=0, atol=1e-7)
    np.testing.assert_allclose(hi[sel], rhi, rtol=0, atol=1e-7)


def test_lockstep_empty_with_the_prior_box_inside_a_block():
    """A 300 N push (five times the prior box's 57 N) at a few samples, inside a block and at a
    block's first sample: the polytope is empty with the prior box there, no working set can
    pass a lockstep check (no feasible vertex), and the per-sample code reports status 6 with
    the torque box alone, as the per-sample path and the general kernel do; the samples around
    are solved with the prior box."""
    args, _ = push_data(600, 5)
    J = args["J"]
    push = np.array([300.0, 0, 0, 0, 0, 0])
    hit = np.array([40, 41, 42, BLOCK, 2 * BLOCK + 77])
    tb = args["tau_bar"].copy()
    tb[hit] += np.einsum("kin,i->kn", J[hit], push)
    args["tau_bar"] = tb
    prob = E.problem(**args)
    lo, hi, st = _square_only(prob)
    assert (st[hit] == 6).all() and (np.delete(st, hit) == 5).all()
    assert (lo[hit, 0] > 200.0).all()  # the data alone: the push, far outside the prior box
    slo, shi, sst = _square_only(prob, lockstep=False)
    np.testing.assert_array_equal(st, sst)
    np.testing.assert_allclose(lo, slo, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hi, shi, rtol=1e-9, atol=1e-9)
    rlo, rhi, rst = _set_membership(prob, 0.95, square=False)
    assert (rst[hit] == 1).all()  # the general kernel: solved without the prior box
    np.testing.assert_allclose(lo, rlo, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(hi, rhi, rtol=1e-7, atol=1e-7)


def test_lockstep_inverse_leaves_samples_its_pivot_order_does_not_fit():
    """``J^-T`` of a block in the pivot order of one sample: equal to numpy's inverse where the
    order fits, and left to the per-sample code (``okv = 0``) where the joints' columns are
    reversed (partial pivoting would choose other rows), an edge is infinite, or the condition
    exceeds the limit; the whole path still gives the per-sample path's bounds there."""
    args, _ = push_data(2 * BLOCK, 2)
    J = args["J"].copy()
    rev = np.array([5, 6, 70])
    J[rev] = J[rev][:, :, ::-1]
    J[90, :, 5] *= 1e-9  # ill-conditioned
    tmax = np.tile(args["tau_max"], (2 * BLOCK, 1))
    tmax[100, 1] = np.inf
    args.update(J=J, tau_max=tmax)
    prob = E.problem(**args)
    kk = interval_k(0.95, 6, 6)
    sig = 1.0 / np.sqrt(prob.w)
    W, m = BLOCK, 6
    blk = block_work(m, W)
    _, _, P = _lu_order(J[0].T)
    run = SMProblem(prob.tau_bar, prob.J, prob.tau_min, prob.tau_max, sig, kk, prob.prior_mean,
                    np.zeros(m), np.zeros(m, np.bool_), BIG_BOX)  # fmt: skip
    lockstep_inverse(run, MAX_CONDITION, 0, W, P, blk)
    Bs, rns, okv = blk.Bs, blk.rns, blk.okv
    bad = np.array([5, 6, 70, 90, 100])
    assert (okv[bad] == 0.0).all()
    good = np.setdiff1d(np.arange(W), bad)
    assert (okv[good] == 1.0).all()
    Binv = np.linalg.inv(np.transpose(J[:W], (0, 2, 1)))  # (W, m, m): J^-T per sample
    np.testing.assert_allclose(np.moveaxis(Bs, 2, 0)[good], Binv[good], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(rns[:, good].T, np.abs(Binv[good]).sum(2), rtol=1e-12)
    lo, hi, st = _square_only(prob)
    slo, shi, sst = _square_only(prob, lockstep=False)
    np.testing.assert_array_equal(st, sst)
    assert (st[[90, 100]] == -1).all() and (st[[5, 6, 70]] == 5).all()
    ok = st == 5
    np.testing.assert_allclose(lo[ok], slo[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(hi[ok], shi[ok], rtol=1e-9, atol=1e-9)


def _lu_order(M):
    """Partial pivoting's row order of ``M`` (m, m): ``(L, U, order)`` with ``M[order] = L U``."""
    A = np.array(M, float)
    m = len(A)
    order = np.arange(m)
    for c in range(m):
        r = c + int(np.argmax(np.abs(A[c:, c])))
        A[[c, r]] = A[[r, c]]
        order[[c, r]] = order[[r, c]]
        A[c + 1 :, c] /= A[c, c]
        A[c + 1 :, c + 1 :] -= np.outer(A[c + 1 :, c], A[c, c + 1 :])
    return np.tril(A, -1) + np.eye(m), np.triu(A), order


#: two samples of a replayed hour's ``nodither_noband`` variant (zero-width bands, the paper's
#: prior) on which the general kernel's cold path (the primal active-set method) ends on an
#: optimal face rather than a vertex; a value read off the face there is 2.1e-5 and 2.6e-5 N
#: from linprog
FACE_SAMPLES = [
    dict(
        tau_bar=[9.405096195448658, -0.1668455442751693, 7.858249776538557, -1.8100019243011556, -1.6274205904329253, -1.0867548920159618],
        J=[-4.732601613135367e-06, 0.2949868682759174, -0.06501313165716399, -6.598234367054788e-07, -0.06499999995774995, 0.0, 0.45000365233477424, 2.994475789009762e-06, -6.599624242696341e-07, 0.06499999999644279, -6.598291281029309e-07, 0.0, 0.0, -0.3800036523596301, -0.37999775096670524, 1.6451676993647875e-07, 2.2488063980059535e-06, -0.0, 0.0, -1.0151217260473365e-05, -1.0151217260473365e-05, 0.9999999993513797, -1.015112979546891e-05, -3.4597047199083496e-05, 0.0, 0.9999999999484764, 0.9999999999484764, 1.0151217254412106e-05, 0.9999999999452742, 2.5306760292909503e-06, 1.0, 0.0, 0.0, -3.4557104270761175e-05, 2.5310272297919834e-06, -0.99999999939832],
        tau=[-0.09600965153009966, 0.011511290887055381, 0.23679162487629002, -0.05970567037793373, -0.0481687781731277, -0.15696349852585967],
        w=[0.03356877366594205, 0.03502867011941798, 0.04570027844582663, 0.5192750606271793, 0.531035630686196, 1.7812208481530396],
    ),
    dict(
        tau_bar=[9.442608053008856, -0.25589803904282604, 7.557793089662987, -1.7998907637860462, -1.6629601039246884, -1.140594729214282],
        J=[-1.0459400829675867e-05, 0.29498088686834767, -0.06501911298907474, -1.4870218463443942e-06, -0.06499999990063972, 0.0, 0.4500026288519985, 6.748391754630918e-06, -1.4874673767752164e-06, 0.06499999998278226, -1.4870301258312178e-06, 0.0, 0.0, -0.3800026289735222, -0.3799967275805974, 1.6451676982661122e-07, 3.2719387313181388e-06, -0.0, 0.0, -2.287738647920199e-05, -2.287738647920199e-05, 0.9999999984733882, -2.2877259174529157e-05, -5.033757683312699e-05, 0.0, 0.9999999997383126, 0.9999999997383126, 2.2877386450263823e-05, 0.9999999997351123, 2.529875639765648e-06, 1.0, 0.0, 0.0, -5.0297601705991045e-05, 2.5310272281016936e-06, -0.999999998729864],
        tau=[-0.09600965153009966, 0.011511290887055381, 0.23679162487629002, -0.05970567037793373, -0.0481687781731277, -0.15696349852585967],
        w=[0.03356877366594205, 0.03502867011941798, 0.04570027844582663, 0.5192750606271793, 0.531035630686196, 1.7812208481530396],
    ),
]  # fmt: skip


@pytest.mark.parametrize("k", range(len(FACE_SAMPLES)))
def test_general_kernel_cold_path_on_an_optimal_face_matches_linprog(k):
    """The general kernel (``square=False``), cold on one sample, gives linprog's bounds to 1e-8
    where its primal active-set method ends on an optimal face rather than a vertex: the point
    is put back on the face's rows before its value is read (read off the face, it is 2e-5 N
    off)."""
    s = FACE_SAMPLES[k]
    tau = np.array(s["tau"])[None]
    prob = E.problem(
        np.array(s["tau_bar"])[None], np.array(s["J"]).reshape(1, 6, 6), tau, tau,
        1.0 / np.sqrt(np.array(s["w"]))[None], np.zeros(6), np.array([20.0] * 3 + [0.3] * 3),
    )  # fmt: skip
    lo, hi, st = _set_membership(prob, 0.95, square=False)
    assert st[0] == 0  # solved cold, with the prior box
    rl, rh = set_membership_reference(prob)
    np.testing.assert_allclose(np.r_[lo[0], hi[0]], np.r_[rl[0], rh[0]], rtol=0, atol=1e-8)

"""The causal estimate's per-sample path: what :class:`ditherlab.analysis.causal.CausalEstimator`
computes, one sample after the other in one compiled call per block.

The general update (:meth:`CausalEstimator.update` with ``fast=False``) rebuilds its inputs as
arrays over the kept past and runs the offline replay's functions on them: obviously the offline
estimator, and about 2 ms of Python and numpy overhead per update. This path keeps the same
quantities as state and computes each new sample from them:

- a history of the raw samples, the derived velocity and gravity (:class:`FastPath` ``hist``,
  the kept rows copied to its front when it fills), each window a slice of it summed oldest
  first, as :func:`ditherlab.core.timeseries.causal_mean` and the extraction's window sums add;
- the regime, the dither flag and the extraction from those windows, gravity's mean over the
  last dither period (what the dither variants subtract from the extracted signal:
  :func:`ditherlab.analysis.estimation.model_seen`), and the dither's ramp-in
  per joint (:func:`ditherlab.physics.dither.ramp_step`, its state carried from sample to
  sample, afresh after a gap);
- per dither variant the model's ``dither_extraction``: the Jacobian's rows scaled by its gain
  where the variant reads the extraction, and its lead (the variant's torque of ``k`` samples
  before kept in the history, :func:`ditherlab.analysis.estimation.extraction_lead`);
- per variant the bands, the reduced problem of eq. (3) for the one sample, and the estimator's
  own compiled kernels on it (the exact solver from the prior mean, the closed form of zero-width
  bands, the profile intervals and their reference fallback);
- gravity and the Jacobian from the robot's compiled kernels (one call each per block).

Every sample is computed from the state alone, so the result does not depend on how the stream
is cut into blocks (``replay --causal`` and ``live`` both run this path and agree bit for bit);
``tests/test_causal_fast.py`` compares it with the general update.

It covers the models and settings the live loop runs: profile intervals and a model without
effects or with ``dither_extraction`` alone (the demo's). :func:`supported` says why not
otherwise; the estimator then takes the general update (set-membership intervals solve linear
programs per component and side; a torque effect is evaluated on a recording).
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import numpy as np
from numba import njit, typeof

from ditherlab.analysis.estimation import lead_span
from ditherlab.core.errors import ConfigError
from ditherlab.core.names import DITHER, MOVING, STILL
from ditherlab.data.estimates import COMPONENTS
from ditherlab.data.torque_model import TorqueModel
from ditherlab.estimator.backends.exact import ExactWork, _solve_exact_loop, piece_work
from ditherlab.estimator.formulation import RIDGE, Samples, chi2_1_quantile
from ditherlab.estimator.interval_methods.gaussian import GaussWork, _gaussian_loop
from ditherlab.estimator.interval_methods.profile import (
    MAX_MAGNIFICATION,
    UNOBSERVABLE,
    ProfileOptions,
    ProfileOut,
    ProfileWork,
    _fast_loop,
    _profile_reference_kernel,
    _profile_work,
)
from ditherlab.physics.dither import PEAK_FACTOR, ramp_level, ramp_samples, ramp_state, ramp_step
from ditherlab.physics.effects.extraction import DitherExtraction, extraction_gain
from ditherlab.robot import RobotModel
from ditherlab.robot.tree import _gravity_kernel, _jacobian_kernel
from ditherlab.robot.tree import gravity as tree_gravity
from ditherlab.robot.tree import jacobian as tree_jacobian

__all__ = ["FastBlock", "FastParams", "FastPath", "fast_params", "supported"]

#: rows of a variant in the kernel's output: F (6), lo (6), hi (6)
VROWS = 18
#: the history's rows beyond the kept past (copied to its front every that many samples)
SPARE = 1024
#: the dither flag's modes: none, the stream's flag, the feedforward's range
ON_NONE, ON_FLAG, ON_FFW = 0, 1, 2

_STILL, _DITHER, _MOVING = int(STILL), int(DITHER), int(MOVING)


class FastParams(NamedTuple):
    """What the kernel computes with, fixed before the first sample.

    Attributes
    ----------
    bands : (12, n) [N·m, N·m·s/rad]: ``still`` ``tau_min, tau_max, sigma``; ``moving``
        ``tau_min, tau_max, sigma, coulomb, viscous`` (zeros for a missing term); ``dither``
        ``tau_min, tau_max, sigma``; the amplitude that ends the dither's ramp-in
        (:func:`ditherlab.physics.dither.ramp_level`, zeros without one)
    has : (2,) bool: the model has a ``moving`` band, a ``dither`` band
    gain : (n,) the drive gains scaling ``J^T`` rows (:func:`ditherlab.physics.effects.force_gain`)
    prior : (2, 6) [N, N·m]: ``prior_mean``, ``prior_sigma``
    free, held : the estimated and the held components (indices into 6)
    p_true : (m,) the estimated components' prior weights (0: no prior, the ridge instead)
    ints : int64 ``[move window, period window, extraction window, dither mode, square wave,
        kept rows, longest ramp-in, the extraction lead's span k (0: no lead)]`` [samples]
    floats : ``[period mean length [samples], peak factor, gap [s], chi2 threshold, moving
        threshold [rad/s], feedforward on [N·m]]``
    variants : (V,) int64: bit 0 a dither variant, bit 1 a no-band variant
    lead : (3, n): the model's ``dither_extraction`` per joint: its gain [-] (1 on joints it
        does not name; :func:`ditherlab.analysis.estimation.extraction_jacobian`), the lead's
        ``d_j / k`` [-] and 1.0 on the joints it names
        (:func:`ditherlab.analysis.estimation.extraction_lead`; zeros without the effect)
    """

    bands: np.ndarray
    has: np.ndarray
    gain: np.ndarray
    prior: np.ndarray
    free: np.ndarray
    held: np.ndarray
    p_true: np.ndarray
    ints: np.ndarray
    floats: np.ndarray
    variants: np.ndarray
    lead: np.ndarray


class FastBlock(NamedTuple):
    """New samples as the kernel takes them (time first; an absent quantity has 0 rows).

    Attributes
    ----------
    t : (N,) [s] ; q, tau : (N, n) [rad], [N·m] ; dq : (N, n) [rad/s] or (0, n)
    on : (N,) bool or (0,) ; ffw : (N, n) [N·m] or (0, n)
    g : (N, n) [N·m] gravity ; J : (N, 6, n) the tool-point Jacobians (not yet scaled by the gains)
    """

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    dq: np.ndarray
    on: np.ndarray
    ffw: np.ndarray
    g: np.ndarray
    J: np.ndarray


class Feats(NamedTuple):
    """One sample's causal quantities (scratch of the kernel).

    Attributes
    ----------
    reg : (n,) int8 regimes ; dqm : (n,) [rad/s] the velocity's mean over a dither period
    ext : (4, n) [N·m]: the extraction's upper and lower means, signal, amplitude
    flags : (2,) bool: the dither on, on over a whole period (the extraction valid)
    ramp : (n,) bool: the joints in the dither's ramp-in
    gm : (n,) [N·m] gravity's mean over a dither period: gravity as the extraction shows it
    """

    reg: np.ndarray
    dqm: np.ndarray
    ext: np.ndarray
    flags: np.ndarray
    ramp: np.ndarray
    gm: np.ndarray


def supported(model: TorqueModel, interval: str) -> str | None:
    """Why the per-sample path cannot run a model and interval method (None when it can): it
    runs profile intervals and a model without effects or with ``dither_extraction`` alone."""
    if interval != "profile":
        return f"{interval} intervals"
    if any(spec.name != DitherExtraction.name for spec in model.effects):
        return "a model with effects other than dither_extraction"
    return None


# ------------------------------------------------------------------ the compiled kernel


@njit(cache=True)
def _validate(hist, st, blk):  # pragma: no cover - compiled
    """``(0, 0)``, or ``(1, k)`` when sample ``k``'s time is not after the previous one, or
    ``(2 + f, k)`` when quantity ``f`` (t, q, tau, dq, ffw) of sample ``k`` is not finite."""
    t = blk.t
    for k in range(len(t)):
        if k > 0 or st[3]:
            last = t[k - 1] if k > 0 else hist[st[0] - 1, 0]
            if not t[k] - last > 0.0:
                return 1, k
    for k in range(len(t)):
        if not math.isfinite(t[k]):
            return 2, k
    for f, x in enumerate((blk.q, blk.tau, blk.dq, blk.ffw)):
        for k in range(x.shape[0]):
            for j in range(x.shape[1]):
                if not math.isfinite(x[k, j]):
                    return 3 + f, k
    return 0, 0


@njit(cache=True, inline="always")
def _push(hist, st, blk, k, par):  # pragma: no cover - compiled
    """Append sample ``k`` of ``blk`` to the history (a gap starts afresh; a full history keeps
    its last rows); returns its row. Columns: ``t``, ``q``, ``tau``, ``dq``, ``ffw``, the flag,
    gravity."""
    n = blk.q.shape[1]
    cap, keep = hist.shape[0], par.ints[5]
    if st[0] == cap:
        for r in range(keep):
            for c in range(hist.shape[1]):
                hist[r, c] = hist[cap - keep + r, c]
        st[1] = max(st[1] - (cap - keep), 0)
        st[0] = keep
    i = st[0]
    t = blk.t[k]
    if st[3] and t - hist[i - 1, 0] > par.floats[2]:
        st[1] = i
        st[2] += 1
    s0 = st[1]
    hist[i, 0] = t
    for j in range(n):
        hist[i, 1 + j] = blk.q[k, j]
        hist[i, 1 + n + j] = blk.tau[k, j]
        if blk.dq.shape[0]:
            hist[i, 1 + 2 * n + j] = blk.dq[k, j]
        elif i > s0:
            hist[i, 1 + 2 * n + j] = (blk.q[k, j] - hist[i - 1, 1 + j]) / (t - hist[i - 1, 0])
        else:
            hist[i, 1 + 2 * n + j] = 0.0
        if blk.ffw.shape[0]:
            hist[i, 1 + 3 * n + j] = blk.ffw[k, j]
        hist[i, 2 + 4 * n + j] = blk.g[k, j]
    hist[i, 1 + 4 * n] = _dither_on(hist, s0, i, blk, k, par)
    st[0] = i + 1
    st[3] = 1
    return i


@njit(cache=True, inline="always")
def _dither_on(hist, s0, i, blk, k, par):  # pragma: no cover - compiled
    """1.0 where the dither is on at row ``i``: the flag, else the feedforward's range over the
    last period above the threshold on any joint; 0.0 without either."""
    mode = par.ints[3]
    if mode == ON_FLAG:
        return 1.0 if blk.on[k] else 0.0
    if mode == ON_NONE:
        return 0.0
    n = blk.q.shape[1]
    a = max(s0, i - par.ints[1] + 1)
    for j in range(n):
        c = 1 + 3 * n + j
        lo = hist[a, c]
        hi = hist[a, c]
        for r in range(a + 1, i + 1):
            lo = min(lo, hist[r, c])
            hi = max(hi, hist[r, c])
        if hi - lo > par.floats[5]:
            return 1.0
    return 0.0


@njit(cache=True, inline="always")
def _window_mean(hist, a, i, c):  # pragma: no cover - compiled
    """The mean of column ``c`` over rows ``a..i``, added oldest first."""
    s = 0.0
    for r in range(a, i + 1):
        s += hist[r, c]
    return s / (i + 1 - a)


@njit(cache=True)
def _features(hist, s0, i, par, f, rs):  # pragma: no cover - compiled
    """Row ``i``'s regimes, velocity mean, extraction, gravity's mean over a dither period and
    ramp-in into ``f`` (:class:`Feats`), the rows since ``s0`` its past; ``rs`` the ramp-in's
    state (:func:`ditherlab.physics.dither.ramp_state`)."""
    n = len(f.reg)
    wm, P = par.ints[0], par.ints[1]
    on = hist[i, 1 + 4 * n] != 0.0
    full = i - s0 >= P - 1
    for r in range(max(s0, i - P + 1), i + 1):
        full = full and hist[r, 1 + 4 * n] != 0.0
    f.flags[0] = on
    f.flags[1] = full
    for j in range(n):
        c = 1 + 2 * n + j
        moving = abs(_window_mean(hist, max(s0, i - wm + 1), i, c)) > par.floats[4]
        f.reg[j] = _MOVING if moving else (_DITHER if on else _STILL)
        f.dqm[j] = _window_mean(hist, max(s0, i - P + 1), i, c)
        if par.ints[2] > 0:
            _extract(hist, s0, i, 1 + n + j, par, f.ext[:, j])
            f.gm[j] = _window_mean(hist, max(s0, i - P + 1), i, 2 + 4 * n + j)
    if par.ints[2] > 0:
        ramp_step(on, full, f.ext[3], par.bands[11], par.ints[6], rs, f.ramp)
    else:
        f.ramp[:] = False
    return on


@njit(cache=True, inline="always")
def _extract(hist, s0, i, c, par, e):  # pragma: no cover - compiled
    """The dither extraction of column ``c`` at row ``i`` into ``e`` (4,): the means above and
    below the window's mean, the signal, the amplitude (:func:`ditherlab.physics.dither.extract`)."""
    a = max(s0, i - par.ints[2] + 1)
    ctr = _window_mean(hist, a, i, c)
    sa, sb, na, nb = 0.0, 0.0, 0, 0
    for r in range(a, i + 1):
        v = hist[r, c]
        if v > ctr:
            sa += v
            na += 1
        elif v < ctr:
            sb += v
            nb += 1
    up = sa / na if na > 0 else ctr
    low = sb / nb if nb > 0 else ctr
    e[0], e[1] = up, low
    if par.ints[4]:
        e[2] = 0.5 * (up + low)
    else:
        L = par.floats[0]
        m = int(np.floor(L))
        if i - s0 < m:
            e[2] = _window_mean(hist, s0, i, c)
        else:
            s = (L - m) * hist[i - m, c]
            for r in range(i - m + 1, i + 1):
                s += hist[r, c]
            e[2] = s / L
    amp = 0.5 * (up - low)
    e[3] = amp if par.floats[1] == 1.0 else par.floats[1] * amp


@njit(cache=True, inline="always")
def _sliding(bands, j, v):  # pragma: no cover - compiled
    """The moving band's sliding line at velocity ``v`` [rad/s] of joint ``j`` [N·m]."""
    return 0.0 + bands[6, j] * np.sign(v) + bands[7, j] * v


@njit(cache=True)
def _variant_inputs(code, tau, g, dq, par, f, out):  # pragma: no cover - compiled
    """One variant's ``tau_bar, tau_min, tau_max, sigma`` (each (n,) [N·m]) of one sample into
    ``out`` (4, n) (:func:`ditherlab.analysis.estimation.variant_inputs`)."""
    B = par.bands
    dith = code & 1 and par.ints[2] > 0
    for j in range(len(tau)):
        tb, a, b, s = tau[j] - g[j] - 0.0, B[0, j], B[1, j], B[2, j]
        if f.reg[j] == _MOVING and par.has[0]:
            sl = _sliding(B, j, dq[j])
            a, b, s = B[3, j] + sl, B[4, j] + sl, B[5, j]
        if dith and f.reg[j] == _DITHER and f.flags[1] and not f.ramp[j]:
            tb = f.ext[2, j] - f.gm[j]
            if par.has[1]:
                a, b, s = B[8, j], B[9, j], B[10, j]
            else:
                A = max(f.ext[3, j], 0.0)
                mid = 0.5 * (a + b)
                a, b = min(a + A, mid), max(b - A, mid)
        if (
            dith
            and par.has[0]
            and f.reg[j] == _MOVING
            and f.flags[1]
            and f.flags[0]
            and not f.ramp[j]
        ):
            sl = _sliding(B, j, f.dqm[j])
            tb = f.ext[2, j] - f.gm[j]
            a, b, s = B[3, j] + sl, B[4, j] + sl, B[5, j]
        if code & 2:
            ctr = 0.5 * (a + b)
            s = np.sqrt(s**2 + (b - a) ** 2 / 12.0)
            a, b = ctr, ctr
        out[0, j], out[1, j], out[2, j], out[3, j] = tb, a, b, s


@njit(cache=True, inline="always")
def _reads(hist, i, par, f):  # pragma: no cover - compiled
    """Where a dither variant reads the extraction at row ``i``, per joint, into the history's
    use columns (:func:`ditherlab.analysis.estimation.reads_extraction`: the dither on over a
    whole window, the joint in the dither regime or moving, out of its ramp-in)."""
    n, V = len(f.reg), len(par.variants)
    c0 = 2 + 5 * n + V * n
    for j in range(n):
        r = f.reg[j] == _DITHER or f.reg[j] == _MOVING
        use = r and f.flags[1] and f.flags[0] and not f.ramp[j]
        hist[i, c0 + j] = 1.0 if use else 0.0


@njit(cache=True, inline="always")
def _lead(hist, s0, i, v, par, vin, sc):  # pragma: no cover - compiled
    """Dither variant ``v``'s torque ``vin[0]`` (n,) [N·m] at row ``i`` kept in the history,
    then moved forward by the extraction's delay where row ``i`` and the row ``k`` before it
    (since ``s0``) read the extraction, and the Jacobian's scale ``sc`` (n,) set to the
    extraction's gain where row ``i`` reads it
    (:func:`ditherlab.analysis.estimation.extraction_lead`, ``extraction_jacobian``)."""
    n, V, k = vin.shape[1], len(par.variants), par.ints[7]
    cv, cu = 2 + 5 * n + v * n, 2 + 5 * n + V * n
    for j in range(n):
        tb = vin[0, j]
        hist[i, cv + j] = tb
        use = hist[i, cu + j] != 0.0
        sc[j] = par.lead[0, j] if use else 1.0
        if k > 0 and par.lead[2, j] != 0.0 and use and i - k >= s0 and hist[i - k, cu + j] != 0.0:
            vin[0, j] = tb + (tb - hist[i - k, cv + j]) * par.lead[1, j]


@njit(cache=True)
def _problem(vin, J, sc, par, S):  # pragma: no cover - compiled
    """Eq. (3) of one sample reduced to the estimated components into ``S`` (a one-sample
    :class:`~ditherlab.estimator.formulation.Samples`), as
    :func:`ditherlab.estimator.problem` reduces it; ``vin`` (4, n) the variant's inputs,
    ``J`` (6, n) the Jacobian, ``sc`` (n,) its rows' scale beyond the drive gains (the
    extraction's gain, :func:`_lead`)."""
    n = vin.shape[1]
    fb = par.prior[0]
    for j in range(n):
        held = 0.0
        for h in par.held:
            held += J[h, j] * par.gain[j] * sc[j] * fb[h]
        S.tau_bar[0, j] = vin[0, j] - held if len(par.held) else vin[0, j]
        S.tau_min[0, j] = vin[1, j]
        S.tau_max[0, j] = vin[2, j]
        S.w[0, j] = 1.0 / vin[3, j] ** 2
    info = 0.0
    for r, i in enumerate(par.free):
        row = 0.0
        for j in range(n):
            S.J[0, r, j] = J[i, j] * par.gain[j] * sc[j]
            row += S.J[0, r, j] ** 2 * S.w[0, j]
        info += row
    m = len(par.free)
    scale = info / m
    scale = scale if scale > 0 else 1.0
    for r in range(m):
        S.p[0, r] = par.p_true[r] if par.p_true[r] > 0 else RIDGE * scale


class Work(NamedTuple):
    """The estimator kernels' scratch for one sample, made once per block.

    Attributes
    ----------
    exact : :class:`~ditherlab.estimator.backends.exact.ExactWork` ; gauss : the closed form's
        :class:`~ditherlab.estimator.interval_methods.gaussian.GaussWork` ; profile : the profile
        intervals' :class:`~ditherlab.estimator.interval_methods.profile.ProfileWork`
    half : (1, m) [N, N·m] half-widths ; active : (1, n) bool ; it, seg : (1,) int64 ;
        mag : (1,) ; opts : the :class:`ProfileOptions`
    """

    exact: ExactWork
    gauss: GaussWork
    profile: ProfileWork
    half: np.ndarray
    active: np.ndarray
    it: np.ndarray
    seg: np.ndarray
    mag: np.ndarray
    opts: ProfileOptions


@njit(cache=True)
def _work(m, n, par):  # pragma: no cover - compiled
    """A :class:`Work` for ``m`` components and ``n`` joints."""
    exact = ExactWork(
        piece_work(m, n), np.empty(m), np.empty(m), np.zeros(n, np.int8), np.zeros(n, np.int8),
        np.zeros(n, np.int8), np.empty(m), np.empty(n), np.empty(n), np.empty(2 * n + 1),
    )  # fmt: skip
    gauss = GaussWork(
        np.empty((m, m)), np.empty((m, m)), piece_work(m, n), np.empty(m), np.empty(m),
        np.ones(n, np.int8),
    )  # fmt: skip
    opts = ProfileOptions(par.floats[3], par.p_true == 0.0, UNOBSERVABLE, MAX_MAGNIFICATION)
    return Work(
        exact, gauss, _profile_work(m, n, 4 * n + 8), np.empty((1, m)), np.zeros((1, n), np.bool_),
        np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1), opts,
    )  # fmt: skip


@njit(cache=True)
def _estimate(S, ws, closed, F, lo, hi):  # pragma: no cover - compiled
    """The estimate ``F (1, m)`` [N, N·m] and profile interval ``lo, hi (1, m)`` of a
    one-sample problem ``S`` (``closed``: zero-width bands, every component with a prior: the
    closed form), on the scratch ``ws`` (:class:`Work`); returns the active joints' bits."""
    n = S.w.shape[1]
    if closed:
        _gaussian_loop(S, ws.opts.threshold, True, F, ws.half, ws.active, ws.gauss)
        for r in range(F.shape[1]):
            lo[0, r] = F[0, r] - ws.half[0, r]
            hi[0, r] = F[0, r] + ws.half[0, r]
    else:
        _solve_exact_loop(S, 100, False, F, ws.it, ws.exact)
        ws.seg[0] = 0
        ws.mag[0] = 0.0
        _fast_loop(S, F, ws.opts, ProfileOut(lo, hi, ws.seg, ws.mag), ws.profile)
        if ws.seg[0] < 0:  # handed back: the reference path (as the batch intervals do)
            ws.seg[0] = 0
            _profile_reference_kernel(S, F, ws.opts, ProfileOut(lo, hi, ws.seg, ws.mag))
    bits = 0
    for j in range(n):
        r = S.tau_bar[0, j]
        for i in range(F.shape[1]):
            r -= S.J[0, i, j] * F[0, i]
        if r - min(max(r, S.tau_min[0, j]), S.tau_max[0, j]) != 0.0:
            bits += 1 << j
    return bits


@njit(cache=True)
def _write(par, row, k, F, lo, hi, out):  # pragma: no cover - compiled
    """A variant's rows of sample ``k`` in ``out``: the full wrench and its bounds (held
    components at the prior mean)."""
    for c in range(6):
        out[row + c, k] = par.prior[0, c]
        out[row + 6 + c, k] = par.prior[0, c]
        out[row + 12 + c, k] = par.prior[0, c]
    for r, c in enumerate(par.free):
        out[row + c, k] = F[0, r]
        out[row + 6 + c, k] = lo[0, r]
        out[row + 12 + c, k] = hi[0, r]


@njit(cache=True)
def _run(hist, st, rs, blk, par, out, act):  # pragma: no cover - compiled
    """Every sample of ``blk`` (:class:`FastBlock`) in time order into the columns ``out``
    (rows: per variant :data:`VROWS`, the extraction's ``upper, lower, signal`` per joint with
    a dither period, whether any joint moves) and ``act`` (V, N) int64, the variants' active
    joints as bits; ``hist``, ``st`` (next row, first row since the last gap, gaps, any sample
    seen) and ``rs`` (the ramp-in's) the state. Returns :func:`_validate`'s code; nothing is
    changed unless it is 0."""
    code = _validate(hist, st, blk)
    if code[0] != 0:
        return code
    n, m, V = blk.q.shape[1], len(par.free), len(par.variants)
    f = Feats(
        np.empty(n, np.int8), np.empty(n), np.empty((4, n)), np.zeros(2, np.bool_),
        np.zeros(n, np.bool_), np.zeros(n),
    )  # fmt: skip
    S = Samples(
        np.empty((1, n)), np.empty((1, m, n)), np.empty((1, n)), np.empty((1, n)),
        np.empty((1, n)), np.empty((1, m)), par.prior[0][par.free].copy(),
    )  # fmt: skip
    vin, sc, ones = np.empty((4, n)), np.ones(n), np.ones(n)
    F, lo, hi = np.empty((1, m)), np.empty((1, m)), np.empty((1, m))
    ws = _work(m, n, par)
    closed_ok = (par.p_true > 0.0).all()
    for k in range(len(blk.t)):
        i = _push(hist, st, blk, k, par)
        if i == st[1]:  # the first sample, or after a gap: no ramp-in seen
            rs[:] = -1
        _features(hist, st[1], i, par, f, rs)
        _reads(hist, i, par, f)
        for v in range(V):
            code_v = par.variants[v]
            _variant_inputs(code_v, blk.tau[k], blk.g[k], hist[i, 1 + 2 * n :], par, f, vin)
            dith = code_v & 1 and par.ints[2] > 0
            if dith:
                _lead(hist, st[1], i, v, par, vin, sc)
            _problem(vin, blk.J[k], sc if dith else ones, par, S)
            act[v, k] = _estimate(S, ws, code_v & 2 and closed_ok, F, lo, hi)
            _write(par, v * VROWS, k, F, lo, hi, out)
        if par.ints[2] > 0:
            for j in range(n):
                for c in range(3):
                    out[V * VROWS + 3 * j + c, k] = f.ext[c, j]
        moving = False
        for j in range(n):
            moving = moving or f.reg[j] == _MOVING
        out[out.shape[0] - 1, k] = moving
    return 0, 0


# ------------------------------------------------------------------ the state around it


def fast_params(
    model: TorqueModel, settings, comps: list[str], gain: np.ndarray, thresholds: tuple
) -> FastParams:
    """The kernel's :class:`FastParams` of a model, the causal settings
    (:class:`ditherlab.analysis.causal.CausalSettings`), the estimated components, the drive
    gains (n,) and ``thresholds``: the mean velocity above which a joint moves [rad/s], the
    feedforward range above which the dither is on [N·m]."""
    MOVING_THRESHOLD, FFW_ON = thresholds
    win, per = settings.windows(), settings.period
    mv, db = model.regimes.get("moving"), model.regimes.get("dither")
    psig = np.asarray(model.prior_sigma, dtype=float)
    free = np.array([i for i, c in enumerate(COMPONENTS) if c in comps and psig[i] > 0], np.int64)
    with np.errstate(divide="ignore"):
        p_true = np.where(np.isinf(psig[free]), 0.0, 1.0 / psig[free] ** 2)
    W_ext = 0 if per is None else max(2, int(round(per / settings.dt)))
    L = 1.0 if per is None else max(1.0, per / settings.dt)
    keep = max(win["move"], win["period"], W_ext, int(np.floor(L)) + 1, 2) + 2
    codes = [int(v.startswith("dither")) | 2 * int(v.endswith("noband")) for v in settings.variants]
    lead, k = _lead_params(model, win["period"] if per is not None else 0)
    return FastParams(
        bands=_band_rows(model),
        has=np.array([mv is not None, db is not None]),
        gain=np.ascontiguousarray(gain, dtype=float),
        prior=np.array([model.prior_mean, psig], float),
        free=free,
        held=np.setdiff1d(np.arange(6), free).astype(np.int64),
        p_true=p_true,
        ints=np.array(
            [
                win["move"],
                win["period"],
                W_ext,
                ON_NONE,
                settings.waveform == "square",
                keep,
                ramp_samples(1.0 / settings.dt),
                k,
            ],
            np.int64,
        ),  # fmt: skip
        floats=np.array(
            [
                L,
                PEAK_FACTOR[settings.waveform],
                0.0,
                chi2_1_quantile(settings.level),
                MOVING_THRESHOLD,
                FFW_ON,
            ]
        ),  # fmt: skip
        variants=np.array(codes, np.int64),
        lead=lead,
    )


def _band_rows(model: TorqueModel) -> np.ndarray:
    """:attr:`FastParams.bands` (12, n) of a model."""
    zero = np.zeros(model.n)
    still, mv, db = (model.regimes.get(k) for k in ("still", "moving", "dither"))
    mv_rows = [zero] * 5 if mv is None else [mv.tau_min, mv.tau_max, mv.sigma]
    if mv is not None:
        mv_rows += [zero if x is None else x for x in (mv.coulomb, mv.viscous)]
    db_rows = [zero] * 3 if db is None else [db.tau_min, db.tau_max, db.sigma]
    level = ramp_level(model)
    rows = [still.tau_min, still.tau_max, still.sigma, *mv_rows, *db_rows]
    return np.array([*rows, zero if level is None else level], float)


def _lead_params(model: TorqueModel, window: int) -> tuple[np.ndarray, int]:
    """:attr:`FastParams.lead` (3, n) of a model and the lead's span ``k`` [samples] (0
    without ``dither_extraction`` or without dither: ``window`` 0), as
    :func:`ditherlab.analysis.estimation.extraction_lead` computes them for a dither period of
    ``window`` samples."""
    n = model.n
    gain = extraction_gain(model.effects, n)
    lags = extraction_gain(model.effects, n, "lag")
    out = np.zeros((3, n))
    out[0] = 1.0 if gain is None else gain
    if lags is None or window == 0:
        return out, 0
    k = lead_span(window)
    for spec in model.effects:
        if spec.name == DitherExtraction.name:
            for jj in spec.joints:
                out[2, jj - 1] = 1.0
    for j in np.flatnonzero(out[2]):
        out[1, j] = ((window - 1) / 2 + lags[j]) / k
    return out, k


def compiled(dispatcher, *args):
    """The compiled function of the numba ``dispatcher`` for the types of ``args`` (compiled, or
    read from numba's cache, here). Called directly it skips numba's dispatch on the argument
    types (about 0.4 us per array: 10-20 us per update with the arrays of a block, the
    parameters and the robot's tree); the caller passes arrays of exactly these types (C
    contiguous, writable, the same dtypes and dimensions)."""
    sig = tuple(typeof(a) for a in args)
    dispatcher.compile(sig)
    entry = getattr(dispatcher.overloads.get(sig), "entry_point", None)
    return dispatcher if entry is None else entry  # numba's dispatch where it has no entry


def _kinematics(robot: RobotModel, n: int):
    """``fill(q (N, n) [rad], g (N, n), J (N, 6, n))``: gravity [N·m] and the tool-point
    Jacobian, by the robot's compiled tree kernels called directly when it has them
    (:mod:`ditherlab.robot.tree`), else by its kernels (:meth:`RobotModel.evaluate`'s)."""
    kern = robot._kernels_cache  # what RobotModel.evaluate runs, without its checks and cache
    fg, fj = kern["gravity"][0], kern["jacobian"][0]
    if (
        isinstance(fg, partial) and fg.func is tree_gravity
        and isinstance(fj, partial) and fj.func is tree_jacobian
    ):  # fmt: skip
        q, g, J = np.empty((1, n)), np.empty((1, n)), np.empty((1, 6, n))
        eg = compiled(_gravity_kernel, fg.args[0], q, g)
        ej = compiled(_jacobian_kernel, fj.args[0], q, J)
        tg, tj = fg.args[0], fj.args[0]

        def fill(q, g, J):
            eg(tg, q, g)
            ej(tj, q, J)

        return fill

    def fill_general(q, g, J):
        with robot._lock:  # pinocchio's Data is shared scratch space
            qs = robot.pin_configuration(q)
            fg(qs, g)
            fj(qs, J)

    return fill_general


def as_kernel(x: Any, shape: tuple[int, ...], dtype: type = float) -> np.ndarray:
    """``x`` as a C-contiguous, writable array of ``dtype`` and ``shape`` (copied only when it
    is not one already): the types :func:`compiled` functions were made for (a read-only array,
    an Arrow-backed column, is a type of its own to numba)."""
    a = np.ascontiguousarray(x, dtype=dtype)
    if a.shape != shape:
        a = a.reshape(shape)
    return a if a.flags.writeable else a.copy()


class FastPath:
    """The per-sample path's state (module docstring): :meth:`run` takes checked samples and
    returns their estimates as rows.

    Parameters
    ----------
    par : :class:`FastParams` ; robot : the model's robot (gravity and Jacobian)
    gap : [s] a longer step starts afresh
    """

    def __init__(self, par: FastParams, robot: RobotModel, gap: float) -> None:
        self.par = par._replace(floats=par.floats.copy(), ints=par.ints.copy())
        self.par.floats[2] = gap
        self.robot = robot
        self.n = len(par.gain)
        keep = int(par.ints[5])
        V = len(par.variants)
        #: columns: t, q, tau, dq, ffw, the flag, gravity, per variant its torque, where the
        #: extraction is read (:func:`_push`, :func:`_lead`)
        self.hist = np.zeros((2 * keep + SPARE, 2 + 5 * self.n + (V + 1) * self.n))
        #: next row, first row since the last gap, gaps, whether any sample came
        self.st = np.zeros(4, np.int64)
        #: the dither's ramp-in (:func:`ditherlab.physics.dither.ramp_state`)
        self.rs = ramp_state(self.n)
        self.present: tuple[bool, ...] | None = None
        V, ext = len(par.variants), 3 * self.n if par.ints[2] > 0 else 0
        self.rows = V * VROWS + ext + 1
        self.kinematics = _kinematics(robot, self.n)
        self._entry: dict[tuple[bool, ...], Any] = {}

    @property
    def gaps(self) -> int:
        """Gaps in the stream so far."""
        return int(self.st[2])

    def run(self, t, q, tau, dq, on, ffw) -> tuple[np.ndarray, np.ndarray]:
        """The estimates of new samples (``t`` (N,) [s], ``q``, ``tau``, ``dq``, ``ffw`` (N, n),
        ``on`` (N,) bool; ``dq``, ``on``, ``ffw`` None when absent; C-contiguous writable float
        arrays, as :func:`as_kernel` makes them) as rows (:func:`_run`);
        ConfigError for a time not after the last one, a value that is not finite, or a quantity
        given for some samples only."""
        present = (dq is not None, on is not None, ffw is not None)
        if self.present is None:
            self.present = present
            mode = ON_FLAG if on is not None else ON_FFW if ffw is not None else ON_NONE
            self.par.ints[3] = mode
        elif present != self.present:
            k = ("dq", "dither", "ffw")[int(np.argmax(np.array(present) != self.present))]
            raise ConfigError(
                f"the stream's {k} is given for some samples only; "
                "expected it for every sample or for none"
            )
        N, n = len(t), self.n
        g, J = np.empty((N, n)), np.empty((N, 6, n))
        self.kinematics(q, g, J)
        none2, none1 = np.empty((0, n)), np.empty(0, np.bool_)
        blk = FastBlock(
            t, q, tau, none2 if dq is None else dq, none1 if on is None else on,
            none2 if ffw is None else ffw, g, J,
        )  # fmt: skip
        out = np.empty((self.rows, N))
        act = np.empty((len(self.par.variants), N), np.int64)
        run = self._entry.get(present)
        if run is None:
            args = (self.hist, self.st, self.rs, blk, self.par, out, act)
            run = self._entry[present] = compiled(_run, *args)
        code, k = run(self.hist, self.st, self.rs, blk, self.par, out, act)
        if code:
            self._raise(code, k, t)
        return out, act

    def _raise(self, code: int, k: int, t: np.ndarray) -> None:
        """The ConfigError of :func:`_validate`'s ``code`` at sample ``k`` of times ``t``."""
        if code == 1:
            last = t[k - 1] if k > 0 else self.hist[self.st[0] - 1, 0]
            raise ConfigError(
                f"sample time {t[k]!r} s is not after the previous one "
                f"({last!r} s); expected strictly increasing times"
            )
        name = ("t", "q", "tau", "dq", "tau_ffw")[code - 2]
        raise ConfigError(f"{name} at t = {t[0]:.6f} s is not finite; expected numbers")

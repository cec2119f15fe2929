"""Identify the disturbance model of eq. (3) from recordings with a reference F/T sensor.

Per joint and regime the friction residual

``rho = tau - tau_grav(q) - effects_torque - external_torque(sensor_wrench)``   [N·m]

is modelled as a uniform band ``[a, b]`` plus Gaussian noise ``N(0, sigma^2)`` (the paper's §II),
whose density is ``[Phi((x - a)/sigma) - Phi((x - b)/sigma)] / (b - a)``, and fitted by maximum
likelihood. Regimes (:func:`ditherlab.recording.regimes`):

- ``still``: the joint stands still without dither; ``rho`` from the raw torque.
- ``dither``: the joint stands still while the dither is on. ``rho`` is taken from the **extracted**
  torque signal (paper §IV-A: per dither period, the mean of the upper and lower means; see
  :func:`ditherlab.replay.extract_dither`), not from the raw square wave: the fitted band is then
  the effective band of the extracted signal, which is exactly what the dither variants of the
  estimator use (:mod:`ditherlab.replay`). On the raw torque the band would be the full friction
  band plus the square wave, which the estimator never sees.
- ``moving``: the joint moves; ``rho = coulomb·sign(dq) + viscous·dq + u`` with ``(coulomb,
  viscous)`` by least squares and the remainder ``u`` fitted by the band-plus-noise model, so the
  moving band is centred on the sliding friction.

``R_e = diag(sigma^2)`` per regime. Every parameter carries a standard error from a seeded block
bootstrap: the samples are cut into blocks of ``block`` seconds (per recording), blocks are
resampled with replacement, and the fit is repeated. Neighbouring samples at 250 Hz are far from
independent (the friction state persists between pushes), so the Fisher information of all samples
would be far too optimistic; whole blocks are.

The likelihood is evaluated on a fine histogram of ``rho`` (bins of sigma / 8, at most 4096; the
binning adds ``width^2/12`` to the variance, Sheppard), which makes each fit and each bootstrap
replicate cost the same few milliseconds whatever the length of the recording.

How sigma and the edges are fitted, and why (details in :func:`fit_band`): sigma comes from
lagged differences of the residual (the friction state persists, the noise does not), then the
band edges by maximum likelihood of the uniform-plus-Gaussian density at that sigma, with two
point masses at the edges added to the uniform part (a push beyond the band leaves the friction
exactly on an edge). The joint maximum likelihood of all three is available (``sigma="ml"``,
``edges=False``) and is what the plain model of the paper prescribes; on push campaigns it is
misspecified and was measured to be off by several standard errors (see :func:`fit_band`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import optimize
from scipy.special import expit, log_ndtr

from ditherlab.errors import ConfigError, ModelError, RecordingError
from ditherlab.model import Band, TorqueModel
from ditherlab.recording import DITHER, MOVING, STILL, Recording, regimes

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)
N_BINS = 4096


# ---------------------------------------------------------------------------- the density
def band_noise_logpdf(x: np.ndarray, a: float, b: float, sigma: float) -> np.ndarray:
    """Log density of ``U[a, b] + N(0, sigma^2)`` at ``x``.

    Parameters
    ----------
    x : (M,) [N·m]
    a, b : band edges [N·m], ``a <= b``
    sigma : noise standard deviation [N·m], > 0

    Returns
    -------
    (M,) log density [log 1/(N·m)]; for ``b - a`` below ``1e-9·sigma`` the Gaussian limit.
    """
    x = np.asarray(x, dtype=float)
    w = b - a
    if w <= 1e-9 * sigma:
        z = (x - 0.5 * (a + b)) / sigma
        return -0.5 * z * z - _LOG_SQRT_2PI - np.log(sigma)
    return _log_diff_cdf((x - a) / sigma, (x - b) / sigma) - np.log(w)


def _log_diff_cdf(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """log(Phi(u) - Phi(v)) for u > v, stable in both tails (uses Phi(-v) - Phi(-u) on the right)."""
    flip = (u + v) > 0
    hi = np.where(flip, -v, u)
    lo = np.where(flip, -u, v)
    lh = log_ndtr(hi)
    ll = log_ndtr(lo)
    d = np.minimum(ll - lh, -1e-300)
    with np.errstate(divide="ignore"):
        out = lh + np.log1p(-np.exp(d))
    # u - v below the float resolution of the CDFs: the midpoint rule phi((u + v)/2) (u - v)
    close = d > -1e-10
    if np.any(close):
        mid = 0.5 * (u + v)
        with np.errstate(divide="ignore"):
            approx = -0.5 * mid * mid - _LOG_SQRT_2PI + np.log(np.maximum(u - v, 0.0))
        out = np.where(close, approx, out)
    return out


def _nll_and_grad(theta: np.ndarray, x: np.ndarray, wts: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted negative log-likelihood per unit weight and its gradient in (c, h, log sigma)."""
    c, h, ls = theta
    s = np.exp(ls)
    a, b = c - h, c + h
    u = (x - a) / s
    v = (x - b) / s
    logd = _log_diff_cdf(u, v)
    w = 2.0 * h
    wsum = wts.sum()
    nll = -(wts @ logd) / wsum + np.log(w)
    # phi(u) / D and phi(v) / D in log space
    ru = np.exp(-0.5 * u * u - _LOG_SQRT_2PI - logd)
    rv = np.exp(-0.5 * v * v - _LOG_SQRT_2PI - logd)
    dl_da = -ru / s  # d log D / d a
    dl_db = rv / s
    dl_ds = (-u * ru + v * rv) / s
    g_a = -(wts @ dl_da) / wsum - 1.0 / w
    g_b = -(wts @ dl_db) / wsum + 1.0 / w
    g_s = -(wts @ dl_ds) / wsum
    grad = np.array([g_a + g_b, -g_a + g_b, g_s * s])
    return float(nll), grad


@dataclass(frozen=True)
class BandFit:
    """Maximum-likelihood fit of ``U[a, b] + N(0, sigma^2)`` to one residual.

    Attributes
    ----------
    a, b : band edges [N·m]
    sigma : noise standard deviation [N·m]
    se_a, se_b, se_sigma : bootstrap standard errors [N·m] (NaN without a bootstrap)
    n : number of samples fitted
    nll : negative log-likelihood per sample at the optimum
    """

    a: float
    b: float
    sigma: float
    se_a: float = float("nan")
    se_b: float = float("nan")
    se_sigma: float = float("nan")
    n: int = 0
    nll: float = float("nan")


def _histogram(x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Bin index per sample and bin centres; bins of about ``width`` [N·m], 64 to N_BINS of them."""
    lo, hi = float(x.min()), float(x.max())
    if hi - lo <= 1e-12 * max(1.0, abs(lo)):
        hi = lo + 1e-9
    nb = int(np.clip(np.ceil((hi - lo) / max(width, 1e-300)), 64, N_BINS))
    edges = np.linspace(lo, hi, nb + 1)
    idx = np.clip(((x - lo) / (hi - lo) * nb).astype(np.int64), 0, nb - 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    return idx, centres


def sigma_from_differences(x: np.ndarray, lag: int = 1, blocks: np.ndarray | None = None) -> float:
    """Noise level from lagged differences: ``MAD(x[k + lag] - x[k]) / 0.6745 / sqrt(2)``.

    The friction part of a residual at rest is piecewise constant (it changes only while a push
    moves it), so it cancels in differences and what remains is the Gaussian noise. ``lag`` is the
    correlation length of that noise: 1 for a raw torque, one dither period for an extracted
    signal (a one-period running mean). Differences across ``blocks`` boundaries are skipped.

    Parameters
    ----------
    x : (M,) [N·m]
    lag : samples
    blocks : (M,) labels, optional

    Returns
    -------
    sigma [N·m] (> 0)
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    lag = max(int(lag), 1)
    if len(x) <= lag + 2:
        return float(max(np.std(x), 1e-9))
    d = x[lag:] - x[:-lag]
    if blocks is not None:
        b = np.asarray(blocks).reshape(-1)
        d = d[b[lag:] == b[:-lag]]
    if len(d) == 0:
        return float(max(np.std(x), 1e-9))
    mad = float(np.median(np.abs(d - np.median(d)))) / 0.6745 / np.sqrt(2.0)
    if mad <= 0:
        mad = float(np.std(d)) / np.sqrt(2.0)
    return max(mad, 1e-9)


def _nll_mix(theta: np.ndarray, x: np.ndarray, wts: np.ndarray) -> tuple[float, np.ndarray]:
    """NLL per unit weight, and gradient, of the band with two atoms, convolved with the noise.

    ``theta = (c, h, log sigma, eta_a, eta_b, zeta_a, zeta_b)``: band ``[a, b] = [c - h, c + h]``;
    mixture weights ``softmax(0, eta_a, eta_b)`` of the uniform part and of two point masses at
    ``a + h·S(zeta_a)`` and ``b - h·S(zeta_b)`` (``S`` the logistic function), i.e. each atom
    lies between its edge and the band centre.
    """
    c, h, ls, ea, eb, za, zb = theta
    s = np.exp(ls)
    a, b = c - h, c + h
    w = 2.0 * h
    m = max(0.0, ea, eb)
    e = np.exp(np.array([0.0, ea, eb]) - m)
    pu, pa, pb = e / e.sum()
    sa = expit(za)
    sb = expit(zb)
    ca, cb = a + h * sa, b - h * sb
    u = (x - a) / s
    v = (x - b) / s
    ua = (x - ca) / s
    ub = (x - cb) / s
    lphi_u = -0.5 * u * u - _LOG_SQRT_2PI
    lphi_v = -0.5 * v * v - _LOG_SQRT_2PI
    t_u = np.log(max(pu, 1e-300)) + _log_diff_cdf(u, v) - np.log(w)
    t_a = np.log(pa) - 0.5 * ua * ua - _LOG_SQRT_2PI - ls if pa > 0 else np.full_like(x, -np.inf)
    t_b = np.log(pb) - 0.5 * ub * ub - _LOG_SQRT_2PI - ls if pb > 0 else np.full_like(x, -np.inf)
    top = np.maximum(np.maximum(t_u, t_a), t_b)
    logf = top + np.log(np.exp(t_u - top) + np.exp(t_a - top) + np.exp(t_b - top))
    wsum = wts.sum()
    nll = -(wts @ logf) / wsum
    ru = np.exp(t_u - logf)  # share of each part in the density
    ra = np.exp(t_a - logf)
    rb = np.exp(t_b - logf)
    phiu_U = np.exp(lphi_u - logf) * pu / w  # pu * phi(u) / (w f)
    phiv_U = np.exp(lphi_v - logf) * pu / w
    # d log f / d a, d b through the uniform part; d / d ca, d cb through the atoms
    da = -phiu_U / s + ru / w
    db = phiv_U / s - ru / w
    dca = ra * ua / s
    dcb = rb * ub / s
    ds = (-u * phiu_U + v * phiv_U) / s + ra * (ua * ua - 1) / s + rb * (ub * ub - 1) / s
    g = (
        np.array(
            [
                wts @ (da + db + dca + dcb),
                wts @ (db - da + dca * (sa - 1.0) + dcb * (1.0 - sb)),
                (wts @ ds) * s,
                wts @ (ra - pa),
                wts @ (rb - pb),
                (wts @ dca) * h * sa * (1.0 - sa),
                -(wts @ dcb) * h * sb * (1.0 - sb),
            ]
        )
        / -wsum
    )
    return float(nll), g


def _fit_weighted(
    centres: np.ndarray,
    wts: np.ndarray,
    start: tuple[float, ...],
    s_floor: float,
    fixed_sigma: bool = False,
    edges: bool = True,
) -> tuple[float, float, float, float, tuple[float, ...]]:
    """Maximise the binned likelihood; returns (a, b, sigma, nll per sample, start of the
    optimum for warm starts).

    ``start = (c, h, sigma[, eta_a, eta_b, zeta_a, zeta_b])``. ``edges`` adds the two atoms
    (see fit_band).
    """
    keep = wts > 0
    x, w = centres[keep], wts[keep].astype(float)
    c0, h0, s0 = start[:3]
    rest = tuple(start[3:7]) if len(start) >= 7 else (-2.0, -2.0, -4.0, -4.0)
    h0 = max(h0, 1e-6 * s0)
    # unconstrained coordinates: (c, log h, log sigma, eta_a, eta_b, zeta_a, zeta_b); BFGS
    # (L-BFGS-B in this scipy spent ~2 ms per iteration in its own bookkeeping, 5x the cost of
    # the likelihood here)
    full = np.array([c0, np.log(h0), np.log(max(s0, s_floor)), *rest])
    free = np.array([True, True, not fixed_sigma, edges, edges, edges, edges])
    if not edges:
        full[3:5] = -np.inf
    ls_floor = np.log(s_floor)

    def fun(th: np.ndarray) -> tuple[float, np.ndarray]:
        z = full.copy()
        z[free] = th
        h = np.exp(z[1])
        # a soft floor keeps sigma above the bin resolution
        zs = z[2]
        pen, dpen = 0.0, 0.0
        if zs < ls_floor:
            pen, dpen = 1e3 * (zs - ls_floor) ** 2, 2e3 * (zs - ls_floor)
        zz = np.r_[z[0], h, zs, z[3:]]
        if edges:
            f, g = _nll_mix(zz, x, w)
        else:
            f, g3 = _nll_and_grad(zz[:3], x, w)
            g = np.r_[g3, 0.0, 0.0, 0.0, 0.0]
        g = g.copy()
        g[1] *= h
        g[2] += dpen
        return f + pen, g[free]

    res = optimize.minimize(
        fun, full[free], jac=True, method="BFGS", options={"maxiter": 3000, "gtol": 1e-9}
    )
    z = full.copy()
    z[free] = res.x
    c, h, ls = z[0], np.exp(z[1]), z[2]
    warm = (float(c), float(h), float(np.exp(ls)), *(float(v) for v in z[3:7]))
    return float(c - h), float(c + h), float(np.exp(ls)), float(res.fun), warm


def fit_band(
    x: np.ndarray,
    *,
    sigma: str | float = "differences",
    edges: bool = True,
    lag: int = 1,
    blocks: np.ndarray | None = None,
    n_boot: int = 50,
    seed: int = 0,
) -> BandFit:
    """Fit ``x ~ U[a, b] + N(0, sigma^2)`` by maximum likelihood, with block-bootstrap errors.

    Parameters
    ----------
    x : (M,) [N·m]
        Residual samples of one joint in one regime, in time order.
    sigma : ``"differences"`` (default), ``"ml"``, or a number [N·m]
        ``"differences"``: two-stage — sigma from lagged differences
        (:func:`sigma_from_differences`), then ``a, b`` by maximum likelihood at that sigma.
        ``"ml"``: all three by maximum likelihood. A number holds sigma fixed at it.
        Why two-stage by default: at rest the friction is not uniformly distributed *in time*
        (it sits for seconds wherever the last push left it), so the joint fit of the three
        parameters is misspecified and trades noise for band; on the synthetic push campaign of
        the tests it returned sigma = 0.77 N·m for a wrist joint whose noise is 0.075 N·m. The
        differences see the noise alone; the band edges then come from the extremes the friction
        visited, which is what the estimator needs.
    edges : add two point masses to the uniform part (default), each free to sit between its
        band edge and the centre. Physics: a joint at rest keeps the friction wherever the last
        push left it; a push beyond the band ends in a slip, after which the friction re-sticks
        at the sliding level (Coulomb, inside the static band) or on the edge. So the friction of
        a push campaign is a uniform part plus two atoms. Without them the atoms, blurred by the
        noise, pull the fitted edges outwards (by 2.6 sigma in the synthetic campaign of the
        tests); with atoms tied to the edges the edges fall onto the Coulomb level (±8.5 N·m on
        the simulator's joint 1, whose static band is ±10 N·m); with free atoms they came out at
        ±9.7 N·m, the atoms at ±8.5 N·m. The atoms' weights and places are nuisance parameters;
        ``a, b, sigma`` keep their meaning.
    lag : correlation length of the noise [samples] for ``sigma="differences"``
    blocks : (M,) int, optional
        Block label of each sample (time blocks or pushes); the bootstrap resamples whole blocks.
        Default: one block per 500 consecutive samples.
    n_boot : number of bootstrap replicates (0: no standard errors)
    seed : seed of the bootstrap's random draws

    Returns
    -------
    BandFit
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    if len(x) < 10:
        raise RecordingError(f"a band fit needs at least 10 samples, got {len(x)}")
    if blocks is None:
        blocks = np.arange(len(x)) // 500
    blocks = np.asarray(blocks).reshape(-1)
    q_lo, q_hi = np.quantile(x, [0.001, 0.999])
    if isinstance(sigma, str) and sigma not in ("differences", "ml"):
        raise RecordingError(
            f"sigma method {sigma!r} is unknown, expected differences, ml or a number"
        )
    fixed = not (isinstance(sigma, str) and sigma == "ml")
    if isinstance(sigma, str):
        s_diff = sigma_from_differences(x, lag, blocks)
    else:
        s_diff = float(sigma)
        if not s_diff > 0:
            raise RecordingError(f"fixed sigma is {sigma!r}, expected a positive number [N·m]")
    # the binned likelihood needs bins well below sigma (sigma / 8 here: the binning adds
    # width^2 / 12 to the variance, 0.13 % of sigma^2); a sigma far below the finest bin is floored
    idx, centres = _histogram(x, s_diff / 8.0)
    nbins = len(centres)
    counts = np.bincount(idx, minlength=nbins).astype(float)
    width = centres[1] - centres[0]
    s_floor = max(1e-6 * s_diff, width / 20.0)
    starts = [s_diff] if fixed else [s_diff, max(0.02 * float(q_hi - q_lo), s_floor)]
    best = None
    for s_start in starts:
        s_start = max(s_start, s_floor)
        h_start = max(0.5 * (q_hi - q_lo) - 2.5 * s_start, 0.0)
        c_start = 0.5 * (q_lo + q_hi)
        # atoms at the edges, or the band 10 % wider with the atoms a little inside
        for extra in ((-2.0, -2.0, -4.0, -4.0), (-2.0, -2.0, -2.0, -2.0)) if edges else ((),):
            hh = h_start * (1.0 if not extra or extra[2] < -3 else 1.1)
            cand = _fit_weighted(
                centres, counts, (c_start, hh, s_start, *extra), s_floor, fixed, edges
            )
            if best is None or cand[3] < best[3]:
                best = cand
    a, b, s, nll, warm = best
    se = (float("nan"),) * 3
    if n_boot > 0:
        labels, inv = np.unique(blocks, return_inverse=True)
        nb = len(labels)
        block_hist = np.zeros((nb, nbins))
        np.add.at(block_hist, (inv, idx), 1.0)
        members = None
        rng = np.random.default_rng(seed)
        reps = np.empty((n_boot, 3))
        for r in range(n_boot):
            pick = rng.integers(0, nb, nb)
            mult = np.bincount(pick, minlength=nb).astype(float)
            wts = mult @ block_hist
            rs0 = s
            if fixed and isinstance(sigma, str):
                if members is None:
                    members = [np.flatnonzero(inv == k) for k in range(nb)]
                xs = np.concatenate([x[members[k]] for k in pick])
                bl = np.concatenate([np.full(len(members[k]), i) for i, k in enumerate(pick)])
                rs0 = max(sigma_from_differences(xs, lag, bl), s_floor)
            reps[r] = _fit_weighted(
                centres, wts, (warm[0], warm[1], rs0, *warm[3:]), s_floor, fixed, edges
            )[:3]
        # fewer than 5 blocks cannot say how much the fit varies: no standard error
        sd = reps.std(axis=0, ddof=1) if (n_boot > 1 and nb >= 5) else np.full(3, np.nan)
        se = (float(sd[0]), float(sd[1]), float(sd[2]))
    return BandFit(a, b, s, se[0], se[1], se[2], n=len(x), nll=nll)


def fit_sliding(
    x: np.ndarray,
    dq: np.ndarray,
    *,
    blocks: np.ndarray | None = None,
    n_boot: int = 50,
    seed: int = 0,
    band_rows: np.ndarray | None = None,
) -> tuple[float, float, BandFit, float, float]:
    """Coulomb + viscous friction by least squares, then the band-plus-noise fit of the remainder.

    Parameters
    ----------
    x : (M,) [N·m] residual of one moving joint
    dq : (M,) [rad/s] its velocity
    blocks, n_boot, seed : as in :func:`fit_band`
    band_rows : (M,) bool, the samples the band is fitted on (default all; used when at least
        200 and a tenth of the samples)

    Returns
    -------
    coulomb [N·m], viscous [N·m·s/rad], the BandFit of ``x - coulomb·sign(dq) - viscous·dq``,
    and the bootstrap standard errors of coulomb and viscous.
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    dq = np.asarray(dq, dtype=float).reshape(-1)
    A = np.column_stack([np.sign(dq), dq, np.ones_like(dq)])

    def ls(rows: np.ndarray | None) -> np.ndarray:
        if rows is None:
            return np.linalg.lstsq(A, x, rcond=None)[0]
        return np.linalg.lstsq(A[rows], x[rows], rcond=None)[0]

    coef = ls(None)
    fc, fv = float(coef[0]), float(coef[1])
    rest = x - fc * np.sign(dq) - fv * dq
    keep = np.ones(len(x), bool) if band_rows is None else np.asarray(band_rows, bool)
    if keep.sum() < max(200, 0.1 * len(x)):
        keep[:] = True
    fit = fit_band(
        rest[keep],
        blocks=None if blocks is None else np.asarray(blocks)[keep],
        n_boot=n_boot,
        seed=seed,
    )
    se_c = se_v = float("nan")
    if n_boot > 1:
        if blocks is None:
            blocks = np.arange(len(x)) // 500
        labels, inv = np.unique(np.asarray(blocks), return_inverse=True)
        members = [np.flatnonzero(inv == k) for k in range(len(labels))]
        rng = np.random.default_rng(seed + 1)
        reps = np.empty((n_boot, 2))
        for r in range(n_boot):
            pick = rng.integers(0, len(labels), len(labels))
            rows = np.concatenate([members[k] for k in pick])
            reps[r] = ls(rows)[:2]
        if len(labels) >= 5:
            se_c, se_v = (float(v) for v in reps.std(axis=0, ddof=1))
    return fc, fv, fit, se_c, se_v


# ---------------------------------------------------------------------------- residuals
def _effects_torque(model: TorqueModel | None, rec: Recording) -> np.ndarray:
    """Sum of the model's effects [N·m] (N, n); zero when the model has none."""
    if model is None or not model.effects:
        return np.zeros((len(rec), rec.n))
    from ditherlab.effects import effects_torque

    return effects_torque(model, rec)


def _sensor_external(model: TorqueModel | None, rec: Recording, J: np.ndarray) -> np.ndarray:
    """``external_torque(sensor_wrench)`` [N·m] (N, n), through ditherlab.effects when it applies."""
    if model is not None and model.effects:
        from ditherlab.effects import external_torque, sensor_wrench

        return external_torque(model, rec, sensor_wrench(model, rec))
    return np.einsum("nkj,nk->nj", J, rec.wrench)


def friction_residual(
    rec: Recording, model: TorqueModel | None = None, *, assume_no_force: bool = False
) -> np.ndarray:
    """``rho = tau - gravity - effects_torque - external_torque(sensor_wrench)`` per sample.

    Parameters
    ----------
    rec : Recording with F/T columns (or ``assume_no_force=True``: the external term is zero)
    model : the model whose effects are subtracted (None: no effects)

    Returns
    -------
    (N, n) [N·m]
    """
    rho = _tau_minus_model(rec.tau, rec, model)
    if assume_no_force:
        return rho
    J = rec.robot().jacobian(rec.q)
    return rho - _sensor_external(model, rec, J)


def _tau_minus_model(tau: np.ndarray, rec: Recording, model: TorqueModel | None) -> np.ndarray:
    g = rec.robot().gravity(rec.q)
    return tau - g - _effects_torque(model, rec)


def causal_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Mean over the last ``w`` samples (fewer at the start), per column.

    Parameters
    ----------
    x : (N, n) any unit
    w : window [samples]

    Returns
    -------
    (N, n), same unit
    """
    x = np.asarray(x, dtype=float)
    c = np.cumsum(np.vstack([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    k = np.arange(1, len(x) + 1)
    lo = np.maximum(k - w, 0)
    cnt = (k - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    return (c[k] - c[lo]) / cnt


# ---------------------------------------------------------------------------- identification
def _check_inputs(recs: Sequence[Recording], assume_no_force: bool) -> None:
    if not recs:
        raise RecordingError("identify needs at least one recording")
    first = recs[0]
    for r in recs:
        if not assume_no_force and not r.has_wrench:
            raise RecordingError(
                f"{r.name or 'recording'}: identify needs a reference F/T sensor (columns "
                "f_x..m_z) and this recording has none; with --assume-no-force it can still fit "
                "the bands from periods where you state that no external force acts"
            )
        if r.n != first.n or _robot_key(r.meta) != _robot_key(first.meta):
            raise RecordingError(
                f"{r.name or 'recording'}: robot {r.robot_label} with {r.n} joints differs from "
                f"{first.name or 'the first recording'}'s {first.robot_label} with {first.n} joints"
            )


def _robot_key(meta: dict) -> str:
    import json

    return json.dumps({k: meta.get(k) for k in ("robot", "tool_offset", "payload")}, sort_keys=True)


def identify(
    recs: Sequence[Recording],
    *,
    base: TorqueModel | None = None,
    assume_no_force: bool = False,
    n_boot: int = 50,
    block: float = 2.0,
    min_samples: int = 200,
    dither_band: str = "shrunk",
    max_accel: float = 0.5,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> TorqueModel:
    """Fit the bands, noise and sliding friction of every joint and regime.

    Parameters
    ----------
    recs : recordings of the same robot with F/T columns ``f_x..m_z``
    base : a model to start from: its prior, effects (subtracted before fitting) and any regime
        that the data do not cover are kept; None starts from the paper's prior and no effects.
    assume_no_force : no F/T sensor: treat the external force as zero everywhere (the user states
        that no force acts, e.g. a log of rest periods); the bands then hold any force as friction.
    n_boot : bootstrap replicates for the standard errors (seeded by ``seed``)
    block : bootstrap block length [s]
    min_samples : a joint-regime with fewer samples is not fitted (kept from ``base`` if there)
    dither_band : ``"shrunk"`` (default) or ``"ml"``: the edges of the ``dither`` band.
        ``"shrunk"``: the paper's rule (§IV-A, Fig. 4) — the fitted ``still`` band shrunk on each
        side by the dither amplitude measured in the data (median over the dithered samples of
        the extracted amplitude); its noise is still fitted on the extracted signal.
        ``"ml"``: the band-plus-noise fit of the extracted residual itself. On the built-in
        simulator's push campaign the extracted signal follows ``J^T F`` only in part (the
        paper's underestimate: the servo and the centre loop take up some of the push), so that
        fit spread to [-6.3, 7.5] N·m on joint 1 — almost the still band — and gave away the
        dither's gain; on data where the extraction is faithful (the synthetic tests) both agree.
    max_accel : [rad/s²] the moving regime is fitted only where the joint's acceleration
        (averaged over 0.1 s) is at most this: the model neglects dynamic torques, and on the
        simulator's start-up excitation the abrupt reversals (~200 N·m of inertia on joint 1)
        otherwise widened the moving band to [-202, 102] N·m
    progress : ``progress(done, total)`` callback

    Returns
    -------
    TorqueModel with ``regimes`` ``still`` / ``dither`` / ``moving`` (those the data cover), each
    :class:`~ditherlab.model.Band` with ``stderr`` for every fitted parameter.

    Raises
    ------
    RecordingError
        No F/T columns (and not ``assume_no_force``), recordings of different robots, or no
        joint with enough samples in any regime.
    """
    recs = list(recs)
    if dither_band not in ("shrunk", "ml"):
        raise ConfigError(f"dither_band is {dither_band!r}, expected 'shrunk' or 'ml'")
    _check_inputs(recs, assume_no_force)
    first = recs[0]
    n = first.n
    if base is not None:
        check_robot(base, first)
    model_for_effects = base
    # residuals per regime, concatenated over recordings; blocks labelled per recording
    # residual samples per (regime, joint), concatenated over recordings, with a label per
    # contiguous run inside a time block (bootstrap unit; differences never cross labels)
    xs: dict[tuple[int, int], list[np.ndarray]] = {}
    labels: dict[tuple[int, int], list[np.ndarray]] = {}
    dqs: dict[tuple[int, int], list[np.ndarray]] = {}
    slides: dict[tuple[int, int], list[np.ndarray]] = {}
    lags: dict[int, int] = {STILL: 1, MOVING: 1, DITHER: 1}
    amps: dict[int, list[np.ndarray]] = {}
    steps = len(recs) + 3 * n
    done = 0
    label_offset = 0
    for rec in recs:
        reg = regimes(rec)
        rho = friction_residual(rec, model_for_effects, assume_no_force=assume_no_force)
        t = rec.t
        blk = ((t - t[0]) // block).astype(np.int64)
        dq = rec.dq
        # the paper's model neglects dynamic torques ("slow velocities and low accelerations"):
        # the moving regime is fitted where the (0.1 s averaged) acceleration is low
        slow = np.abs(causal_mean(rec.ddq, max(int(round(0.1 * rec.sample_rate)), 1)))
        slow = slow <= max_accel
        # break-away / stopping transients, short slips and velocity reversals are not on the
        # sliding line (the samples diagnose leaves out): the moving band is fitted without them
        # (their outliers, -6..+13 N·m on a simulated joint 2 whose residual is otherwise within
        # +-0.8, set its edges), the sliding friction with them
        from ditherlab.effects import REVERSAL_V, stick_transitions

        slide = ~stick_transitions(reg, rec.sample_rate) & (np.abs(dq) >= REVERSAL_V)
        sources = [(STILL, rho, reg == STILL), (MOVING, rho, (reg == MOVING) & slow)]
        if (reg == DITHER).any():
            from ditherlab.replay import extract_dither

            sig = extract_dither(rec)
            if sig is not None:
                # the extracted signal replaces the raw torque; keep samples whose one-period
                # window lies wholly in the dither
                # the extracted signal is (for the slow part) a one-period running mean: compare
                # it with the model torque passed through the same window, so that the
                # extraction's delay does not count as friction
                model_tau = rec.tau - rho
                w = max(int(round(sig.period * rec.sample_rate)), 1)
                rho_d = sig.signal - causal_mean(model_tau, w)
                dmask = (reg == DITHER) & sig.valid[:, None]
                sources.append((DITHER, rho_d, dmask))
                for j in range(n):
                    if dmask[:, j].any():
                        amps.setdefault(j, []).append(sig.amplitude[dmask[:, j], j])
                lags[DITHER] = max(lags[DITHER], int(round(sig.period * rec.sample_rate)))
        for code, r, mask in sources:
            for j in range(n):
                m = mask[:, j]
                if not m.any():
                    continue
                run = np.cumsum(np.r_[True, m[1:] != m[:-1]])
                lab = label_offset + run * (int(blk.max()) + 1) + blk
                xs.setdefault((code, j), []).append(r[m, j])
                labels.setdefault((code, j), []).append(lab[m])
                dqs.setdefault((code, j), []).append(dq[m, j])
                slides.setdefault((code, j), []).append(slide[m, j])
        label_offset += (len(t) + 1) * (int(blk.max()) + 1) + 1
        done += 1
        if progress:
            progress(done, steps)

    fits: dict[tuple[int, int], dict[str, tuple[float, float]]] = {}
    for code in (STILL, DITHER, MOVING):
        for j in range(n):
            key = (code, j)
            if key in xs and sum(len(v) for v in xs[key]) >= min_samples:
                x = np.concatenate(xs[key])
                bl = np.unique(np.concatenate(labels[key]), return_inverse=True)[1]
                jseed = seed * 1000 + code * 100 + j
                f: dict[str, tuple[float, float]] = {}
                if code == MOVING:
                    d = np.concatenate(dqs[key])
                    fc, fv, fit, se_c, se_v = fit_sliding(
                        x,
                        d,
                        blocks=bl,
                        n_boot=n_boot,
                        seed=jseed,
                        band_rows=np.concatenate(slides[key]),
                    )
                    f["coulomb"], f["viscous"] = (fc, se_c), (fv, se_v)
                else:
                    fit = fit_band(x, lag=lags[code], blocks=bl, n_boot=n_boot, seed=jseed)
                f["tau_min"], f["tau_max"] = (fit.a, fit.se_a), (fit.b, fit.se_b)
                f["sigma"] = (fit.sigma, fit.se_sigma)
                fits[key] = f
            done += 1
            if progress:
                progress(done, steps)
    if not fits:
        raise RecordingError(
            f"{first.name or 'recording'}: no joint has {min_samples} samples in any regime "
            "(still, dither, moving); record longer"
        )
    out_regimes: dict[str, Band] = dict(base.regimes) if base is not None else {}
    for code, name in ((STILL, "still"), (DITHER, "dither"), (MOVING, "moving")):
        band = _assemble(code, n, fits, out_regimes.get(name))
        if band is not None:
            out_regimes[name] = band
    capped = _cap_moving(out_regimes, fits)
    widened = _coulomb_floor(out_regimes, fits)
    if dither_band == "shrunk" and "dither" in out_regimes and "still" in out_regimes and amps:
        out_regimes["dither"], amp = _shrunk_dither_band(
            out_regimes["still"], out_regimes["dither"], amps
        )
        dither_note = (
            "; dither band = still band shrunk by the measured dither amplitude "
            + "["
            + ", ".join(f"{a:.3g}" for a in amp)
            + "] N·m (paper Fig. 4)"
        )
    else:
        dither_note = "; dither band fitted on the extracted signal" if amps else ""
    history = list(base.history) if base is not None else []
    prior_mean = base.prior_mean if base is not None else np.zeros(6)
    from ditherlab.model import PAPER_PRIOR_SIGMA

    prior_sigma = base.prior_sigma if base is not None else np.array(PAPER_PRIOR_SIGMA)
    notes = (
        "identified by ditherlab identify from "
        + ", ".join(r.name or "<memory>" for r in recs)
        + (" assuming no external force (no F/T sensor)" if assume_no_force else "")
        + f"; bootstrap {n_boot} x {block:g} s blocks, seed {seed}"
        + dither_note
        + (
            "; moving band capped at the still band's width and viscous at >= 0 (the moving "
            "data hold torques the sliding-friction model does not explain, e.g. servo transients"
            f" or inertia) on joint(s) {', '.join(str(j + 1) for j in capped)}"
            if capped
            else ""
        )
        + (
            "; still band widened to the sliding friction (a stuck joint holds at least "
            f"coulomb) on joint(s) {', '.join(str(j + 1) for j in widened)}"
            if widened
            else ""
        )
    )
    model = TorqueModel(
        robot=first.meta["robot"],
        n=n,
        regimes=out_regimes,
        prior_mean=prior_mean,
        prior_sigma=prior_sigma,
        effects=list(base.effects) if base is not None else [],
        history=history,
        version=base.version if base is not None else 1,
        tool_offset=first.meta.get("tool_offset"),
        payload=first.meta.get("payload"),
        notes=notes,
    )
    return model


def _cap_moving(regs: dict[str, Band], fits: dict) -> list[int]:
    """Keep the moving band physical: no wider than the still band (sliding friction is better
    known than static friction, the paper's §VI-D), and viscous friction not negative. A wider
    ML band means the moving samples hold torques the model lacks (a servo transient at the end
    of the simulator's start-up excitation reached -195 N·m on joint 1). Returns the joints
    (0-based) changed."""
    st, mv = regs.get("still"), regs.get("moving")
    if st is None or mv is None:
        return []
    out = []
    for j in range(len(st.sigma)):
        if (MOVING, j) not in fits:
            continue
        changed = False
        hs = 0.5 * (st.tau_max[j] - st.tau_min[j])
        if mv.tau_max[j] - mv.tau_min[j] > 2 * hs:
            mv.tau_min[j], mv.tau_max[j] = -hs, hs
            changed = True
        if mv.viscous is not None and mv.viscous[j] < 0:
            mv.viscous[j] = 0.0
            changed = True
        if changed:
            out.append(j)
    return out


def _coulomb_floor(regs: dict[str, Band], fits: dict) -> list[int]:
    """Widen the fitted still band of a joint to ``[-|coulomb|, |coulomb|]`` where the moving
    data give its sliding friction: physically the static band holds at least the sliding
    friction (Fs >= Fc), and a joint that the pushes never moved out of its band shows only a
    sliver of it in the still data. Returns the (0-based) joints widened."""
    st, mv = regs.get("still"), regs.get("moving")
    if st is None or mv is None or mv.coulomb is None:
        return []
    out = []
    for j in range(len(st.sigma)):
        if (MOVING, j) not in fits or (STILL, j) not in fits:
            continue
        c = abs(float(mv.coulomb[j]))
        if st.tau_min[j] > -c or st.tau_max[j] < c:
            st.tau_min[j] = min(st.tau_min[j], -c)
            st.tau_max[j] = max(st.tau_max[j], c)
            out.append(j)
    return out


def _shrunk_dither_band(
    still: Band, fitted: Band, amps: dict[int, list[np.ndarray]]
) -> tuple[Band, np.ndarray]:
    """The still band shrunk by the median measured dither amplitude per joint (paper Fig. 4),
    with the noise of the extracted signal; joints never dithered keep the fitted values."""
    from ditherlab.dither import dithered_band

    n = len(still.sigma)
    A = np.zeros(n)
    have = np.zeros(n, bool)
    for j, parts in amps.items():
        a = np.concatenate(parts)
        if a.size:
            A[j], have[j] = float(np.median(a)), True
    lo, hi = dithered_band(still.tau_min, still.tau_max, A)
    lo = np.where(have, lo, fitted.tau_min)
    hi = np.where(have, hi, fitted.tau_max)
    stderr = dict(fitted.stderr)
    for k in ("tau_min", "tau_max"):
        if k in still.stderr:
            stderr[k] = np.where(have, still.stderr[k], fitted.stderr.get(k, -1.0))
    return Band(tau_min=lo, tau_max=hi, sigma=fitted.sigma, stderr=stderr), A


def _assemble(
    code: int,
    n: int,
    fits: dict[tuple[int, int], dict[str, tuple[float, float]]],
    old: Band | None,
) -> Band | None:
    """One regime's Band from the per-joint fits.

    A joint without enough samples in this regime keeps ``old``'s values (a base model) or, for
    the ``still`` regime, takes the static band implied by its sliding friction (``moving``:
    ``[-coulomb + a, coulomb + b]``) with the moving noise; its standard errors are -1 (not
    fitted). A regime that cannot be completed that way is left out (None).
    """
    keys = ("tau_min", "tau_max", "sigma") + (("coulomb", "viscous") if code == MOVING else ())
    vals = {k: np.full(n, np.nan) for k in keys}
    ses = {k: np.full(n, -1.0) for k in keys}
    for j in range(n):
        f = fits.get((code, j))
        if f is not None:
            for k in keys:
                vals[k][j] = f[k][0]
                se = f[k][1]
                ses[k][j] = se if np.isfinite(se) else -1.0
        elif old is not None:
            for k in keys:
                v = getattr(old, k)
                if v is not None:
                    vals[k][j] = v[j]
        elif code == STILL and (MOVING, j) in fits:
            m = fits[(MOVING, j)]
            c = abs(m["coulomb"][0])
            vals["tau_min"][j] = -c + m["tau_min"][0]
            vals["tau_max"][j] = c + m["tau_max"][0]
            vals["sigma"][j] = m["sigma"][0]
    if any(np.isnan(v).any() for v in vals.values()):
        return None
    if not np.all(vals["sigma"] > 0):
        return None
    return Band(
        tau_min=vals["tau_min"],
        tau_max=vals["tau_max"],
        sigma=vals["sigma"],
        coulomb=vals.get("coulomb"),
        viscous=vals.get("viscous"),
        stderr=ses,
    )


def check_robot(model: TorqueModel, rec: Recording) -> None:
    """Raise ModelError when the recording's robot is not the model's (name/URDF or joint count)."""
    spec_r = rec.meta["robot"]
    spec_m = model.robot
    same = model.n == rec.n and (
        spec_m == spec_r
        if isinstance(spec_m, str) or isinstance(spec_r, str)
        else spec_m.get("urdf") == spec_r.get("urdf")
    )
    if not same:
        mlabel = spec_m if isinstance(spec_m, str) else spec_m.get("name", "urdf")
        where = f"{rec.name}: " if rec.name else ""
        raise ModelError(
            f"{where}the recording's robot is {rec.robot_label} with {rec.n} joints but the model "
            f"{model.source or ''} is for {mlabel} with {model.n} joints".replace("  ", " ")
        )


def summary(model: TorqueModel) -> str:
    """A few lines per regime: band edges and noise per joint with their standard errors."""
    lines = []
    for name, b in model.regimes.items():
        lines.append(f"[{name}]")
        for j in range(model.n):
            se = {k: v[j] for k, v in b.stderr.items()}

            def pm(k: str, se: dict = se) -> str:
                v = se.get(k, -1.0)
                return f" ± {v:.3g}" if v is not None and v >= 0 else ""

            line = (
                f"  joint {j + 1}: band [{b.tau_min[j]:8.3f}{pm('tau_min')}, "
                f"{b.tau_max[j]:8.3f}{pm('tau_max')}] N·m, sigma {b.sigma[j]:.4f}{pm('sigma')} N·m"
            )
            if b.coulomb is not None:
                line += f", coulomb {b.coulomb[j]:.3f}{pm('coulomb')} N·m"
            if b.viscous is not None:
                line += f", viscous {b.viscous[j]:.3f}{pm('viscous')} N·m·s/rad"
            lines.append(line)
    return "\n".join(lines)


__all__ = [
    "BandFit",
    "band_noise_logpdf",
    "check_robot",
    "fit_band",
    "fit_sliding",
    "friction_residual",
    "identify",
    "summary",
    "identify_files",
    "ModelError",
]


def identify_files(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    base: str | Path | None = None,
    add: Sequence[str] = (),
    assume_no_force: bool = False,
    n_boot: int = 30,
    seed: int = 0,
    read_options: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> TorqueModel:
    """Read recordings, :func:`identify`, add effects (``ditherlab.effects.add_effect``), save.

    Parameters
    ----------
    paths : recording files
    out : model file to write (TOML, atomic; never one of the inputs)
    base : a model file to start from
    add : effect names to fit after the bands, in order
    assume_no_force, n_boot, seed, progress : as in :func:`identify`
    read_options : options for :func:`ditherlab.io.read` (``mapping``, ``robot``)

    Returns
    -------
    The written TorqueModel.
    """
    from ditherlab.io import read
    from ditherlab.io.atomic import check_not_input

    inputs = [Path(p) for p in paths] + ([Path(base)] if base is not None else [])
    check_not_input(out, inputs)
    recs = [read(p, **(read_options or {})) for p in paths]
    base_model = TorqueModel.load(base) if base is not None else None
    model = identify(
        recs,
        base=base_model,
        assume_no_force=assume_no_force,
        n_boot=n_boot,
        seed=seed,
        progress=progress,
    )
    if add:
        from ditherlab.effects import add_effect

        for name in add:
            model = add_effect(model, recs, name)
    model.source = None
    model.save(out)
    return model

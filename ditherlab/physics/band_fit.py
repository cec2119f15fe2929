"""The band-plus-noise likelihood of the paper's §II and its maximum-likelihood fits.

A friction residual ``x`` is a uniform band ``[a, b]`` plus Gaussian noise ``N(0, sigma^2)``, with
density ``[Phi((x - a)/sigma) - Phi((x - b)/sigma)] / (b - a)`` (:func:`band_noise_logpdf`).
:func:`fit_band` fits a band, :func:`fit_sliding` the sliding friction line with a band about it,
each with block-bootstrap standard errors. Pure numpy/scipy on arrays: what the residual is, and
per which regime, is :mod:`ditherlab.analysis.identification`'s business.

The likelihood is evaluated on a fine histogram of ``rho`` (bins of sigma / 8, at most 4096; the
binning adds ``width^2/12`` to the variance, Sheppard), which makes each fit and each bootstrap
replicate cost the same few milliseconds whatever the length of the recording.

How sigma and the edges are fitted, and why (details in :func:`fit_band`): sigma comes from
lagged differences of the residual (the friction state persists, the noise does not), then the
band edges by maximum likelihood of the uniform-plus-Gaussian density at that sigma, with two
point masses at the edges added to the uniform part (a push beyond the band leaves the friction
exactly on an edge). The joint maximum likelihood of all three is available (``sigma="ml"``,
``edges=False``) and is what the plain model of the paper prescribes; on push campaigns it is
misspecified (:func:`fit_band`; ``docs/design/physics-band-fit.md``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import optimize
from scipy.special import expit, log_ndtr, ndtri

from ditherlab.core.errors import RecordingError

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)
N_BINS = 4096

#: the fewest bootstrap blocks a fit's standard errors are computed from: with fewer, how much
#: the fit varies cannot be said (NaN)
MIN_BOOT_BLOCKS = 5

__all__ = [
    "BandFit",
    "band_noise_logpdf",
    "block_members",
    "fit_band",
    "NOISE_LAG_S",
    "fit_sliding",
    "HELD_LEVEL",
    "MIN_BOOT_BLOCKS",
    "HELD_WINDOW_S",
    "held_levels",
    "noise_lag",
    "sigma_from_differences",
]


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


def block_members(inv: np.ndarray, nb: int) -> list[np.ndarray]:
    """The sample indices of each block, ascending: ``[flatnonzero(inv == k) for k < nb]`` by
    one stable sort (that comprehension scans all samples once per block: quadratic in the
    length of a log).

    Parameters
    ----------
    inv : (M,) int, each sample's block in ``0 .. nb - 1`` ; nb : the number of blocks

    Returns
    -------
    nb arrays of sample indices
    """
    order = np.argsort(inv, kind="stable")
    ends = np.cumsum(np.bincount(inv, minlength=nb))
    return np.split(order, ends[:-1])


#: [s] the spacing of the differences that estimate a raw torque's noise: one sample step of the
#: paper's 250 Hz. A log sampled faster than its noise's bandwidth (a filtered torque, a current
#: loop of 1 kHz logged at 5 kHz) has noise correlated over a few samples, which one-sample
#: differences cancel; differences this far apart see it whole, and for white noise any spacing
#: gives the same sigma
NOISE_LAG_S = 0.004


def noise_lag(rate: float) -> int:
    """The lag [samples] of :func:`sigma_from_differences` for a raw torque logged at ``rate``
    [Hz]: :data:`NOISE_LAG_S` in samples, at least 1 (1 at 250 Hz and below, 20 at 5 kHz)."""
    if not (np.isfinite(rate) and rate > 0):
        return 1
    return max(1, int(round(NOISE_LAG_S * rate)))


def _robust_sd(d: np.ndarray) -> float:
    """The standard deviation of a normal sample from its median absolute deviation (MAD /
    0.6745): the few large values (a push's step in a difference) do not move it."""
    return float(np.median(np.abs(d - np.median(d)))) / 0.6745


def sigma_from_differences(x: np.ndarray, lag: int = 1, blocks: np.ndarray | None = None) -> float:
    """Noise level from lagged differences: ``MAD(x[k + lag] - x[k]) / 0.6745 / sqrt(2)``.

    The friction part of a residual at rest is piecewise constant (it changes only while a push
    moves it), so it cancels in differences and what remains is the Gaussian noise. ``lag`` is the
    correlation length of that noise: :func:`noise_lag` for a raw torque, one dither period for an
    extracted signal (a one-period running mean). Differences across ``blocks`` boundaries are
    skipped.

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
    mad = _robust_sd(d) / np.sqrt(2.0)
    if mad <= 0:
        mad = float(np.std(d)) / np.sqrt(2.0)
    return max(mad, 1e-9)


class BlockDifferences:
    """The lagged differences inside each block, once, for the noise level of block-bootstrap
    replicates (:func:`sigma_from_differences` of the replicate's blocks, concatenated, each
    drawn copy its own block) without building the replicate.

    A replicate's differences are the multiset of its blocks' own differences, each as often as
    the block was drawn; their median and their median absolute deviation are found in that
    multiset by weights (the differences sorted once), so :meth:`sigma` equals
    ``sigma_from_differences(concatenated blocks, lag, copy labels)`` exactly, in memory and
    time linear in the samples (the concatenation holds several copies of the samples per
    replicate).

    Parameters
    ----------
    x : (M,) [N·m] ; lag : samples ; members : the sample indices of each block, ascending
    (:func:`block_members`)
    """

    def __init__(self, x: np.ndarray, lag: int, members: list[np.ndarray]):
        self.lag = max(int(lag), 1)
        self.sizes = np.array([len(m) for m in members], dtype=np.int64)
        parts = [x[m[self.lag :]] - x[m[: -self.lag]] for m in members if len(m) > self.lag]
        owner = [
            np.full(len(m) - self.lag, k, dtype=np.int64)
            for k, m in enumerate(members)
            if len(m) > self.lag
        ]
        d = np.concatenate(parts) if parts else np.zeros(0)
        order = np.argsort(d, kind="stable")
        self.d = d[order]
        self.owner = (np.concatenate(owner) if owner else np.zeros(0, np.int64))[order]

    def sigma(self, mult: np.ndarray) -> float | None:
        """The noise level [N·m] of the replicate that draws block ``k`` ``mult[k]`` times
        (``mult`` (nb,), integer counts), or None where :func:`sigma_from_differences` would not use the differences'
        MAD (too few samples, no differences, a MAD of 0): the caller builds the replicate."""
        n_samples = int(self.sizes @ mult.astype(np.int64))
        w = mult.astype(np.int64)[self.owner]
        total = int(w.sum())
        if n_samples <= self.lag + 2 or total == 0:
            return None
        cum = np.cumsum(w)
        lo, hi = (total - 1) // 2, total // 2
        med = (
            self.d[np.searchsorted(cum, lo, "right")] + self.d[np.searchsorted(cum, hi, "right")]
        ) / 2
        a, b = _weighted_abs_kth(self.d, w, med, lo, hi)
        mad = float((a + b) / 2) / 0.6745 / np.sqrt(2.0)
        return max(mad, 1e-9) if mad > 0 else None


@njit(cache=True)
def _weighted_abs_kth(d, w, m, lo, hi):
    """The ``lo``-th and ``hi``-th smallest (0-based) of ``|d - m|`` counted with weights ``w``
    (``d`` ascending): a merge outwards from ``m`` of the two runs ascending in ``|d - m|``."""
    n = len(d)
    right = np.searchsorted(d, m)  # d[right:] >= m
    left = right - 1
    seen = 0
    a = b = 0.0
    got_a = False
    while True:
        if left < 0 and right >= n:
            return a, b  # unreachable: lo, hi < the total weight
        if right >= n or (left >= 0 and abs(d[left] - m) <= abs(d[right] - m)):
            v, k = abs(d[left] - m), left
            left -= 1
        else:
            v, k = abs(d[right] - m), right
            right += 1
        seen += w[k]
        if not got_a and seen > lo:
            a, got_a = v, True
        if seen > hi:
            return a, v


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
    # unconstrained coordinates: (c, log h, log sigma, eta_a, eta_b, zeta_a, zeta_b); BFGS (its
    # own bookkeeping is cheaper than L-BFGS-B's here; docs/design/physics-band-fit.md)
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

    # the line search tries steps far out (a band 1e300 wide, sigma -> 0): the likelihood is
    # inf or NaN there and BFGS steps back; numpy's overflow warnings about those trials are
    # not the user's business
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        res = optimize.minimize(
            fun, full[free], jac=True, method="BFGS", options={"maxiter": 3000, "gtol": 1e-9}
        )
        z = full.copy()
        z[free] = res.x
        # a fit whose atoms took all the weight can leave h at exp(huge) = inf: returned as it
        # is (a bootstrap replicate like that makes its standard error NaN, "not fitted")
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
        Two-stage by default because at rest the friction is not uniformly distributed *in
        time* (it sits wherever the last push left it), so the joint fit of the three
        parameters is misspecified and trades noise for band; the differences see the noise
        alone, and the band edges then come from the extremes the friction visited, which is
        what the estimator needs (``docs/design/physics-band-fit.md``).
    edges : add two point masses to the uniform part (default), each free to sit between its
        band edge and the centre: a push beyond the band ends in a slip, after which the
        friction re-sticks at the sliding level or on the edge, so the friction of a push
        campaign is a uniform part plus two atoms, which would otherwise pull the fitted edges
        outwards. The atoms' weights and places are nuisance parameters; ``a, b, sigma`` keep
        their meaning (``docs/design/physics-band-fit.md``).
    lag : [samples] correlation length of the noise for ``sigma="differences"``
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
    prob = _band_problem(x, sigma, edges, lag, blocks)
    a, b, s, nll, warm = _best_fit(prob)
    se = _bootstrap_se(prob, warm, s, n_boot, seed) if n_boot > 0 else (float("nan"),) * 3
    return BandFit(a, b, s, se[0], se[1], se[2], n=len(x), nll=nll)


@dataclass(frozen=True, eq=False)
class _BandProblem:
    """One band fit's samples, their histogram and its settings (:func:`fit_band`).

    Attributes
    ----------
    x : (M,) [N·m] the samples ; blocks : (M,) their block labels
    idx : (M,) int, each sample's bin ; centres : (B,) [N·m] the bins' centres
    counts : (B,) samples per bin
    sigma0 : [N·m] sigma from the differences or the given number (the ML fit's start)
    s_floor : [N·m] the smallest sigma the bins resolve
    q_lo, q_hi : [N·m] the samples' 0.1 % and 99.9 % quantiles
    lag : [samples] ; edges : the two atoms are fitted
    fixed : sigma is held (not fitted by maximum likelihood)
    from_differences : sigma comes from the lagged differences (each replicate its own)
    """

    x: np.ndarray
    blocks: np.ndarray
    idx: np.ndarray
    centres: np.ndarray
    counts: np.ndarray
    sigma0: float
    s_floor: float
    q_lo: float
    q_hi: float
    lag: int
    edges: bool
    fixed: bool
    from_differences: bool


def _band_problem(
    x: np.ndarray, sigma: str | float, edges: bool, lag: int, blocks: np.ndarray
) -> _BandProblem:
    """The checked settings of :func:`fit_band` and the samples' histogram."""
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
    counts = np.bincount(idx, minlength=len(centres)).astype(float)
    width = centres[1] - centres[0]
    return _BandProblem(
        x=x,
        blocks=blocks,
        idx=idx,
        centres=centres,
        counts=counts,
        sigma0=s_diff,
        s_floor=max(1e-6 * s_diff, width / 20.0),
        q_lo=q_lo,
        q_hi=q_hi,
        lag=lag,
        edges=edges,
        fixed=fixed,
        from_differences=fixed and isinstance(sigma, str),
    )


def _best_fit(prob: _BandProblem) -> tuple[float, float, float, float, tuple[float, ...]]:
    """The maximum-likelihood fit of the whole sample from several starts, the best of them:
    (a, b, sigma, nll per sample, its warm start) as :func:`_fit_weighted` returns it."""
    s_diff, s_floor, q_lo, q_hi = prob.sigma0, prob.s_floor, prob.q_lo, prob.q_hi
    starts = [s_diff] if prob.fixed else [s_diff, max(0.02 * float(q_hi - q_lo), s_floor)]
    best = None
    for s_start in starts:
        s_start = max(s_start, s_floor)
        h_start = max(0.5 * (q_hi - q_lo) - 2.5 * s_start, 0.0)
        c_start = 0.5 * (q_lo + q_hi)
        # atoms at the edges, or the band 10 % wider with the atoms a little inside
        for extra in ((-2.0, -2.0, -4.0, -4.0), (-2.0, -2.0, -2.0, -2.0)) if prob.edges else ((),):
            hh = h_start * (1.0 if not extra or extra[2] < -3 else 1.1)
            cand = _fit_weighted(
                prob.centres,
                prob.counts,
                (c_start, hh, s_start, *extra),
                s_floor,
                prob.fixed,
                prob.edges,
            )
            if best is None or cand[3] < best[3]:
                best = cand
    return best


def _bootstrap_se(
    prob: _BandProblem, warm: tuple[float, ...], s: float, n_boot: int, seed: int
) -> tuple[float, float, float]:
    """Block-bootstrap standard errors [N·m] of (a, b, sigma): ``n_boot`` replicates drawn from
    ``seed``, each fitted from the whole sample's optimum ``warm`` (sigma ``s``); NaN with
    fewer than 5 blocks (too few to say how much the fit varies) or a replicate that diverged."""
    labels, inv = np.unique(prob.blocks, return_inverse=True)
    nb = len(labels)
    nbins = len(prob.centres)
    members = None
    rng = np.random.default_rng(seed)
    reps = np.empty((n_boot, 3))
    for r in range(n_boot):
        pick = rng.integers(0, nb, nb)
        mult = np.bincount(pick, minlength=nb).astype(float)
        # the replicate's histogram: every sample counted as often as its block was drawn
        # (sums of whole numbers: exact, in any order)
        wts = np.bincount(prob.idx, weights=mult[inv], minlength=nbins)
        rs0 = s
        if prob.from_differences:
            if members is None:
                members = block_members(inv, nb)
                diffs = BlockDifferences(prob.x, prob.lag, members)
            rs = diffs.sigma(mult)
            if rs is None:  # the rare fallbacks of sigma_from_differences: build it
                xs = np.concatenate([prob.x[members[k]] for k in pick])
                bl = np.concatenate([np.full(len(members[k]), i) for i, k in enumerate(pick)])
                rs = sigma_from_differences(xs, prob.lag, bl)
            rs0 = max(rs, prob.s_floor)
        reps[r] = _fit_weighted(
            prob.centres,
            wts,
            (warm[0], warm[1], rs0, *warm[3:]),
            prob.s_floor,
            prob.fixed,
            prob.edges,
        )[:3]
    with np.errstate(invalid="ignore"):
        sd = (
            reps.std(axis=0, ddof=1)
            if (n_boot > 1 and nb >= MIN_BOOT_BLOCKS)
            else np.full(3, np.nan)
        )
    return float(sd[0]), float(sd[1]), float(sd[2])


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
        members = block_members(inv, len(labels))
        rng = np.random.default_rng(seed + 1)
        reps = np.empty((n_boot, 2))
        for r in range(n_boot):
            pick = rng.integers(0, len(labels), len(labels))
            rows = np.concatenate([members[k] for k in pick])
            reps[r] = ls(rows)[:2]
        if len(labels) >= MIN_BOOT_BLOCKS:
            se_c, se_v = (float(v) for v in reps.std(axis=0, ddof=1))
    return fc, fv, fit, se_c, se_v


#: [s] the window over which a level counts as held by friction: long against the torque
#: noise's correlation (a few ms), short against a push (the paper's last 1-3 s)
HELD_WINDOW_S = 0.1
#: family-wise level of the held-level test of one band edge over all its windows
HELD_LEVEL = 0.01


@dataclass(frozen=True)
class HeldLevels:
    """The extreme levels a residual at rest held over a window, less the test's margin.

    Attributes
    ----------
    lo, hi : [N·m] the lowest window mean plus ``z·sigma``, the highest minus it: a band edge
        inside ``[lo, hi]`` is rejected by that window at the family-wise level
    sigma : [N·m] the noise standard deviation of one window's mean
    z : the one-sided quantile used (Bonferroni over ``2·windows`` tests)
    windows : how many windows were tested
    """

    lo: float
    hi: float
    sigma: float
    z: float
    windows: int


def held_levels(
    x: np.ndarray, labels: np.ndarray, window: int, level: float = HELD_LEVEL
) -> HeldLevels | None:
    """The levels a friction residual at rest held for ``window`` samples, tested against noise.

    At rest the friction holds whatever torque the pushes leave on the joint, anywhere in its
    static band; so the band must contain every level the residual held for a while. The mean
    of each whole window of ``window`` consecutive samples inside one label (a contiguous run)
    is compared with a band edge by a one-sided test against the noise of a mean: its sigma from
    second differences of consecutive window means (a push's ramp, linear over three windows,
    cancels), Bonferroni over both edges of every window at family-wise ``level``. Assumes the
    noise decorrelates within a window.

    Parameters
    ----------
    x : (M,) [N·m] residual of one joint at rest, in time order
    labels : (M,) contiguous-run labels (a window never spans two)
    window : [samples] ; level : family-wise error rate of the two edges' tests

    Returns
    -------
    HeldLevels, or None with fewer than 20 windows (too few to know the noise of a mean)
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    labels = np.asarray(labels).reshape(-1)
    window = max(int(window), 1)
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    ends = np.r_[starts[1:], len(x)]
    cs = np.r_[0.0, np.cumsum(x)]
    means, runs = [], []
    for k, (s0, e0) in enumerate(zip(starts, ends, strict=True)):
        nw = (e0 - s0) // window
        if nw:
            w0 = s0 + window * np.arange(nw + 1)
            means.append(np.diff(cs[w0]) / window)
            runs.append(np.full(nw, k))
    if not means or sum(len(m) for m in means) < 20:
        return None
    m, r = np.concatenate(means), np.concatenate(runs)
    same = (r[2:] == r[1:-1]) & (r[1:-1] == r[:-2])
    d2 = (m[2:] - 2.0 * m[1:-1] + m[:-2])[same]
    if len(d2) < 10:
        return None
    sig = _robust_sd(d2) / np.sqrt(6.0)
    if not sig > 0:
        return None
    z = float(-ndtri(level / (2 * len(m))))
    return HeldLevels(float(m.min() + z * sig), float(m.max() - z * sig), sig, z, len(m))


def fit_regime(
    x: np.ndarray,
    labels: np.ndarray,
    lag: int,
    n_boot: int,
    seed: int,
    dq: np.ndarray | None = None,
    slide: np.ndarray | None = None,
    hold: int = 0,
) -> dict[str, tuple[float, float]]:
    """(value, standard error) per parameter of one joint-regime of identify: :func:`fit_band`
    of its residual ``x`` (M,) [N·m], or with the velocity ``dq`` (M,) [rad/s] (a moving
    regime) :func:`fit_sliding` (``slide``: its ``band_rows``); ``labels`` (M,) the bootstrap
    blocks (contiguous runs). A regime at rest with ``hold`` > 0 [samples] also gives
    ``held_min`` and ``held_max``: :func:`held_levels` over windows of ``hold`` samples, each
    with the noise sigma of a window's mean as its standard error (absent when too few windows).
    A pure function of its arguments: another process gives the same numbers."""
    bl = np.unique(labels, return_inverse=True)[1]
    f: dict[str, tuple[float, float]] = {}
    if dq is not None:
        fc, fv, fit, se_c, se_v = fit_sliding(
            x, dq, blocks=bl, n_boot=n_boot, seed=seed, band_rows=slide
        )
        f["coulomb"], f["viscous"] = (fc, se_c), (fv, se_v)
    else:
        fit = fit_band(x, lag=lag, blocks=bl, n_boot=n_boot, seed=seed)
        held = held_levels(x, bl, hold) if hold > 0 else None
        if held is not None:
            f["held_min"], f["held_max"] = (held.lo, held.sigma), (held.hi, held.sigma)
    f["tau_min"], f["tau_max"] = (fit.a, fit.se_a), (fit.b, fit.se_b)
    f["sigma"] = (fit.sigma, fit.se_sigma)
    return f


def fit_regimes(
    jobs: Iterable[tuple | None], executor: Executor | None = None
) -> Iterator[dict[str, tuple[float, float]] | None]:
    """:func:`fit_regime` of every job's arguments (None: no fit, None out), in order. Without
    an executor one job at a time, as they come; with one, every job is submitted first (their
    samples then held at once) and the results are returned in the jobs' order."""
    if executor is None:
        yield from (None if a is None else fit_regime(*a) for a in jobs)
        return
    futures = [None if a is None else executor.submit(fit_regime, *a) for a in jobs]
    yield from (None if f is None else f.result() for f in futures)

"""Confidence intervals of the estimated wrench components; :func:`intervals` dispatches to
:mod:`.set_membership` and :mod:`.profile` (:mod:`.gaussian` is the closed-form profile of
zero-width bands).

Two intervals per estimated component, both exact for the model as stated:

set membership  {F : a_j - k sigma_j <= tau_bar_j - J_j^T F <= b_j + k sigma_j for every joint,
                     |F_i - F_bar_i| <= k prior_sigma_i for every component with a prior};
                [lo_i, hi_i] = [min F_i, max F_i] over that polytope (two LPs per component).
                With k = Phi^-1(1 - alpha / (2 q)), q = n + (number of estimated components with
                a finite prior) (Bonferroni), the true F lies in the polytope with probability
                >= level when the data follow the model (friction inside its band, Gaussian
                noise, F drawn from the prior), so every component's interval covers the truth
                with probability >= level (conservative). When the polytope is empty (a force
                far beyond the prior box, or data inconsistent with the model at this level) the
                prior box is dropped for that sample (this keeps the coverage guarantee: the
                event "truth in the polytope" implies a non-empty polytope); when the data alone
                are inconsistent, NaN.
profile         {t : min_{F: F_i = t} f(F) - min_F f(F) <= chi2_1(level)}, f the cost of eq. (3)
                (tau_f profiled out inside its band). The profile is convex and piecewise
                quadratic in t; it is followed exactly from F_hat along the piecewise-linear path
                of constrained minimisers (a parametric active set: one joint enters or leaves
                at each breakpoint) as far as the threshold. In the purely Gaussian case
                (zero-width bands) this is the Bayesian interval F_hat_i +- z sd_i and covers
                exactly; a band makes it wider (residuals inside the band cost nothing).

Prior-less components whose data bound exceeds BIG_BOX = 1e9 are reported infinite. Components
held at the prior give lo = hi = prior_mean. Components without a prior that the data cannot see
(information below 1e-10 of the sample's mean) give -inf / +inf.

Why these two, and how their coverage is checked: ``docs/design/estimator-intervals.md``; the
measured coverage is on the Validation page (``docs/validation.md``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.estimator.backends.exact import _solve_exact
from ditherlab.estimator.formulation import Problem
from ditherlab.estimator.interval_methods.profile import _profile
from ditherlab.estimator.interval_methods.set_membership import _set_membership

INTERVAL_METHODS = ("set_membership", "profile")


def _check(method: str, level: float) -> None:
    if method not in INTERVAL_METHODS:
        raise ConfigError(
            f"estimator: interval method {method!r} is unknown; expected one of "
            f"{', '.join(INTERVAL_METHODS)}"
        )
    if not 0.0 < float(level) < 1.0:
        raise ConfigError(f"estimator: interval level {level!r} is invalid; expected 0 < level < 1")


def intervals(
    prob: Problem,
    F_hat=None,
    method: str = "set_membership",
    level: float = 0.95,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Confidence interval of every wrench component, per sample.

    Parameters
    ----------
    prob : Problem
        Eq. (3) for N samples (:func:`~ditherlab.estimator.problem`, the same one
        :func:`~ditherlab.estimator.solve` takes).
    F_hat : (N, 6) [N, N·m], optional
        The estimate of :func:`~ditherlab.estimator.estimate` (computed when not given; used by
        ``profile``).
    method : {"set_membership", "profile"}
        ``set_membership``: ``[min F_i, max F_i]`` over every ``F`` whose residuals lie in the
        bands widened by ``k sigma`` and which lies in the prior box ``F_bar +- k prior_sigma``,
        ``k`` = :func:`interval_k` (Bonferroni over the joints and prior components), so it covers
        the truth with probability >= ``level`` under the model. If that set is empty the prior
        box is dropped for the sample; NaN when even the data alone admit no ``F``.
        ``profile``: the ``t`` whose profiled cost ``min_{F_i = t} cost - min cost`` is at most
        the chi-square(1) quantile of ``level`` (3.84 at 0.95); the cost is eq. (3)'s, i.e.
        ``-2 log`` of the likelihood times the prior with the friction profiled out in its band.
    level : float
        Confidence level in (0, 1).
    progress : callable(done, total), optional
        Called after each chunk of :data:`CHUNK` samples.

    Returns
    -------
    lo, hi : (N, 6) [N, N·m]
        Interval bounds; ``lo = hi = prior_mean`` for components held at the prior; ``-inf`` /
        ``inf`` for prior-less components the data cannot determine.
    """
    _check(method, level)
    N, m = prob.N, prob.m
    if F_hat is None and method == "profile":
        Fm, _ = _solve_exact(prob)
    elif F_hat is not None:
        Fh = np.asarray(F_hat, dtype=float)
        if Fh.shape != (N, 6):
            raise ConfigError(f"estimator: F_hat has shape {Fh.shape}; expected ({N}, 6)")
        Fm = np.ascontiguousarray(Fh if m == 6 else Fh[:, prob.free])
    if m == 0 or N == 0:
        lo = np.broadcast_to(prob.full_mean, (N, 6)).copy()
        return lo, lo.copy()
    if method == "profile":
        lo_m, hi_m = _profile(prob, Fm, level, progress)
    else:
        lo_m, hi_m, _ = _set_membership(prob, level, progress)
    if m == 6:  # every component estimated: the kernels' bounds are the answer
        return lo_m, hi_m
    lo = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    hi = lo.copy()
    lo[:, prob.free] = lo_m
    hi[:, prob.free] = hi_m
    return lo, hi

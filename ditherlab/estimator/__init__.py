"""The force estimator of eq. (3) of the paper: batched exact solver, reference QP, intervals.

For every sample ``k`` (time is the first axis) the estimator solves::

    minimise over F (6), tau_f (n):
        (tau_bar - J^T F - tau_f)^T R_e^{-1} (tau_bar - J^T F - tau_f)
      + (F - F_bar)^T R_F^{-1} (F - F_bar)
    subject to tau_min <= tau_f <= tau_max

with ``R_e = diag(sigma^2)`` and ``R_F = diag(prior_sigma^2)``. Because ``R_e`` is diagonal the
optimal ``tau_f`` for a fixed ``F`` is the residual ``r = tau_bar - J^T F`` clipped into the
band, so the problem is the convex, continuously differentiable, piecewise-quadratic function::

    f(F) = sum_j w_j dist(r_j(F), [tau_min_j, tau_max_j])^2 + sum_i p_i (F_i - F_bar_i)^2

with ``w = 1 / sigma^2`` and ``p = 1 / prior_sigma^2``. Joints whose residual lies inside their
band contribute nothing; joints outside contribute their weighted squared distance to the edge.

Backends (one function, :func:`estimate`, dispatches on ``backend``):

``"exact"``
    Semi-smooth Newton / active-set iteration on ``f``, compiled with numba, all samples in one
    call. Given the set of joints outside their band (and on which side), the minimiser of the
    quadratic piece is one ``m x m`` least-squares solve (by QR); the iteration stops when the
    minimiser lies on the piece it was computed from, which makes it the global minimiser of
    the convex ``f`` (:attr:`Solution.kkt` reports the scaled gradient). A step that does not
    lower ``f`` is replaced by an exact line search, which makes the iteration monotone and
    finite. Why it is built so, and where it reaches the limits of double precision (noise
    weights ``max(w) / min(p)`` beyond ~1e14): ``docs/design/estimator-exact-solver.md``.
``"proxsuite"`` / ``"quadprog"``
    The reference: the same QP in ``(F, tau_f)`` solved per sample through ``qpsolvers``
    (ProxQP with ``eps_abs = 1e-12`` on a scaled problem; quadprog's dual active set method).
    Slow, obviously right; the tests compare the exact backend with both.

Components and priors
    ``components`` selects the estimated wrench components; the others are held at
    ``prior_mean``. A component whose ``prior_sigma`` is ``0`` is also held at its mean. A
    component whose ``prior_sigma`` is ``inf`` has no prior; to keep the problem strictly convex
    when the data do not determine it (all joints inside their bands, ``J`` rank deficient) it
    gets a vanishing ridge ``p_i = 1e-12 * s`` with ``s`` the mean per-component data information
    ``trace(J W J^T) / m`` of that sample. The result is then, up to ~1e-12 relative, the
    minimiser of ``f`` closest to ``prior_mean`` (the Tikhonov limit); directions the data cannot
    see stay at ``prior_mean``, and their intervals are infinite.

Use
    :func:`estimate` states and solves the problem in one call. To solve and bound the same
    samples, state the problem once with :func:`problem` (a :class:`Problem`) and pass it to
    :func:`solve` and :func:`intervals`.

Layout
    :mod:`.formulation` validates and reduces the inputs to a :class:`Problem` and completes a
    :class:`Solution`; :mod:`.backends` holds ``exact`` (:mod:`.backends.exact`) and the
    references (:mod:`.backends.qp`); :mod:`.interval_methods` the confidence intervals. The
    compiled kernels take their arrays grouped in ``NamedTuple`` s
    (:class:`~ditherlab.estimator.formulation.Samples` and the scratch of each
    kernel): ``docs/design/estimator-kernels.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ditherlab.core.errors import ConfigError
from ditherlab.estimator.backends import _available, available_backends
from ditherlab.estimator.backends.exact import solve_exact
from ditherlab.estimator.backends.qp import QP_OPTIONS, qp_matrices
from ditherlab.estimator.formulation import (
    CHUNK,
    COMPONENTS,
    RIDGE,
    Problem,
    Samples,
    Solution,
    complete,
    problem,
)
from ditherlab.estimator.interval_methods import INTERVAL_METHODS, intervals
from ditherlab.estimator.interval_methods.gaussian import gaussian_profile_intervals
from ditherlab.estimator.interval_methods.profile import UNOBSERVABLE
from ditherlab.estimator.interval_methods.set_membership import (
    BIG_BOX,
    interval_k,
    set_membership_reference,
)

__all__ = [
    "BIG_BOX",
    "CHUNK",
    "COMPONENTS",
    "INTERVAL_METHODS",
    "QP_OPTIONS",
    "RIDGE",
    "UNOBSERVABLE",
    "Problem",
    "Samples",
    "Solution",
    "available_backends",
    "complete",
    "estimate",
    "gaussian_profile_intervals",
    "interval_k",
    "intervals",
    "problem",
    "qp_matrices",
    "set_membership_reference",
    "solve",
]


def estimate(
    tau_bar,
    J,
    tau_min,
    tau_max,
    sigma,
    prior_mean,
    prior_sigma,
    components: Sequence[str] | None = None,
    backend: str = "exact",
    progress: Callable[[int, int], None] | None = None,
) -> Solution:
    """Solve eq. (3) for every sample.

    Parameters
    ----------
    tau_bar : (N, n) [N·m]
        Motor torque compensated for gravity (and modelled effects), arm side.
    J : (N, 6, n) [m, 1]
        Jacobian at the tool point, linear part first (``tau_ext = J^T F``).
    tau_min, tau_max : (n,) or (N, n) [N·m]
        Friction band; per sample for the dither variant (shrunk bands). ``+-inf`` allowed.
    sigma : (n,) or (N, n) [N·m]
        Standard deviation of the Gaussian noise, ``R_e = diag(sigma^2)``; positive.
    prior_mean : (6,) [N, N·m]
        ``F_bar``.
    prior_sigma : (6,) [N, N·m]
        ``R_F = diag(prior_sigma^2)``; ``inf`` = no prior, ``0`` = held at ``prior_mean``.
    components : sequence of str, optional
        Subset of :data:`COMPONENTS` to estimate (default all six); the rest are held at
        ``prior_mean``.
    backend : {"exact", "proxsuite", "quadprog"}
        ``exact`` is the fast path; the others are the per-sample reference QP (qpsolvers).
    progress : callable(done, total), optional
        Called as samples are done (the exact path then works in chunks of :data:`CHUNK`).

    Returns
    -------
    Solution
        ``F (N, 6)``, ``tau_f (N, n)``, ``active (N, n)``, ``cost (N,)``, ``iterations (N,)``,
        ``kkt (N,)``.
    """
    prob = problem(tau_bar, J, tau_min, tau_max, sigma, prior_mean, prior_sigma, components)
    return solve(prob, backend, progress)


def solve(
    prob: Problem, backend: str = "exact", progress: Callable[[int, int], None] | None = None
) -> Solution:
    """Solve a prepared :class:`Problem` (:func:`problem`) with one backend; ``backend`` and
    ``progress`` as for :func:`estimate`.

    Returns
    -------
    Solution
        ``F (N, 6)`` [N, N·m], ``tau_f (N, n)`` [N·m], ``active (N, n)``, ``cost (N,)``,
        ``iterations (N,)``, ``kkt (N,)``.
    """
    backends = _available(references=backend != "exact")
    if backend not in backends:
        raise ConfigError(
            f"estimator: backend {backend!r} is not available; installed: "
            f"{', '.join(backends)} (the references need `pip install qpsolvers proxsuite quadprog`)"
        )
    if backend == "exact":  # the solve and its completion in one pass
        return solve_exact(prob, progress=progress)
    Fm, it = backends[backend](prob, progress=progress)
    return complete(prob, Fm, it)

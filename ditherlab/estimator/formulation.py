"""Eq. (3) as the backends consume it: the :class:`Problem`, its :class:`Solution`, and the
helpers every backend and interval method shares (validation and broadcasting, chunking,
:func:`complete`). The components, priors and the ridge are described in
:mod:`ditherlab.estimator`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import NamedTuple

import numpy as np
from numba import njit

from ditherlab.core.errors import ConfigError, ModelError
from ditherlab.core.files import atomic_path
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.estimator.piecewise import sample_at

#: Names of the six wrench components, in the order of ``F`` and of the rows of ``J``.
COMPONENTS = WRENCH_COLUMNS
#: Relative ridge that replaces an infinite prior_sigma (see :mod:`ditherlab.estimator`).
RIDGE = 1e-12
#: Samples per kernel call when a progress callback is given.
CHUNK = 65536


def normal_quantile(p: float) -> float:
    """``Phi^-1(p)`` of the standard normal (the stdlib's, within 1e-15 of scipy.stats' norm.ppf
    and without importing scipy.stats, which is slow to import at a command's start)."""
    return NormalDist().inv_cdf(p)


def chi2_1_quantile(level: float) -> float:
    """The chi-square quantile of one degree of freedom at ``level``: ``Phi^-1((1 + level) / 2)^2``
    (3.841458820694124 at 0.95)."""
    return normal_quantile(0.5 + 0.5 * level) ** 2


def _chunks(N: int, progress) -> list[slice]:
    """Slices of the sample axis: one when there is no progress callback, else CHUNK each."""
    if progress is None or N <= CHUNK:
        return [slice(0, N)]
    return [slice(k, min(N, k + CHUNK)) for k in range(0, N, CHUNK)]


@dataclass
class Solution:
    """The solution of eq. (3) for every sample.

    Attributes
    ----------
    F : (N, 6) [N, N·m]
        Estimated wrench (components not estimated are ``prior_mean``).
    tau_f : (N, n) [N·m]
        Optimal friction torque: the residual ``tau_bar - J^T F`` clipped into the band.
    active : (N, n) bool
        Joints whose residual lies strictly outside their band (they "feel" the force).
    cost : (N,)
        Value of the objective of eq. (3) at the optimum (a ridge for ``prior_sigma = inf`` is not
        included).
    iterations : (N,) int
        Newton iterations (``exact``) or solver iterations (reference backends) per sample.
    kkt : (N,)
        Largest scaled gradient component ``|df/dF_i| / (sum of the magnitudes of its terms)``
        at the returned point, a direct check of optimality (0 = exact).
    """

    F: np.ndarray
    tau_f: np.ndarray
    active: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    kkt: np.ndarray


class Samples(NamedTuple):
    """Eq. (3) for a run of ``N`` samples as the compiled kernels take it (numba accepts a
    NamedTuple of arrays as one argument): the fields of a :class:`Problem` a kernel reads,
    sliced to the run (:meth:`Problem.samples`).

    Attributes
    ----------
    tau_bar : (N, n) [N·m]
        Gravity-compensated torque minus the held components' torque.
    J : (N, m, n) [m, 1]
        The estimated components' rows of the tool-point Jacobian.
    tau_min, tau_max : (N, n) [N·m]
        Band edges (``-inf``/``inf`` allowed).
    w : (N, n) [1/(N·m)^2]
        Noise weights ``1 / sigma^2``.
    p : (N, m) [1/N^2, 1/(N·m)^2]
        Prior weights ``1 / prior_sigma^2`` (with the ridge).
    prior_mean : (m,) [N, N·m]
        Prior mean of the estimated components.
    """

    tau_bar: np.ndarray
    J: np.ndarray
    tau_min: np.ndarray
    tau_max: np.ndarray
    w: np.ndarray
    p: np.ndarray
    prior_mean: np.ndarray


@dataclass(frozen=True)
class Problem:
    """Eq. (3) for N samples, reduced to the ``m`` estimated components and broadcast.

    Built by :func:`problem`; the fields are what every backend consumes.

    Attributes
    ----------
    tau_bar : (N, n) [N·m]
        Gravity-compensated torque minus the torque of the held components ``J_held^T F_bar``.
    J : (N, m, n) [m, 1]
        Rows of the Jacobian (transposed ``J^T`` columns) of the estimated components.
    tau_min, tau_max : (N, n) [N·m]
        Band edges (``-inf``/``inf`` allowed).
    w : (N, n) [1/(N·m)^2]
        Noise weights ``1 / sigma^2``.
    p : (N, m) [1/N^2, 1/(N·m)^2]
        Prior weights ``1 / prior_sigma^2`` (with the ridge where ``prior_sigma = inf``).
    p_true : (m,) [1/N^2, 1/(N·m)^2]
        Prior weights without the ridge (0 where ``prior_sigma = inf``).
    prior_mean : (m,) [N, N·m]
        Prior mean of the estimated components.
    free : (m,) int
        Indices (into the 6 components) of the estimated components.
    full_mean : (6,) [N, N·m]
        Prior mean of all six components (the held ones are returned at it).
    """

    tau_bar: np.ndarray
    J: np.ndarray
    tau_min: np.ndarray
    tau_max: np.ndarray
    w: np.ndarray
    p: np.ndarray
    p_true: np.ndarray
    prior_mean: np.ndarray
    free: np.ndarray
    full_mean: np.ndarray

    @property
    def N(self) -> int:
        """Number of samples."""
        return self.tau_bar.shape[0]

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.tau_bar.shape[1]

    @property
    def m(self) -> int:
        """Number of estimated components."""
        return len(self.free)

    def samples(self, rows: slice | np.ndarray = slice(None)) -> Samples:
        """The per-sample arrays of ``rows`` (a slice or indices) for a compiled kernel."""
        return Samples(
            self.tau_bar[rows], self.J[rows], self.tau_min[rows], self.tau_max[rows],
            self.w[rows], self.p[rows], self.prior_mean,
        )  # fmt: skip

    def save(self, path) -> None:
        """Write the problem to an ``.npz`` file (a failing case becomes a test fixture)."""
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **{k: getattr(self, k) for k in self.__dataclass_fields__})

    @classmethod
    def load(cls, path) -> Problem:
        """Read a problem written by :meth:`save`."""
        with np.load(path) as z:
            return cls(**{k: z[k] for k in cls.__dataclass_fields__})


# ----------------------------------------------------------------------------- problem building


def _per_sample(name: str, x, N: int, n: int) -> np.ndarray:
    """A per-joint array (n,) or (N, n) as a float array of that shape (checked)."""
    a = np.asarray(x, dtype=float)
    if a.shape not in ((n,), (N, n)):
        raise ConfigError(
            f"estimator: {name} has shape {a.shape}; expected ({n},) or ({N}, {n}) to match tau_bar"
        )
    return a


def _to_samples(x: np.ndarray, N: int) -> np.ndarray:
    """``x`` (n,), (1, n) or (N, n) broadcast to a contiguous (N, n) float array. A row given
    for every sample (or a broadcast view of one) is repeated with ``np.repeat``: the same
    values, at a third of the time of copying the broadcast view element by element."""
    x = np.asarray(x)
    if x.ndim == 1 or x.shape[0] == 1 or (x.shape[0] > 1 and x.strides[0] == 0):
        return kernel_array(np.repeat(x.reshape(-1, x.shape[-1])[:1], N, axis=0))
    return kernel_array(x)


def kernel_array(x) -> np.ndarray:
    """``x`` as a C-contiguous, writable float array (copied only when it is not one already).

    numba compiles one specialisation of a kernel per combination of its arrays' types, and a
    read-only array (a broadcast view, an Arrow-backed column) is a type of its own: each new
    combination costs minutes of compilation. Every array a :class:`Problem` hands to the kernels
    goes through here, so one compiled signature serves every input.
    """
    return np.require(x, dtype=float, requirements=["C", "W"])


def _component_indices(components: Sequence[str] | None) -> np.ndarray:
    if components is None:
        return np.arange(6)
    if isinstance(components, str):
        components = [components]
    idx = []
    for c in components:
        if c not in COMPONENTS:
            raise ConfigError(
                f"estimator: component {c!r} is unknown; expected a subset of {', '.join(COMPONENTS)}"
            )
        idx.append(COMPONENTS.index(c))
    return np.array(sorted(set(idx)), dtype=np.int64)


def _check_data(tau_bar, J) -> tuple[np.ndarray, np.ndarray]:
    """``tau_bar (N, n)`` [N·m] and ``J (N, 6, n)`` as float arrays: shapes and finite values."""
    tb = np.asarray(tau_bar, dtype=float)
    if tb.ndim != 2:
        raise ConfigError(f"estimator: tau_bar has shape {tb.shape}; expected (N, n)")
    N, n = tb.shape
    Jx = np.asarray(J, dtype=float)
    if Jx.shape != (N, 6, n):
        raise ConfigError(f"estimator: J has shape {Jx.shape}; expected ({N}, 6, {n})")
    for name, arr in (("tau_bar", tb), ("J", Jx)):
        if np.isfinite(arr.sum()):  # a NaN or inf makes the sum non-finite (a single pass)
            continue
        bad = ~np.isfinite(arr)  # or finite values whose sum overflows: look element by element
        if bad.any():
            k = int(np.argwhere(bad)[0][0])
            raise ConfigError(
                f"estimator: {name} at sample {k} is not finite; expected finite values"
            )
    return tb, Jx


def _check_noise(tau_min, tau_max, sigma, N: int, n: int) -> tuple[np.ndarray, ...]:
    """The bands and the noise, (n,) or (N, n) as given [N·m] (checked on the arrays given,
    before they are broadcast to every sample): bands not inverted nor NaN, ``sigma`` positive
    and finite."""
    a = _per_sample("tau_min", tau_min, N, n)
    b = _per_sample("tau_max", tau_max, N, n)
    s = _per_sample("sigma", sigma, N, n)
    a, b, s = np.broadcast_arrays(a, b, s)  # views: (n,) when all three are per joint
    if a.ndim == 1:
        a, b, s = a[None], b[None], s[None]  # the first sample's, as every sample's
    inv = a > b
    if inv.any():
        k, j = (int(v) for v in np.argwhere(inv)[0])
        raise ModelError(
            f"estimator: band of joint {j + 1} at sample {k} is inverted "
            f"(tau_min = {a[k, j]:g} > tau_max = {b[k, j]:g}); expected tau_min <= tau_max"
        )
    if np.isnan(a).any() or np.isnan(b).any():
        raise ModelError("estimator: a band edge is NaN; expected numbers (or +-inf)")
    badsig = ~(np.isfinite(s) & (s > 0))
    if badsig.any():
        k, j = (int(v) for v in np.argwhere(badsig)[0])
        raise ModelError(
            f"estimator: sigma of joint {j + 1} at sample {k} is {s[k, j]:g}; "
            "expected a positive finite noise level [N·m]"
        )
    return a, b, s


def _check_prior(prior_mean, prior_sigma) -> tuple[np.ndarray, np.ndarray]:
    """``prior_mean (6,)`` finite and ``prior_sigma (6,)`` >= 0 [N, N·m] as float arrays."""
    fbar = np.asarray(prior_mean, dtype=float).reshape(-1)
    psig = np.asarray(prior_sigma, dtype=float).reshape(-1)
    if fbar.shape != (6,) or not np.isfinite(fbar).all():
        raise ConfigError(f"estimator: prior_mean is {fbar!r}; expected 6 finite values [N, N·m]")
    if psig.shape != (6,) or np.isnan(psig).any() or (psig < 0).any():
        raise ModelError(
            f"estimator: prior_sigma is {psig!r}; expected 6 values >= 0 (inf = no prior) [N, N·m]"
        )
    return fbar, psig


def _prior_weights(
    psig: np.ndarray, free: np.ndarray, Jf: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(p (N, m), p_true (m,))``: the prior weights ``1 / prior_sigma^2`` of the estimated
    components, with the vanishing ridge (:data:`RIDGE` times the sample's mean data
    information) in ``p`` where ``prior_sigma = inf``."""
    N = len(w)
    with np.errstate(divide="ignore"):
        p_true = np.where(np.isinf(psig[free]), 0.0, 1.0 / psig[free] ** 2)
    p = _to_samples(p_true[None], N)
    noprior = np.isinf(psig[free])
    if noprior.any():
        info = np.einsum("kin,kn->ki", Jf**2, w)  # per-component data information
        scale = info.mean(axis=1) if len(free) else np.ones(N)
        scale = np.where(scale > 0, scale, 1.0)
        p[:, noprior] = RIDGE * scale[:, None]
    return p, p_true


def problem(
    tau_bar,
    J,
    tau_min,
    tau_max,
    sigma,
    prior_mean,
    prior_sigma,
    components: Sequence[str] | None = None,
) -> Problem:
    """Validate and reduce eq. (3) to the estimated components; the parameters are
    :func:`~ditherlab.estimator.estimate`'s.

    Returns
    -------
    Problem
        Broadcast, contiguous arrays every backend consumes.

    Raises
    ------
    ConfigError
        Wrong shapes, non-finite torques or Jacobians, unknown component names.
    ModelError
        An inverted band (``tau_min > tau_max``), a noise ``sigma`` that is not positive and finite,
        a negative ``prior_sigma``.
    """
    tb, Jx = _check_data(tau_bar, J)
    N, n = tb.shape
    a, b, s = _check_noise(tau_min, tau_max, sigma, N, n)
    # per joint or per sample as given; every sample's copies made once checked
    a, b, w = _to_samples(a, N), _to_samples(b, N), _to_samples(1.0 / s**2, N)
    fbar, psig = _check_prior(prior_mean, prior_sigma)
    free = _component_indices(components)
    free = free[psig[free] > 0]
    held = np.setdiff1d(np.arange(6), free)
    # The held components' torque moves into tau_bar:  tau_bar - J_held^T F_bar_held.
    if len(held):
        tb_red = tb - np.einsum("kin,i->kn", Jx[:, held, :], fbar[held])
        Jf = kernel_array(Jx[:, free, :])
    else:  # all six estimated: no copies of contiguous, writable inputs
        tb_red, Jf = tb, kernel_array(Jx)
    p, p_true = _prior_weights(psig, free, Jf, w)
    return Problem(
        tau_bar=kernel_array(tb_red),
        J=Jf,
        tau_min=a,
        tau_max=b,
        w=w,
        p=np.ascontiguousarray(p),
        p_true=p_true,
        prior_mean=np.ascontiguousarray(fbar[free]),
        free=free,
        full_mean=fbar,
    )


# ------------------------------------------------------------------------------- completion


@njit(cache=True, inline="always", _nrt=False)
def _complete_sample(smp, p_true, Fk, tf, act, grad, mag):
    """``tau_f`` into ``tf (n,)`` and ``active`` into ``act (n,)`` of the estimate ``Fk (m,)``
    at the sample ``smp`` (:class:`~ditherlab.estimator.piecewise.Sample`); ``grad``, ``mag``
    (m,) scratch. Returns ``(cost, kkt)`` (see :func:`complete`)."""
    tb, J, a, b, w, p, fb = smp
    m, n = J.shape
    c = 0.0
    for i in range(m):
        dev = Fk[i] - fb[i]
        c += p_true[i] * dev * dev
        grad[i] = p[i] * dev
        mag[i] = p[i] * (abs(Fk[i]) + abs(fb[i]))
    for j in range(n):
        r = tb[j]
        sz = abs(tb[j])
        for i in range(m):
            r -= J[i, j] * Fk[i]
            sz += abs(J[i, j] * Fk[i])
        t = min(max(r, a[j]), b[j])
        tf[j] = t
        d = r - t
        act[j] = d != 0.0
        c += w[j] * d * d
        sz += abs(t)
        for i in range(m):
            grad[i] -= J[i, j] * w[j] * d
            mag[i] += abs(J[i, j]) * w[j] * sz
    e = 0.0
    for i in range(m):
        if mag[i] > 0.0:
            e = max(e, abs(grad[i]) / mag[i])
    return c, e


@njit(cache=True)
def _complete_kernel(S, p_true, Fm, tau_f, active, cost, kkt):
    """``tau_f (N, n)``, ``active (N, n)``, ``cost (N,)`` and ``kkt (N,)`` of the estimate
    ``Fm (N, m)`` of the run ``S`` (:class:`Samples`), ``p_true (m,)`` the prior weights without
    the ridge (see :func:`complete`)."""
    N, m, n = S.J.shape
    grad = np.empty(m)
    mag = np.empty(m)
    for k in range(N):
        cost[k], kkt[k] = _complete_sample(
            sample_at(S, k), p_true, Fm[k], tau_f[k], active[k], grad, mag
        )


def complete(prob: Problem, Fm: np.ndarray, iterations: np.ndarray | None = None) -> Solution:
    """Turn the estimated components ``Fm (N, m)`` into a full :class:`Solution`.

    ``tau_f`` is the residual clipped into the band, ``active`` marks the joints outside it, and
    ``kkt`` is the largest ``|df/dF_i|`` relative to the size of the numbers it is computed from
    (``|J| w (|tau_bar| + |J^T F| + |tau_f|)`` and the prior term), so ~1e-16 is the float floor.
    """
    N, n = prob.N, prob.n
    F = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    F[:, prob.free] = Fm
    tau_f = np.empty((N, n))
    active = np.empty((N, n), np.bool_)
    cost = np.empty(N)
    kkt = np.empty(N)
    Fc = np.ascontiguousarray(Fm, dtype=float)
    _complete_kernel(prob.samples(), prob.p_true, Fc, tau_f, active, cost, kkt)
    its = np.zeros(N, np.int64) if iterations is None else np.asarray(iterations)
    return Solution(F=F, tau_f=tau_f, active=active, cost=cost, iterations=its, kkt=kkt)

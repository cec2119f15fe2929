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
    call. Given the set ``A`` of joints outside their band (and on which side), the minimiser of
    the quadratic piece is one ``m x m`` solve (``m`` = number of estimated components). The
    iteration stops when the active set of the new point equals the one it was computed from:
    then the gradient of ``f`` equals the gradient of that quadratic piece, which is zero, so the
    point is the global minimiser of the convex ``f`` (exact up to the rounding of one Cholesky
    solve; :attr:`Solution.kkt` reports the scaled gradient, typically ~1e-15). A full step that
    does not lower ``f`` is replaced by an exact line search on the piecewise-quadratic ``f``
    along the Newton direction, which makes the iteration monotone and finite. The pieces are
    solved by QR (not the normal equations), so tiny noise does not square the conditioning.
    Limit: when ``max(w) / min(p)`` exceeds ~1e14 (e.g. sigma 1e-4 N·m with prior_sigma 2e4 N)
    whether a joint held at its band edge is active is decided below double precision; the
    solver then tries releasing each such joint and keeps the release when it lowers ``f``,
    which fixed the cases found by fuzzing but not all of them (a fuzz of 300 problems at that
    conditioning left 5 samples up to 6 N away from quadprog; at sane conditioning the worst
    deviation was 5e-8 relative).
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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from ditherlab.errors import ConfigError, ModelError

#: Names of the six wrench components, in the order of ``F`` and of the rows of ``J``.
COMPONENTS = ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")
#: Relative ridge that replaces an infinite prior_sigma (see the module docstring).
RIDGE = 1e-12
#: Intervals whose half-width exceeds this many "information units" are reported as infinite.
UNOBSERVABLE = 1e5
#: Half-width [N, N·m] of the artificial box of the set-membership LP for prior-less components.
BIG_BOX = 1e9


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


@dataclass
class Problem:
    """Eq. (3) for N samples, reduced to the ``m`` estimated components and broadcast.

    Built by :func:`problem`; the fields are what every backend consumes.

    Attributes
    ----------
    tau_bar : (N, n) [N·m]
        Gravity-compensated torque minus the torque of the held components ``J_held^T F_bar``.
    J : (N, m, n)
        Rows of the Jacobian (transposed ``J^T`` columns) of the estimated components.
    tau_min, tau_max : (N, n) [N·m]
        Band edges (``-inf``/``inf`` allowed).
    w : (N, n) [1/(N·m)^2]
        Noise weights ``1 / sigma^2``.
    p : (N, m)
        Prior weights ``1 / prior_sigma^2`` (with the ridge where ``prior_sigma = inf``).
    p_true : (m,)
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
        return self.tau_bar.shape[0]

    @property
    def n(self) -> int:
        return self.tau_bar.shape[1]

    @property
    def m(self) -> int:
        return len(self.free)

    def save(self, path) -> None:
        """Write the problem to an ``.npz`` file (a failing case becomes a test fixture)."""
        from ditherlab.io.atomic import atomic_path

        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **{k: getattr(self, k) for k in self.__dataclass_fields__})

    @classmethod
    def load(cls, path) -> Problem:
        """Read a problem written by :meth:`save`."""
        with np.load(path) as z:
            return cls(**{k: z[k] for k in cls.__dataclass_fields__})


# ----------------------------------------------------------------------------- problem building


def _per_sample(name: str, x, N: int, n: int) -> np.ndarray:
    """Broadcast a per-joint array (n,) or (N, n) to a contiguous (N, n) float array."""
    a = np.asarray(x, dtype=float)
    if a.shape not in ((n,), (N, n)):
        raise ConfigError(
            f"estimator: {name} has shape {a.shape}; expected ({n},) or ({N}, {n}) to match tau_bar"
        )
    return np.ascontiguousarray(np.broadcast_to(a, (N, n)))


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
    """Validate and reduce eq. (3) to the estimated components; see :func:`estimate`.

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
    tb = np.asarray(tau_bar, dtype=float)
    if tb.ndim != 2:
        raise ConfigError(f"estimator: tau_bar has shape {tb.shape}; expected (N, n)")
    N, n = tb.shape
    Jx = np.asarray(J, dtype=float)
    if Jx.shape != (N, 6, n):
        raise ConfigError(f"estimator: J has shape {Jx.shape}; expected ({N}, 6, {n})")
    for name, arr in (("tau_bar", tb), ("J", Jx)):
        bad = ~np.isfinite(arr)
        if bad.any():
            k = int(np.argwhere(bad)[0][0])
            raise ConfigError(
                f"estimator: {name} at sample {k} is not finite; expected finite values"
            )
    a = _per_sample("tau_min", tau_min, N, n)
    b = _per_sample("tau_max", tau_max, N, n)
    s = _per_sample("sigma", sigma, N, n)
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
    fbar = np.asarray(prior_mean, dtype=float).reshape(-1)
    psig = np.asarray(prior_sigma, dtype=float).reshape(-1)
    if fbar.shape != (6,) or not np.isfinite(fbar).all():
        raise ConfigError(f"estimator: prior_mean is {fbar!r}; expected 6 finite values [N, N·m]")
    if psig.shape != (6,) or np.isnan(psig).any() or (psig < 0).any():
        raise ModelError(
            f"estimator: prior_sigma is {psig!r}; expected 6 values >= 0 (inf = no prior) [N, N·m]"
        )
    free = _component_indices(components)
    free = free[psig[free] > 0]
    held = np.setdiff1d(np.arange(6), free)
    # The held components' torque moves into tau_bar:  tau_bar - J_held^T F_bar_held.
    if len(held):
        tb_red = tb - np.einsum("kin,i->kn", Jx[:, held, :], fbar[held])
        Jf = np.ascontiguousarray(Jx[:, free, :])
    else:  # all six estimated: no copies
        tb_red, Jf = np.ascontiguousarray(tb), np.ascontiguousarray(Jx)
    w = 1.0 / s**2
    with np.errstate(divide="ignore"):
        p_true = np.where(np.isinf(psig[free]), 0.0, 1.0 / psig[free] ** 2)
    p = np.broadcast_to(p_true, (N, len(free))).copy()
    noprior = np.isinf(psig[free])
    if noprior.any():
        info = np.einsum("kin,kn->ki", Jf**2, w)  # per-component data information
        scale = info.mean(axis=1) if len(free) else np.ones(N)
        scale = np.where(scale > 0, scale, 1.0)
        p[:, noprior] = RIDGE * scale[:, None]
    return Problem(
        tau_bar=np.ascontiguousarray(tb_red),
        J=Jf,
        tau_min=a,
        tau_max=b,
        w=np.ascontiguousarray(w),
        p=np.ascontiguousarray(p),
        p_true=p_true,
        prior_mean=np.ascontiguousarray(fbar[free]),
        free=free,
        full_mean=fbar,
    )


# ------------------------------------------------------------------------------ numba kernels


@njit(cache=True, inline="always")
def _dist(r, lo, hi):
    if r > hi:
        return r - hi
    if r < lo:
        return r - lo
    return 0.0


@njit(cache=True)
def _cost(tb, J, a, b, w, p, fb, F, m, n):
    c = 0.0
    for i in range(m):
        c += p[i] * (F[i] - fb[i]) ** 2
    for j in range(n):
        r = tb[j]
        for i in range(m):
            r -= J[i, j] * F[i]
        d = _dist(r, a[j], b[j])
        c += w[j] * d * d
    return c


@njit(cache=True)
def _sides(tb, J, a, b, F, m, n, s):
    """Side of every joint at F: +1 above its band, -1 below, 0 inside."""
    for j in range(n):
        r = tb[j]
        for i in range(m):
            r -= J[i, j] * F[i]
        if r > b[j]:
            s[j] = 1
        elif r < a[j]:
            s[j] = -1
        else:
            s[j] = 0


@njit(cache=True)
def _givens_row(R, u, m, z, beta, rhs):
    """Add the row ``u`` (m,) to the upper-triangular ``R`` (m, m) by Givens rotations, in place.

    With ``rhs`` the right-hand side ``z`` (m,) is rotated along with the row's own value
    ``beta``; ``u`` is overwritten. Returns what is left of ``beta`` (the row's residual).
    """
    for i in range(m):
        ui = u[i]
        if ui == 0.0:
            continue
        rii = R[i, i]
        r = math.sqrt(rii * rii + ui * ui)
        c = rii / r
        sn = ui / r
        R[i, i] = r
        for k in range(i + 1, m):
            rik = R[i, k]
            R[i, k] = c * rik + sn * u[k]
            u[k] = c * u[k] - sn * rik
        if rhs:
            zi = z[i]
            z[i] = c * zi + sn * beta
            beta = c * beta - sn * zi
    return beta


@njit(cache=True)
def _newton_piece(tb, J, a, b, w, p, fb, s, m, n, R, z, u, x):
    """Minimiser x of the quadratic piece of f with active set s (joint j outside on side s_j).

    The piece is the least-squares problem ``|sqrt(p) (F - F_bar)|^2 + sum_{j active}
    w_j (tau_bar_j - e_j - J_j^T F)^2``; it is solved by QR (Givens rotations adding one active
    joint row at a time to the triangular factor ``diag(sqrt(p))``), not by the normal
    equations: with tiny noise the normal equations square a condition number of ~1e5 and lose
    1e-4 N in the prior-held directions.
    """
    for i in range(m):
        for k in range(m):
            R[i, k] = 0.0
        R[i, i] = math.sqrt(p[i])
        z[i] = 0.0  # unknown: dF = F - F_bar
    for j in range(n):
        if s[j] == 0:
            continue
        e = b[j] if s[j] > 0 else a[j]
        sw = math.sqrt(w[j])
        beta = tb[j] - e
        for i in range(m):
            beta -= J[i, j] * fb[i]
            u[i] = sw * J[i, j]
        beta *= sw
        _givens_row(R, u, m, z, beta, True)
    for i in range(m - 1, -1, -1):
        v = z[i]
        for k in range(i + 1, m):
            v -= R[i, k] * x[k]
        x[i] = v / R[i, i]
    for i in range(m):
        x[i] += fb[i]


@njit(cache=True)
def _line_search(tb, J, a, b, w, p, fb, F, d, m, n):
    """Exact minimiser t in [0, 1] of the convex piecewise quadratic phi(t) = f(F + t d)."""
    r0 = np.empty(n)
    c = np.empty(n)
    bps = np.empty(2 * n + 1)
    nb = 0
    for j in range(n):
        r = tb[j]
        cj = 0.0
        for i in range(m):
            r -= J[i, j] * F[i]
            cj += J[i, j] * d[i]
        r0[j] = r
        c[j] = cj
        if cj != 0.0:
            for e in (a[j], b[j]):
                t = (r - e) / cj
                if 0.0 < t < 1.0:
                    bps[nb] = t
                    nb += 1
    bps[nb] = 1.0
    nb += 1
    bps[:nb].sort()

    def dphi(t):
        v = 0.0
        for i in range(m):
            v += p[i] * d[i] * (F[i] + t * d[i] - fb[i])
        for j in range(n):
            v -= w[j] * c[j] * _dist(r0[j] - t * c[j], a[j], b[j])
        return v

    t0 = 0.0
    g0 = dphi(0.0)
    if g0 >= 0.0:
        return 0.0
    for q in range(nb):
        t1 = bps[q]
        g1 = dphi(t1)
        if g1 >= 0.0:
            # phi' is linear on [t0, t1]: its root
            return t0 - g0 * (t1 - t0) / (g1 - g0)
        t0, g0 = t1, g1
    return 1.0


@njit(cache=True)
def _solve_exact_kernel(tb, J, a, b, w, p, fb, max_iter, warm, F_out, it_out):
    N, m, n = J.shape
    R = np.empty((m, m))
    z = np.empty(m)
    u = np.empty(m)
    x = np.empty(m)
    d = np.empty(m)
    F = fb.copy()
    s = np.zeros(n, np.int8)
    sn = np.zeros(n, np.int8)
    sa = np.zeros(n, np.int8)
    for k in range(N):
        tbk, Jk, ak, bk, wk, pk = tb[k], J[k], a[k], b[k], w[k], p[k]
        # warm start from the previous sample's solution (time series are smooth)
        if not warm:
            for i in range(m):
                F[i] = fb[i]
        _sides(tbk, Jk, ak, bk, F, m, n, s)
        fcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
        it = 0
        n_amb_tries = 0
        while it < max_iter:
            it += 1
            _newton_piece(tbk, Jk, ak, bk, wk, pk, fb, s, m, n, R, z, u, x)
            _sides(tbk, Jk, ak, bk, x, m, n, sn)
            same = True
            for j in range(n):
                if sn[j] != s[j]:
                    same = False
                    break
            if same:
                # Joints held active at a distance within rounding of their edge: with a huge
                # w_j (tiny noise) and a weak prior the sign of that distance is noise, and the
                # piece without them may be the true optimum (13 N away in a fuzzed case).
                improved = False
                if n_amb_tries < 8:
                    f1 = _cost(tbk, Jk, ak, bk, wk, pk, fb, x, m, n)
                    fbest = f1 - 1e-12 * (1.0 + f1)
                    for j in range(n):
                        if s[j] == 0:
                            continue
                        e = bk[j] if s[j] > 0 else ak[j]
                        r = tbk[j]
                        size = abs(tbk[j]) + abs(e)
                        for i in range(m):
                            r -= Jk[i, j] * x[i]
                            size += abs(Jk[i, j] * x[i])
                        if abs(r - e) > 1e-9 * size:
                            continue
                        for q in range(n):
                            sa[q] = s[q]
                        sa[j] = 0
                        _newton_piece(tbk, Jk, ak, bk, wk, pk, fb, sa, m, n, R, z, u, d)
                        f2 = _cost(tbk, Jk, ak, bk, wk, pk, fb, d, m, n)
                        if f2 < fbest:
                            fbest = f2
                            improved = True
                            for i in range(m):
                                F[i] = d[i]
                if improved:
                    n_amb_tries += 1
                    fcur = fbest
                    _sides(tbk, Jk, ak, bk, F, m, n, s)
                    continue
                for i in range(m):
                    F[i] = x[i]
                break
            fnew = _cost(tbk, Jk, ak, bk, wk, pk, fb, x, m, n)
            if fnew < fcur:
                for i in range(m):
                    F[i] = x[i]
                fcur = fnew
                for j in range(n):
                    s[j] = sn[j]
            else:
                step = 0.0
                for i in range(m):
                    d[i] = x[i] - F[i]
                    step = max(step, abs(d[i]) / (1.0 + abs(F[i])))
                if step < 1e-15:
                    break  # the piece's minimiser is the current point: ties at a band edge
                t = _line_search(tbk, Jk, ak, bk, wk, pk, fb, F, d, m, n)
                if t <= 0.0:
                    break
                for i in range(m):
                    F[i] += t * d[i]
                fcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
                _sides(tbk, Jk, ak, bk, F, m, n, s)
        for i in range(m):
            F_out[k, i] = F[i]
        it_out[k] = it


# ---------------------------------------------------------------------------------- backends


#: Samples per kernel call when a progress callback is given.
CHUNK = 65536


def _chunks(N: int, progress) -> list[slice]:
    """Slices of the sample axis: one when there is no progress callback, else CHUNK each."""
    if progress is None or N <= CHUNK:
        return [slice(0, N)]
    return [slice(k, min(N, k + CHUNK)) for k in range(0, N, CHUNK)]


def _solve_exact(
    prob: Problem, max_iter: int = 100, warm: bool = True, progress=None
) -> tuple[np.ndarray, np.ndarray]:
    F = np.empty((prob.N, prob.m))
    it = np.zeros(prob.N, np.int64)
    if prob.N and prob.m:
        for sl in _chunks(prob.N, progress):
            _solve_exact_kernel(
                prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], prob.w[sl],
                prob.p[sl], prob.prior_mean, max_iter, warm, F[sl], it[sl],
            )  # fmt: skip
            if progress is not None:
                progress(sl.stop, prob.N)
    return F, it


def qp_matrices(prob: Problem, k: int) -> tuple[np.ndarray, ...]:
    """The scaled QP of sample ``k`` in the variables ``x = (y (m), v (n))``.

    ``F = F_bar + S c * y`` and ``v = (J^T (F - F_bar) + tau_f) / (S sigma)`` (the modelled
    torque in noise units), so the Hessian is diagonal and the band becomes the rows
    ``lo <= v - A y <= hi`` with ``A = diag(1/sigma) J^T diag(c)``. The cost divided by ``S^2``
    is ``|t - v|^2 + sum_i p_i c_i^2 y_i^2`` with ``t = (tau_bar - J^T F_bar) / (S sigma)``.
    ``c_i = 1 / sqrt(p_i)`` (the prior sigma, or the ridge's) makes the Hessian the identity;
    ``S`` makes ``t`` and the bounds O(1). (The textbook form in ``(F, tau_f)`` has a condition
    number ~ w J^2 / p, 1e11 with tiny noise, on which ProxQP at eps_abs = 1e-10 is off by tens
    of newtons.)

    Returns
    -------
    P, q, G, h, A, b, c
        The qpsolvers form ``min 1/2 x^T P x + q^T x  s.t.  G x <= h, A x = b`` (zero-width
        bands become equalities) and the scale ``S c (m,)``.
    """
    m, n = prob.m, prob.n
    J, w, p = prob.J[k], prob.w[k], prob.p[k]
    sig = 1.0 / np.sqrt(w)
    c = 1.0 / np.sqrt(p)
    t = (prob.tau_bar[k] - J.T @ prob.prior_mean) / sig
    lo = prob.tau_min[k] / sig
    hi = prob.tau_max[k] / sig
    S = max(1.0, np.abs(t).max(initial=0.0))
    for v in (lo, hi):
        S = max(S, np.abs(v[np.isfinite(v)]).max(initial=0.0))
    t, lo, hi = t / S, lo / S, hi / S
    A = (J * c[:, None]).T / sig[:, None]  # (n, m)
    P = 2.0 * np.diag(np.concatenate([p * c**2, np.ones(n)]))
    q = np.concatenate([np.zeros(m), -2.0 * t])
    rows, rhs, eq_rows, eq_rhs = [], [], [], []
    for j in range(n):
        r = np.zeros(m + n)
        r[:m] = -A[j]
        r[m + j] = 1.0
        if lo[j] == hi[j]:  # a zero-width band is an equality (two opposite rows stall ProxQP)
            eq_rows.append(r)
            eq_rhs.append(hi[j])
            continue
        if np.isfinite(hi[j]):
            rows.append(r)
            rhs.append(hi[j])
        if np.isfinite(lo[j]):
            rows.append(-r)
            rhs.append(-lo[j])
    G = np.array(rows).reshape(-1, m + n)
    h = np.array(rhs, dtype=float)
    A_eq = np.array(eq_rows).reshape(-1, m + n)
    b_eq = np.array(eq_rhs, dtype=float)
    return P, q, G, h, A_eq, b_eq, c * S


#: qpsolvers options per reference backend: tight tolerances (the issue measured proxsuite at its
#: default eps = 1e-5 off by up to 20 N on these problems).
QP_OPTIONS = {
    "proxsuite": ("proxqp", {"eps_abs": 1e-14, "eps_rel": 0.0, "max_iter": 100_000}),
    "quadprog": ("quadprog", {}),
}


def _solve_reference(prob: Problem, backend: str, progress=None) -> tuple[np.ndarray, np.ndarray]:
    import qpsolvers

    solver, opts = QP_OPTIONS[backend]
    F = np.empty((prob.N, prob.m))
    it = np.zeros(prob.N, np.int64)
    if prob.m == 0:
        return F, it
    for k in range(prob.N):
        P, q, G, h, A, b, c = qp_matrices(prob, k)
        qp = qpsolvers.Problem(
            P, q, G if len(h) else None, h if len(h) else None, A if len(b) else None,
            b if len(b) else None,
        )  # fmt: skip
        sol = qpsolvers.solve_problem(qp, solver=solver, **opts)
        if not sol.found or sol.x is None:
            raise ConfigError(f"estimator: the {backend} reference found no solution at sample {k}")
        F[k] = prob.prior_mean + c * sol.x[: prob.m]
        extra = getattr(sol, "extras", {}) or {}
        info = extra.get("info")
        it[k] = getattr(info, "iter", 0) if info is not None else 0
        if progress is not None and (k + 1) % 1000 == 0:
            progress(k + 1, prob.N)
    if progress is not None:
        progress(prob.N, prob.N)
    return F, it


def _available() -> dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]]:
    out: dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]] = {
        "exact": lambda prob, progress=None: _solve_exact(prob, progress=progress)
    }
    try:
        import qpsolvers
    except ImportError:  # pragma: no cover - qpsolvers is a dependency
        return out
    for name, (solver, _) in QP_OPTIONS.items():
        if solver in qpsolvers.available_solvers:
            out[name] = lambda prob, progress=None, name=name: _solve_reference(
                prob, name, progress
            )
    return out


def available_backends() -> list[str]:
    """Names of the estimator backends usable here (``exact`` always)."""
    return list(_available())


# ----------------------------------------------------------------------------------- public


@njit(cache=True)
def _complete_kernel(tb, J, a, b, w, p, p_true, fb, Fm, tau_f, active, cost, kkt):
    N, m, n = J.shape
    grad = np.empty(m)
    mag = np.empty(m)
    for k in range(N):
        c = 0.0
        for i in range(m):
            dev = Fm[k, i] - fb[i]
            c += p_true[i] * dev * dev
            grad[i] = p[k, i] * dev
            mag[i] = p[k, i] * (abs(Fm[k, i]) + abs(fb[i]))
        for j in range(n):
            r = tb[k, j]
            sz = abs(tb[k, j])
            for i in range(m):
                r -= J[k, i, j] * Fm[k, i]
                sz += abs(J[k, i, j] * Fm[k, i])
            tf = min(max(r, a[k, j]), b[k, j])
            tau_f[k, j] = tf
            d = r - tf
            active[k, j] = d != 0.0
            c += w[k, j] * d * d
            sz += abs(tf)
            for i in range(m):
                grad[i] -= J[k, i, j] * w[k, j] * d
                mag[i] += abs(J[k, i, j]) * w[k, j] * sz
        cost[k] = c
        e = 0.0
        for i in range(m):
            if mag[i] > 0.0:
                e = max(e, abs(grad[i]) / mag[i])
        kkt[k] = e


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
    _complete_kernel(
        prob.tau_bar, prob.J, prob.tau_min, prob.tau_max, prob.w, prob.p, prob.p_true,
        prob.prior_mean, np.ascontiguousarray(Fm, dtype=float), tau_f, active, cost, kkt,
    )  # fmt: skip
    its = np.zeros(N, np.int64) if iterations is None else np.asarray(iterations)
    return Solution(F=F, tau_f=tau_f, active=active, cost=cost, iterations=its, kkt=kkt)


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
    """Solve a prepared :class:`Problem` with one backend (see :func:`estimate`)."""
    backends = _available()
    if backend not in backends:
        raise ConfigError(
            f"estimator: backend {backend!r} is not available; installed: "
            f"{', '.join(backends)} (the references need `pip install qpsolvers proxsuite quadprog`)"
        )
    Fm, it = backends[backend](prob, progress=progress)
    return complete(prob, Fm, it)


# ------------------------------------------------------------------------- confidence intervals
#
# Two intervals per estimated component, both exact for the model as stated:
#
# set membership  {F : a_j - k sigma_j <= tau_bar_j - J_j^T F <= b_j + k sigma_j for every joint,
#                      |F_i - F_bar_i| <= k prior_sigma_i for every component with a prior};
#                 [lo_i, hi_i] = [min F_i, max F_i] over that polytope (two LPs per component).
#                 With k = Phi^-1(1 - alpha / (2 q)), q = n + (number of estimated components with
#                 a finite prior) (Bonferroni), the true F lies in the polytope with probability
#                 >= level when the data follow the model (friction inside its band, Gaussian
#                 noise, F drawn from the prior), so every component's interval covers the truth
#                 with probability >= level (conservative). When the polytope is empty (a force
#                 far beyond the prior box, or data inconsistent with the model at this level) the
#                 prior box is dropped for that sample (this keeps the coverage guarantee: the
#                 event "truth in the polytope" implies a non-empty polytope); when the data alone
#                 are inconsistent, NaN.
# profile         {t : min_{F: F_i = t} f(F) - min_F f(F) <= chi2_1(level)}, f the cost of eq. (3)
#                 (tau_f profiled out inside its band). The profile is convex and piecewise
#                 quadratic in t; it is followed exactly from F_hat along the piecewise-linear path
#                 of constrained minimisers (a parametric active set: one joint enters or leaves
#                 at each breakpoint) until it reaches the threshold. In the purely Gaussian case
#                 (zero-width bands) this is the Bayesian 95 % interval F_hat_i +- 1.96 sd_i and
#                 covers exactly; a band makes it wider (residuals inside the band cost nothing).
#
# Measured coverage of 95 % intervals on data drawn from the model (tests, seeded): profile
# 0.949 with Gaussian noise only, 0.975 with bands (forces ~0.999, moments ~0.95); set membership
# 0.996-0.997. The LP fast path agrees with linprog (HiGHS) to ~1e-8 on the test problems and to
# ~4e-6 relative on fuzzed ill-conditioned ones (HiGHS's own feasibility tolerance is 1e-7).
# Prior-less components whose data bound exceeds BIG_BOX = 1e9 are reported infinite.
#
# Components held at the prior give lo = hi = prior_mean. Components without a prior that the
# data cannot see (information below 1e-10 of the sample's mean) give -inf / +inf.


@njit(cache=True)
def _qr_factor(J, w, p, s, m, n, R, u):
    """Upper-triangular R with R^T R = diag(p) + sum_{s_j != 0} w_j J_j J_j^T (Givens rows)."""
    for i in range(m):
        for k in range(m):
            R[i, k] = 0.0
        R[i, i] = math.sqrt(p[i])
    for j in range(n):
        if s[j] == 0:
            continue
        sw = math.sqrt(w[j])
        for i in range(m):
            u[i] = sw * J[i, j]
        _givens_row(R, u, m, u, 0.0, False)


@njit(cache=True)
def _hinv_col(R, i, m, y, x):
    """x = H^{-1} e_i with H = R^T R (two triangular solves)."""
    for q in range(m):
        v = 1.0 if q == i else 0.0
        for k in range(q):
            v -= R[k, q] * y[k]
        y[q] = v / R[q, q]
    for q in range(m - 1, -1, -1):
        v = y[q]
        for k in range(q + 1, m):
            v -= R[q, k] * x[k]
        x[q] = v / R[q, q]


@njit(cache=True)
def _profile_kernel(tb, J, a, b, w, p, fb, Fh, thr, ridge, unobs, lo_out, hi_out, seg_out):
    N, m, n = J.shape
    R = np.empty((m, m))
    R0 = np.empty((m, m))
    u = np.empty(m)
    y = np.empty(m)
    v = np.empty(m)
    F = np.empty(m)
    r = np.empty(n)
    s = np.zeros(n, np.int8)
    s0 = np.zeros(n, np.int8)
    maxseg = 4 * n + 8
    for k in range(N):
        tbk, Jk, ak, bk, wk, pk = tb[k], J[k], a[k], b[k], w[k], p[k]
        f0 = _cost(tbk, Jk, ak, bk, wk, pk, fb, Fh[k], m, n)
        target = f0 + thr
        scale = 0.0
        for i in range(m):
            for j in range(n):
                scale += wk[j] * Jk[i, j] ** 2
        scale = scale / m if scale > 0.0 else 1.0
        far = unobs * math.sqrt(thr / scale)
        # every path starts at F_hat with the same active set: factor it once per sample
        _sides(tbk, Jk, ak, bk, Fh[k], m, n, s0)
        _qr_factor(Jk, wk, pk, s0, m, n, R0, u)
        for i in range(m):
            for sg in (1.0, -1.0):
                for q in range(m):
                    F[q] = Fh[k, q]
                for j in range(n):
                    s[j] = s0[j]
                pcur = f0
                end = np.nan
                nseg = 0
                while nseg < maxseg:
                    nseg += 1
                    if nseg == 1:
                        _hinv_col(R0, i, m, y, v)
                    else:
                        _qr_factor(Jk, wk, pk, s, m, n, R, u)
                        _hinv_col(R, i, m, y, v)
                    h = v[i]
                    for q in range(m):
                        v[q] /= h
                    # slope of the profile along the path: grad f . v (grad f = mu e_i on it)
                    dp = 0.0
                    for q in range(m):
                        dp += 2.0 * pk[q] * (F[q] - fb[q]) * v[q]
                    db = np.inf
                    jb = -1
                    for j in range(n):
                        rj = tbk[j]
                        cj = 0.0
                        for q in range(m):
                            rj -= Jk[q, j] * F[q]
                            cj += Jk[q, j] * v[q]
                        r[j] = rj
                        dp -= 2.0 * wk[j] * cj * _dist(rj, ak[j], bk[j])
                        cj *= sg  # r_j(D) = r_j - D cj
                        dj = np.inf
                        if s[j] == 0:
                            if cj < 0.0:
                                dj = (bk[j] - rj) / (-cj)
                            elif cj > 0.0:
                                dj = (rj - ak[j]) / cj
                        elif s[j] > 0:
                            if cj > 0.0:
                                dj = (rj - bk[j]) / cj
                        elif cj < 0.0:
                            dj = (ak[j] - rj) / (-cj)
                        if dj < 0.0:
                            dj = 0.0
                        if dj < db:
                            db = dj
                            jb = j
                    dp *= sg
                    rem = target - pcur
                    if rem <= 0.0:
                        dstar = 0.0
                    else:
                        qq = 1.0 / h  # p(D) = pcur + dp D + D^2 / h on this piece
                        dstar = 2.0 * rem / (dp + math.sqrt(dp * dp + 4.0 * qq * rem))
                    if dstar <= db:
                        end = F[i] + sg * dstar - Fh[k, i]
                        break
                    for q in range(m):
                        F[q] += sg * db * v[q]
                    if s[jb] == 0:
                        cj = 0.0
                        for q in range(m):
                            cj += Jk[q, jb] * v[q]
                        s[jb] = 1 if sg * cj < 0.0 else -1
                    else:
                        s[jb] = 0
                    pcur = _cost(tbk, Jk, ak, bk, wk, pk, fb, F, m, n)
                seg_out[k] = max(seg_out[k], nseg)
                if ridge[i] and abs(end) > far:
                    end = sg * np.inf
                if sg > 0:
                    hi_out[k, i] = Fh[k, i] + end
                else:
                    lo_out[k, i] = Fh[k, i] + end


@njit(cache=True)
def _lp_active_set(A, bv, nr, d, c, x, W, nW, G, lam, dirn, maxit):
    """Minimise c^T x subject to A[:nr, :d] x <= bv[:nr] from the feasible point x.

    Primal active-set method: W[:nW] are tight, linearly independent rows; move along the
    steepest descent direction projected on their null space until a row blocks (added); at a
    point where the projection vanishes, drop the row with the most negative multiplier; stop
    when all multipliers are >= 0 (optimal). Returns (status, nW): 0 optimal, 1 unbounded,
    2 iteration limit.
    """
    cn = 0.0
    for q in range(d):
        cn += c[q] * c[q]
    cn = math.sqrt(cn)
    for _it in range(maxit):
        # lam = -(A_W A_W^T)^{-1} A_W c ; dirn = -c - A_W^T lam
        for a1 in range(nW):
            r1 = W[a1]
            for a2 in range(a1 + 1):
                r2 = W[a2]
                v = 0.0
                for q in range(d):
                    v += A[r1, q] * A[r2, q]
                G[a1, a2] = v
            v = 0.0
            for q in range(d):
                v += A[r1, q] * c[q]
            lam[a1] = -v
        # Cholesky in place (lower) and solve
        for a1 in range(nW):
            for a2 in range(a1 + 1):
                v = G[a1, a2]
                for q in range(a2):
                    v -= G[a1, q] * G[a2, q]
                if a1 == a2:
                    G[a1, a1] = math.sqrt(v) if v > 0.0 else 1e-300
                else:
                    G[a1, a2] = v / G[a2, a2]
        for a1 in range(nW):
            v = lam[a1]
            for q in range(a1):
                v -= G[a1, q] * lam[q]
            lam[a1] = v / G[a1, a1]
        for a1 in range(nW - 1, -1, -1):
            v = lam[a1]
            for q in range(a1 + 1, nW):
                v -= G[q, a1] * lam[q]
            lam[a1] = v / G[a1, a1]
        dn = 0.0
        for q in range(d):
            v = -c[q]
            for a1 in range(nW):
                v -= A[W[a1], q] * lam[a1]
            dirn[q] = v
            dn += v * v
        dn = math.sqrt(dn)
        if nW == d or dn <= 1e-10 * cn:  # a vertex: the projected direction is zero
            worst = -1
            wl = -1e-10 * cn
            for a1 in range(nW):
                if lam[a1] < wl:
                    wl = lam[a1]
                    worst = a1
            if worst < 0:
                return 0, nW
            W[worst] = W[nW - 1]
            nW -= 1
            continue
        alpha = np.inf
        kb = -1
        for k in range(nr):
            inw = False
            for a1 in range(nW):
                if W[a1] == k:
                    inw = True
                    break
            if inw:
                continue
            ad = 0.0
            ax = 0.0
            an = 0.0
            for q in range(d):
                ad += A[k, q] * dirn[q]
                ax += A[k, q] * x[q]
                an += A[k, q] * A[k, q]
            if ad <= 1e-10 * math.sqrt(an) * dn:
                continue
            sl = bv[k] - ax
            al = (sl if sl > 0.0 else 0.0) / ad
            if al < alpha:
                alpha = al
                kb = k
        if kb < 0:
            return 1, nW
        for q in range(d):
            x[q] += alpha * dirn[q]
        W[nW] = kb
        nW += 1
    return 2, nW


@njit(cache=True)
def _sm_rows(tbk, Jk, ak, bk, sk, fb, halfbox, kk, ridge, attempt, A, bv, m, n):
    """The LP rows of one sample: joint slabs, the (prior or artificial) box, and z >= 0."""
    d1 = m + 1
    # rows: J_j^T F <= tb_j - a_j + k sig_j ; -J_j^T F <= -(tb_j - b_j - k sig_j) ; box rows
    nrow = 0
    for j in range(n):
        for side in (1.0, -1.0):
            edge = ak[j] if side > 0 else bk[j]
            if not math.isfinite(edge):
                continue
            for i in range(m):
                A[nrow, i] = side * Jk[i, j]
            A[nrow, m] = -1.0  # phase-1 slack z
            bv[nrow] = side * (tbk[j] - edge) + kk * sk[j]
            nrow += 1
    nj = nrow
    for i in range(m):
        # an artificial box far beyond any force keeps the LP bounded; an optimum held by it
        # (positive multiplier) is reported as unbounded
        hb = halfbox[i] if not ridge[i] and attempt == 0 else BIG_BOX
        for side in (1.0, -1.0):
            for q in range(d1):
                A[nrow, q] = 0.0
            A[nrow, i] = side
            bv[nrow] = side * fb[i] + hb
            nrow += 1
    for q in range(d1):
        A[nrow, q] = 0.0
    A[nrow, m] = -1.0
    bv[nrow] = 0.0
    nrow += 1
    return nrow, nj


@njit(cache=True)
def _lu_rows(A, Wo, m, M, piv, tmp):
    """LU with partial pivoting of the m x m matrix of rows A[Wo]; Wo is reordered to the pivot
    order (so L U = A[Wo] afterwards). False if (numerically) singular."""
    big = 0.0
    for a1 in range(m):
        for q in range(m):
            M[a1, q] = A[Wo[a1], q]
            big = max(big, abs(M[a1, q]))
        piv[a1] = a1
    for col in range(m):
        pr = col
        for r in range(col + 1, m):
            if abs(M[r, col]) > abs(M[pr, col]):
                pr = r
        if abs(M[pr, col]) <= 1e-12 * big:
            return False
        if pr != col:
            for q in range(m):
                t = M[col, q]
                M[col, q] = M[pr, q]
                M[pr, q] = t
            t2 = piv[col]
            piv[col] = piv[pr]
            piv[pr] = t2
        for r in range(col + 1, m):
            f = M[r, col] / M[col, col]
            M[r, col] = f
            for q in range(col + 1, m):
                M[r, q] -= f * M[col, q]
    for a1 in range(m):
        tmp[a1] = Wo[piv[a1]]
    for a1 in range(m):
        Wo[a1] = tmp[a1]
    return True


@njit(cache=True)
def _lu_solve(M, m, rhs, out):
    """out = (L U)^{-1} rhs."""
    for a1 in range(m):
        v = rhs[a1]
        for q in range(a1):
            v -= M[a1, q] * out[q]
        out[a1] = v
    for a1 in range(m - 1, -1, -1):
        v = out[a1]
        for q in range(a1 + 1, m):
            v -= M[a1, q] * out[q]
        out[a1] = v / M[a1, a1]


@njit(cache=True)
def _lu_solve_t(M, m, rhs, out):
    """out = (L U)^{-T} rhs."""
    for a1 in range(m):
        v = rhs[a1]
        for q in range(a1):
            v -= M[q, a1] * out[q]
        out[a1] = v / M[a1, a1]
    for a1 in range(m - 1, -1, -1):
        v = out[a1]
        for q in range(a1 + 1, m):
            v -= M[q, a1] * out[q]
        out[a1] = v


@njit(cache=True)
def _dual_vertex(A, bv, rn, nrow, m, c, Wo, x, lam, M, piv, u, tmp, rhs, maxit):
    """Dual simplex from the vertex Wo (m rows) for min c^T x subject to A x <= bv.

    The previous sample's optimal vertex stays dual feasible (its multipliers depend on J and
    c only) but the new torques move the right-hand sides: while a row is violated, it enters
    and the row chosen by the dual ratio test leaves. Returns 0 optimal (x, lam, Wo), 1 the
    polytope is empty, 2 gave up (singular, not dual feasible, iteration limit).
    """
    cn = 0.0
    for q in range(m):
        cn = max(cn, abs(c[q]))
    for it in range(maxit):
        if not _lu_rows(A, Wo, m, M, piv, tmp):
            return 2
        for a1 in range(m):
            rhs[a1] = bv[Wo[a1]]
        _lu_solve(M, m, rhs, x)
        for a1 in range(m):
            rhs[a1] = -c[a1]
        _lu_solve_t(M, m, rhs, lam)
        if it == 0:
            for a1 in range(m):
                if lam[a1] < -1e-10 * cn:
                    return 2
        worst = 0.0
        r = -1
        for row in range(nrow):
            v = -bv[row]
            for q in range(m):
                v += A[row, q] * x[q]
            if v > 1e-9 * (1.0 + abs(bv[row])):
                v /= rn[row]  # violation in F units: the most violated row enters
                if v > worst:
                    worst = v
                    r = row
        if r < 0:
            return 0
        for q in range(m):
            rhs[q] = A[r, q]
        _lu_solve_t(M, m, rhs, u)
        theta = np.inf
        leave = -1
        for a1 in range(m):
            if u[a1] > 1e-12:
                t = max(lam[a1], 0.0) / u[a1]
                if t < theta:
                    theta = t
                    leave = a1
        if leave < 0:
            return 1
        Wo[leave] = r
    return 2


@njit(cache=True)
def _set_membership_kernel(tb, J, a, b, sig, fb, halfbox, kk, ridge, lo_out, hi_out, st_out):
    N, m, n = J.shape
    nr = 2 * n + 2 * m
    d1 = m + 1
    A = np.zeros((nr + 1, d1))
    bv = np.zeros(nr + 1)
    G = np.empty((d1, d1))
    lam = np.empty(d1)
    dirn = np.empty(d1)
    x = np.empty(d1)
    c = np.zeros(d1)
    W = np.empty(d1, np.int64)
    M = np.empty((m, m))
    piv = np.empty(m, np.int64)
    tmpw = np.empty(m, np.int64)
    u = np.empty(m)
    rhs = np.empty(m)
    rn = np.empty(nr + 1)
    # optimal working set of every objective (component i, min / max) at the previous sample
    Wst = np.full((2 * m, m), -1, np.int64)
    wval = np.zeros(2 * m, np.bool_)
    for k in range(N):
        tbk, Jk = tb[k], J[k]
        nrow, nj = _sm_rows(tbk, Jk, a[k], b[k], sig[k], fb, halfbox, kk, ridge, 0, A, bv, m, n)
        for row in range(nrow):
            v = 1e-300
            for q in range(m):
                v += abs(A[row, q])
            rn[row] = v
        # warm start: the previous sample's optimal vertices, repaired by dual simplex pivots
        warm = True
        for o in range(2 * m):
            if not wval[o]:
                warm = False
                break
        if warm:
            for o in range(2 * m):
                i = o // 2
                sg = 1.0 if o % 2 == 0 else -1.0
                for q in range(m):
                    c[q] = 0.0
                c[i] = sg
                for a1 in range(m):
                    W[a1] = Wst[o, a1]
                st = _dual_vertex(
                    A, bv, rn, nrow - 1, m, c, W, x, lam, M, piv, u, tmpw, rhs, 4 * m + 8
                )
                if st != 0:
                    warm = False
                    break
                for a1 in range(m):
                    Wst[o, a1] = W[a1]
                val = x[i]
                for a1 in range(m):
                    row = W[a1]
                    if row >= nj and lam[a1] > 1e-9:
                        if ridge[(row - nj) // 2]:
                            val = -sg * np.inf
                if sg > 0:
                    lo_out[k, i] = val
                else:
                    hi_out[k, i] = val
            if warm:
                st_out[k] = 4
                continue
        # cold path: phase 1 (with the prior box, else without it), then 2m LPs chained
        for attempt in range(2):
            if attempt == 1:
                nrow, nj = _sm_rows(tbk, Jk, a[k], b[k], sig[k], fb, halfbox, kk, ridge, 1,
                                    A, bv, m, n)  # fmt: skip
            z0 = 0.0
            for row in range(nj):
                v = -bv[row]
                for i in range(m):
                    v += A[row, i] * fb[i]
                z0 = max(z0, v)
            for i in range(m):
                x[i] = fb[i]
                c[i] = 0.0
            x[m] = z0 + 1.0
            c[m] = 1.0
            st, nW = _lp_active_set(A, bv, nrow, d1, c, x, W, 0, G, lam, dirn, 50 * nrow)
            bscale = 1.0
            for row in range(nj):
                bscale = max(bscale, abs(bv[row]))
            if st == 0 and x[m] <= 1e-9 * bscale:
                st_out[k] = attempt
                break
            st_out[k] = 2 if st == 0 else 3
        if st_out[k] >= 2:
            for i in range(m):
                lo_out[k, i] = np.nan
                hi_out[k, i] = np.nan
            wval[:] = False
            continue
        # phase 2 in F alone (z fixed at 0: drop the z column; rows keep their order)
        nW = 0
        for i in range(m):
            for sg in (1.0, -1.0):
                o = 2 * i + (0 if sg > 0 else 1)
                for q in range(m):
                    c[q] = 0.0
                c[i] = sg
                st, nW = _lp_active_set(A, bv, nrow - 1, m, c, x, W, nW, G, lam, dirn, 50 * nrow)
                wval[o] = st == 0 and nW == m and st_out[k] == 0
                if wval[o]:
                    for a1 in range(m):
                        Wst[o, a1] = W[a1]
                if st == 1:
                    val = -sg * np.inf
                elif st != 0:
                    val = np.nan
                    st_out[k] = 3
                else:
                    val = x[i]
                    # an artificial box row (no prior, or prior box dropped) that holds the
                    # optimum with a positive multiplier: without it the LP is unbounded
                    for a1 in range(nW):
                        row = W[a1]
                        if row >= nj and lam[a1] > 1e-9:
                            ib = (row - nj) // 2
                            if ridge[ib] or st_out[k] == 1:
                                val = -sg * np.inf
                if sg > 0:
                    lo_out[k, i] = val
                else:
                    hi_out[k, i] = val


INTERVAL_METHODS = ("set_membership", "profile")


def interval_k(level: float, n: int, n_prior: int) -> float:
    """Bonferroni half-width multiplier of the set-membership interval.

    ``k = Phi^-1(1 - (1 - level) / (2 q))`` with ``q = n + n_prior`` events (each joint's noise
    within ``+- k sigma``, each prior component within ``+- k prior_sigma``).
    """
    from scipy.stats import norm

    return float(norm.ppf(1.0 - (1.0 - level) / (2.0 * max(1, n + n_prior))))


def _halfbox(prob: Problem, k: float) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.where(
            prob.p_true > 0, k / np.sqrt(np.where(prob.p_true > 0, prob.p_true, 1.0)), np.inf
        )


def _set_membership(
    prob: Problem, level: float, progress=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numba set-membership bounds ``lo, hi (N, m)`` and a status per sample: 0 solved
    cold with the prior box, 1 without it (empty with it), 2 empty (NaN), 3 failure (NaN),
    4 solved by warm-started dual simplex pivots from the previous sample's vertices."""
    ridge = prob.p_true == 0.0
    kk = interval_k(level, prob.n, int((~ridge).sum()))
    lo_m, hi_m = np.empty((prob.N, prob.m)), np.empty((prob.N, prob.m))
    st = np.zeros(prob.N, np.int64)
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, _halfbox(prob, kk))
    for sl in _chunks(prob.N, progress):
        _set_membership_kernel(
            prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], sig[sl],
            prob.prior_mean, half, kk, ridge, lo_m[sl], hi_m[sl], st[sl],
        )  # fmt: skip
        if progress is not None:
            progress(sl.stop, prob.N)
    return lo_m, hi_m, st


def set_membership_reference(prob: Problem, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """The set-membership interval by ``scipy.optimize.linprog`` (HiGHS), two LPs per component.

    Slow and obviously right: the reference for the numba fast path. Returns ``lo, hi (N, m)``
    over the estimated components (NaN where the polytope is empty even without the prior box,
    +-inf where unbounded: no ridge box here, so unobservable components come out infinite).
    """
    from scipy.optimize import linprog

    kk = interval_k(level, prob.n, int((prob.p_true > 0).sum()))
    half = _halfbox(prob, kk)
    N, m = prob.N, prob.m
    lo, hi = np.full((N, m), np.nan), np.full((N, m), np.nan)
    sig = 1.0 / np.sqrt(prob.w)
    bounds = [
        (prob.prior_mean[i] - half[i], prob.prior_mean[i] + half[i])
        if np.isfinite(half[i])
        else (None, None)
        for i in range(m)
    ]
    for k in range(N):
        Jt = prob.J[k].T  # (n, m)
        ub1 = prob.tau_bar[k] - prob.tau_min[k] + kk * sig[k]
        ub2 = -(prob.tau_bar[k] - prob.tau_max[k] - kk * sig[k])
        rows = np.vstack([Jt[np.isfinite(ub1)], -Jt[np.isfinite(ub2)]])
        rhs = np.concatenate([ub1[np.isfinite(ub1)], ub2[np.isfinite(ub2)]])
        bk = bounds
        if linprog(np.zeros(m), A_ub=rows, b_ub=rhs, bounds=bk, method="highs").status == 2:
            bk = [(None, None)] * m  # empty with the prior box: the data alone
            if linprog(np.zeros(m), A_ub=rows, b_ub=rhs, bounds=bk, method="highs").status == 2:
                continue  # empty: NaN
        for i in range(m):
            for sg in (1.0, -1.0):
                c = np.zeros(m)
                c[i] = sg
                for meth in ("highs-ds", "highs-ipm"):  # the dual simplex, else interior point
                    res = linprog(c, A_ub=rows, b_ub=rhs, bounds=bk, method=meth)
                    if res.status in (0, 2, 3):
                        break
                if res.status == 2:
                    # the polytope is known to be non-empty (checked above): HiGHS's presolve
                    # reports "infeasible or unbounded" as infeasible; it is unbounded
                    val = -sg * np.inf
                elif res.status not in (0, 3):
                    raise ConfigError(
                        f"estimator: linprog failed at sample {k} (status {res.status}: "
                        f"{res.message}); expected a solved LP"
                    )
                elif res.status == 3:
                    val = -sg * np.inf
                else:
                    val = res.x[i]
                (lo if sg > 0 else hi)[k, i] = val
    return lo, hi


def intervals(
    tau_bar,
    J,
    tau_min,
    tau_max,
    sigma,
    prior_mean,
    prior_sigma,
    F_hat=None,
    method: str = "set_membership",
    level: float = 0.95,
    components: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Confidence interval of every wrench component, per sample.

    Parameters
    ----------
    tau_bar, J, tau_min, tau_max, sigma, prior_mean, prior_sigma, components
        As for :func:`estimate`.
    F_hat : (N, 6) [N, N·m], optional
        The estimate of :func:`estimate` (computed when not given; used by ``profile``).
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
    if method not in INTERVAL_METHODS:
        raise ConfigError(
            f"estimator: interval method {method!r} is unknown; expected one of "
            f"{', '.join(INTERVAL_METHODS)}"
        )
    if not 0.0 < float(level) < 1.0:
        raise ConfigError(f"estimator: interval level {level!r} is invalid; expected 0 < level < 1")
    prob = problem(tau_bar, J, tau_min, tau_max, sigma, prior_mean, prior_sigma, components)
    N, m = prob.N, prob.m
    if F_hat is None and method == "profile":
        Fm, _ = _solve_exact(prob)
    elif F_hat is not None:
        Fh = np.asarray(F_hat, dtype=float)
        if Fh.shape != (N, 6):
            raise ConfigError(f"estimator: F_hat has shape {Fh.shape}; expected ({N}, 6)")
        Fm = np.ascontiguousarray(Fh[:, prob.free])
    lo = np.broadcast_to(prob.full_mean, (N, 6)).copy()
    hi = lo.copy()
    if m == 0 or N == 0:
        return lo, hi
    lo_m, hi_m = np.empty((N, m)), np.empty((N, m))
    ridge = prob.p_true == 0.0
    if method == "profile":
        from scipy.stats import chi2

        thr = float(chi2.ppf(level, 1))
        seg = np.zeros(N, np.int64)
        Fm = np.ascontiguousarray(Fm)
        for sl in _chunks(N, progress):
            _profile_kernel(
                prob.tau_bar[sl], prob.J[sl], prob.tau_min[sl], prob.tau_max[sl], prob.w[sl],
                prob.p[sl], prob.prior_mean, Fm[sl], thr, ridge, UNOBSERVABLE, lo_m[sl],
                hi_m[sl], seg[sl],
            )  # fmt: skip
            if progress is not None:
                progress(sl.stop, N)
    else:
        lo_m, hi_m, _ = _set_membership(prob, level, progress)
    lo[:, prob.free] = lo_m
    hi[:, prob.free] = hi_m
    return lo, hi

"""The reference backends ``proxsuite`` and ``quadprog``: the same QP solved per sample through
``qpsolvers`` (slow, obviously right; the tests compare the exact backend with both).
"""

from __future__ import annotations

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.estimator.formulation import Problem


def qp_matrices(prob: Problem, k: int) -> tuple[np.ndarray, ...]:
    """The scaled QP of sample ``k`` in the variables ``x = (y (m), v (n))``.

    ``F = F_bar + S c * y`` and ``v = (J^T (F - F_bar) + tau_f) / (S sigma)`` (the modelled
    torque in noise units), so the Hessian is diagonal and the band becomes the rows
    ``lo <= v - A y <= hi`` with ``A = diag(1/sigma) J^T diag(c)``. The cost divided by ``S^2``
    is ``|t - v|^2 + sum_i p_i c_i^2 y_i^2`` with ``t = (tau_bar - J^T F_bar) / (S sigma)``.
    ``c_i = 1 / sqrt(p_i)`` (the prior sigma, or the ridge's) makes the Hessian the identity;
    ``S`` makes ``t`` and the bounds O(1). (The textbook form in ``(F, tau_f)`` has a condition
    number ~ w J^2 / p, huge with tiny noise, on which ProxQP stops far from the optimum.)

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


#: qpsolvers options per reference backend: tight tolerances (at its default eps = 1e-5 proxsuite's
#: answer to these problems is not accurate enough for a reference; the estimator bench measures
#: the deviation).
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

"""Small dense linear algebra in plain compiled loops: the same bits on every CPU.

numpy's LAPACK and BLAS (OpenBLAS) choose their kernels by CPU when they start, and kernels sum
in different orders. The plant is chaotic (stick or slip is a comparison), so a last-bit
difference in its inverse mass matrix grows into other recordings on other machines (README
"The built-in simulator", session 17). Written out in plain loops and compiled without
``fastmath``, these give one result wherever they run. The least squares of :mod:`ditherlab.fit`
solve with the same factor.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def cholesky(A):  # pragma: no cover - compiled
    """Lower Cholesky factor ``L`` (``L Lᵀ = A``) of a symmetric matrix ``A`` (n, n), reading its
    lower triangle; None when ``A`` is not positive definite (a pivot not > 0)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return None
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return L


@njit(cache=True)
def spd_solve(A, b):  # pragma: no cover - compiled
    """``A⁻¹ b`` for a symmetric positive definite ``A`` (n, n) and ``b`` (n,) by Cholesky and
    two triangular solves; None when ``A`` is not positive definite."""
    L = cholesky(A)
    if L is None:
        return None
    n = len(b)
    y = np.empty(n)
    for a in range(n):
        v = b[a]
        for c in range(a):
            v -= L[a, c] * y[c]
        y[a] = v / L[a, a]
    x = np.empty(n)
    for a in range(n - 1, -1, -1):
        v = y[a]
        for c in range(a + 1, n):
            v -= L[c, a] * x[c]
        x[a] = v / L[a, a]
    return x


@njit(cache=True)
def spd_inverse(A):  # pragma: no cover - compiled
    """Inverse of a symmetric positive definite matrix by Cholesky, in plain loops: the same
    bits on every CPU (LAPACK's result depends on the BLAS kernel the CPU selects).

    Parameters
    ----------
    A : (n, n) float64, symmetric positive definite (the links' mass matrix [kg m²])

    Returns
    -------
    (n, n) float64, exactly symmetric: ``A⁻¹`` (within 1e-12 of LAPACK's relative to its largest
    entry on the IRB140's mass matrices, ``tests/test_sim_reproducible.py``) [1/(kg m²)]
    """
    n = A.shape[0]
    L = cholesky(A)
    if L is None:
        raise ValueError("spd_inverse: the matrix is not positive definite")
    # inverse of L (lower triangular), then A^-1 = L^-T L^-1
    Li = np.zeros((n, n))
    for j in range(n):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * Li[k, j]
            Li[i, j] = s / L[i, i]
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for k in range(i, n):
                s += Li[k, i] * Li[k, j]
            out[i, j] = s
            out[j, i] = s
    return out


@njit(cache=True)
def min_norm_solve(J, b):  # pragma: no cover - compiled
    """The least-norm ``x`` with ``J x = b`` for ``J`` (m, n) of full row rank (m ≤ n) and ``b``
    (m,): ``Jᵀ (J Jᵀ)⁻¹ b``, the pseudo-inverse's answer (``J⁻¹ b`` for a square ``J``); None
    when ``J`` loses rank (a singular pose): a pivot of ``J Jᵀ``'s Cholesky factor, squared, at
    most 1e-12 of its largest diagonal entry."""
    m, n = J.shape
    G = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            s = 0.0
            for k in range(n):
                s += J[i, k] * J[j, k]
            G[i, j] = s
            G[j, i] = s
    L = cholesky(G)
    if L is None:
        return None
    big = 0.0
    for i in range(m):
        big = max(big, G[i, i])
    for i in range(m):  # a pivot lost to rounding: the rows are dependent
        if L[i, i] * L[i, i] <= 1e-12 * big:
            return None
    y = spd_solve(G, b)
    x = np.zeros(n)
    for k in range(n):
        s = 0.0
        for i in range(m):
            s += J[i, k] * y[i]
        x[k] = s
    return x


def vector_norm(x) -> float:
    """Euclidean length of a vector (n,), its squares added in order (``np.linalg.norm`` calls
    BLAS, whose kernel depends on the CPU)."""
    s = 0.0
    for v in np.asarray(x, dtype=float).ravel():
        s += float(v) * float(v)
    return math.sqrt(s)

"""Small dense linear algebra in plain compiled loops, independent of the BLAS kernel.

numpy's LAPACK and BLAS (OpenBLAS) choose their kernels by CPU when they start, and kernels sum
in different orders. The plant is chaotic (stick or slip is a comparison), so a last-bit
difference in its inverse mass matrix grows into other recordings on other machines
(``docs/design/reproducible-plant.md``). Written out in plain loops and compiled without
``fastmath``, these give the same bits under every OpenBLAS kernel (checked with two, and with
numpy's AVX2/FMA paths off: ``tests/test_sim_reproducible.py``). The least squares of
:mod:`ditherlab.physics.effect_fit` solve with the same factor; the simulator's lead-through solves for its
joint rates with :func:`lu_solve`.

numba's on-disk cache does not notice an edit of this file in the caches of compiled functions
elsewhere that call these (``fit._solve_kernel``): clear ``__pycache__`` after editing it.
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
    """``A⁻¹ b`` (n,) for a symmetric positive definite ``A`` (n, n) and ``b`` (n,) by Cholesky
    and two triangular solves; None when ``A`` is not positive definite; ValueError when the
    shapes do not match."""
    n = len(b)
    if A.shape[0] != n or A.shape[1] != n:
        raise ValueError("spd_solve: A must be (n, n) for b of length n")
    L = cholesky(A)
    if L is None:
        return None
    y = np.empty(n)
    for a in range(n):
        v = b[a]
        for c in range(a):
            v -= L[a, c] * y[c]
        y[a] = v / L[a, a]
    return _back_substitute(L.T, y)


@njit(cache=True)
def _back_substitute(U, y):  # pragma: no cover - compiled
    """``U⁻¹ y`` (n,) for an upper triangular ``U`` (n, n) (only its upper triangle is read)."""
    n = len(y)
    x = np.empty(n)
    for a in range(n - 1, -1, -1):
        v = y[a]
        for c in range(a + 1, n):
            v -= U[a, c] * x[c]
        x[a] = v / U[a, a]
    return x


@njit(cache=True)
def spd_inverse(A):  # pragma: no cover - compiled
    """Inverse of a symmetric positive definite matrix by Cholesky, in plain loops: the same
    bits under every BLAS kernel (LAPACK's result depends on the kernel the CPU selects).

    Parameters
    ----------
    A : (n, n) float64, symmetric positive definite (the links' mass matrix [kg m²])

    Returns
    -------
    (n, n) float64, exactly symmetric: ``A⁻¹`` (within 1e-12 of LAPACK's relative to its largest
    entry on the IRB140's mass matrices, ``tests/test_linalg.py``) [1/(kg m²)]
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
def lu_solve(A, b):  # pragma: no cover - compiled
    """``A⁻¹ b`` (n,) for a square ``A`` (n, n) and ``b`` (n,) by Gaussian elimination with
    partial pivoting (the lead-through's joint rates from the tool velocity: ``J⁻¹ v``, the
    pseudo-inverse's answer for a square ``J`` of full rank, accurate to ~cond(A)·eps).

    None when ``A`` is singular to working precision: a pivot at most 1e-12 of ``A``'s largest
    entry (a singular pose); ValueError when the shapes do not match."""
    n = len(b)
    if A.shape[0] != n or A.shape[1] != n:
        raise ValueError("lu_solve: A must be (n, n) for b of length n")
    U = A.copy()
    x = b.copy()
    big = 0.0
    for i in range(n):
        for j in range(n):
            big = max(big, abs(U[i, j]))
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(U[i, k]) > abs(U[p, k]):
                p = i
        if not abs(U[p, k]) > 1e-12 * big:
            return None
        if p != k:
            for j in range(n):
                U[k, j], U[p, j] = U[p, j], U[k, j]
            x[k], x[p] = x[p], x[k]
        for i in range(k + 1, n):
            f = U[i, k] / U[k, k]
            for j in range(k, n):
                U[i, j] -= f * U[k, j]
            x[i] -= f * x[k]
    return _back_substitute(U, x)


def vector_norm(x) -> float:
    """Euclidean length of a vector (n,) [its unit], its squares added in order in plain Python
    (``np.linalg.norm`` calls BLAS, whose kernel depends on the CPU)."""
    s = 0.0
    for v in np.asarray(x, dtype=float).ravel():
        s += float(v) * float(v)
    return math.sqrt(s)

"""Small dense linear algebra for the simulator, the same bits on every CPU.

numpy's LAPACK and BLAS (OpenBLAS) choose their kernels by CPU when they start, and kernels sum
in different orders. The plant is chaotic (stick or slip is a comparison), so a last-bit
difference in its inverse mass matrix grows into other recordings on other machines (README
"The built-in simulator", session 17). Written out in plain loops and compiled without
``fastmath``, these give one result wherever they run.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def spd_inverse(A):
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
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
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

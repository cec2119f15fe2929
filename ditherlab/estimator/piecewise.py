"""Numba helpers shared by the exact backend and the profile intervals.

``f`` is the cost of eq. (3) with ``tau_f`` profiled out (see :mod:`ditherlab.estimator`).
numba's on-disk cache does not follow calls into other files: after editing a kernel here,
delete the ``__pycache__`` of ``backends/`` and ``intervals/`` (or touch their modules) so
their cached callers recompile.
"""

from __future__ import annotations

import math

from numba import njit


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

"""Numba helpers shared by the exact backend and the profile intervals: one sample of eq. (3)
(:class:`Sample`), its cost ``f`` with ``tau_f`` profiled out (see :mod:`ditherlab.estimator`),
the sides of its joints, and a Givens row update.

The helpers create no array and are compiled without numba's reference counts (``_nrt=False``),
as are the kernel loops that call them (``docs/design/estimator-kernels.md``). numba's on-disk
cache does not follow calls into other files: after editing a kernel here, delete the
``__pycache__`` of ``backends/`` and ``intervals/`` (or touch their modules) so their cached
callers recompile.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit


class Sample(NamedTuple):
    """Eq. (3) at one sample (a row of :class:`~ditherlab.estimator.formulation.Samples`).

    Attributes
    ----------
    tau_bar : (n,) [N·m]
    J : (m, n) [m, 1]
    tau_min, tau_max : (n,) [N·m]
    w : (n,) [1/(N·m)^2]
    p : (m,) [1/N^2, 1/(N·m)^2]
    prior_mean : (m,) [N, N·m]
    """

    tau_bar: np.ndarray
    J: np.ndarray
    tau_min: np.ndarray
    tau_max: np.ndarray
    w: np.ndarray
    p: np.ndarray
    prior_mean: np.ndarray


@njit(cache=True, inline="always", _nrt=False)
def sample_at(S, k):
    """Sample ``k`` of the run ``S`` (:class:`~ditherlab.estimator.formulation.Samples`)."""
    return Sample(S.tau_bar[k], S.J[k], S.tau_min[k], S.tau_max[k], S.w[k], S.p[k], S.prior_mean)


@njit(cache=True, inline="always")
def _dist(r, lo, hi):
    if r > hi:
        return r - hi
    if r < lo:
        return r - lo
    return 0.0


@njit(cache=True, _nrt=False)
def _cost(smp, F):
    """``f(F)`` at the sample ``smp`` (:class:`Sample`), ``F (m,)`` [N, N·m]."""
    tb, J, a, b, w, p, fb = smp
    m, n = J.shape
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


@njit(cache=True, _nrt=False)
def _sides(smp, F, s):
    """``s (n,)``: the side of every joint of the sample ``smp`` at ``F (m,)``: +1 above its
    band, -1 below, 0 inside."""
    tb, J, a, b = smp.tau_bar, smp.J, smp.tau_min, smp.tau_max
    m, n = J.shape
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


@njit(cache=True, _nrt=False)
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

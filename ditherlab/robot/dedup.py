"""Distinct configurations of a batch of joint positions: :func:`unique_configurations`.

A robot that stands still repeats the same configuration thousands of times, so every batched
method of :class:`~ditherlab.robot.RobotModel` computes each *distinct* configuration once and
scatters the result back. Exact repeats give bit-identical results to the per-sample loop; an
optional quantisation ``tol`` [rad] merges configurations that differ by less than the encoder
resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ditherlab.core.errors import RobotError

__all__ = ["UniqueConfigurations", "unique_configurations"]


@dataclass(frozen=True)
class UniqueConfigurations:
    """Distinct configurations of a batch and the map back to every sample.

    Attributes
    ----------
    q : (U, n) [rad]
        One configuration per group: the exact configuration when ``tol == 0``, the centre of the
        quantisation cell otherwise.
    inverse : (N,) int
        Sample ``i`` belongs to group ``inverse[i]``, so ``values[inverse]`` scatters per-group
        results back to the samples.
    tol : float
        Quantisation step [rad] (0 = exact repeats only).
    """

    q: np.ndarray
    inverse: np.ndarray
    tol: float

    @property
    def ratio(self) -> float:
        """Samples per distinct configuration (N / U, ≥ 1)."""
        return len(self.inverse) / max(len(self.q), 1)


def unique_configurations(q: np.ndarray, tol: float = 0.0) -> UniqueConfigurations:
    """Group the samples of ``q`` into distinct configurations.

    Parameters
    ----------
    q : (N, n) [rad]
        Joint positions.
    tol : float [rad]
        0 merges exact repeats only (bit-identical rows; -0.0 counts as 0.0). ``tol > 0`` merges
        configurations in the same cell of a grid of step ``tol`` on every joint and represents
        each cell by its centre, so every sample is evaluated at most ``tol / 2`` [rad] away from
        its own value per joint.

    Returns
    -------
    UniqueConfigurations
        ``q (U, n)`` in order of first appearance, ``inverse (N,)`` with ``q_out[inverse] == q``
        (exactly when ``tol == 0``).

    Notes
    -----
    1. Runs of consecutive identical rows (a robot standing still with a quiet encoder) are
       collapsed in O(N).
    2. The run representatives are grouped by a 64-bit hash of their bits (``pandas.factorize``,
       O(R)), so a configuration that recurs later (encoder flicker between two counts) is also
       computed once.
    3. The grouping is verified bit for bit; on a hash collision (2**-64 per pair) it falls back
       to sorting the rows (``numpy.unique``), so the result is exact either way.
    """
    q = np.ascontiguousarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise RobotError(f"q has shape {q.shape}, expected (N, n)")
    N, n = q.shape
    if not (np.isfinite(tol) and tol >= 0):
        raise RobotError(f"quantisation tolerance is {tol!r}, expected a finite value >= 0 [rad]")
    if N == 0:
        return UniqueConfigurations(q.copy(), np.zeros(0, dtype=np.intp), float(tol))
    if tol > 0:
        key = np.floor(q / tol + 0.5) + 0.0  # cell index (exact integers for |q / tol| < 2**52)
    else:
        key = q + 0.0  # + 0.0 maps -0.0 to 0.0
    bits = key.view(np.uint64)  # (N, n): compare and hash bit patterns (NaN == NaN here)
    # 1) collapse runs of identical consecutive rows
    starts = np.empty(N, dtype=bool)
    starts[0] = True
    np.any(bits[1:] != bits[:-1], axis=1, out=starts[1:])
    run_first = np.flatnonzero(starts)
    run_id = np.cumsum(starts) - 1  # (N,) run of each sample
    reps = bits[run_first]  # (R, n)
    # 2) hash the representatives, group equal hashes in order of first appearance
    codes, _ = pd.factorize(_row_hash(reps))
    codes = codes.astype(np.intp, copy=False)
    prev_max = np.maximum.accumulate(np.concatenate(([-1], codes[:-1])))
    first = np.flatnonzero(codes > prev_max)  # codes appear in increasing order
    # 3) verify bit for bit (a hash collision would merge different rows)
    if not np.array_equal(reps[first][codes], reps):  # pragma: no cover - 2**-64 per pair
        rows = np.ascontiguousarray(reps).view(np.dtype((np.void, 8 * n))).ravel()
        _, first, codes = np.unique(rows, return_index=True, return_inverse=True)
        codes = codes.reshape(-1)
    inverse = codes[run_id]
    uq = key[run_first[first]] * tol if tol > 0 else q[run_first[first]]
    return UniqueConfigurations(np.ascontiguousarray(uq), inverse, float(tol))


_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def _row_hash(bits: np.ndarray) -> np.ndarray:
    """(R,) uint64 hash of the rows of a (R, n) uint64 array (splitmix64 finaliser per column)."""
    h = np.zeros(len(bits), dtype=np.uint64)
    for j in range(bits.shape[1]):
        x = h ^ (bits[:, j] + np.uint64(_GOLDEN * (j + 1) % 2**64))
        x ^= x >> np.uint64(30)
        x *= _MIX1
        x ^= x >> np.uint64(27)
        x *= _MIX2
        x ^= x >> np.uint64(31)
        h = x
    return h

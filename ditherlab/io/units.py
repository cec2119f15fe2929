"""Joint positions and velocities logged in degrees, recognised before anything uses them.

Two tests, each decisive on its own, neither tuned to a robot:

- **Range.** Some joint lies more than π rad beyond the robot model's limits, and every joint's
  samples read as degrees lie within the limits (0.1 rad of slack). A radian log of the right
  robot never leaves its limits by half a turn; a degree log is inside them once converted.
- **Velocity consistency** (when ``dq`` is logged). The least-squares slope of the derivative
  of ``q`` against the logged ``dq``, over the joints that move, is 180/π within
  :data:`SLOPE_TOLERANCE` and the two agree (correlation at least :data:`MIN_CORRELATION`):
  ``q`` is in degrees and ``dq`` in rad/s. A slope of π/180 says the opposite: ``dq`` in deg/s.
  The constant is a unit conversion, 57.3 apart from the slope 1 of a consistent log.

A joint log that fails either test is refused (:func:`degrees_evidence` names the evidence);
one whose angles are far outside the limits for another reason keeps the warning of
:meth:`ditherlab.robot.RobotModel.check_units`.
"""

from __future__ import annotations

import numpy as np

from ditherlab.data.recording import Recording, differentiate

__all__ = ["MIN_CORRELATION", "SLOPE_TOLERANCE", "degrees_evidence"]

#: relative band around 180/π (or π/180) in which the velocity slope counts as a unit factor
SLOPE_TOLERANCE = 0.2
#: the least correlation of the derivative of q with the logged dq for the slope to count
MIN_CORRELATION = 0.9
_DEG = 180.0 / np.pi


def degrees_evidence(rec: Recording) -> str | None:
    """Why ``rec``'s joint positions (or velocities) look like degrees, in one clause naming the
    columns and the figures, or None when nothing does.

    Parameters
    ----------
    rec : the recording; ``q (N, n)`` should be [rad], a logged ``dq (N, n)`` [rad/s].
    """
    robot = rec.robot()
    q = rec.q
    finite = np.isfinite(q).all(axis=1)
    if finite.sum() < 3:
        return None
    return _range_evidence(q[finite], robot.q_lower, robot.q_upper) or (
        _velocity_evidence(rec.t[finite], q[finite], rec.dq[finite]) if rec.has_dq else None
    )


def _range_evidence(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> str | None:
    """The range test on ``q (N, n)`` against the limits ``(n,) [rad]``."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    excess = np.fmax(lower - lo, hi - upper)
    excess = np.where(np.isfinite(excess), excess, -np.inf)
    j = int(np.argmax(excess))
    if excess[j] <= np.pi:
        return None
    slack = 0.1
    if np.any(np.radians(lo) < lower - slack) or np.any(np.radians(hi) > upper + slack):
        return None
    peak = hi[j] if hi[j] - upper[j] >= lower[j] - lo[j] else lo[j]
    return (
        f"q_{j + 1} reaches {peak:.4g}, more than π beyond its limits [{lower[j]:.3g}, "
        f"{upper[j]:.3g}] rad, and every q_* read as degrees lies within the limits"
    )


def _velocity_evidence(t: np.ndarray, q: np.ndarray, dq: np.ndarray) -> str | None:
    """The velocity test: ``t (N,) [s]``, ``q (N, n)``, the logged ``dq (N, n)``."""
    dq_of_q = differentiate(t, q)
    ok = np.isfinite(dq).all(axis=1) & np.isfinite(dq_of_q).all(axis=1)
    x, y = dq[ok].ravel(), dq_of_q[ok].ravel()
    sxx, syy = float(x @ x), float(y @ y)
    if sxx == 0.0 or syy == 0.0:
        return None
    slope = float(x @ y) / sxx
    corr = float(x @ y) / np.sqrt(sxx * syy)
    if corr < MIN_CORRELATION:
        return None
    if abs(slope / _DEG - 1.0) <= SLOPE_TOLERANCE:
        return (
            f"the derivative of q_* is {slope:.3g} times the logged dq_* (correlation "
            f"{corr:.3f}; 180/π = 57.3 when q is in degrees and dq in rad/s)"
        )
    if abs(slope * _DEG - 1.0) <= SLOPE_TOLERANCE:
        return (
            f"the logged dq_* is {1 / slope:.3g} times the derivative of q_* (correlation "
            f"{corr:.3f}; 180/π = 57.3 when dq is in deg/s and q in rad)"
        )
    return None

"""Joint angles as users give them: :data:`PAPER_POSE`, :func:`parse_pose` (a pose from text) and
:func:`check_units` (angles far outside the limits, as if logged in degrees)."""

from __future__ import annotations

import warnings

import numpy as np

from ditherlab.core.errors import DitherlabWarning, RobotError, where_prefix

__all__ = ["PAPER_POSE", "check_units", "outside_limits", "parse_pose"]

#: The pose of the paper's Fig. 1 for the IRB140, ``(6,) [rad]``: q1 = 0, upper arm vertical,
#: forearm horizontal along +x, q5 = 90° so the flange points down (flange centre at
#: (0.450, 0, 0.647) m).
PAPER_POSE: np.ndarray = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
PAPER_POSE.setflags(write=False)


def parse_pose(text: str | None, n: int, robot_name: str, where: str = "--q") -> np.ndarray:
    """A configuration of an ``n``-joint robot from text: ``"paper"`` (:data:`PAPER_POSE`, for
    robot ``irb140`` only), ``"zero"``, or ``n`` comma-separated angles in radians.

    Returns
    -------
    (n,) [rad]
    """
    if text is None or text.strip().lower() in ("", "zero"):
        return np.zeros(n)
    if text.strip().lower() == "paper":
        if robot_name != "irb140":
            raise RobotError(
                f"{where} is 'paper', which is defined for robot 'irb140' only (this is "
                f"{robot_name!r}); expected {n} comma-separated angles in rad"
            )
        return np.array(PAPER_POSE)
    try:
        q = np.array([float(x) for x in text.split(",")])
    except ValueError:
        q = np.zeros(0)
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise RobotError(
            f"{where} is {text!r}, expected {n} comma-separated angles in rad (or 'zero', 'paper')"
        )
    return q


def outside_limits(q: np.ndarray, q_lower: np.ndarray, q_upper: np.ndarray) -> int | None:
    """The first joint (0-based) of a pose ``q (n,) [rad]`` outside ``[q_lower, q_upper]``
    (n,) [rad], else None."""
    bad = np.flatnonzero((q < q_lower) | (q > q_upper))
    return int(bad[0]) if bad.size else None


def check_units(
    q2: np.ndarray,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    where: str | None = None,
    margin: float = np.pi,
) -> bool:
    """Warn (DitherlabWarning) when joint angles lie far outside the limits, as if in degrees.

    Called by :meth:`RobotModel.check_units <ditherlab.robot.RobotModel.check_units>`; the
    warning points at that method's caller.

    Parameters
    ----------
    q2 : (N, n) [rad]
        Joint positions.
    q_lower, q_upper : (n,) [rad]
        The joint limits (infinite for continuous joints).
    where : str, optional
        File or recording name for the message.
    margin : float [rad]
        A joint is suspicious when some sample lies more than ``margin`` outside
        ``[q_lower, q_upper]`` (NaN samples are ignored).

    Returns
    -------
    bool
        True when a warning was issued (for the joint that is furthest outside).
    """
    if q2.shape[0] == 0 or not np.any(np.isfinite(q2)):
        return False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        lo, hi = np.nanmin(q2, axis=0), np.nanmax(q2, axis=0)
    excess = np.fmax(q_lower - lo, hi - q_upper)  # [rad] beyond the limits
    excess = np.where(np.isfinite(excess), excess, -np.inf)
    j = int(np.argmax(excess))
    if excess[j] <= margin:
        return False
    peak = hi[j] if hi[j] - q_upper[j] >= q_lower[j] - lo[j] else lo[j]
    in_deg = q_lower[j] - 0.1 <= np.radians(lo[j]) and np.radians(hi[j]) <= (q_upper[j] + 0.1)
    hint = " as if in degrees" if in_deg else ""
    warnings.warn(
        f"{where_prefix(where)}q_{j + 1} reaches {peak:.4g}, far outside the joint limits "
        f"[{q_lower[j]:.3g}, {q_upper[j]:.3g}] rad{hint} (expected radians)",
        DitherlabWarning,
        stacklevel=3,
    )
    return True

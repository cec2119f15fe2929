"""Time stamps as ROS 2 carries them: whole nanoseconds, ``builtin_interfaces/Time`` (``sec``
int32, ``nanosec`` uint32).

A time [s] sent over DDS arrives as ``sec + nanosec * 1e-9``; :func:`stamp_time` is that
conversion, for arrays and for one message alike, so that the causal replay of a recording
(:mod:`ditherlab.analysis.causal`) and the live estimate of the same recording streamed over DDS
see the very same floats.
"""

from __future__ import annotations

import numpy as np

__all__ = ["NS_PER_S", "split_stamp", "stamp_time", "wire_time"]

#: nanoseconds per second
NS_PER_S = 1_000_000_000


def split_stamp(t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """``t`` [s] rounded to whole nanoseconds, as ``(sec, nanosec)`` int64 arrays of its shape
    (``nanosec`` in ``[0, 1e9)``; a negative time has a negative ``sec``)."""
    ns = np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
    return ns // NS_PER_S, ns % NS_PER_S


def stamp_time(sec: np.ndarray | int, nanosec: np.ndarray | int) -> np.ndarray | float:
    """``sec + nanosec * 1e-9`` [s] as float64: the time a stamp stands for (arrays or scalars;
    the same IEEE operations either way)."""
    if np.ndim(sec) == 0 and np.ndim(nanosec) == 0:
        return float(sec) + float(nanosec) * 1e-9
    s = np.asarray(sec, dtype=np.int64).astype(float)
    return s + np.asarray(nanosec, dtype=np.int64).astype(float) * 1e-9


def wire_time(t: np.ndarray) -> np.ndarray:
    """``t`` (N,) [s] as it arrives over DDS: rounded to whole nanoseconds and converted back
    (:func:`split_stamp`, :func:`stamp_time`); differs from ``t`` by at most 0.5 ns plus a
    rounding."""
    sec, ns = split_stamp(t)
    return np.asarray(stamp_time(sec, ns), dtype=float)

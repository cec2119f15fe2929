"""Effects of how the external wrench is seen: the servo's attenuation and lag of ``J^T F``,
and the reference F/T sensor's bias, the bias's drift and the sensor's mounting frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.torque_model import REGIMES
from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound
from ditherlab.physics.effects.signals import Signals

#: the longest delay or lag a servo or a tool mount shows a push with [s] (the searched grid's end)
MAX_LATE_S = 0.3


def late_bounds(names: tuple[str, ...]) -> tuple[Bound, ...]:
    """Bounds of searched delays / lags [samples]: 0 .. :data:`MAX_LATE_S` at the log's rate."""
    return tuple(
        Bound(
            name,
            "samples",
            f"0 .. {MAX_LATE_S:g} s",
            "a servo's transport delay and a compliant mount's lag are below 0.3 s; a push lasts "
            "0.5-2 s",
            0.0,
            lambda sigs, j: MAX_LATE_S * sigs[0].sample_rate + 1.0,
        )
        for name in names
    )


def _largest_reading(c: int):
    """The largest |reading| [N or N·m] of F/T column ``c`` in the recordings (a function of
    the recordings' Signals and the joint, for a Bound)."""

    def f(sigs, j):
        return max(float(np.max(np.abs(s.wrench("ft_bias")[:, c]), initial=0.0)) for s in sigs)

    return f


def _within_readings(source: str) -> tuple[Bound, ...]:
    """One Bound per F/T column (``f_x`` .. ``m_z``): within ± the largest reading of the axis
    in the recordings, for the reason ``source``."""
    return tuple(
        Bound(
            c,
            "N" if c.startswith("f") else "N·m",
            "within ± the largest reading of the axis",
            source,
            lambda sigs, j, k=k: -_largest_reading(k)(sigs, j),
            _largest_reading(k),
        )
        for k, c in enumerate(WRENCH_COLUMNS)
    )


def _angle_deg(p, sigs) -> float:
    return float(np.degrees(np.linalg.norm(np.asarray(p["rotation"], dtype=float))))


def _offset_m(p, sigs) -> float:
    return float(np.linalg.norm(np.asarray(p["offset"], dtype=float)))


#: the time constants of a sensor's warm-up [s] (``ft_drift``)
WARM_UP_S = (5.0, 3600.0)


def _less(ext: str, term: str) -> str:
    """The external torque's text ``ext`` (``J^T F``, ``J^T (F - a)``, ``J^T ft_frame·F``, ...)
    with ``term`` taken from the wrench: ``J^T (F - term)``, ``J^T (F - a - term)``, ..."""
    if ext.endswith(")"):
        return f"{ext[:-1]} - {term})"
    return f"{ext[:-1]}(F - {term})" if ext.endswith("F") else f"{ext} - J^T {term}"


__all__ = ["AttenuationLag", "FtBias", "FtDrift", "FtFrame"]


@njit(cache=True)
def _first_order_lag(x: np.ndarray, a: float) -> np.ndarray:
    """``y_k = a x_k + (1 - a) y_(k-1)`` from rest at ``x_0`` (N,): what
    ``scipy.signal.lfilter([a], [1, a - 1], x, zi=[x_0 (1 - a)])`` computes, in its order of
    operations (tested against it)."""
    y = np.empty_like(x)
    z = x[0] * (1.0 - a)
    for k in range(len(x)):
        v = a * x[k] + z
        y[k] = v
        z = -(a - 1.0) * v
    return y


def rotvec_matrix(rot: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a rotation vector ``rot`` (3,) [rad] (axis times angle), by
    its unit quaternion as ``scipy.spatial.transform.Rotation.from_rotvec(rot).as_matrix()``
    computes it (tested against it)."""
    r = np.asarray(rot, dtype=float)
    angle = math.sqrt(float(r @ r))
    if angle <= 1e-3:  # Taylor series of sin(angle / 2) / angle
        scale = 0.5 - angle**2 / 48.0 + angle**4 / 3840.0
    else:
        scale = math.sin(angle / 2.0) / angle
    x, y, z = scale * r
    w = math.cos(angle / 2.0)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array(
        [
            [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
        ]
    )


class AttenuationLag(Effect):
    """The servo shows ``gain`` of the external torque, late: ``J^T F`` delayed by ``delay``
    samples (a transport delay: communication, a filter with a flat group delay) and passed
    through a first-order lag of ``lag`` samples (a compliant mount or a force loop: a spring and
    damper in series with the tool), ``gain · lag(J^T F(t - delay))``.

    Both are searched, each on its own grid with the other zero (a pure delay or a pure lag),
    and the one that fits best is kept: a compliant support passes the push through a lag,
    which a delay only approximates (``docs/design/physics-effect-models.md``).
    """

    name = "attenuation_lag"
    order = 7
    physics = "the servo shows only part of the external torque, and late"
    driven_by = "J^T F (F/T sensor), delay or first-order lag searched"
    linear = ("gain",)
    hyper = ("delay", "lag")
    kind = "external"
    shows_in = REGIMES
    pointwise = False  # a delay and a filter in time
    bounds = (
        Bound(
            "gain",
            "-",
            "0 .. 1.1",
            "the servo shows at most the whole push; the F/T sensor's calibration is ±10 %",
            0.0,
            1.1,
        ),
        *late_bounds(("delay", "lag")),
    )

    def signs(self, h):
        return (1,)

    def check(self, sig):
        sig.wrench(self.name)

    @staticmethod
    def delayed(sig: Signals, X: np.ndarray, h: Any) -> np.ndarray:
        """``X`` (N,) delayed by ``h[0]`` samples and low-passed by a first-order lag of time
        constant ``h[1]`` samples (None in either: 0), started at rest at ``X[0]``."""
        d, lag = int(h[0] or 0), float(h[1] or 0.0)
        out = X
        if d > 0:
            out = np.empty_like(X)
            out[d:] = X[:-d]
            out[:d] = X[:1]
        if lag > 0:
            a = 1.0 / (lag + 1.0)  # backward Euler of T dy/dt = x - y, T = lag samples
            out = _first_order_lag(np.ascontiguousarray(out, dtype=float), a)
        return out

    def grid(self, sig, j):
        fs = sig[0].sample_rate
        kmax = max(int(round(0.3 * fs)), 2)
        ks = sorted(set(np.unique(np.round(np.geomspace(1, kmax, 20)).astype(int))))
        return [(0, 0)] + [(k, 0) for k in ks] + [(0, k) for k in ks]

    def design(self, sig, j, h, ref):
        X = sig._get("jtf_lp", lambda: sig.jtf(sig.wrench_lp(self.name)))[:, j]
        return Design(self.delayed(sig, X, h)[:, None], offset=-X)

    def driver(self, sig, j, p):
        return sig.jtf(sig.wrench_lp(self.name))[:, j], f"(J^T F)_{j + 1} [N·m]"

    def external(self, sig, j, X, w, h):
        return w[0] * self.delayed(sig, X, h)

    def external_text(self, p, ext):
        return f"{fmt(p['gain'])}·({ext})({_late(p)})"

    def term(self, p, j):
        return f"attenuation_lag(gain={fmt(p['gain'])}, {_late(p)})"


def _late(p: dict[str, Any]) -> str:
    """'delay=D samples' and/or 'lag=L samples' of attenuation_lag parameters ``p``."""
    parts = [f"delay={int(p.get('delay') or 0)} samples"]
    if p.get("lag"):
        parts.append(f"lag={fmt(p['lag'])} samples")
    return ", ".join(parts)


class FtBias(Effect):
    name = "ft_bias"
    order = 8
    physics = "the reference F/T sensor reads a constant offset"
    driven_by = "J^T (constant in F)"
    shared = True
    linear = WRENCH_COLUMNS
    kind = "sensor"
    shows_in = REGIMES
    bounds = _within_readings(
        "a bias is part of every reading, so it cannot exceed the largest one"
    )

    def check(self, sig):
        sig.wrench(self.name)

    def design(self, sig, j, h, ref):
        sig.wrench(self.name)
        return Design(-sig.jac.transpose(0, 2, 1))

    def driver(self, sig, j, p):
        b = self.weights(p)
        return -(sig.jac[:, :, j] @ b), f"-(J^T bias)_{j + 1} [N·m]"

    def correct_wrench(self, F, p, sig):
        return F - self.weights(p)

    def sensor_text(self, ext):
        return _less(ext, "ft_bias")

    def term(self, p, j):
        b = ", ".join(fmt(p[c]) for c in self.linear)
        return f"ft_bias([{b}])"


class FtDrift(Effect):
    """The reference F/T sensor's bias drifts as it warms up: it reads ``F + d x(t)``, ``t``
    the time since the recording's first sample, ``x(t) = (1 - exp(-t/T)) / (1 - exp(-S/T))``
    a warm-up of time constant ``T`` [s] scaled to 1 at ``t = S`` (``span``: the longest
    recording's length when fitted) and ``d`` (6,) the drift over those ``S`` seconds [N, N·m].

    A strain-gauge sensor's zero moves as its electronics and the gauges' bond warm up after
    power-on (a first-order approach to the warm offset), and with the room's temperature. The
    parameters are the drift reached within the recording, not the offset when warm: that one is
    not determined when ``T`` is much longer than the recording (the drift is then a straight
    line, ``x(t) = t / S``, the grid's longest ``T``). A constant part of the bias is
    :class:`FtBias`; the two add. The true wrench is ``F - d x(t)``; the torque of the fit is
    ``-J^T d x(t)``, linear in ``d`` at each ``T`` of the grid. It is identifiable when the
    pose or the recording's length lets ``J^T x(t)`` differ from the bands' constant.
    """

    name = "ft_drift"
    order = 12
    physics = "the reference F/T sensor's bias drifts as it warms up"
    driven_by = "J^T (1 - exp(-t/T)): a first-order warm-up from the first sample, T searched"
    shared = True
    linear = WRENCH_COLUMNS
    hyper = "time_constant"
    kind = "sensor"
    shows_in = REGIMES
    bounds = _within_readings(
        "the drift is part of every reading, so within the recording it cannot exceed the "
        "largest one"
    ) + (
        Bound(
            "time_constant",
            "s",
            f"{WARM_UP_S[0]:g} .. {WARM_UP_S[1]:g} s",
            "a strain-gauge sensor's electronics and bond warm up over minutes to an hour after "
            "power-on; a faster change is not a warm-up",
            WARM_UP_S[0],
            WARM_UP_S[1],
        ),
    )

    def check(self, sig):
        sig.wrench(self.name)

    def grid(self, sig, j):
        """Five time constants from an eighth of the recording's span to eight times it, each
        within :data:`WARM_UP_S`."""
        S = self.reference(sig, j)["span"]
        T = np.clip(np.geomspace(S / 8.0, 8.0 * S, 5), *WARM_UP_S)
        return [float(v) for v in np.unique(T)]

    def reference(self, sig, j):
        return {"span": float(max(s.length - 1 for s in sig) / sig[0].sample_rate) or 1.0}

    @staticmethod
    def shape(ts: np.ndarray, T: float, span: float) -> np.ndarray:
        """``x(t)`` (N,) [-] at the times since the first sample ``ts`` (N,) [s]."""
        return -np.expm1(-ts / T) / -math.expm1(-span / T)

    def design(self, sig, j, h, ref):
        sig.wrench(self.name)
        x = self.shape(sig.ts, float(h), float(ref["span"]))
        return Design(-sig.jac.transpose(0, 2, 1) * x[:, None, None])

    def _drift(self, sig: Signals, p: dict[str, Any]) -> np.ndarray:
        """(N, 6) [N, N·m] the drift at the samples of ``sig``."""
        x = self.shape(sig.ts, float(p["time_constant"]), float(p["span"]))
        return x[:, None] * self.weights(p)

    def driver(self, sig, j, p):
        return -sig.jtf(self._drift(sig, p))[:, j], f"-(J^T drift)_{j + 1} [N·m]"

    def correct_wrench(self, F, p, sig):
        return F - self._drift(sig, p)

    def sensor_text(self, ext):
        return _less(ext, "ft_drift(t)")

    def term(self, p, j):
        d = ", ".join(fmt(p[c]) for c in self.linear)
        return f"ft_drift([{d}] over {fmt(p['span'])} s, time constant {fmt(p['time_constant'])} s)"


class FtFrame(Effect):
    """The F/T sensor is mounted rotated (and its origin offset) with respect to the tool frame,
    while the log converts its reading as if it were not.

    The sensor's axes are the tool's axes turned by the rotation vector ``rotation`` (tool axes,
    rad; ``R_s = exp([rotation]x)``) and its origin sits at ``offset`` (tool axes, m) from the
    tool point. With ``R`` the tool frame's axes in base axes and ``Q = R R_s R^T``, the logged
    wrench is ``F_log = Q^T F``, ``m_log = Q^T (m - (R offset) x F)``, so the true wrench at the
    tool point is ``F = Q F_log``, ``m = Q m_log + (R offset) x F`` (:meth:`correct_wrench`,
    exact). For the fit ``Q`` is linearised, ``Q ~ I + [R rotation]x``: the torque
    ``J^T (F - F_log)`` is linear in the six parameters, the rotation's column k being
    ``J^T ((R e_k) x F_log, (R e_k) x m_log)`` and the offset's ``J^T (0, (R e_k) x F_log)``.
    The linear fit returns ``sin(angle)`` instead of the angle (0.13 % low at 5 degrees) and
    leaves the second-order part ``(1 - cos) [u]x^2 F`` (0.4 % of |F| at 5 degrees) unexplained
    while fitting; the stored rotation is applied exactly. Identifiable only when the force
    turns with respect to the tool (pushes along several axes, several poses).
    """

    name = "ft_frame"
    order = 10
    physics = "the F/T sensor is mounted rotated (and offset) with respect to the tool frame"
    driven_by = "J^T ((R e_k) x F): the F/T columns turned about the tool's axes"
    shared = True
    linear = ("rot_x", "rot_y", "rot_z", "offset_x", "offset_y", "offset_z")
    kind = "sensor"
    shows_in = REGIMES
    bounds = (
        Bound(
            "rotation angle",
            "°",
            "0 .. 20°",
            "a mounting error; the linearised fit holds within 2 % up to 20°, a larger turn is "
            "a frame convention to set in the mapping",
            0.0,
            20.0,
            value=_angle_deg,
        ),
        Bound(
            "offset distance",
            "m",
            "0 .. 0.2 m",
            "the sensor sits at the flange; a larger offset is another tool point (tool_offset)",
            0.0,
            0.2,
            value=_offset_m,
        ),
    )

    def check(self, sig):
        sig.wrench(self.name)

    def weights(self, p):
        return np.array([*p["rotation"], *p["offset"]], dtype=float)

    def linear_params(self, w):
        return {"rotation": [float(x) for x in w[:3]], "offset": [float(x) for x in w[3:]]}

    def to_range(self, w):
        """The rotation shortened to the largest angle and the offset to the largest distance
        of their ranges, each along its own direction."""
        out = np.array(w, dtype=float)
        angle, distance = self.bounds  # [°] of the rotation vector's norm [rad]; [m]
        for part, top in ((slice(0, 3), math.radians(angle.hi)), (slice(3, 6), distance.hi)):
            size = float(np.linalg.norm(out[part]))
            if size > top:
                out[part] *= top / size
        return out

    @staticmethod
    def _columns(sig: Signals, F: np.ndarray) -> np.ndarray:
        """(N, 6, 6): the wrench change per unit parameter, ``F - F_log`` linearised."""
        R = sig.tool_rotation
        f, m = F[:, :3], F[:, 3:]
        cols = np.zeros((len(F), 6, 6))
        for k in range(3):
            u = R[:, :, k]  # the tool's axis k in base axes
            cols[:, :3, k] = np.cross(u, f)
            cols[:, 3:, k] = np.cross(u, m)
            cols[:, 3:, 3 + k] = np.cross(u, f)
        return cols

    def design(self, sig, j, h, ref):
        cols = self._columns(sig, sig.wrench_lp(self.name))
        return Design(np.einsum("tcj,tck->tjk", sig.jac, cols))

    def driver(self, sig, j, p):
        F = sig.wrench_lp(self.name)
        dF = self.correct_wrench(F, p, sig) - F
        return sig.jtf(dF)[:, j], f"(J^T (F - F_log))_{j + 1} [N·m]"

    def correct_wrench(self, F, p, sig):
        rot = np.asarray(p["rotation"], dtype=float)
        d = np.asarray(p["offset"], dtype=float)
        R = sig.tool_rotation
        Rs = rotvec_matrix(rot)
        Q = R @ Rs @ R.transpose(0, 2, 1)
        f = np.einsum("tab,tb->ta", Q, F[:, :3])
        m = np.einsum("tab,tb->ta", Q, F[:, 3:]) + np.cross(R @ d, f)
        return np.concatenate([f, m], axis=1)

    def sensor_text(self, ext):
        return ext.replace("J^T ", "J^T ft_frame·", 1)

    def term(self, p, j):
        rot = np.asarray(p["rotation"], dtype=float)
        angle = float(np.degrees(np.linalg.norm(rot)))
        axis = rot / np.linalg.norm(rot) if angle > 0 else rot
        a = ", ".join(fmt(x) for x in axis)
        o = ", ".join(fmt(x) for x in p["offset"])
        return f"ft_frame({fmt(angle)}° about [{a}] (tool axes), offset [{o}] m)"

"""The compiled joint step of the LuGre plant: PID servo, LuGre friction, coupled arm.

Per joint ``j`` the plant is (arm side of the gear, rigid transmission)::

    (M(q) + diag(Jm)) ddq + h(q, dq) + F_j = tau_m + r_j(q) + tau_ext
    F_j   = s_j (sigma0 z + sigma1 dz/dt) + s_j sigma2 dq                        (LuGre)
    dz/dt = dq - sigma0 |dq| z / g(dq)
    g(dq) = s_j (Fc + k_L |tau_m| + (Fs - Fc) exp(-(dq / vs)^2))                 (Stribeck curve)
    tau_m = Kp e + Kd de + Ki int(e) + tau_ffw,   e = q_ref - (q - delta)        (servo)

``M`` [kg m²], ``h = C dq + g`` [N·m] and ``tau_ext = J^T P`` [N·m] are held over one block
(one logged sample, 4 ms at 250 Hz) and evaluated by pinocchio outside; inside the block the
state advances in ``nsub`` substeps of ``dt`` [s]. The arm's acceleration is linearly implicit
in the stiff terms (the servo's Kp and Kd, the bristles' sigma0 and sigma1, the viscous
sigma2): ``A = M + diag(Jm) + dt diag(D) + dt² diag(K)`` is inverted once per block, and the
bristle state is advanced by the exact solution of its equation at the new velocity, so the
step is stable for any bristle stiffness. Sticking, presliding (the bristle spring), hysteresis
and stick-slip all follow from the state equation; there is no band and no switch.

Packed inputs (time first where there is time):

- ``state`` (5, n): q [rad], dq [rad/s], z [rad], int(e) [rad·s], tau_m [N·m] (updated in place)
- ``ref`` (2, nsub, n): q_ref [rad], dq_ref [rad/s] at each substep
- ``fric`` (8, n): sigma0 [N·m/rad], sigma1 [N·m·s/rad], sigma2 [N·m·s/rad], Fc, Fs [N·m],
  vs [rad/s], k_L [-], s [-] (the block's friction factor: temperature)
- ``servo`` (10, n): Kp [N·m/rad], Kd [N·m·s/rad], Ki [N·m/(rad·s)], tau_max [N·m], int_max
  [rad·s], dither amplitude reaching the motor [N·m], delta [rad] (encoder zero error),
  ripple amplitude [N·m], ripple periods per revolution [-], ripple phase [rad], reflected
  motor inertia Jm [kg m²]
- ``block`` (3, n): h(q, dq) [N·m], tau_ext [N·m], the feedforward's static part [N·m]
- ``mass`` (n, n) [kg m²]: M(q), its upper triangle (pinocchio's CRBA fills only that)
- ``wave`` (nsub,): the dither wave in [-1, 1]
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["FRICTION_ROWS", "SERVO_ROWS", "lugre_block", "stribeck_curve", "bristle_update"]

FRICTION_ROWS = ("sigma0", "sigma1", "sigma2", "fc", "fs", "vs", "k_load", "scale")
SERVO_ROWS = (
    "kp",
    "kd",
    "ki",
    "tau_max",
    "int_max",
    "dither_amp",
    "offset",
    "ripple_amp",
    "ripple_periods",
    "ripple_phase",
    "jm",
)


@njit(cache=True, inline="always")
def stribeck_curve(v: float, fric: np.ndarray, j: int, load: float) -> float:
    """g(v) [N·m] of joint j: the steady sliding friction at velocity v [rad/s] under a
    transmitted torque ``load`` [N·m]."""
    fc = fric[3, j] + fric[6, j] * abs(load)
    hump = (fric[4, j] - fric[3, j]) * np.exp(-((v / fric[5, j]) ** 2))
    return fric[7, j] * (fc + hump)


@njit(cache=True, inline="always")
def bristle_update(z: float, v: float, g: float, sigma0: float, dt: float) -> float:
    """The bristle deflection [rad] after dt [s] at constant velocity v [rad/s]: the exact
    solution of ``dz/dt = v - sigma0 |v| z / g``."""
    if v == 0.0:
        return z
    zss = np.sign(v) * g / sigma0
    return zss + (z - zss) * np.exp(-sigma0 * abs(v) * dt / g)


@njit(cache=True, inline="always")
def _torques(s, state, ref, fric, servo, block, wave, out):
    """The net torque on each joint (out, (n,)) at substep s; sets tau_m (state[4])."""
    n = state.shape[1]
    for j in range(n):
        q, v, z = state[0, j], state[1, j], state[2, j]
        e = ref[0, s, j] - (q - servo[6, j])
        u = servo[0, j] * e + servo[1, j] * (ref[1, s, j] - v) + servo[2, j] * state[3, j]
        u += block[2, j] + wave[s] * servo[5, j]
        u = min(max(u, -servo[3, j]), servo[3, j])
        state[4, j] = u
        g = stribeck_curve(v, fric, j, u)
        zdot = v - fric[0, j] * abs(v) * z / g
        friction = fric[7, j] * (fric[0, j] * z + fric[1, j] * zdot + fric[2, j] * v)
        ripple = servo[7, j] * np.sin(servo[8, j] * q + servo[9, j])
        out[j] = u + ripple + block[1, j] - block[0, j] - friction


@njit(cache=True, inline="always")
def _cholesky(mass, fric, servo, dt):
    """The lower Cholesky factor (n, n) of the step's matrix ``A = M + diag(Jm) + dt diag(Kd +
    s (sigma1 + sigma2)) + dt² diag(Kp + s sigma0)`` (module docstring)."""
    n = mass.shape[0]
    a = np.empty((n, n))
    for i in range(n):
        for k in range(i, n):
            a[i, k] = mass[i, k]
            a[k, i] = mass[i, k]
        s = fric[7, i]
        a[i, i] += servo[10, i] + dt * (servo[1, i] + s * (fric[1, i] + fric[2, i]))
        a[i, i] += dt * dt * (servo[0, i] + s * fric[0, i])
    low = np.zeros((n, n))
    for i in range(n):
        for k in range(i + 1):
            acc = a[i, k]
            for m in range(k):
                acc -= low[i, m] * low[k, m]
            low[i, k] = np.sqrt(acc) if i == k else acc / low[k, k]
    return low


@njit(cache=True, inline="always")
def _solve(low, b, out):
    """out = A^-1 b with A = low low^T (low lower triangular, (n, n))."""
    n = b.shape[0]
    for i in range(n):
        acc = b[i]
        for m in range(i):
            acc -= low[i, m] * out[m]
        out[i] = acc / low[i, i]
    for i in range(n - 1, -1, -1):
        acc = out[i]
        for m in range(i + 1, n):
            acc -= low[m, i] * out[m]
        out[i] = acc / low[i, i]


@njit(cache=True)
def lugre_block(state, ref, fric, servo, block, mass, wave, dt):
    """Advance ``state`` (5, n) over ``len(wave)`` substeps of ``dt`` [s] (in place); returns
    the mean velocity over the block (n,) [rad/s] (what an encoder difference measures)."""
    n = state.shape[1]
    net, acc = np.zeros(n), np.zeros(n)
    low = _cholesky(mass, fric, servo, dt)
    q_start = state[0].copy()
    nsub = wave.shape[0]
    for s in range(nsub):
        _torques(s, state, ref, fric, servo, block, wave, net)
        _solve(low, net, acc)
        for j in range(n):
            v_new = state[1, j] + dt * acc[j]
            state[1, j] = v_new
            state[0, j] += dt * v_new
            g = stribeck_curve(v_new, fric, j, state[4, j])
            state[2, j] = bristle_update(state[2, j], v_new, g, fric[0, j], dt)
            e = ref[0, s, j] - (state[0, j] - servo[6, j])
            state[3, j] = min(max(state[3, j] + dt * e, -servo[4, j]), servo[4, j])
    return (state[0] - q_start) / (dt * nsub)

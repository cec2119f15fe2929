"""Drive calibration effects: what the drive logs differs from the joint's truth by a
calibration error of its own measurements, the torque reading's scale (``drive_gain``) and the
encoder's zero (``joint_offset``).

Neither is friction, a gear effect or a link's physics: the arm is what the model says, the log
of it is not. Both are linear in their parameters, so they are fitted by the same band-aware
least squares as every effect, and both need a varying load or pose to be seen (in one fixed
pose gravity is constant and the band takes them: ``identify --add`` refuses them there).
"""

from __future__ import annotations

import math

import numpy as np

from ditherlab.data.torque_model import REGIMES
from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound
from ditherlab.physics.effects.signals import Signals

__all__ = ["DriveGain", "JointOffset"]


class DriveGain(Effect):
    """The logged torque of a joint is ``k`` times its true torque (a motor constant, current
    scale or gear ratio wrong in the log's mapping): ``tau_logged = k · tau_true``.

    The residual is then ``(k - 1) · tau_true``. Fitted linearly as ``(k - 1)`` times the
    model's rigid torque of the joint, ``tau_grav + J^T F`` plus ``M(q) ddq + C(q, dq) dq`` while it moves
    (:attr:`Signals.rigid_load`): the friction part ``(k - 1) · friction`` is constant within a
    regime or proportional to ``sign(dq)`` / ``dq``, so the re-identified bands and sliding line
    take it (they are the logged friction, scaled by k). Linear in the one parameter, so no
    search and no local minima; the small parts left out are ``(k - 1)`` times the reflected
    motor inertia torque and times the inertia effect's own correction. In one fixed pose with
    no force ``tau_grav`` is a constant: the band takes it, and ``identify --add`` refuses the
    effect ("cannot be told apart from the bands").
    """

    name = "drive_gain"
    order = 10
    physics = "the logged torque is k times the true torque (motor constant or gear ratio wrong)"
    driven_by = "the model's rigid torque tau_grav + J^T F (+ M ddq + C dq moving)"
    linear = ("gain_error",)
    shows_in = REGIMES
    bounds = (
        Bound(
            "k",
            "-",
            "0.5 .. 2",
            "a torque constant, current scale or gear ratio wrong by at most a factor 2: "
            "datasheet tolerances are ±10 %, more is a wrong unit or ratio in the mapping",
            0.5,
            2.0,
            value=lambda p, sigs: 1.0 + float(p["gain_error"]),
            linear=("gain_error", 1.0),
        ),
    )

    def design(self, sig, j, h, ref):
        return Design(sig.rigid_load[:, j : j + 1])

    def force_gain(self, p):
        # the log scales the push's torque too: the sensorless estimate reads k·J^T F
        return 1.0 + float(p["gain_error"])

    def driver(self, sig, j, p):
        return sig.rigid_load[:, j], f"tau_grav + J^T F + M ddq + C dq, joint {j + 1} [N·m]"

    def term(self, p, j):
        g = p["gain_error"]
        return f"drive_gain(k={fmt(1.0 + g)}: {fmt(g)}·(tau_grav + J^T F + M ddq + C dq)_{j + 1})"


#: central-difference step for the gravity derivative [rad] (rounding error ~1e-10 relative)
_FD_STEP = 1e-6
#: columns of the gravity derivative below this share of its largest entry are structurally zero
_ZERO = 1e-9


def gravity_derivative(sig: Signals) -> np.ndarray:
    """(N, n, n) [N·m/rad]: ``∂tau_grav_j / ∂q_k`` at the logged poses, by central differences
    of :meth:`ditherlab.robot.RobotModel.gravity` (its tool and payload included), cached with
    the recording's robot quantities. Columns that are zero for this robot up to rounding (a
    vertical first axis, a last axis with its mass on the axis) are set exactly to zero."""

    def make() -> np.ndarray:
        robot = sig.rec.robot()
        q = sig.q
        n = sig.n
        D = np.zeros((len(q), n, n))
        for k in range(n):
            dq = np.zeros(n)
            dq[k] = _FD_STEP
            D[:, :, k] = (robot.gravity(q + dq) - robot.gravity(q - dq)) / (2 * _FD_STEP)
        col = np.abs(D).max(axis=(0, 1))
        D[:, :, col <= _ZERO * max(float(col.max()), 1e-300)] = 0.0
        return D

    # cached with the robot quantities shared by both views of the recording
    return sig.cached("gravity_derivative", make)


def load_derivative(sig: Signals) -> np.ndarray:
    """(N, n, n) [N·m/rad]: ``∂(tau_grav + J^T F)_j / ∂q_k``, F the low-passed F/T columns
    when the recording's view has them (the residual subtracts the same ``J^T F``), else the
    gravity derivative alone."""
    if not sig.has_wrench:
        return gravity_derivative(sig)

    def make() -> np.ndarray:
        robot = sig.rec.robot()
        q, n = sig.q, sig.n
        F = sig.wrench_lp("joint_offset")
        D = gravity_derivative(sig).copy()
        for k in range(n):
            dq = np.zeros(n)
            dq[k] = _FD_STEP
            dJ = (robot.jacobian(q + dq) - robot.jacobian(q - dq)) / (2 * _FD_STEP)
            D[:, :, k] += np.einsum("tij,ti->tj", dJ, F)
        col = np.abs(D).max(axis=(0, 1))
        D[:, :, col <= _ZERO * max(float(col.max()), 1e-300)] = 0.0
        return D

    return sig._get("load_derivative", make)


class JointOffset(Effect):
    """Encoder zero offsets: the true pose is ``q + δ`` while the model evaluates gravity and the
    Jacobian at the logged ``q``. Linearised, ``tau_grav(q + δ) + J(q + δ)^T F ≈ tau_grav(q) +
    J(q)^T F + ∂(tau_grav + J^T F)/∂q · δ``: one offset per joint, shared by every joint's
    torque (the offset of joint 3 changes the gravity torque of joints 2 and 3). Derivatives by
    central differences of the robot model (its tool and payload included); ``J^T F`` only
    where the F/T sensor is seen. The offset's change of ``M(q)`` is left out.

    The first-order term's error is ``½ δᵀ (∂²tau/∂q²) δ``, second order in offsets of a few
    mrad and far below a joint's noise floor; the ``J^T F`` term is first order and matters
    during pushes: without it a push's torque is read as an offset
    (``docs/design/physics-effect-models.md``). An offset nothing depends on (joint 1 about the
    vertical without pushes, a last joint with its mass on its axis) has a zero column: it stays
    0 and the identifiability test leaves it out. A single fixed pose without force gives
    constant columns that the bands take: refused there.
    """

    name = "joint_offset"
    order = 11
    physics = "encoder zero offsets: gravity is evaluated at the logged q, the arm is at q + δ"
    driven_by = "∂(tau_grav + J^T F)/∂q (pose, F/T sensor)"
    shared = True
    linear = ("offset",)
    shows_in = REGIMES
    bounds = (
        Bound(
            "offset",
            "rad",
            "-10° .. 10° per joint",
            "an encoder zero's calibration error; a larger one is a zero convention to set in "
            "the mapping",
            -math.radians(10.0),
            math.radians(10.0),
        ),
    )

    def signs(self, h):
        return ()

    def weights(self, p):
        return np.array(p["offset"], dtype=float)

    def linear_params(self, w):
        return {"offset": [float(x) for x in w]}

    def design(self, sig, j, h, ref):
        return Design(load_derivative(sig))

    def driver(self, sig, j, p):
        return load_derivative(sig)[:, j, :] @ self.weights(p), (
            f"(∂(tau_grav + J^T F)/∂q · δ)_{j + 1} [N·m]"
        )

    def term(self, p, j):
        d = ", ".join(fmt(x) for x in p["offset"])
        return f"joint_offset(δ=[{d}] rad: (∂(tau_grav + J^T F)/∂q · δ)_{j + 1})"

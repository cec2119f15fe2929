"""Rigid-body effects: an unmodelled payload, and the links' and motors' inertia."""

from __future__ import annotations

import numpy as np

from ditherlab.effects.base import Design, Effect, fmt

__all__ = ["Inertia", "Payload"]


class Payload(Effect):
    """An unmodelled mass at the tool: its gravity torque, and while moving its inertia and
    Coriolis torques (pinocchio's joint-torque regressor of the tool link, linear in the mass
    and its first moments; the point mass's own rotational inertia, ``m·|c|²``, is neglected).
    Measured on the simulator's 3-pose excitation with a 2 kg payload: gravity alone left a
    residual that load_friction was then suggested for (max 1.13x the floor)."""

    name = "payload"
    order = 6
    physics = (
        "an unmodelled mass at the tool: gravity and inertia torques that change with the pose"
    )
    driven_by = "q, dq, ddq (joint-torque regressor of the last link)"
    shared = True
    linear = ("mass", "mc_x", "mc_y", "mc_z")
    shows_in = ("moving", "still", "dither")

    def signs(self, h):
        return (1, 0, 0, 0)

    def weights(self, p):
        return np.array([p["mass"], *p["mass_com"]], dtype=float)

    def linear_params(self, w):
        return {"mass": float(w[0]), "mass_com": [float(x) for x in w[1:]]}

    def design(self, sig, j, h, ref):
        return Design(sig.torque_regressor[:, :, :4])

    def driver(self, sig, j, p):
        w = np.array([p["mass"], *p["mass_com"]])
        return sig.torque_regressor[:, j, :4] @ w, f"payload torque joint {j + 1} [N·m]"

    def term(self, p, j):
        c = ", ".join(fmt(x / p["mass"]) if p["mass"] else "0" for x in p["mass_com"])
        return f"payload(m={fmt(p['mass'])} kg, com=[{c}] m)"


class Inertia(Effect):
    name = "inertia"
    order = 9
    physics = "dynamic torque M(q)·ddq of the links plus the reflected motor inertia"
    driven_by = "ddq"
    linear = ("scale", "motor_inertia")
    shows_in = ("moving",)

    def signs(self, h):
        return (1, 1)

    def design(self, sig, j, h, ref):
        Mddq = np.einsum("tk,tk->t", sig.mass[:, j, :], sig.ddq)
        return Design(np.column_stack([Mddq, sig.ddq[:, j]]))

    def driver(self, sig, j, p):
        return sig.ddq[:, j], f"ddq_{j + 1} [rad/s²]"

    def term(self, p, j):
        return f"inertia({fmt(p['scale'])}·M ddq + {fmt(p['motor_inertia'])}·ddq_{j + 1})"

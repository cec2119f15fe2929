"""Friction effects: viscous, Stribeck, load-dependent and temperature-dependent friction.

Friction acts as a sliding torque only while a joint moves; while it sticks, friction is whatever
lies in the band, so there these effects can only widen the band (``Design.widen``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ditherlab.core.errors import ModelError, where_prefix
from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound, effort_scale, friction_scale
from ditherlab.physics.effects.signals import Signals


def _viscous_max(sigs: Sequence[Signals], j: int | None) -> float:
    """[N·m·s/rad]: the viscous coefficient whose torque at the joint's fastest logged speed
    equals its effort limit (:func:`~ditherlab.physics.effects.ranges.effort_scale`)."""
    jj = slice(None) if j is None else slice(j, j + 1)
    v = max(float(np.max(np.abs(s.dq[:, jj]), initial=0.0)) for s in sigs)
    return effort_scale(sigs, j) / v if v > 0 else np.inf


__all__ = ["LoadFriction", "Stribeck", "TemperatureFriction", "Viscous"]


class Viscous(Effect):
    name = "viscous"
    order = 1
    physics = "torque proportional to velocity (lubricant shear)"
    driven_by = "dq"
    linear = ("coef",)
    shows_in = ("moving",)
    bounds = (
        Bound(
            "coef",
            "N·m·s/rad",
            "0 .. effort limit / fastest logged speed",
            "lubricant shear dissipates (>= 0) and cannot stall the motor at the log's speeds",
            0.0,
            _viscous_max,
        ),
    )

    def design(self, sig, j, h, ref):
        return Design(sig.dq[:, j : j + 1])

    def term(self, p, j):
        return f"{fmt(p['coef'])}·viscous(dq_{j + 1})"


class Stribeck(Effect):
    name = "stribeck"
    order = 2
    physics = "friction higher near zero speed, decaying with speed (Stribeck curve)"
    driven_by = "dq (moving)"
    linear = ("fs_minus_fc",)
    hyper = "vs"
    shows_in = ("moving",)
    bounds = (
        Bound(
            "fs_minus_fc",
            "N·m",
            "0 .. the joint's sliding friction level",
            "static friction lies between 1 and 2 times the Coulomb level (Armstrong-Hélouvry, "
            "Dupont and Canudas de Wit 1994)",
            0.0,
            friction_scale,
        ),
    )

    def signs(self, h):
        return (1,)  # friction is *higher* near zero speed

    def design(self, sig, j, h, ref):
        dq = sig.dq[:, j]
        c = np.exp(-((dq / h) ** 2)) * np.sign(dq) * sig.moving[:, j]
        return Design(c[:, None])

    def grid(self, sig, j):
        v = np.concatenate([np.abs(s.dq[s.moving[:, j], j]) for s in sig])
        hi = float(np.quantile(v, 0.9)) if v.size else 1.0
        hi = max(hi, 1e-3)
        return list(np.geomspace(hi / 100, hi, 16))

    def driver(self, sig, j, p):
        return sig.dq[:, j], f"dq_{j + 1} [rad/s]"

    def term(self, p, j):
        return f"{fmt(p['fs_minus_fc'])}·stribeck(dq_{j + 1}, vs={fmt(p['vs'])})"


class LoadFriction(Effect):
    """Friction that grows with the torque the gear transmits (the mesh's normal force).

    The gear torque is not logged; it is the torque the links ask of the gear,
    ``L = |L0 + c·(1 + g·|L0|/fc)·sign(dq)|`` with ``L0 = tau_grav + J^T F + M(q) ddq + C(q, dq) dq``:
    gravity and the external wrench, the links' inertia torque while moving, and the friction
    on the gear's *output* side (bearings after the gear), which the teeth also carry in the
    direction of motion: ``c`` [N·m] at no load, growing by the relative rate ``g / fc`` per
    N·m of load like the joint's friction itself (``fc`` [N·m]: the joint's sliding friction
    level in the data, the median ``|tau - tau_grav - J^T F|`` while moving). ``c`` and ``g``
    are searched on a grid; while the joint sticks the split of the held friction is unknown and
    ``L = |tau_grav + J^T F|``. All terms are the model's, never the measured torque: a load
    taken from the measured torque contains the residual itself, and then "explains" any
    missing effect (a payload, a ripple) through ``k·|tau|``. Why each term of the load:
    ``docs/design/physics-effect-models.md``.
    """

    name = "load_friction"
    order = 3
    signed_evidence = True
    physics = "Coulomb friction and the stick band grow with the torque the gear transmits"
    driven_by = "|L0 + c·(1 + g·|L0|/fc)·sign(dq)|, L0 = tau_grav + J^T F + M ddq + C dq; sign(dq)"
    linear = ("k",)
    hyper = ("output_friction", "output_growth")
    shows_in = ("moving", "still", "dither")
    bounds = (
        Bound(
            "k",
            "N·m per N·m",
            "0 .. 1",
            "a gear loses at most as much torque as it transmits: efficiency 50 % or more "
            "(harmonic drives cold and slow 50-65 %, cycloid and planetary gears 60-95 %)",
            0.0,
            1.0,
        ),
    )

    def signs(self, h):
        return (1,)  # friction grows with load

    @staticmethod
    def load(sig: Signals, j: int, h: Any = None, fc: float = 1.0) -> np.ndarray:
        """(N,) [N·m]: the gear torque of joint j for ``h = (c [N·m], g [-])`` (None: no
        output-side friction) and the friction level ``fc`` [N·m]."""
        c, g = h if h is not None else (0.0, 0.0)
        L = sig.rigid_load[:, j].copy()
        mv = sig.moving[:, j]
        if c:
            grow = 1.0 + (g or 0.0) * np.abs(L[mv]) / max(fc, 1e-9)
            L[mv] += c * grow * np.sign(sig.dq[mv, j])
        return np.abs(L)

    @staticmethod
    def level(sig: Sequence[Signals], j: int) -> float:
        """[N·m]: the joint's sliding friction level, median |tau - tau_grav - J^T F| moving."""
        parts = []
        for s in sig:
            mv = s.moving[:, j]
            r = s.tau[mv, j] - s.gravity[mv, j]
            if s.has_wrench:
                r = r - s.sensor_torque("load_friction")[mv, j]
            parts.append(np.abs(r))
        v = np.concatenate(parts)
        return float(np.median(v)) if v.size else 0.0

    def grid(self, sig, j):
        fc = self.level(sig, j)
        cs = [float(x) for x in fc * np.linspace(0.0, 1.0, 9)]
        return [(0.0, 0.0)] + [(c, g) for c in cs[1:] for g in (0.0, 0.1, 0.2, 0.3)]

    def reference(self, sig, j):
        return {
            "load_ref": float(np.mean(np.concatenate([self.load(s, j) for s in sig]))),
            "friction_level": self.level(sig, j),
        }

    def design(self, sig, j, h, ref):
        x = self.load(sig, j, h, ref.get("friction_level", 1.0)) - ref["load_ref"]
        mv = sig.moving[:, j]
        return Design((x * np.sign(sig.dq[:, j]) * mv)[:, None], (x * ~mv)[:, None])

    def driver(self, sig, j, p):
        h = (p.get("output_friction"), p.get("output_growth"))
        L = self.load(sig, j, h, p.get("friction_level") or 1.0)
        return L, f"|gear torque| joint {j + 1} [N·m]"

    def term(self, p, j):
        c, g = fmt(p.get("output_friction") or 0.0), fmt(p.get("output_growth") or 0.0)
        fc = fmt(p.get("friction_level") or 0.0)
        return (
            f"{fmt(p['k'])}·load_friction(|L0 + {c}·(1 + {g}·|L0|/{fc})·sign dq|_{j + 1}, "
            f"sign dq_{j + 1})"
        )


class TemperatureFriction(Effect):
    name = "temperature_friction"
    order = 4
    signed_evidence = True
    physics = "friction falls as the joint warms up (lubricant viscosity)"
    driven_by = "temp_j, or time since start when no temperature is logged"
    linear = ("coef",)
    hyper = "time_constant"
    shows_in = ("moving", "still", "dither")
    bounds = (
        Bound(
            "coef",
            "N·m/°C",
            "-(sliding friction level)/20 .. 0 per °C (temperature logged)",
            "friction falls with warming, by about half over 30-40 °C (Bittencourt and "
            "Gunnarsson 2012)",
            lambda sigs, j: -friction_scale(sigs, j) / 20.0,
            0.0,
            value=lambda p, sigs: p["coef"] if p.get("time_constant") is None else None,
        ),
        Bound(
            "coef",
            "N·m",
            "0 .. the sliding friction level (time since start)",
            "a cold joint's extra friction is at most its warm level (Bittencourt and "
            "Gunnarsson 2012)",
            0.0,
            friction_scale,
            value=lambda p, sigs: p["coef"] if p.get("time_constant") is not None else None,
        ),
    )

    def signs(self, h):
        # falls as the temperature rises; decays with time since start (higher when cold)
        return (-1,) if h is None else (1,)

    @staticmethod
    def _x(sig: Signals, j: int, h: Any) -> np.ndarray:
        if h is None:
            if sig.temp is None:
                raise ModelError(
                    f"{where_prefix(sig.rec.name)}effect 'temperature_friction' is driven by column "
                    f"temp_{j + 1}, which the recording lacks"
                )
            return sig.temp[:, j]
        return np.exp(-sig.ts / h)

    def check(self, sig):
        return None

    def grid(self, sig, j):
        if all(s.temp is not None for s in sig):
            return [None]
        T = max(s.ts[-1] for s in sig) or 1.0
        return list(np.geomspace(T / 20, 5 * T, 14))

    def reference(self, sig, j):
        if all(s.temp is not None for s in sig):
            return {"x_ref": float(np.mean(np.concatenate([s.temp[:, j] for s in sig])))}
        return {"x_ref": None}

    def design(self, sig, j, h, ref):
        x = self._x(sig, j, h)
        xr = ref["x_ref"] if ref.get("x_ref") is not None else float(np.mean(x))
        x = x - xr
        mv = sig.moving[:, j]
        return Design((x * np.sign(sig.dq[:, j]) * mv)[:, None], (x * ~mv)[:, None])

    def driver(self, sig, j, p):
        if p.get("time_constant") is None and sig.temp is not None:
            return sig.temp[:, j], f"temp_{j + 1} [°C]"
        return sig.ts, "time since start [s]"

    def term(self, p, j):
        if p.get("time_constant") is None:
            return f"{fmt(p['coef'])}·temperature_friction(temp_{j + 1})"
        return f"{fmt(p['coef'])}·temperature_friction(exp(-t/{fmt(p['time_constant'])} s))"

"""Effects of how the external wrench is seen: the servo's attenuation and lag of ``J^T F``,
and the reference F/T sensor's bias.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.signal import lfilter

from ditherlab.effects.base import Design, Effect, fmt
from ditherlab.effects.signals import Signals
from ditherlab.model import REGIMES
from ditherlab.recording import WRENCH_COLUMNS

__all__ = ["AttenuationLag", "FtBias"]


class AttenuationLag(Effect):
    """The servo shows ``gain`` of the external torque, late: ``J^T F`` delayed by ``delay``
    samples (a transport delay: communication, a filter with a flat group delay) and passed
    through a first-order lag of ``lag`` samples (a compliant mount or a force loop: a spring and
    damper in series with the tool), ``gain · lag(J^T F(t - delay))``.

    Both are searched, each on its own grid with the other zero (a pure delay or a pure lag),
    and the one that fits best is kept. Measured on the simulator (70 % of the push reaching the
    arm through a 0.15 s first-order lag, pushes up to 50 N while moving): the best pure delay
    (0.12 s, gain 0.61) leaves joint 2 at 1.33x the noise floor, the first-order lag (0.152 s,
    gain 0.68-0.72) at 0.85x.
    """

    name = "attenuation_lag"
    order = 7
    physics = "the servo shows only part of the external torque, and late"
    driven_by = "J^T F (F/T sensor), delay or first-order lag searched"
    linear = ("gain",)
    hyper = ("delay", "lag")
    kind = "external"
    shows_in = REGIMES

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
            out, _ = lfilter([a], [1.0, a - 1.0], out, zi=[out[0] * (1.0 - a)])
        return out

    def grid(self, sig, j):
        fs = sig[0].sample_rate
        kmax = max(int(round(0.3 * fs)), 2)
        ks = sorted(set(np.unique(np.round(np.geomspace(1, kmax, 20)).astype(int))))
        return [(0, 0)] + [(k, 0) for k in ks] + [(0, k) for k in ks]

    def design(self, sig, j, h, ref):
        X = sig.jtf(sig.wrench_lp(self.name))[:, j]
        return Design(self.delayed(sig, X, h)[:, None], offset=-X)

    def driver(self, sig, j, p):
        return sig.jtf(sig.wrench_lp(self.name))[:, j], f"(J^T F)_{j + 1} [N·m]"

    def external(self, sig, X, w, h):
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

    def check(self, sig):
        sig.wrench(self.name)

    def design(self, sig, j, h, ref):
        sig.wrench(self.name)
        return Design(-sig.jac.transpose(0, 2, 1))

    def driver(self, sig, j, p):
        b = self.weights(p)
        return -(sig.jac[:, :, j] @ b), f"-(J^T bias)_{j + 1} [N·m]"

    def correct_wrench(self, F, p):
        return F - self.weights(p)

    def sensor_text(self, ext):
        return "J^T (F - ft_bias)"

    def term(self, p, j):
        b = ", ".join(fmt(p[c]) for c in self.linear)
        return f"ft_bias([{b}])"

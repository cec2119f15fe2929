"""Slow external loads on the tool that the F/T sensor measures (clean controls).

``--external-load KIND`` (repeatable); each acts at the tool point, its force drawn per seed:

- ``cable``: a cable pulling in a drawn direction (within 30° of horizontal) with 5..15 N that
  varies slowly: ``F0 (1 + 0.3 sin(2π f t + phi))``, f 0.01..0.05 Hz.
- ``hose``: a hose anchored 0.3..0.6 m from the tool's home position (below and to a side),
  pulling toward its anchor like a zero-length spring of 5..15 N at the home position: the force
  changes with the pose.
- ``hand``: a hand resting on the tool for 2..4 stretches of 8..20 s, pressing 5..20 N mostly
  down, with a slow sway of ±10 % at 0.1..0.3 Hz and raised-cosine onsets of 0.5 s.

The sensor sees each of them in full (it sits between the tool and the arm), so a model that
uses the sensor's reading explains them: a correct diagnosis suggests nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ditherlab.core.errors import ConfigError

__all__ = ["LOADS", "Loads", "build_loads"]

LOADS = ("cable", "hose", "hand")


@dataclass
class Loads:
    """The loads of a run: a time part (N, 3) [N] and the hoses' anchors and stiffnesses."""

    timed: np.ndarray
    anchors: np.ndarray  # (k, 3) [m]
    stiffness: np.ndarray  # (k,) [N/m]
    truth: list[dict]

    def force(self, k: int, p_tool: np.ndarray) -> np.ndarray:
        """(3,) [N]: the loads' force on the tool at sample k, tool point at p_tool (3,) [m]."""
        f = self.timed[k]
        if not len(self.stiffness):
            return f
        f = f.copy()
        for a, s in zip(self.anchors, self.stiffness, strict=True):
            f += s * (a - p_tool)
        return f


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.sqrt(v @ v)


def _cable(t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    el = np.radians(rng.uniform(-30, 30))
    az = rng.uniform(0, 2 * np.pi)
    d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    f0, fr, ph = rng.uniform(5, 15), rng.uniform(0.01, 0.05), rng.uniform(0, 2 * np.pi)
    mag = f0 * (1 + 0.3 * np.sin(2 * np.pi * fr * t + ph))
    truth = {"kind": "cable", "direction": d.tolist(), "force": float(f0), "frequency": float(fr)}
    return mag[:, None] * d, truth


def _hand(t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    on = np.zeros(len(t))
    span = t[-1] - t[0]
    stretches = []
    for _ in range(int(rng.integers(2, 5))):
        length = min(rng.uniform(8, 20), 0.3 * span)
        t0 = t[0] + rng.uniform(0, span - length)
        ramp = np.clip((t - t0) / 0.5, 0, 1) * np.clip((t0 + length - t) / 0.5, 0, 1)
        on = np.maximum(on, 0.5 * (1 - np.cos(np.pi * ramp)))
        stretches.append([float(t0), float(length)])
    d = _unit(np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), -1.0]))
    f0, fr = rng.uniform(5, 20), rng.uniform(0.1, 0.3)
    sway = 1 + 0.1 * np.sin(2 * np.pi * fr * t + rng.uniform(0, 2 * np.pi))
    truth = {"kind": "hand", "direction": d.tolist(), "force": float(f0), "stretches": stretches}
    return (f0 * on * sway)[:, None] * d, truth


def build_loads(kinds: tuple[str, ...], t: np.ndarray, p_home: np.ndarray, rng) -> Loads:
    """The loads ``kinds`` over the sample times t (N,) [s], the tool's home position p_home
    (3,) [m], drawn from ``rng``."""
    timed, anchors, stiffness, truth = np.zeros((len(t), 3)), [], [], []
    for kind in kinds:
        if kind not in LOADS:
            raise ConfigError(
                f"--external-load {kind}: unknown load; expected one of {', '.join(LOADS)}"
            )
        if kind == "hose":
            off = _unit(np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -1.5]))
            dist, f0 = rng.uniform(0.3, 0.6), rng.uniform(5, 15)
            anchors.append(p_home + dist * off)
            stiffness.append(f0 / dist)
            truth.append({"kind": "hose", "anchor": anchors[-1].tolist(), "force": float(f0)})
            continue
        part, one = (_cable if kind == "cable" else _hand)(t, rng)
        timed += part
        truth.append(one)
    return Loads(timed, np.reshape(anchors, (-1, 3)), np.asarray(stiffness, float), truth)

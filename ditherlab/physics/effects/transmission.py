"""Transmission effects: torque ripple periodic in the joint angle (gear teeth, cogging)."""

from __future__ import annotations

import math

import numpy as np

from ditherlab.core.timeseries import tmm
from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound, effort_scale

#: the largest ripple amplitude, as a share of the joint's effort limit [-]
RIPPLE_SHARE = 0.1

__all__ = ["PositionRipple"]


class PositionRipple(Effect):
    name = "position_ripple"
    order = 5
    physics = "periodic torque in joint angle (gear teeth, cogging)"
    driven_by = "q, period found by a least-squares periodogram"
    linear = ("a_sin", "b_cos", "a2_sin", "b2_cos")
    hyper = "period"
    continuous = True
    shows_in = ("moving",)
    bounds = tuple(
        Bound(
            name,
            "N·m",
            "0 .. 10 % of the joint's effort limit",
            "gear meshing and cogging ripple stay at a few % of a drive's rated torque "
            "(harmonic drive and servo motor catalogues)",
            0.0,
            lambda sigs, j: RIPPLE_SHARE * effort_scale(sigs, j),
            value=lambda p, sigs, a=a, b=b: math.hypot(p[a], p[b]),
        )
        for name, a, b in (
            ("amplitude", "a_sin", "b_cos"),
            ("amplitude_2", "a2_sin", "b2_cos"),
        )
    )

    def design(self, sig, j, h, ref):
        # fundamental and second harmonic (tooth meshing is rarely a pure sine)
        ph = 2 * np.pi * sig.q[:, j] / h
        return Design(np.column_stack([np.sin(ph), np.cos(ph), np.sin(2 * ph), np.cos(2 * ph)]))

    #: periods of its ripple a joint's moving range must cover for a periodic fit to mean
    #: anything (fewer: any smooth trend over the range is "periodic")
    MIN_PERIODS = 3.0

    def unsupported(self, sig, j, h):
        q = np.concatenate([s.q[s.moving[:, j], j] for s in sig])
        span = float(q.max() - q.min()) if q.size else 0.0
        periods = span / float(h) if h else 0.0
        if periods >= self.MIN_PERIODS:
            return None
        return (
            f"effect {self.name!r} on joint {j + 1}: the joint's motion covers {periods:.1f} periods "
            f"of {fmt(float(h))} rad (at least {self.MIN_PERIODS:g} needed to tell a ripple from a "
            "trend); record motions over a wider range"
        )

    def grid(self, sig, j):
        q = np.concatenate([s.q[s.moving[:, j], j] for s in sig])
        if q.size < 10:
            return [2 * np.pi]
        span = float(q.max() - q.min())
        step = float(np.median(np.concatenate([np.abs(np.diff(s.q[:, j])) for s in sig])))
        lo = max(8 * step, span / 400, 1e-3)
        hi = max(span / 1.5, lo * 1.01)
        # periodogram resolution: neighbouring frequencies differ by < 1/4 cycle over the span
        n = int(min(600, max(16, 4 * span / lo)))
        return list(1.0 / np.geomspace(1 / lo, 1 / hi, n))

    def shortlist(self, sc, j, grid, masks, lags=None, keep: int = 3):
        """Least-squares periodogram (Lomb–Scargle without offset) of the moving samples of each
        training set; the ``keep`` periods with the largest weighted variance reduction."""
        if len(grid) <= keep:
            return [list(grid) for _ in masks]
        lags = lags if lags is not None else [0] * len(sc)
        e = np.concatenate([s.e[s.use[:, j], j] for s in sc])
        q = np.concatenate(
            [np.roll(s.sig.q[:, j], g)[s.use[:, j]] for s, g in zip(sc, lags, strict=True)]
        )
        hh = np.concatenate([s.h[s.use[:, j], j] for s in sc])
        wt = 1.0 / np.concatenate([s.sigma[s.use[:, j], j] for s in sc]) ** 2
        lin = hh == 0  # moving samples: plain least squares
        f = 2 * np.pi / np.asarray(grid, dtype=float)
        out = []
        sums = []
        idx = np.flatnonzero(lin)
        # reduce over samples in chunks of periods to bound memory
        parts = {k: [] for k in ("ss", "sc", "cc", "es", "ec")}
        W = np.column_stack([m[idx] * wt[idx] for m in masks])  # (M, F)
        for c0 in range(0, len(f), 100):
            ph = np.outer(q[idx], f[c0 : c0 + 100])
            S, C = np.sin(ph), np.cos(ph)
            ee = e[idx][:, None]
            parts["ss"].append(tmm(W, S * S))
            parts["sc"].append(tmm(W, S * C))
            parts["cc"].append(tmm(W, C * C))
            parts["es"].append(tmm(W, ee * S))
            parts["ec"].append(tmm(W, ee * C))
        sums = {k: np.concatenate(v, axis=1) for k, v in parts.items()}  # (F, P)
        det = sums["ss"] * sums["cc"] - sums["sc"] ** 2
        det = np.where(det > 1e-12 * (sums["ss"] * sums["cc"] + 1e-300), det, np.inf)
        red = (
            sums["cc"] * sums["es"] ** 2
            - 2 * sums["sc"] * sums["es"] * sums["ec"]
            + sums["ss"] * sums["ec"] ** 2
        ) / det
        for k in range(len(masks)):
            best = np.argsort(-red[k])[:keep]
            out.append([grid[i] for i in best])
        return out

    def driver(self, sig, j, p):
        return np.mod(sig.q[:, j], p["period"]), f"q_{j + 1} mod {fmt(p['period'])} rad"

    def term(self, p, j):
        amp = math.hypot(p["a_sin"], p["b_cos"])
        return f"{fmt(amp)}·position_ripple(q_{j + 1}, period={fmt(p['period'])} rad)"

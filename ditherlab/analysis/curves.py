"""The detection curve of the report (:mod:`ditherlab.analysis.detection`): detection probability against
applied force, a logistic fitted by maximum likelihood on a grid, with a seeded bootstrap."""

from __future__ import annotations

from typing import Any

import numpy as np


def fit_logistic(
    force: np.ndarray, hit: np.ndarray, *, n_boot: int = 200, seed: int = 0, level: float = 0.9
) -> dict[str, Any]:
    """Detection probability against applied force: ``1 / (1 + exp(-(F - F50) / s))``.

    Maximum likelihood on a grid (F50 over 0 .. 1.5 max F in 300 steps, s log-spaced over
    0.25 .. 50 N in 60 steps), so perfectly separated data give the steepest curve on the grid
    instead of diverging; percentile intervals from a seeded bootstrap over pushes.

    Parameters
    ----------
    force : (P,) applied peak forces [N]
    hit : (P,) bool, response or not
    n_boot : bootstrap replicates
    seed : bootstrap seed
    level : central probability of the intervals

    Returns
    -------
    dict with ``F50``, ``F90``, ``scale`` [N] and ``F50_ci``, ``F90_ci`` (lo, hi) [N]; NaNs for
    fewer than 3 pushes; when every push (or none) was seen, NaNs and ``bound`` = ``"below"``
    (``"above"``) with ``bound_force`` the smallest (largest) force [N].
    """
    force = np.asarray(force, dtype=float)
    hit = np.asarray(hit, dtype=bool)
    nan = float("nan")
    if len(force) < 3:
        return {"F50": nan, "F90": nan, "scale": nan, "F50_ci": [nan, nan], "F90_ci": [nan, nan]}
    if hit.all() or not hit.any():
        # no transition in the data: F50 and F90 lie below the smallest (all seen) or above
        # the largest force (none seen); report the bound instead of a grid edge
        bound = float(force.min()) if hit.all() else float(force.max())
        return {
            "F50": nan,
            "F90": nan,
            "scale": nan,
            "F50_ci": [nan, nan],
            "F90_ci": [nan, nan],
            "bound": ("below" if hit.all() else "above"),
            "bound_force": bound,
        }
    fmax = float(force.max())
    g50 = np.linspace(0.0, 1.5 * fmax, 300)
    gs = np.geomspace(0.25, 50.0, 60)
    G50, GS = np.meshgrid(g50, gs, indexing="ij")
    # the fit and every bootstrap replicate: weights per push, the replicates drawn in order
    weights = [np.ones(len(force))]
    if n_boot > 1:
        rng = np.random.default_rng(seed)
        for _ in range(n_boot):
            w = np.bincount(rng.integers(0, len(force), len(force)), minlength=len(force))
            weights.append(w.astype(float))
    fits = _grid_ml(force, hit, G50, GS, weights)
    f50, s = float(g50[fits[0][0]]), float(gs[fits[0][1]])
    ln9 = float(np.log(9.0))
    out: dict[str, Any] = {"F50": f50, "F90": f50 + s * ln9, "scale": s}
    if n_boot > 1:
        reps = np.array([(g50[i], g50[i] + gs[j] * ln9) for i, j in fits[1:]], dtype=float)
        q = [(1 - level) / 2, (1 + level) / 2]
        out["F50_ci"] = np.quantile(reps[:, 0], q).tolist()
        out["F90_ci"] = np.quantile(reps[:, 1], q).tolist()
    else:
        out["F50_ci"] = [nan, nan]
        out["F90_ci"] = [nan, nan]
    return out


def _grid_ml(
    force: np.ndarray,
    hit: np.ndarray,
    G50: np.ndarray,
    GS: np.ndarray,
    weights: list[np.ndarray],
    rows: int = 10,
) -> list[tuple[int, int]]:
    """The grid point ``(i, j)`` of largest weighted log-likelihood of the logistic curve, per
    weight vector (P,): the first largest in row-major order, as ``np.argmax``. The (300, 60, P)
    log-probabilities are made ``rows`` F50 values at a time (memory bounded however many pushes
    there are; each (60, P) slice's products are numpy's as for the whole grid)."""
    best = [(-np.inf, 0, 0)] * len(weights)
    wh = [w * hit for w in weights]
    wm = [w * ~hit for w in weights]
    n_s = G50.shape[1]
    for i0 in range(0, G50.shape[0], rows):
        sl = slice(i0, i0 + rows)
        z = (force[None, None, :] - G50[sl, :, None]) / GS[sl, :, None]  # (rows, 60, P)
        lp = -np.logaddexp(0.0, -z)  # log p(hit)
        lq = -np.logaddexp(0.0, z)  # log p(miss)
        for r in range(len(weights)):
            ll = lp @ wh[r] + lq @ wm[r]
            k = int(np.argmax(ll))
            if ll.flat[k] > best[r][0]:
                best[r] = (float(ll.flat[k]), i0 + k // n_s, k % n_s)
    return [(i, j) for _, i, j in best]


__all__ = ["fit_logistic"]

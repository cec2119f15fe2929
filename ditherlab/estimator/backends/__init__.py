"""The estimator backends: ``exact`` (:mod:`.exact`) and the qpsolvers references (:mod:`.qp`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ditherlab.estimator.backends.exact import _solve_exact
from ditherlab.estimator.backends.qp import QP_OPTIONS, _solve_reference


def _available(references: bool = True) -> dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]]:
    """The backends by name: ``exact`` always; with ``references`` the qpsolvers ones installed
    here (looking them up imports qpsolvers and with it scipy.sparse, slow to import at a
    command's start, which the exact backend does not need)."""
    out: dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]] = {
        "exact": lambda prob, progress=None: _solve_exact(prob, progress=progress)
    }
    if not references:
        return out
    try:
        import qpsolvers
    except ImportError:  # pragma: no cover - qpsolvers is a dependency
        return out
    for name, (solver, _) in QP_OPTIONS.items():
        if solver in qpsolvers.available_solvers:
            out[name] = lambda prob, progress=None, name=name: _solve_reference(
                prob, name, progress
            )
    return out


def available_backends() -> list[str]:
    """Names of the estimator backends usable here (``exact`` always)."""
    return list(_available())

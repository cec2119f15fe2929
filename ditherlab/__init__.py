"""ditherlab: sensorless force estimation with dithering — logs, estimator replay, simulation,
diagnosis and visual review (Stolt, Robertsson, Johansson: force estimation using dithering to
decrease the low-velocity friction uncertainties, ABB IRB140).

Public entry points::

    import ditherlab
    rec = ditherlab.read("push.parquet")       # any supported format -> Recording
    ditherlab.write(rec, "push.mcap")
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ditherlab.core.errors import DitherlabError, DitherlabWarning

if TYPE_CHECKING:  # pragma: no cover
    from ditherlab.data.recording import Recording

__version__ = "0.1.0"
__all__ = ["DitherlabError", "DitherlabWarning", "Recording", "read", "write", "__version__"]


def __getattr__(name: str) -> Any:
    # ``ditherlab.Recording`` on first use: importing the package (``ditherlab --help``, every
    # ``from ditherlab.core.errors import ...``) then does not load pandas and pinocchio (~0.7 s)
    if name == "Recording":
        from ditherlab.data.recording import Recording

        return Recording
    raise AttributeError(f"module 'ditherlab' has no attribute {name!r}")


def read(path: Any, **options: Any) -> Recording:
    """Read a recording from any supported file (dispatch on the suffix); see ditherlab.io."""
    from ditherlab.io import read as _read

    return _read(path, **options)


def write(rec: Recording, path: Any, **options: Any) -> Any:
    """Write a recording atomically in the format given by the suffix; see ditherlab.io."""
    from ditherlab.io import write as _write

    return _write(rec, path, **options)

"""The live estimate in Rerun as it is computed (``ditherlab live --sink rerun``): per force
and moment component the estimate of one variant, its interval's bounds and, when the stream
carries it, the sensor's value, on the ``time`` timeline [s]."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import rerun as rr

from ditherlab.core.errors import DitherlabError
from ditherlab.core.files import atomic_path
from ditherlab.data.estimates import COMPONENTS

__all__ = ["LiveView"]


class LiveView:
    """A Rerun recording fed block by block: a viewer spawned (``path`` None) or an ``.rrd``
    file written atomically when closed.

    Parameters
    ----------
    variant : the estimator variant shown ; path : the ``.rrd`` file, or None for a viewer
    """

    def __init__(self, variant: str, path: Path | None = None) -> None:
        self.variant, self.path = variant, path
        self._stack = contextlib.ExitStack()
        self.stream = rr.RecordingStream("ditherlab_live")
        if path is None:
            try:
                rr.spawn(recording=self.stream)
            except RuntimeError as exc:  # no viewer binary: rerun prints how to install one
                first = str(exc).strip().splitlines()[0] if str(exc).strip() else "no viewer"
                raise DitherlabError(
                    f"--sink rerun: the Rerun viewer did not start ({first}); expected the "
                    "rerun viewer installed, or --sink rerun:FILE.rrd"
                ) from None
        else:
            self._tmp = self._stack.enter_context(atomic_path(path))
            self.stream.save(self._tmp)
        self.rows = 0

    def write(self, cols: dict[str, np.ndarray]) -> None:
        """Send one block of estimate rows (the estimates file's columns, each (N,))."""
        t = np.asarray(cols["t"], dtype=float)
        if not len(t):
            return
        idx = [rr.TimeColumn("time", duration=t)]
        v = self.variant
        for c in COMPONENTS:
            for path, key in (
                (f"estimate/{c}", f"{v}/{c}"),
                (f"estimate/{c}_lo", f"{v}/{c}_lo"),
                (f"estimate/{c}_hi", f"{v}/{c}_hi"),
                (f"sensor/{c}", c),
            ):
                if key in cols:
                    scal = rr.Scalars.columns(scalars=np.asarray(cols[key], dtype=float))
                    self.stream.send_columns(path, indexes=idx, columns=scal)
        self.rows += len(t)

    def close(self, ok: bool = True) -> None:
        """Flush; the ``.rrd`` file goes in place (``ok``) or is removed."""
        self.stream.flush()
        if self.path is not None:
            self.stream.disconnect()
        if ok:
            self._stack.close()
        else:
            self._stack.__exit__(RuntimeError, RuntimeError("live stopped"), None)

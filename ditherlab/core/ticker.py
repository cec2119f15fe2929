"""Counting the steps of long work for a ``progress(done, total)`` callback."""

from __future__ import annotations

from collections.abc import Callable


class Ticker:
    """Calls ``progress(done, total)`` once a step, ``done`` counted from 0 (nothing when
    ``progress`` is None). ``total`` may grow while the work runs (steps known late)."""

    def __init__(self, total: int, progress: Callable[[int, int], None] | None) -> None:
        self.done, self.total, self.progress = 0, total, progress

    def __call__(self) -> None:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total)

"""Progress of long work: a ``progress(done, total)`` callback that the library calls, drawn as
a bar on a terminal's stderr, as a start line and an end line in a log file, or not at all."""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Iterator

from tqdm import tqdm


@contextlib.contextmanager
def progress_bar(desc: str, quiet: bool = False) -> Iterator[Callable[[int, int], None]]:
    """A ``progress(done, total)`` callback drawing a bar on stderr (nothing when quiet)."""
    if quiet:
        yield lambda done, total: None
        return
    if not sys.stderr.isatty():
        # A log file or CI: a line when the work starts reporting, one when it has finished,
        # instead of a redrawn bar; nothing at all when the command fails before it starts.
        t0 = time.perf_counter()
        started = []

        def note(done: int, total: int) -> None:
            if not started:
                started.append(True)
                print(f"{desc} ...", file=sys.stderr, flush=True)

        yield note
        if started:
            print(f"{desc}: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return
    bar = tqdm(
        desc=desc,
        total=1,
        unit="",
        file=sys.stderr,
        leave=False,
        dynamic_ncols=True,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
    )
    try:

        def update(done: int, total: int) -> None:
            bar.total = max(int(total), 1)
            bar.n = min(int(done), bar.total)
            bar.refresh()

        yield update
    finally:
        bar.close()

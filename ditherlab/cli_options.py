"""What every ``ditherlab`` command shares (:mod:`ditherlab.cli`): the option aliases, the
progress bar, stdout, and the warnings held while a command runs."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated

import typer

from ditherlab.core.errors import DitherlabWarning

OutPath = Annotated[Path, typer.Option("-o", "--out", help="Output file (written atomically).")]
Seed = Annotated[
    int, typer.Option("--seed", help="Random seed; the same seed gives the same output.")
]
RobotOpt = Annotated[
    str | None,
    typer.Option(
        "--robot", help="Robot for files without metadata: a built-in name or a URDF path."
    ),
]
JsonFlag = Annotated[bool, typer.Option("--json", help="Print machine-readable JSON on stdout.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars.")]
Force = Annotated[
    bool, typer.Option("--force", help="Write into (or replace) an existing non-empty folder.")
]
Chunk = Annotated[
    int | None,
    typer.Option(
        "--chunk",
        min=1,
        help="Rows read and processed at a time (default 65536, about 4.4 min at 250 Hz; "
        "memory grows with it, not with the log's length).",
    ),
]


def echo(msg: str = "") -> None:
    """Human-readable output on stdout."""
    typer.echo(msg)


def _format_warning(message, category, filename, lineno, line=None) -> str:  # noqa: ANN001
    return f"warning: {message}\n"


@contextlib.contextmanager
def held_warnings() -> Iterator[Callable[[], None]]:
    """Hold the warnings of numerical libraries (numpy's RuntimeWarning on an overflow, ...)
    while a command runs; yields ``release()``, which prints them (after a success). Left
    unreleased (an error), they are dropped: the error line is the only line. DitherlabWarnings
    (a note to the user, e.g. angles in degrees) are printed at once, as before."""
    held: list[tuple] = []
    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if issubclass(category, DitherlabWarning):
            shown(message, category, filename, lineno, file, line)
        else:
            held.append((message, category, filename, lineno, file, line))

    def release() -> None:
        for w in held:
            shown(*w)
        held.clear()

    warnings.showwarning = show
    try:
        yield release
    finally:
        warnings.showwarning = shown

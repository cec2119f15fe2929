"""What every ``ditherlab`` command shares (:mod:`ditherlab.cli`): the option aliases, stdout,
and the warnings held while a command runs.

Outputs are taken as text (``-o DIR/`` says a folder: :func:`ditherlab.core.files.check_output`
refuses it where a file is written); boolean options are flags.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated

import typer

from ditherlab.core.errors import DitherlabWarning

LevelOpt = Annotated[float, typer.Option("--level", help="Interval confidence level.")]
IntervalOpt = Annotated[
    str, typer.Option("--interval", help="Interval method: profile or set_membership.")
]
ComponentsOpt = Annotated[
    str,
    typer.Option("--components", help="Estimated components: all, fxyz, or a list like f_x,f_z."),
]
Seed = Annotated[
    int, typer.Option("--seed", help="Random seed; the same seed gives the same output.")
]
MappingOpt = Annotated[
    str | None,
    typer.Option(
        "--mapping",
        metavar="FILE|NAME",
        help="TOML mapping file (or built-in name, e.g. ur10e) for a foreign log.",
    ),
]
RobotOpt = Annotated[
    str | None,
    typer.Option(
        "--robot",
        metavar="NAME|URDF|XACRO",
        help="Robot for files without metadata: a built-in name (irb140), an arm of "
        "`ditherlab robot --list` (ur5), or a .urdf or .xacro path.",
    ),
]
ToolFrameOpt = Annotated[
    str | None,
    typer.Option(
        "--tool-frame",
        metavar="LINK",
        help="The robot's tool frame, where it is not the description's own (default: "
        "tool0, flange, ... or the last link).",
    ),
]
RobotArgOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--robot-arg",
        metavar="NAME:=VALUE",
        help="An argument of a .xacro --robot, repeatable; package://PKG:=DIR says where a ROS "
        "package is.",
    ),
]
JointTopicOpt = Annotated[
    str | None,
    typer.Option(
        "--joint-topic",
        metavar="TOPIC",
        help="ROS 2 bag: the JointState topic to read (needed when the bag has several).",
    ),
]
WrenchTopicOpt = Annotated[
    str | None,
    typer.Option(
        "--wrench-topic",
        metavar="TOPIC",
        help="ROS 2 bag: the WrenchStamped topic to merge ('' for none; default: the only one).",
    ),
]
ModelIn = Annotated[
    Path,
    typer.Option("--model", metavar="FILE", help="Torque model (TOML) from `ditherlab identify`."),
]
JsonFlag = Annotated[bool, typer.Option("--json", help="Print machine-readable JSON on stdout.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars.")]
Force = Annotated[
    bool,
    typer.Option(
        "--force", help="Replace an existing output file, or write into a non-empty folder."
    ),
]
Chunk = Annotated[
    int | None,
    typer.Option(
        "--chunk",
        min=1,
        metavar="ROWS",
        help="Rows read and processed at a time (default 65536, about 4.4 min at 250 Hz, or "
        "four 12 s contexts where that is more: 240004 at 5 kHz; memory grows with it, not "
        "with the log's length).",
    ),
]


def out_file(what: str) -> typer.models.OptionInfo:
    """``-o/--out FILE``: a file output (text: a trailing ``/`` is refused as a folder)."""
    return typer.Option("-o", "--out", metavar="FILE", help=f"{what} (written atomically).")


def out_folder(what: str) -> typer.models.OptionInfo:
    """``-o/--out DIR``: a folder output."""
    return typer.Option("-o", "--out", metavar="DIR", help=what)


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
    (a note to the user, e.g. angles in degrees) are printed at once."""
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

"""The ``ditherlab`` command line: a thin typer layer over the commands' workflows
(:mod:`ditherlab.app`, one module per command).

Each command builds its options (a frozen dataclass of the app module), calls the module's
``run`` and prints the result's ``text()`` (or ``to_dict()`` as JSON with ``--json``). User
mistakes raise :class:`~ditherlab.core.errors.DitherlabError`; the command group (:class:`Commands`)
turns them, and usage errors, into one line on stderr and exit status 2, never a traceback. Long
work reports progress through a callback that the library calls as ``progress(done, total)``;
here it drives a progress bar on stderr.

The rules every command follows live in one place each: the outputs in
:func:`ditherlab.core.files.check_output` (through :func:`ditherlab.app.workflow.guard`), the
options shared by the commands in :mod:`ditherlab.cli_options`. Library modules are imported
inside the commands, so ``ditherlab --help`` loads neither pandas nor pinocchio.
"""

from __future__ import annotations

import os

# One BLAS thread per process unless the user set another number: ditherlab's linear algebra is
# many small products between compiled kernels, where OpenBLAS's threads cost more waking up than
# they give (diagnose of one hour: 35.3 -> 28.5 s of CPU, the same report); many recordings run
# in parallel as processes (``fleet``). Set before numpy is first imported (nothing above does).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import contextlib
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
import typer._click.exceptions as UsageErrors  # typer vendors click: its exceptions are here
from typer.core import TyperGroup

from ditherlab.cli_options import (
    Chunk,
    ComponentsOpt,
    Force,
    IntervalOpt,
    JointTopicOpt,
    JsonFlag,
    LevelOpt,
    MappingOpt,
    ModelIn,
    Quiet,
    RobotArgOpt,
    RobotOpt,
    Seed,
    ToolFrameOpt,
    WrenchTopicOpt,
    _format_warning,
    echo,
    held_warnings,
    out_file,
    out_folder,
)
from ditherlab.core.errors import DitherlabError, DitherlabWarning
from ditherlab.core.runtime import reuse_freed_memory

#: the first lines of ``ditherlab --help``: every command, in the order of the work
HELP = """Sensorless force estimation with dithering (Stolt et al., ABB IRB140).

Recordings: info, convert, simulate. The estimator: identify, replay, report, diagnose, view.
A robot's predicted thresholds: robot. Many runs: fleet, sweep, leadthrough.
A running robot over ROS 2 (DDS): live, publish.

Outputs: an existing output file or non-empty folder needs --force; a file output is named
with its suffix (model .toml, estimates .parquet, view .rrd), never as a folder (DIR/); no
command writes over a file it reads."""


class Commands(TyperGroup):
    """The command group: whatever goes wrong for the user is one line on stderr (``error:
    ...``) and exit status 2, the same from :func:`main` and from ``typer.testing.CliRunner``."""

    def main(  # type: ignore[override]
        self,
        args: list[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        code = _one_line_errors(
            lambda: super(Commands, self).main(
                args=args,
                prog_name=prog_name,
                complete_var=complete_var,
                standalone_mode=False,
                **extra,
            )
        )
        if standalone_mode and isinstance(code, int) and code:
            sys.exit(code)
        return code


def _one_line_errors(call: Callable[[], Any]) -> Any:
    """``call()``; every error but a bug ends the process here (sys.exit) after one line."""
    try:
        return call()
    except DitherlabError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except UsageErrors.NoArgsIsHelpError as exc:  # bare ``ditherlab``: the help
        typer.echo(exc.ctx.get_help() if exc.ctx is not None else str(exc))
        sys.exit(2)
    except UsageErrors.UsageError as exc:  # typer's own is the usage and two more lines
        where = exc.ctx.command_path if exc.ctx is not None else "ditherlab"
        msg = " ".join(exc.format_message().split())
        typer.echo(f"error: {where}: {msg} (see '{where} --help')", err=True)
        sys.exit(2)
    except UsageErrors.ClickException as exc:
        typer.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:  # Ctrl-C at a prompt
        typer.echo("aborted", err=True)
        sys.exit(1)


app = typer.Typer(
    name="ditherlab",
    cls=Commands,
    help=HELP,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help: flags as flags, and no rich to import
)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app; a DitherlabError becomes one line on stderr and exit 2.

    Usage errors (an unknown option, a missing argument, a value out of range) too: one line
    naming the command and what was wrong, exit status 2. Warnings of numerical libraries never
    precede that line (:func:`~ditherlab.cli_options.held_warnings`).
    """
    warnings.formatwarning = _format_warning
    warnings.simplefilter("default", DitherlabWarning)
    reuse_freed_memory()
    with held_warnings() as release:
        code = app(args=argv, prog_name="ditherlab", standalone_mode=False)
        release()
    if isinstance(code, int) and code:
        sys.exit(code)


def _version(value: bool) -> None:
    if value:
        from ditherlab.core.version import __version__

        echo(f"ditherlab {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    pass


# ================================================================ what the commands share
@contextlib.contextmanager
def _progress(desc: str, quiet: bool) -> Iterator[Callable[[int, int], None]]:
    """A ``progress(done, total)`` bar on stderr (:func:`ditherlab.core.progress.progress_bar`)."""
    from ditherlab.core.progress import progress_bar

    with progress_bar(desc, quiet) as progress:
        yield progress


def _show(result: Any, json_out: bool = False) -> None:
    """Print a command's result: ``to_dict()`` as JSON, or ``text()``."""
    if json_out:
        import json

        from ditherlab.core.files import json_default

        echo(json.dumps(result.to_dict(), indent=1, default=json_default))
    else:
        echo(result.text())


def _read(
    mapping: str | None,
    robot: str | None,
    joint_topic: str | None = None,
    wrench_topic: str | None = None,
    tool_frame: str | None = None,
    robot_arg: list[str] | None = None,
) -> Any:
    """:class:`ditherlab.app.workflow.ReadOptions` of ``--mapping``, ``--robot``,
    ``--joint-topic``, ``--wrench-topic``, ``--tool-frame`` and ``--robot-arg``."""
    from ditherlab.app.workflow import ReadOptions

    return ReadOptions(
        mapping, robot, joint_topic, wrench_topic, tool_frame, tuple(robot_arg or ())
    )


def _chunk(chunk: int | None) -> dict[str, int]:
    """``chunk_rows`` when ``--chunk`` is given (else the app's default)."""
    return {"chunk_rows": chunk} if chunk else {}


# ================================================================ recordings
@app.command()
def info(
    file: Annotated[
        Path, typer.Argument(metavar="RECORDING", help="Recording (.parquet, .csv, .mcap, bag).")
    ],
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    json_out: JsonFlag = False,
    chunk: Chunk = None,
) -> None:
    """Summarise a recording.

    Duration, sample rate and jitter, joints, optional columns, still/dither/moving time.
    """
    from ditherlab.app import info as cmd

    opts = cmd.InfoOptions(
        file=file,
        read=_read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg),
        **_chunk(chunk),
    )
    _show(cmd.run(opts), json_out)


@app.command()
def convert(
    src: Annotated[
        Path, typer.Argument(metavar="SRC", help="Input recording (any readable format).")
    ],
    dst: Annotated[
        str,
        typer.Argument(metavar="DST", help="Output: .parquet, .csv, .mcap, or a bag folder."),
    ],
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    chunk: Chunk = None,
    force: Force = False,
    known_load: Annotated[
        str | None,
        typer.Option(
            "--known-load",
            metavar="MASS[@X,Y,Z]",
            help="A known load at the tool [kg; centre of mass in m, tool frame], stored in the "
            "output's metadata: replay and report compare the estimate with its wrench.",
        ),
    ] = None,
    quiet: Quiet = False,
) -> None:
    """Convert a recording to another format.

    Written atomically; never over the input. A CSV file brings its sidecar .json.
    """
    from ditherlab.app import convert as cmd

    opts = cmd.ConvertOptions(
        src=src,
        dst=dst,
        read=_read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg),
        force=force,
        known_load=known_load,
        **_chunk(chunk),
    )
    with _progress("convert", quiet) as progress:
        result = cmd.run(opts, progress)
    _show(result)


@app.command()
def simulate(
    scenario: Annotated[
        str,
        typer.Argument(
            metavar="SCENARIO",
            help="push-campaign, lead-through or excitation (for identify and diagnose); "
            "with --plant lugre: excitation, push-campaign or standing (no F/T sensor).",
        ),
    ],
    out: Annotated[str, out_file("Recording: .parquet, .csv, .mcap, or a bag folder")],
    seed: Seed = 0,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config", metavar="FILE", help="TOML overriding the built-in IRB140 parameters."
        ),
    ] = None,
    dither: Annotated[
        bool, typer.Option("--dither/--no-dither", help="Dither while standing still.")
    ] = True,
    hidden: Annotated[
        list[str] | None,
        typer.Option(
            "--hidden",
            metavar="NAME[:SIZE]",
            help="Inject an effect the base model lacks, repeatable; with --plant lugre "
            "NAME[:SIZE][@J1,J2] plants it on those joints (default 2,3).",
        ),
    ] = None,
    pushes_per_direction: Annotated[
        int | None,
        typer.Option("--pushes-per-direction", help="Pushes per axis and sign (push-campaign)."),
    ] = None,
    log_temperature: Annotated[
        bool,
        typer.Option(
            "--log-temperature/--no-log-temperature",
            help="With --hidden temperature_friction: write temp_j columns.",
        ),
    ] = True,
    sim_robot: Annotated[
        str,
        typer.Option(
            "--robot",
            metavar="NAME|URDF|XACRO",
            help="The simulated arm (as for --robot elsewhere) with six joints; the IRB140's "
            "drive, friction and servo parameters unless --config sets them.",
        ),
    ] = "irb140",
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    plant: Annotated[
        str,
        typer.Option(
            "--plant",
            metavar="band|lugre",
            help="band: the built-in plant (stick-slip band); lugre: the second plant (LuGre "
            "friction, PID servo, coloured noise, drifting F/T sensor), parameters drawn from "
            "the seed.",
        ),
    ] = "band",
    external_load: Annotated[
        list[str] | None,
        typer.Option(
            "--external-load",
            metavar="cable|hose|hand",
            help="A slow load on the tool that the F/T sensor measures (--plant lugre), "
            "repeatable.",
        ),
    ] = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Simulate a robot to a recording.

    The built-in plant (gear springs, stick-slip friction, servo and dither) or, with --plant
    lugre, the LuGre plant, through a scenario.
    """
    from ditherlab.app import simulate as cmd

    opts = cmd.SimulateOptions(
        scenario=scenario, out=out, seed=seed, dither=dither, config=config,
        hidden=tuple(hidden or ()), pushes_per_direction=pushes_per_direction,
        log_temperature=log_temperature, force=force, robot=sim_robot, tool_frame=tool_frame,
        robot_args=tuple(robot_arg or ()), plant=plant,
        external_loads=tuple(external_load or ()),
    )  # fmt: skip
    with _progress(f"simulate {scenario}", quiet) as progress:
        _show(cmd.run(opts, progress))


# ================================================================ the estimator
@app.command()
def identify(
    recordings: Annotated[
        list[Path],
        typer.Argument(
            metavar="RECORDING",
            help="Joint logs: with an F/T sensor (f_x..m_z), or without one with "
            "--assume-no-force.",
        ),
    ],
    out: Annotated[str, out_file("Torque model file, .toml")],
    model: Annotated[
        Path | None,
        typer.Option(
            "--model",
            metavar="FILE",
            help="Base model: its prior and effects are kept, its bands re-fitted.",
        ),
    ] = None,
    add: Annotated[
        list[str] | None,
        typer.Option(
            "--add", metavar="EFFECT", help="Fit one more effect (diagnose's library), repeatable."
        ),
    ] = None,
    assume_no_force: Annotated[
        bool,
        typer.Option(
            "--assume-no-force",
            help="No F/T sensor: the force is taken as zero at rest; departures from rest "
            "(pushes) are found, left out and listed.",
        ),
    ] = False,
    window: Annotated[
        list[str] | None,
        typer.Option(
            "--window",
            metavar="START:END",
            help="Fit only this stretch [s, the log's time], repeatable.",
        ),
    ] = None,
    exclude: Annotated[
        list[str] | None,
        typer.Option(
            "--exclude",
            metavar="START:END",
            help="Leave this stretch out [s, the log's time], repeatable.",
        ),
    ] = None,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates for the standard errors.")
    ] = 30,
    seed: Seed = 0,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    chunk: Chunk = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Identify a torque model from recordings.

    Bands, noise (R_e) and sliding friction per joint and regime by maximum likelihood; then
    the effects of --add.
    """
    from ditherlab.app import identify as cmd

    read = _read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg)
    opts = cmd.IdentifyOptions(
        recordings=tuple(recordings), out=out, model=model, add=tuple(add or ()),
        assume_no_force=assume_no_force, windows=tuple(window or ()),
        excludes=tuple(exclude or ()), n_boot=bootstrap, seed=seed,
        read=read, force=force, **_chunk(chunk),
    )  # fmt: skip
    with _progress("identify", quiet) as progress:
        result = cmd.run(opts, progress)
    for line in result.warnings:
        typer.echo(f"warning: {line}", err=True)
    _show(result)


@app.command()
def replay(
    recording: Annotated[
        Path,
        typer.Argument(metavar="RECORDING", help="Recording to replay the estimator over."),
    ],
    model: ModelIn,
    out: Annotated[str, out_file("Estimates file, .parquet")],
    level: LevelOpt = 0.95,
    interval: IntervalOpt = "profile",
    components: ComponentsOpt = "all",
    variants: Annotated[
        str | None,
        typer.Option(
            "--variants",
            help="Comma list of nodither_band, nodither_noband, dither_band, dither_noband "
            "(default: all the recording allows).",
        ),
    ] = None,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    chunk: Chunk = None,
    causal: Annotated[
        bool,
        typer.Option(
            "--causal",
            help="Estimate every sample from the past alone, as `ditherlab live` does.",
        ),
    ] = False,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Replay the estimator over a recording.

    Eq. (3) per sample with its intervals, without and with dither, with and without the
    uniform term; written as an estimates Parquet file.
    """
    from ditherlab.app import replay as cmd

    read = _read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg)
    opts = cmd.ReplayOptions(
        recording=recording, model=model, out=out, level=level, interval=interval,
        components=components, variants=tuple(variants.split(",")) if variants else None,
        read=read, force=force, causal=causal, **_chunk(chunk),
    )  # fmt: skip
    with _progress("replay", quiet) as progress:
        _show(cmd.run(opts, progress))


# ================================================================ live
Topic = Annotated[
    str,
    typer.Option(
        "--topic", metavar="TOPIC", help="The JointState topic (relative: in --namespace)."
    ),
]
Namespace = Annotated[
    str, typer.Option("--namespace", metavar="NS", help="ROS 2 namespace of relative topics.")
]
Domain = Annotated[
    int | None,
    typer.Option("--domain", help="DDS domain (default: ROS_DOMAIN_ID, else 0).", min=0, max=232),
]
DitherTopic = Annotated[
    str,
    typer.Option(
        "--dither-topic",
        metavar="TOPIC",
        help="The ditherlab_msgs/DitherState topic (relative: in --namespace).",
    ),
]


def _needs_dds(command: str) -> None:
    """ConfigError when cyclonedds (the extra ``live``) is not installed."""
    import importlib.util

    from ditherlab.core.errors import ConfigError

    if importlib.util.find_spec("cyclonedds") is None:
        raise ConfigError(
            f"{command} needs the DDS library cyclonedds; expected it installed: "
            "pip install 'ditherlab[live]'"
        )


@app.command()
def live(
    model: ModelIn,
    source: Annotated[
        str,
        typer.Option(
            "--source",
            metavar="SRC",
            help="ros2:TOPIC (JointState over DDS, e.g. ros2:joint_states, in --namespace) or "
            "file:RECORDING.",
        ),
    ],
    sink: Annotated[
        list[str],
        typer.Option(
            "--sink",
            metavar="SINK",
            help="parquet:OUT.parquet, ros2:TOPIC (WrenchStamped; bounds on TOPIC/lower, "
            "TOPIC/upper), rerun, or rerun:FILE.rrd; repeatable.",
        ),
    ],
    rate: Annotated[
        float, typer.Option("--rate", help="file: playback speed (1: real time, 0: at once).")
    ] = 1.0,
    namespace: Namespace = "",
    domain: Domain = None,
    wrench_topic: Annotated[
        str | None,
        typer.Option(
            "--wrench-topic", metavar="TOPIC", help="ros2: a sensor's WrenchStamped, kept beside."
        ),
    ] = None,
    dither_topic: DitherTopic = "ditherlab/dither",
    timeout: Annotated[
        float, typer.Option("--timeout", help="[s] without a sample: the estimate stops.")
    ] = 1.0,
    wait: Annotated[float, typer.Option("--wait", help="[s] to wait for the first sample.")] = 10.0,
    duration: Annotated[
        float | None, typer.Option("--duration", help="[s] of stream to estimate, then stop.")
    ] = None,
    queue: Annotated[
        int, typer.Option("--queue", help="Samples waiting for the estimate at most.", min=1)
    ] = 4096,
    variant: Annotated[
        str | None,
        typer.Option("--variant", help="Variant published and shown (default: dither_band)."),
    ] = None,
    level: LevelOpt = 0.95,
    interval: IntervalOpt = "profile",
    components: ComponentsOpt = "all",
    variants: Annotated[
        str | None,
        typer.Option("--variants", help="Comma list of variants (default: all the stream allows)."),
    ] = None,
    frame: Annotated[
        str | None, typer.Option("--frame", help="WrenchStamped frame (default: the tool frame).")
    ] = None,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    force: Force = False,
) -> None:
    """Estimate a running robot's force, sample by sample.

    The estimate of `replay --causal` (the past alone), from ROS 2 over DDS or a recording
    played at its rate, to Parquet, a ROS 2 topic or Rerun. Ends on Ctrl-C, when the publisher
    stops (--timeout) or at the end of a file; the files are closed whole.
    """
    _needs_dds("live")
    from ditherlab.app import live as cmd

    opts = cmd.LiveOptions(
        model=model, source=source, sinks=tuple(sink), rate=rate, namespace=namespace,
        domain=domain, wrench_topic=wrench_topic, dither_topic=dither_topic, timeout=timeout,
        wait=wait, duration=duration, queue=queue, variant=variant, level=level, frame=frame,
        components=components, variants=tuple(variants.split(",")) if variants else None,
        interval=interval, read=_read(mapping, robot, None, None, None, None), force=force,
    )  # fmt: skip
    _show(cmd.run(opts, echo=lambda line: typer.echo(f"live: {line}", err=True)))


@app.command()
def publish(
    recording: Annotated[
        Path, typer.Argument(metavar="RECORDING", help="Recording to publish (any format).")
    ],
    topic: Topic = "joint_states",
    namespace: Namespace = "",
    domain: Domain = None,
    dither_topic: DitherTopic = "ditherlab/dither",
    wrench_topic: Annotated[
        str | None,
        typer.Option(
            "--wrench-topic", metavar="TOPIC", help="Also publish the F/T sensor as WrenchStamped."
        ),
    ] = None,
    rate: Annotated[float, typer.Option("--rate", help="Playback speed (1: real time).")] = 1.0,
    wait: Annotated[
        float, typer.Option("--wait", help="[s] to wait for a subscriber (0: do not wait).")
    ] = 10.0,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    quiet: Quiet = False,
) -> None:
    """Publish a recording as a ROS 2 robot, in real time.

    sensor_msgs/JointState with the robot's joint names, and ditherlab_msgs/DitherState with
    the same stamps when the recording has dither: a robot for `ditherlab live` on one machine.
    """
    _needs_dds("publish")
    from ditherlab.app import publish as cmd

    opts = cmd.PublishOptions(
        recording=recording, read=_read(mapping, robot, None, None, None, None), topic=topic,
        namespace=namespace, domain=domain, dither_topic=dither_topic, wrench_topic=wrench_topic,
        rate=rate, wait=wait,
    )  # fmt: skip
    with _progress("publish", quiet) as progress:
        _show(cmd.run(opts, progress))


@app.command()
def report(
    estimates: Annotated[
        list[Path],
        typer.Argument(
            metavar="ESTIMATES",
            help="Estimates files from `ditherlab replay` (with or without F/T columns).",
        ),
    ],
    out: Annotated[
        str, out_folder("Report folder (report.md, report.html, report.json, PNG figures).")
    ],
    recording: Annotated[
        list[Path] | None,
        typer.Option(
            "--recording",
            metavar="FILE",
            help="The recordings behind the estimates (adds Figs. 2, 4, 5), repeatable.",
        ),
    ] = None,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates of the detection curves.")
    ] = 200,
    paper: Annotated[
        bool,
        typer.Option(
            "--paper", help="Show the paper's IRB140 table for any robot (always for the IRB140)."
        ),
    ] = False,
    seed: Seed = 0,
    chunk: Chunk = None,
    json_out: JsonFlag = False,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Report the detection thresholds of estimates.

    With an F/T sensor: F50 / F90 per push direction (beside the paper's §VI-C numbers for the
    IRB140 or with --paper, else estimator against estimator), detection curves, interval
    coverage and figures. Without one: the estimator's events, the noise level at rest and
    (with --recording) the thresholds predicted at the rest pose.
    """
    from ditherlab.app import report as cmd

    opts = cmd.ReportOptions(
        estimates=tuple(estimates), out=out, recordings=tuple(recording or ()),
        n_boot=bootstrap, seed=seed, force=force, paper=paper, **_chunk(chunk),
    )  # fmt: skip
    with _progress("report", quiet or json_out) as progress:
        _show(cmd.run(opts, progress), json_out)


@app.command()
def diagnose(
    recordings: Annotated[
        list[Path],
        typer.Argument(
            metavar="RECORDING", help="Recordings (with an F/T sensor for the force error)."
        ),
    ],
    model: Annotated[
        Path, typer.Option("--model", metavar="FILE", help="Torque model (TOML); read only.")
    ],
    out: Annotated[
        str | None,
        out_folder(
            "Report folder: report.md, report.json, PNG figures, and model.toml (the model "
            "with this diagnosis's history row)."
        ),
    ] = None,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    no_history: Annotated[
        bool,
        typer.Option(
            "--no-history", help="Do not write the model with the history row into -o DIR."
        ),
    ] = False,
    regime: Annotated[
        list[str] | None,
        typer.Option(
            "--regime", help="Score only this regime (still, dither, moving); repeatable."
        ),
    ] = None,
    json_out: JsonFlag = False,
    chunk: Chunk = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Diagnose a model on recordings.

    Where the model fails (residual against the noise floor, force error, worst windows) and
    which effect is missing. The --model file is read only: with -o DIR the model with this
    diagnosis's history row is written to DIR/model.toml.
    """
    from ditherlab.app import diagnose as cmd

    read = _read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg)
    opts = cmd.DiagnoseOptions(
        recordings=tuple(recordings), model=model, out=out, history=not no_history,
        regimes=tuple(regime) if regime else None, read=read, force=force,
        **_chunk(chunk),
    )  # fmt: skip
    with _progress("diagnose", quiet or json_out) as progress:
        _show(cmd.run(opts, progress), json_out)


@app.command()
def view(
    recording: Annotated[
        Path, typer.Argument(metavar="RECORDING", help="Recording (.parquet, .csv, .mcap, bag).")
    ],
    estimates: Annotated[
        Path | None,
        typer.Option("--estimates", metavar="FILE", help="Estimates of this recording (replay)."),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option("--model", metavar="FILE", help="Torque model (bands, residuals)."),
    ] = None,
    diagnosis: Annotated[
        Path | None,
        typer.Option("--diagnosis", metavar="FILE", help="report.json of `diagnose -o`."),
    ] = None,
    save: Annotated[
        str | None, typer.Option("--save", metavar="FILE", help="Write a Rerun file (.rrd).")
    ] = None,
    spawn: Annotated[bool, typer.Option("--spawn", help="Open the Rerun viewer.")] = False,
    serve: Annotated[bool, typer.Option("--serve", help="Serve to a web viewer.")] = False,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    chunk: Chunk = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Review a recording in Rerun.

    Its estimates, model and diagnosis beside it: the 3D robot, torques, forces, events.
    """
    from ditherlab.app import view as cmd

    read = _read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg)
    opts = cmd.ViewOptions(
        recording=recording, estimates=estimates, model=model, diagnosis=diagnosis, save=save,
        mode=cmd.view_mode(spawn, serve), read=read, force=force,
        **_chunk(chunk),
    )  # fmt: skip
    with _progress("view", quiet) as progress:
        res = cmd.run(opts, progress)
    _show(res)
    if res.url:
        cmd.wait_until_interrupted()


# ================================================================ a robot
@app.command()
def robot(
    spec: Annotated[
        str | None,
        typer.Argument(
            metavar="[ROBOT]",
            help="Built-in robot name (irb140, panda, ur10e), an arm of --list (ur5), or a "
            ".urdf or .xacro path; none: the list.",
        ),
    ] = None,
    list_robots: Annotated[
        bool,
        typer.Option("--list", help="List the robots by name, with their joint counts."),
    ] = False,
    q: Annotated[
        str | None,
        typer.Option(
            "--q", help="Pose: 'zero', 'paper' (IRB140) or n angles in rad, comma-separated."
        ),
    ] = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    sensitivity: Annotated[
        bool, typer.Option("--sensitivity", help="Predicted F50/F90 per push direction.")
    ] = False,
    model: Annotated[
        Path | None,
        typer.Option("--model", metavar="FILE", help="Model from identify (else the simulator's)."),
    ] = None,
    dither: Annotated[
        bool | None, typer.Option("--dither/--no-dither", help="One condition (else both).")
    ] = None,
    map_out: Annotated[
        str | None,
        typer.Option("--map", metavar="FILE", help="Over --grid: table .csv/.parquet + PNG."),
    ] = None,
    grid: Annotated[
        str | None, typer.Option("--grid", help="Map poses qJ=START:STOP:COUNT[,qK=...] rad.")
    ] = None,
    force_range: Annotated[
        str, typer.Option("--force-range", help="Push magnitudes MIN:MAX [N].")
    ] = "10:60",
    noise_level: Annotated[
        str | None,
        typer.Option(
            "--noise-level",
            help="Measured noise level X,Y,Z [N] (one condition) for the predicted.",
        ),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option(
            "--report",
            metavar="FILE",
            help="report.json of ditherlab report: its measured noise level instead.",
        ),
    ] = None,
    seed: Seed = 0,
    force: Force = False,
    quiet: Quiet = False,
    json_out: JsonFlag = False,
) -> None:
    """Describe a robot at a pose, or predict its thresholds.

    Joints, limits and masses; tool point, gravity and lever arms at a pose; with --sensitivity
    the predicted detection thresholds per push direction (--map: over a grid of poses). No
    ROBOT, or --list: the robots --robot takes by name, with their joint counts.
    """
    from ditherlab.app import robot as cmd

    opts = cmd.RobotOptions(
        spec=spec, list_robots=list_robots, robot_args=tuple(robot_arg or ()), q=q,
        tool_frame=tool_frame, sensitivity=sensitivity, model=model,
        dither=dither, map_out=map_out, grid=grid, force_range=force_range,
        noise_level=noise_level, report=report, seed=seed, force=force,
    )  # fmt: skip
    with _progress("map", quiet or map_out is None) as progress:
        _show(cmd.run(opts, progress), json_out)


# ================================================================ many runs
@app.command()
def fleet(
    recordings: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="RECORDING",
            help="Recordings, folders or quoted glob patterns ('logs/**/*.parquet').",
        ),
    ] = None,
    out: Annotated[
        str, out_folder("Output folder: fleet.parquet, fleet.md, fleet.json, models/.")
    ] = "fleet-out",
    manifest: Annotated[
        Path | None,
        typer.Option(
            "--manifest",
            metavar="FILE",
            help="CSV with columns file, robot, date, notes and per-recording settings (mapping, "
            "description, sensor, joint_topic, wrench_topic).",
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            help="Dask scheduler address (tcp://HOST:8786); default: a LocalCluster here; "
            "'serial' runs a plain loop.",
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option("--workers", help="LocalCluster workers (default: one per core).")
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option(
            "--model",
            metavar="FILE",
            help="Base model every recording starts from (its effects kept).",
        ),
    ] = None,
    assume_no_force: Annotated[
        bool,
        typer.Option("--assume-no-force", help="No F/T sensor and no external force (identify)."),
    ] = False,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates per recording.")
    ] = 0,
    thresholds: Annotated[
        bool,
        typer.Option(
            "--thresholds/--no-thresholds",
            help="Replay the estimator on push recordings for F50 / F90 per axis.",
        ),
    ] = True,
    seed: Seed = 0,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    joint_topic: JointTopicOpt = None,
    wrench_topic: WrenchTopicOpt = None,
    tool_frame: ToolFrameOpt = None,
    robot_arg: RobotArgOpt = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Identify and diagnose many recordings.

    Each recording as a Dask task; one table and a fleet report (effects, drift, outliers).
    Exit status 1 when a recording failed (the outputs hold the others).
    """
    from ditherlab.app import fleet as cmd

    read = _read(mapping, robot, joint_topic, wrench_topic, tool_frame, robot_arg)
    opts = cmd.FleetOptions(
        recordings=tuple(recordings or ()), out=out, manifest=manifest, scheduler=scheduler,
        workers=workers, model=model, assume_no_force=assume_no_force, n_boot=bootstrap,
        thresholds=thresholds, seed=seed, read=read, force=force,
    )  # fmt: skip
    res = cmd.run(opts, progress=not quiet)
    _show(res)
    if res.failed:  # the outputs hold the others: one line and status 1, not 2
        typer.echo(f"error: {res.failed}", err=True)
        raise typer.Exit(1)


@app.command()
def sweep(
    grid: Annotated[
        list[str] | None,
        typer.Option(
            "--grid",
            metavar="KEY=V1,V2,...",
            help="A key of the simulator's parameters (irb140.toml) and its values, repeatable "
            "(per-joint lists: one value, or v1:v2:...:v6).",
        ),
    ] = None,
    out: Annotated[str, out_folder("Output folder: sweep.parquet, .md, .json, PNG.")] = "sweep-out",
    config: Annotated[
        Path | None,
        typer.Option("--config", metavar="FILE", help="Simulator TOML every point starts from."),
    ] = None,
    pushes: Annotated[
        int, typer.Option("--pushes-per-direction", help="Pushes per axis and sign per campaign.")
    ] = 6,
    vibration_limit: Annotated[
        float,
        typer.Option(
            "--vibration-limit", help="Acceptable arm vibration in rad (the paper: 1e-4)."
        ),
    ] = 1e-4,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates per detection curve.")
    ] = 50,
    seed: Seed = 0,
    repeats: Annotated[
        int, typer.Option("--repeats", help="Runs per point on seeds seed, seed+2, ... (mean).")
    ] = 1,
    scheduler: Annotated[
        str | None, typer.Option("--scheduler", help="Dask scheduler (tcp://HOST:8786), 'serial'.")
    ] = None,
    workers: Annotated[int | None, typer.Option("--workers", help="LocalCluster workers.")] = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Sweep the dither design over simulator parameters.

    Simulated paired campaigns at every point of a grid, as Dask tasks.
    """
    from ditherlab.app import sweep as cmd

    opts = cmd.SweepOptions(
        grid=tuple(grid or ()), out=out, config=config, pushes_per_direction=pushes, seed=seed,
        repeats=repeats, curve_boot=bootstrap, vibration_limit=vibration_limit,
        scheduler=scheduler, workers=workers, force=force,
    )  # fmt: skip
    _show(cmd.run(opts, progress=not quiet))


@app.command()
def leadthrough(
    out: Annotated[str, out_folder("Output folder: .md, .json, .png.")],
    seed: Annotated[int, typer.Option("--seed", min=0, help="First simulator seed.")] = 0,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Seeds seed, seed+1, ...")] = 3,
    dither: Annotated[str, typer.Option("--dither", help="'both', 'on' or 'off'.")] = "both",
    config: Annotated[
        Path | None, typer.Option("--config", metavar="FILE", help="Simulator TOML.")
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option("--model", metavar="FILE", help="Drive by `live`'s estimate with this model."),
    ] = None,
    live: Annotated[
        bool, typer.Option("--live", help="Closed loop over DDS with a `live` process (lock-step).")
    ] = False,
    namespace: Annotated[
        str | None,
        typer.Option("--namespace", metavar="NS", help="--live topics' namespace (default: own)."),
    ] = None,
    domain: Domain = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Compare the lead-through's two laws.

    The 10 N dead zone against the confidence interval (paper §V), on the same pushes. With
    --model --live the arm publishes its joint states over DDS and moves by the estimate of a
    `ditherlab live` process, step by step.
    """
    from ditherlab.app import leadthrough as cmd

    dds = None
    if live:
        _needs_dds("leadthrough --live")
        from ditherlab.app.leadthrough_dds import dds_source as dds
    opts = cmd.LeadthroughOptions(
        out=out, seed=seed, repeats=repeats, dither=dither, config=config, force=force,
        model=model, live=live, namespace=namespace, domain=domain,
    )  # fmt: skip
    with _progress("leadthrough", quiet) as progress:
        _show(cmd.run(opts, progress, dds))

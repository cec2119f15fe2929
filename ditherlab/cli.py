"""The ``ditherlab`` command line: a thin typer layer over the library.

Each command parses its options and calls one library function. User mistakes raise
:class:`~ditherlab.core.errors.DitherlabError`; :func:`main` turns them into one line on stderr and
exit status 2, never a traceback. Long work reports progress through a callback that the library
calls as ``progress(done, total)``; here it drives a progress bar on stderr.

Shared pieces for every command live in :mod:`ditherlab.cli_options` (and the output guard at the
top of this file); commands follow, one function each. Add a command as a new function below;
keep it ~10 lines.
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
from pathlib import Path
from typing import Annotated

import typer
import typer._click.exceptions as UsageErrors  # typer vendors click: its exceptions are here

from ditherlab.cli_options import (
    Chunk,
    Force,
    JsonFlag,
    OutPath,
    Quiet,
    RobotOpt,
    Seed,
    _format_warning,
    echo,
    held_warnings,
)
from ditherlab.core.errors import DitherlabError, DitherlabWarning
from ditherlab.core.progress import progress_bar
from ditherlab.core.runtime import reuse_freed_memory

app = typer.Typer(
    name="ditherlab",
    help="Sensorless force estimation with dithering: identify, replay, report, diagnose, "
    "simulate, view, info, convert, fleet, sweep.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def guard(
    out: Path,
    *inputs: Path | None,
    mapping: str | None = None,
    folder: bool = False,
    force: bool = False,
) -> None:
    """The output guard (:func:`ditherlab.core.files.check_output`), before any work: ``out``
    not equal to, inside or containing an input (or the mapping file), writable, and an
    existing non-empty folder only with ``--force``."""
    from ditherlab.core.files import check_output

    extra = [Path(mapping)] if mapping is not None and Path(mapping).exists() else []
    check_output(out, [*inputs, *extra], folder=folder, force=force)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app; a DitherlabError becomes one line on stderr and exit 2.

    Usage errors (an unknown option, a missing argument, a value out of range) too: one line
    naming the command and what was wrong, exit status 2 (typer's own is a framed box of five
    lines). Warnings of numerical libraries never precede that line (:func:`held_warnings`).
    """
    warnings.formatwarning = _format_warning
    warnings.simplefilter("default", DitherlabWarning)
    reuse_freed_memory()
    with held_warnings() as release:
        code = _run(argv)
        release()
    if isinstance(code, int) and code:
        sys.exit(code)


def _run(argv: list[str] | None) -> object:
    """The app's return value; every error but a bug ends the process here (sys.exit)."""
    try:
        return app(args=argv, prog_name="ditherlab", standalone_mode=False)
    except DitherlabError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except UsageErrors.NoArgsIsHelpError as exc:  # bare ``ditherlab``: the help, as typer
        typer.echo(exc.ctx.get_help() if exc.ctx is not None else str(exc))
        sys.exit(2)
    except UsageErrors.UsageError as exc:
        where = exc.ctx.command_path if exc.ctx is not None else "ditherlab"
        msg = " ".join(exc.format_message().split())
        typer.echo(f"error: {where}: {msg} (see '{where} --help')", err=True)
        sys.exit(2)
    except UsageErrors.ClickException as exc:
        typer.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(1)


# ================================================================ commands


# ---------------------------------------------------------------- info, convert (helper "io")
MappingOpt = Annotated[
    str | None,
    typer.Option("--mapping", help="TOML mapping file (or built-in name) for a foreign log."),
]


def _read_options(mapping: str | None, robot: str | None) -> dict:
    return {k: v for k, v in (("mapping", mapping), ("robot", robot)) if v is not None}


@app.command()
def info(
    file: Annotated[Path, typer.Argument(help="Recording (.parquet, .csv, .mcap, ROS 2 bag).")],
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    json_out: JsonFlag = False,
    chunk: Chunk = None,
) -> None:
    """Duration, sample rate and jitter, joints, optional columns, still/dither/moving time."""
    import json

    from ditherlab.analysis.overview import describe, format_info
    from ditherlab.io.stream import open_source

    summary = describe(open_source(file, **_read_options(mapping, robot)), chunk_rows=chunk)
    echo(json.dumps(summary, indent=1) if json_out else format_info(summary))


@app.command()
def convert(
    src: Annotated[Path, typer.Argument(help="Input recording (any readable format).")],
    dst: Annotated[Path, typer.Argument(help="Output: .parquet, .csv, .mcap, or a bag folder.")],
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    chunk: Chunk = None,
    force: Force = False,
) -> None:
    """Convert a recording to another format (atomic; never over the input)."""
    from ditherlab.io import convert as _convert

    opts = _read_options(mapping, robot)
    echo(f"wrote {_convert(src, dst, rows=chunk, force=force, **opts)}")


@app.command()
def view(
    recording: Annotated[Path, typer.Argument(help="Recording (.parquet, .csv, .mcap, bag).")],
    estimates: Annotated[
        Path | None, typer.Option("--estimates", help="Estimates of this recording (replay).")
    ] = None,
    model: Annotated[
        Path | None, typer.Option("--model", help="Torque model (bands, residuals).")
    ] = None,
    diagnosis: Annotated[
        Path | None, typer.Option("--diagnosis", help="report.json of `diagnose -o`.")
    ] = None,
    save: Annotated[Path | None, typer.Option("--save", help="Write a Rerun file (.rrd).")] = None,
    spawn: Annotated[bool, typer.Option("--spawn", help="Open the Rerun viewer.")] = False,
    serve: Annotated[bool, typer.Option("--serve", help="Serve to a web viewer.")] = False,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    chunk: Chunk = None,
    quiet: Quiet = False,
) -> None:
    """Review a recording, its estimates and model in Rerun (3D robot, torques, forces, events)."""
    from ditherlab.output.rerun.rerun_log import load_view_request, run_view, wait_until_interrupted

    if spawn and serve:
        raise DitherlabError("view: choose one of --spawn and --serve")
    mode = "spawn" if spawn else "serve" if serve else None
    if save is not None:
        guard(save, recording, estimates, model, diagnosis, mapping=mapping)
    req = load_view_request(
        recording,
        estimates=estimates,
        model=model,
        diagnosis=diagnosis,
        save=save,
        mode=mode,
        read_options=_read_options(mapping, robot),
    )
    with progress_bar("view", quiet) as progress:
        res = run_view(req, progress=progress, **({"chunk_rows": chunk} if chunk else {}))
    if res.path is not None:
        echo(
            f"wrote {res.path} ({sum(res.summary.rows.values())} rows); open it with: rerun {res.path}"
        )
    elif res.url:
        echo(f"serving the view at {res.url} (Ctrl-C stops)")
        wait_until_interrupted()


# ---------------------------------------------------------------- robot (helper "robot")
def _opt(flag: str, text: str) -> typer.models.OptionInfo:
    return typer.Option(flag, help=text)


@app.command()
def robot(
    spec: Annotated[
        str, typer.Argument(help="Built-in robot name (irb140, panda, ur10e) or a URDF path.")
    ],
    q: Annotated[
        str | None,
        typer.Option(
            "--q", help="Pose: 'zero', 'paper' (IRB140) or n angles in rad, comma-separated."
        ),
    ] = None,
    tool_frame: Annotated[
        str | None,
        typer.Option(
            "--tool-frame",
            help="Tool frame of a URDF (default: tool0, flange, ... or the last link).",
        ),
    ] = None,
    sensitivity: Annotated[
        bool, _opt("--sensitivity", "Predicted F50/F90 per push direction.")
    ] = False,
    model: Annotated[
        Path | None, _opt("--model", "Model from identify (else the simulator's).")
    ] = None,
    dither: Annotated[
        bool | None, _opt("--dither/--no-dither", "One condition (else both).")
    ] = None,
    map_out: Annotated[
        Path | None, _opt("--map", "Over --grid: table .csv/.parquet + PNG.")
    ] = None,
    grid: Annotated[
        str | None, _opt("--grid", "Map poses qJ=START:STOP:COUNT[,qK=...] rad.")
    ] = None,
    force_range: Annotated[str, _opt("--force-range", "Push magnitudes MIN:MAX [N].")] = "10:60",
    noise_level: Annotated[
        str | None,
        _opt("--noise-level", "Measured noise level X,Y,Z [N] (one condition) for the predicted."),
    ] = None,
    report: Annotated[
        Path | None,
        _opt("--report", "report.json of ditherlab report: its measured noise level instead."),
    ] = None,
    seed: Seed = 0,
    quiet: Quiet = False,
    json_out: JsonFlag = False,
) -> None:
    """Joints, limits and masses of a robot; tool point, gravity and lever arms at a pose;
    with --sensitivity the predicted detection thresholds per push direction (--map: over a
    grid of poses)."""
    import json

    from ditherlab.robot import RobotModel, format_description, resolve_spec

    extra = (map_out, grid, model, noise_level, report)
    if not sensitivity and (any(x is not None for x in extra) or dither is not None):
        from ditherlab.core.errors import ConfigError

        raise ConfigError(
            "robot: --map, --grid, --model, --dither, --noise-level and --report need --sensitivity"
        )
    resolved = resolve_spec(spec, tool_frame=tool_frame)
    if sensitivity:
        from ditherlab.analysis.sensitivity_map import run_sensitivity
        from ditherlab.core.files import plain

        if map_out is not None:
            guard(map_out, model)
            guard(map_out.with_suffix(".png"), model, map_out)
        with progress_bar("map", quiet or map_out is None) as prog:
            args = (resolved, q, model, dither, map_out, grid, force_range, seed)
            res = run_sensitivity(*args, progress=prog, noise_level=noise_level, report=report)
        echo(json.dumps(plain(res["json"]), indent=1) if json_out else res["text"])
        return
    rm = RobotModel.from_spec(resolved)
    summary = rm.describe(rm.parse_pose(q))
    echo(json.dumps(summary, indent=1) if json_out else format_description(summary))


# ---------------------------------------------------------------- diagnose (helper "diagnose")
@app.command()
def diagnose(
    recordings: Annotated[
        list[Path], typer.Argument(help="Recordings (with an F/T sensor for the force error).")
    ],
    model: Annotated[
        Path, typer.Option("--model", help="Torque model (TOML); its history gains a row.")
    ],
    out: Annotated[
        Path | None,
        typer.Option("-o", "--out", help="Report folder (report.md, report.json, PNG figures)."),
    ] = None,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    no_history: Annotated[
        bool, typer.Option("--no-history", help="Do not append to the model's history.")
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
    """Where the model fails (residual vs noise floor, force error, worst windows) and which effect is missing."""
    import json

    from ditherlab.app.loop import diagnose_files
    from ditherlab.core.files import all_or_nothing, json_default

    if out is not None:
        guard(out, *recordings, model, mapping=mapping, folder=True, force=force)
    if not no_history and model.is_file():
        guard(model)  # its history gains a row: the model file is an output too
    undo = all_or_nothing(out) if out is not None else contextlib.nullcontext()
    with progress_bar("diagnose", quiet or json_out) as progress, undo:
        d = diagnose_files(
            recordings,
            model,
            out_dir=out,
            read_options=_read_options(mapping, robot),
            history=not no_history,
            regimes=regime,
            progress=progress,
            **({"chunk_rows": chunk} if chunk else {}),
        )
    echo(json.dumps(d.to_dict(), indent=1, default=json_default) if json_out else d.summary())


# ---------------------------------------------------------------- identify, replay, report (helper "replay")
@app.command()
def identify(
    recordings: Annotated[
        list[Path], typer.Argument(help="Push recordings with an F/T sensor (f_x..m_z).")
    ],
    out: OutPath,
    model: Annotated[
        Path | None,
        typer.Option(
            "--model", help="Base model: its prior and effects are kept, its bands re-fitted."
        ),
    ] = None,
    add: Annotated[
        list[str] | None,
        typer.Option("--add", help="Fit one more effect (diagnose's library), repeatable."),
    ] = None,
    assume_no_force: Annotated[
        bool,
        typer.Option(
            "--assume-no-force",
            help="No F/T sensor: you state that no external force acts; bands from rest periods.",
        ),
    ] = False,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates for the standard errors.")
    ] = 30,
    seed: Seed = 0,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    chunk: Chunk = None,
    quiet: Quiet = False,
) -> None:
    """Fit bands, noise (R_e) and sliding friction per joint and regime by maximum likelihood."""
    from ditherlab.analysis.identification import summary
    from ditherlab.app.loop import identify_files

    guard(out, *recordings, model, mapping=mapping)
    with progress_bar("identify", quiet) as progress:
        m = identify_files(
            recordings,
            out,
            base=model,
            add=add or [],
            assume_no_force=assume_no_force,
            n_boot=bootstrap,
            seed=seed,
            read_options=_read_options(mapping, robot),
            progress=progress,
            **({"chunk_rows": chunk} if chunk else {}),
        )
    echo(summary(m))
    echo(f"wrote {out}")


# ---------------------------------------------------------------- simulate (helper "sim")
@app.command()
def simulate(
    scenario: Annotated[
        str,
        typer.Argument(
            help="push-campaign, lead-through or excitation (for identify and diagnose)."
        ),
    ],
    out: OutPath,
    seed: Seed = 0,
    config: Annotated[
        Path | None,
        typer.Option("--config", help="TOML overriding the built-in IRB140 parameters."),
    ] = None,
    dither: Annotated[
        bool, typer.Option("--dither/--no-dither", help="Dither while standing still.")
    ] = True,
    hidden: Annotated[
        list[str] | None,
        typer.Option(
            "--hidden", help="Inject an effect the base model lacks: NAME[:SIZE], repeatable."
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
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Simulate the built-in IRB140 (gear springs, stick-slip friction, servo, dither) to a recording."""
    from ditherlab.io import check_recording_output, write
    from ditherlab.sim import simulate as run_sim

    check_recording_output(out, [config], force=force)
    with progress_bar(f"simulate {scenario}", quiet) as progress:
        rec = run_sim(
            scenario,
            seed=seed,
            dither=dither,
            config=config,
            hidden=hidden or [],
            progress=progress,
            pushes_per_direction=pushes_per_direction,
            log_temperature=None if log_temperature else False,
        )
    echo(f"wrote {write(rec, out)} ({rec.duration:.1f} s simulated)")


@app.command()
def replay(
    recording: Annotated[Path, typer.Argument(help="Recording to replay the estimator over.")],
    model: Annotated[
        Path, typer.Option("--model", help="Torque model (TOML) from `ditherlab identify`.")
    ],
    out: OutPath,
    level: Annotated[float, typer.Option("--level", help="Interval confidence level.")] = 0.95,
    interval: Annotated[
        str, typer.Option("--interval", help="Interval method: profile or set_membership.")
    ] = "profile",
    components: Annotated[
        str,
        typer.Option(
            "--components", help="Estimated components: all, fxyz, or a list like f_x,f_z."
        ),
    ] = "all",
    variants: Annotated[
        str | None,
        typer.Option(
            "--variants",
            help="Comma list of nodither_band, nodither_noband, dither_band, dither_noband (default: all the recording allows).",
        ),
    ] = None,
    mapping: MappingOpt = None,
    robot: RobotOpt = None,
    chunk: Chunk = None,
    quiet: Quiet = False,
) -> None:
    """Replay the estimator (no dither / dither x with / without the uniform term) -> estimates Parquet."""
    from ditherlab.analysis.estimation import describe, replay_file

    guard(out, recording, model, mapping=mapping)
    with progress_bar("replay", quiet) as progress:
        est = replay_file(
            recording,
            model,
            out,
            read_options=_read_options(mapping, robot),
            **({"chunk_rows": chunk} if chunk else {}),
            level=level,
            interval=interval,
            components=components,
            progress=progress,
            variants=variants.split(",") if variants else None,
        )
    echo(describe(est))
    echo(f"wrote {out}")


@app.command()
def report(
    estimates: Annotated[
        list[Path],
        typer.Argument(help="Estimates files from `ditherlab replay` (with the F/T columns)."),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "-o", "--out", help="Report folder (report.md, report.html, report.json, PNG figures)."
        ),
    ],
    recording: Annotated[
        list[Path] | None,
        typer.Option(
            "--recording",
            help="The recordings behind the estimates (adds Figs. 2, 4, 5), repeatable.",
        ),
    ] = None,
    bootstrap: Annotated[
        int, typer.Option("--bootstrap", help="Bootstrap replicates of the detection curves.")
    ] = 200,
    seed: Seed = 0,
    chunk: Chunk = None,
    json_out: JsonFlag = False,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Detection thresholds per direction beside the paper's §VI-C numbers, curves, coverage, figures."""
    import json

    from ditherlab.core.files import all_or_nothing, json_default
    from ditherlab.output.report_page import make_report, summary_text

    guard(out, *estimates, *(recording or []), folder=True, force=force)
    with progress_bar("report", quiet or json_out) as progress, all_or_nothing(out):
        a = make_report(
            estimates,
            out,
            recordings=recording or [],
            n_boot=bootstrap,
            seed=seed,
            progress=progress,
            **({"chunk_rows": chunk} if chunk else {}),
        )
    echo(
        json.dumps(a, indent=1, default=json_default)
        if json_out
        else summary_text(a) + f"\nwrote {out}/report.md"
    )


# ---------------------------------------------------------------- fleet (helper "fleet")
@app.command()
def fleet(
    recordings: Annotated[
        list[str] | None,
        typer.Argument(help="Recordings, folders or quoted glob patterns ('logs/**/*.parquet')."),
    ] = None,
    out: Annotated[
        Path,
        typer.Option(
            "-o", "--out", help="Output folder: fleet.parquet, fleet.md, fleet.json, models/."
        ),
    ] = Path("fleet-out"),
    manifest: Annotated[
        Path | None,
        typer.Option("--manifest", help="CSV with columns file, robot, date, notes."),
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
        typer.Option("--model", help="Base model every recording starts from (its effects kept)."),
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
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Identify and diagnose many recordings as Dask tasks -> one table and a fleet report."""
    from ditherlab.app.fleet import run_fleet

    s = run_fleet(
        recordings or [],
        out,
        manifest=manifest,
        scheduler=scheduler,
        workers=workers,
        base=model,
        assume_no_force=assume_no_force,
        n_boot=bootstrap,
        thresholds=thresholds,
        seed=seed,
        read_options=_read_options(mapping, robot),
        force=force,
        progress=not quiet,
    )
    echo(f"{s['recordings']} recordings of {len(s['robots'])} robots, {len(s['failures'])} failed")
    for f in s["failures"]:
        msg = f["error"] if f["error"].startswith(f["file"]) else f"{f['file']}: {f['error']}"
        echo(f"  failed: {msg}")
    for e, robots in s["effects"].items():
        echo(f"  {e}: {', '.join(robots)}")
    grow = [d for d in s["drift"] if d["growing"]]
    for d in grow:
        echo(
            f"  growing: {d['robot']} joint {d['joint']} {d['regime']} {d['quantity']} "
            f"{d['slope_per_30d']:+.3g} N·m per 30 days"
        )
    for o in s["outliers"]:
        echo(
            f"  outlier: {o['robot']} joint {o['joint']} {o['regime']} {o['quantity']} "
            f"{o['value']:.3g} (fleet median {o['fleet_median']:.3g}, z {o['z']:+.1f})"
        )
    echo(f"wrote {s['table']}, {out / 'fleet.md'}")


# ---------------------------------------------------------------- sweep (helper "fleet.sweep")
@app.command()
def sweep(
    grid: Annotated[
        list[str] | None,
        typer.Option(
            "--grid",
            help="KEY=V1,V2,...: a key of the simulator's parameters (irb140.toml) and its "
            "values, repeatable (per-joint lists: one value, or v1:v2:...:v6).",
        ),
    ] = None,
    out: Annotated[
        Path, typer.Option("-o", "--out", help="Output folder: sweep.parquet, .md, .json, PNG.")
    ] = Path("sweep-out"),
    config: Annotated[
        Path | None, typer.Option("--config", help="Simulator TOML every point starts from.")
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
    """Simulated paired campaigns over a grid of simulator parameters (dither design) as Dask tasks."""
    from ditherlab.app.sweep import run_sweep, summary_text

    s = run_sweep(
        grid or [],
        out,
        config=config,
        pushes_per_direction=pushes,
        seed=seed,
        repeats=repeats,
        curve_boot=bootstrap,
        vibration_limit=vibration_limit,
        scheduler=scheduler,
        workers=workers,
        force=force,
        progress=not quiet,
    )
    echo(summary_text(s))
    echo(f"wrote {s['table']}, {out / 'sweep.md'}, {out / 'sweep.json'}, figures")


# ---------------------------------------------------------------- leadthrough (helper "leadthrough")
@app.command()
def leadthrough(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output folder: .md, .json, .png.")],
    seed: Annotated[int, typer.Option("--seed", min=0, help="First simulator seed.")] = 0,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Seeds seed, seed+1, ...")] = 3,
    dither: Annotated[str, typer.Option("--dither", help="'both', 'on' or 'off'.")] = "both",
    config: Annotated[Path | None, typer.Option("--config", help="Simulator TOML.")] = None,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Lead-through with the 10 N dead zone vs the confidence interval (paper §V), same pushes."""
    from ditherlab.analysis.lead_metrics import compare_laws, means_table
    from ditherlab.core.errors import ConfigError
    from ditherlab.core.files import all_or_nothing
    from ditherlab.output.lead_figures import write_comparison
    from ditherlab.sim.params import load_params

    choices = {"both": (True, False), "on": (True,), "off": (False,)}
    if dither not in choices:
        raise ConfigError(f"--dither: got {dither!r}; expected 'both', 'on' or 'off'")
    guard(out, config, folder=True, force=force)
    if config is not None:
        load_params(config)  # a bad config is one line before any work
    seeds = list(range(seed, seed + repeats))
    with progress_bar("leadthrough", quiet) as progress, all_or_nothing(out):
        result = compare_laws(seeds, choices[dither], config=config, progress=progress)
        files = write_comparison(result, out)
    echo(means_table(result) + f"\nwrote {', '.join(str(f) for f in files)}")

"""``ditherlab simulate``: the built-in IRB140 (gear springs, stick-slip friction, servo, dither;
:mod:`ditherlab.sim`) run through a scenario and written as a recording."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ditherlab.app.workflow import Progress, guard_recording
from ditherlab.io import write
from ditherlab.robot import resolve_spec
from ditherlab.sim import simulate

__all__ = ["SimulateOptions", "Simulated", "run"]


@dataclass(frozen=True)
class SimulateOptions:
    """The options of ``ditherlab simulate``.

    Attributes
    ----------
    scenario : ``push-campaign``, ``lead-through`` or ``excitation``
    out : the recording to write (``.parquet``, ``.csv``, ``.mcap``, or a bag folder)
    seed : the simulator's seed; the same seed gives the same recording
    dither : dither while standing still
    config : a TOML overriding the built-in IRB140 parameters
    hidden : effects the base model lacks, injected: ``NAME[:SIZE]``
    pushes_per_direction : pushes per axis and sign (push-campaign); None: the config's
    log_temperature : with ``temperature_friction`` hidden, write the ``temp_j`` columns
    force : replace an existing output
    robot : the simulated arm (a built-in name, an example-robot-data arm, a URDF or xacro
        path) with the parameters' joint count
    tool_frame : its tool frame, where it is not the description's own
    robot_args : a xacro robot's ``NAME:=VALUE`` arguments
    """

    scenario: str
    out: str | Path
    seed: int = 0
    dither: bool = True
    config: Path | None = None
    hidden: tuple[str, ...] = ()
    pushes_per_direction: int | None = None
    log_temperature: bool = True
    force: bool = False
    robot: str = "irb140"
    tool_frame: str | None = None
    robot_args: tuple[str, ...] = ()


@dataclass
class Simulated:
    """The recording written and its simulated duration [s]."""

    path: Path
    duration: float

    def text(self) -> str:
        """What the CLI prints."""
        return f"wrote {self.path} ({self.duration:.1f} s simulated)"


def run(options: SimulateOptions, progress: Progress | None = None) -> Simulated:
    """Check the output, simulate, write the recording (atomically).

    Parameters
    ----------
    options : :class:`SimulateOptions`
    progress : ``progress(done, total)``, optional

    Returns
    -------
    Simulated
    """
    o = options
    robot_file = Path(o.robot) if Path(o.robot).is_file() else None
    out = guard_recording(o.out, [o.config, robot_file], force=o.force)
    robot = resolve_spec(o.robot, o.tool_frame, "--robot", o.robot_args)
    rec = simulate(
        o.scenario,
        seed=o.seed,
        dither=o.dither,
        config=o.config,
        hidden=list(o.hidden),
        progress=progress,
        pushes_per_direction=o.pushes_per_direction,
        log_temperature=None if o.log_temperature else False,
        robot=robot,
    )
    return Simulated(write(rec, out), rec.duration)

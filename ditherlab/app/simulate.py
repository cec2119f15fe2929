"""``ditherlab simulate``: a simulated plant run through a scenario and written as a recording:
the built-in IRB140 (``--plant band``: gear springs, stick-slip friction, servo, dither;
:mod:`ditherlab.sim`) or the LuGre plant (``--plant lugre``: :mod:`ditherlab.sim_lugre`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ditherlab.app.workflow import Progress, guard_recording
from ditherlab.core.errors import ConfigError
from ditherlab.io import write
from ditherlab.robot import resolve_spec
from ditherlab.sim import simulate
from ditherlab.sim_lugre import simulate_lugre

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
    plant : ``band`` (the built-in plant) or ``lugre`` (the second plant, ``ditherlab.sim_lugre``)
    external_loads : slow loads on the tool the F/T sensor measures (``lugre``): ``cable``,
        ``hose``, ``hand``
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
    plant: str = "band"
    external_loads: tuple[str, ...] = ()


PLANTS = ("band", "lugre")


def _check_plant(o: SimulateOptions) -> None:
    """ConfigError for a plant that is not one, or an option the chosen plant does not take."""
    if o.plant not in PLANTS:
        raise ConfigError(f"--plant {o.plant}: unknown plant; expected one of {', '.join(PLANTS)}")
    if o.plant == "band" and o.external_loads:
        raise ConfigError(
            f"--external-load {o.external_loads[0]}: the band plant has no external loads; "
            "expected --plant lugre"
        )
    if o.plant == "lugre" and o.config is not None:
        raise ConfigError(
            f"--config {o.config}: the LuGre plant draws its parameters from the seed; "
            "expected --config only with --plant band"
        )


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
    _check_plant(o)
    robot_file = Path(o.robot) if Path(o.robot).is_file() else None
    out = guard_recording(o.out, [o.config, robot_file], force=o.force)
    robot = resolve_spec(o.robot, o.tool_frame, "--robot", o.robot_args)
    if o.plant == "lugre":
        rec = simulate_lugre(
            o.scenario,
            seed=o.seed,
            dither=o.dither,
            hidden=o.hidden,
            external_loads=o.external_loads,
            robot=robot,
            log_temperature=o.log_temperature,
            pushes_per_direction=o.pushes_per_direction,
            progress=progress,
        )
        return Simulated(write(rec, out), rec.duration)
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

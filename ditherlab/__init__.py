"""ditherlab: sensorless force estimation with dithering — logs, estimator replay, simulation,
diagnosis and visual review (Stolt, Robertsson, Johansson: force estimation using dithering to
decrease the low-velocity friction uncertainties, ABB IRB140).

The front door mirrors the commands of the command line, with one argument order: recordings
first, then the model, then options (keyword-only). Recordings may be given as
:class:`Recording` objects or as paths (read with :func:`read`), a model as a
:class:`TorqueModel` or the path of its TOML file::

    import ditherlab as dl

    rec = dl.simulate("push-campaign", seed=0, pushes_per_direction=2)
    model = dl.identify([rec])
    est = dl.replay(rec, model)
    d = dl.diagnose([rec], model)
    dl.report([est], "report/", recordings=[rec])

Arrays have time as the first axis and SI units on the arm side of the gearbox:
``rec.q: (N, n) [rad]``, ``rec.tau: (N, n) [N·m]``, ``rec.wrench: (N, 6) [N, N·m]``.

Everything but the errors is loaded on first use: ``import ditherlab`` (and ``ditherlab --help``)
does not load pandas or pinocchio.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from os import PathLike
from typing import TYPE_CHECKING, Any

from ditherlab.core.errors import DitherlabError, DitherlabWarning
from ditherlab.core.version import __version__

if TYPE_CHECKING:  # pragma: no cover
    from ditherlab.analysis.diagnosis import Diagnosis
    from ditherlab.app.view import ViewResult
    from ditherlab.data.estimates import Estimates
    from ditherlab.data.recording import Recording
    from ditherlab.data.torque_model import TorqueModel

    RecordingLike = Recording | str | PathLike[str]
    ModelLike = TorqueModel | str | PathLike[str]

__all__ = [
    "DitherlabError",
    "DitherlabWarning",
    "Recording",
    "TorqueModel",
    "__version__",
    "add_effect",
    "diagnose",
    "identify",
    "read",
    "replay",
    "report",
    "simulate",
    "view",
    "write",
]

Progress = Callable[[int, int], None]


def __getattr__(name: str) -> Any:
    # the classes on first use: importing the package (``ditherlab --help``, every
    # ``from ditherlab.core.errors import ...``) then does not load pandas and pinocchio (~0.7 s)
    if name == "Recording":
        from ditherlab.data.recording import Recording

        return Recording
    if name == "TorqueModel":
        from ditherlab.data.torque_model import TorqueModel

        return TorqueModel
    raise AttributeError(f"module 'ditherlab' has no attribute {name!r}")


def read(path: str | PathLike[str], **options: Any) -> Recording:
    """Read a recording from any supported file (dispatch on the suffix and the content).

    Parameters
    ----------
    path : ``.parquet``, ``.csv`` (with its sidecar ``.json``), ``.mcap``, a ROS 2 bag (folder or
        ``.db3``), or any file with ``mapping=``
    **options : ``robot`` (a built-in name or a URDF path, for files without metadata),
        ``mapping`` (a TOML mapping file or built-in name, for a foreign log), and the format's
        own (:func:`ditherlab.io.read`)

    Returns
    -------
    Recording
        ``t (N,) [s]``, ``q (N, n) [rad]``, ``tau (N, n) [N·m]`` and the optional columns.
    """
    from ditherlab.io import read as _read

    return _read(path, **options)


def write(rec: Recording, path: str | PathLike[str], **options: Any) -> Any:
    """Write a recording atomically in the format its suffix names (no suffix: a ROS 2 bag
    folder); returns the path written (:func:`ditherlab.io.write`)."""
    from ditherlab.io import write as _write

    return _write(rec, path, **options)


def simulate(
    scenario: str = "push-campaign",
    *,
    seed: int = 0,
    dither: bool = True,
    config: str | PathLike[str] | Mapping[str, Any] | None = None,
    hidden: Sequence[str] = (),
    pushes_per_direction: int | None = None,
    progress: Progress | None = None,
) -> Recording:
    """Simulate the built-in IRB140 (gear springs, stick-slip friction, servo, dither).

    Parameters
    ----------
    scenario : ``"push-campaign"``, ``"lead-through"`` or ``"excitation"``
    seed : the same seed gives the same recording
    dither : dither while standing still
    config : a TOML file or dict overriding the built-in parameters (``irb140.toml``)
    hidden : effects the base model lacks, injected: ``"NAME[:SIZE]"``
    pushes_per_direction : pushes per axis and sign (push campaign); None: the config's
    progress : ``progress(done, total)``

    Returns
    -------
    Recording
        At 250 Hz: ``t, q_j, dq_j, tau_j, tau_ffw_j, f_x..m_z, dither``; ``meta["sim"]`` holds
        the parameters and the truth (:func:`ditherlab.sim.simulate`).
    """
    from ditherlab.sim import simulate as _simulate

    return _simulate(
        scenario,
        seed=seed,
        dither=dither,
        config=config,
        hidden=list(hidden),
        progress=progress,
        pushes_per_direction=pushes_per_direction,
    )


def identify(
    recordings: RecordingLike | Sequence[RecordingLike],
    *,
    model: ModelLike | None = None,
    add: Sequence[str] = (),
    assume_no_force: bool = False,
    windows: Sequence[tuple[float, float]] = (),
    excludes: Sequence[tuple[float, float]] = (),
    n_boot: int = 30,
    seed: int = 0,
    progress: Progress | None = None,
) -> TorqueModel:
    """Fit the bands, noise (``R_e``) and sliding friction per joint and regime by maximum
    likelihood, then add effects (``ditherlab identify``).

    Parameters
    ----------
    recordings : recordings with an F/T sensor (``f_x..m_z``, (N, 6) [N, N·m]), or without one
        with ``assume_no_force``
    model : a model to start from: its prior and effects kept, its bands re-fitted
    add : effects to fit after the bands, in order (:func:`add_effect`)
    assume_no_force : no F/T sensor: no external force acts but where the torque departs from
        rest (pushes: :func:`ditherlab.analysis.rest.scan_rest`), which is left out and listed
        in the model's notes
    windows : ``(start, end)`` [s] of the logs' time: only those samples are used (none: all)
    excludes : ``(start, end)`` [s] left out
    n_boot : bootstrap replicates for the standard errors
    seed : the bootstrap's seed
    progress : ``progress(done, total)``

    Returns
    -------
    TorqueModel
        Bands ``tau_min, tau_max (n,) [N·m]``, noise ``sigma (n,) [N·m]`` per regime.
    """
    from ditherlab.app.identify import identify_model, left_out, note_left_out
    from ditherlab.app.workflow import as_model, as_recordings

    base = as_model(model) if model is not None else None
    recs, drop, scans = left_out(
        as_recordings(recordings), base, windows, excludes, scan=assume_no_force
    )
    out = identify_model(
        recs,
        model=base,
        add=add,
        assume_no_force=assume_no_force,
        n_boot=n_boot,
        seed=seed,
        progress=progress,
        drop=drop,
    )
    note_left_out(out, scans)
    return out


def replay(
    recording: RecordingLike,
    model: ModelLike,
    *,
    level: float = 0.95,
    interval: str = "profile",
    components: str | Sequence[str] = "all",
    variants: Sequence[str] | None = None,
    progress: Progress | None = None,
) -> Estimates:
    """Replay the estimator of eq. (3) over a recording (``ditherlab replay``).

    Parameters
    ----------
    recording : the recording (``N`` samples, ``n`` joints)
    model : a model of the same robot
    level : the intervals' confidence level, in (0, 1)
    interval : ``"profile"`` or ``"set_membership"``
    components : ``"all"``, ``"fxyz"``, or names such as ``("f_x", "f_z")``
    variants : of ``nodither_band``, ``nodither_noband``, ``dither_band``, ``dither_noband``;
        None: all the recording allows
    progress : ``progress(done, total)``

    Returns
    -------
    Estimates
        Per variant ``F(variant) (N, 6) [N, N·m]`` and its interval (:func:`ditherlab.analysis.estimation.replay`).
    """
    from ditherlab.analysis.estimation import replay as _replay
    from ditherlab.app.workflow import as_model, as_recording

    return _replay(
        as_recording(recording),
        as_model(model),
        variants=variants,
        level=level,
        interval=interval,
        components=components,
        progress=progress,
    )


def diagnose(
    recordings: RecordingLike | Sequence[RecordingLike],
    model: ModelLike,
    *,
    regimes: Sequence[str] | None = None,
    progress: Progress | None = None,
) -> Diagnosis:
    """Where the model fails (residual against the noise floor, force error, worst windows) and
    which effect is missing (``ditherlab diagnose``).

    Parameters
    ----------
    recordings : recordings of the model's robot (with an F/T sensor for the force error)
    model : the model
    regimes : score only these regimes (``still``, ``dither``, ``moving``); None: all
    progress : ``progress(done, total)``

    Returns
    -------
    Diagnosis
        ``summary()`` in plain words, ``to_dict()`` as ``--json``, ``suggested`` effects
        (:func:`ditherlab.analysis.diagnosis.diagnose`).
    """
    from ditherlab.analysis.diagnosis import diagnose as _diagnose
    from ditherlab.app.workflow import as_model, as_recordings

    return _diagnose(as_recordings(recordings), as_model(model), regimes=regimes, progress=progress)


def add_effect(
    recordings: RecordingLike | Sequence[RecordingLike],
    model: ModelLike,
    effect: str,
    *,
    joints: Sequence[int] | None = None,
    refit: bool = True,
    assume_no_force: bool = False,
) -> TorqueModel:
    """Fit one more effect (a diagnosis's suggestion) on the model's residual and re-fit the
    bands with it in place (``identify --add``).

    Parameters
    ----------
    recordings : recordings to fit on
    model : the model the effect is added to
    effect : the effect's name (:data:`ditherlab.physics.effects.EFFECTS`)
    joints : 1-based joints of a per-joint effect; None: where diagnosis finds it
    refit : re-fit the bands and noise afterwards
    assume_no_force : the recordings have no F/T sensor and no external force acts

    Returns
    -------
    TorqueModel
        With the effect appended, version + 1 (:func:`ditherlab.app.identify.add_effect`).
    """
    from ditherlab.app.identify import add_effect as _add_effect
    from ditherlab.app.workflow import as_model, as_recordings

    return _add_effect(
        as_recordings(recordings),
        as_model(model),
        effect,
        joints,
        refit=refit,
        assume_no_force=assume_no_force,
    )


def report(
    estimates: Estimates | str | PathLike[str] | Sequence[Estimates | str | PathLike[str]],
    out: str | PathLike[str],
    *,
    recordings: Sequence[RecordingLike] = (),
    n_boot: int = 200,
    seed: int = 0,
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """The detection statistics beside the paper's §VI-C numbers, written as a report folder
    (``ditherlab report``).

    Parameters
    ----------
    estimates : estimates (:func:`replay`, with the F/T columns) or their files
    out : the report folder (``report.md``, ``report.html``, ``report.json``, PNG figures)
    recordings : the recordings behind the estimates: with them the torque figures too
    n_boot : bootstrap replicates of the detection curves
    seed : the bootstrap's seed
    force : write into an existing non-empty folder
    progress : ``progress(done, total)``

    Returns
    -------
    dict
        The analysis, as in ``report.json`` (F50 / F90 per direction [N], coverage, pushes).
    """
    from ditherlab.app.report import ReportOptions, run
    from ditherlab.data.estimates import Estimates

    if isinstance(estimates, Estimates | str | PathLike):
        estimates = [estimates]
    opts = ReportOptions(
        tuple(estimates), out, tuple(recordings), n_boot=n_boot, seed=seed, force=force
    )
    return run(opts, progress).analysis


def view(
    recording: RecordingLike,
    *,
    estimates: Estimates | str | PathLike[str] | None = None,
    model: ModelLike | None = None,
    diagnosis: Diagnosis | str | PathLike[str] | None = None,
    save: str | PathLike[str] | None = None,
    spawn: bool = False,
    serve: bool = False,
    force: bool = False,
) -> ViewResult:
    """Review a recording, its estimates, model and diagnosis in Rerun (``ditherlab view``):
    written to an ``.rrd`` file (``save``), or sent to the native (``spawn``) or a web viewer
    (``serve``).

    Parameters
    ----------
    recording : the recording
    estimates : its estimates (:func:`replay`)
    model : the model (bands, residuals)
    diagnosis : a :func:`diagnose` result, or the ``report.json`` of ``ditherlab diagnose -o``
    save : the ``.rrd`` file to write
    spawn, serve : the viewer to send the view to (one output of ``save``, ``spawn``, ``serve``)
    force : replace an existing ``.rrd`` file

    Returns
    -------
    ViewResult
        ``path`` written or ``url`` served, and the rows logged per entity
        (:func:`ditherlab.app.view.view`).
    """
    from ditherlab.app.view import view as _view
    from ditherlab.app.view import view_mode

    return _view(
        recording,
        estimates=estimates,
        model=model,
        diagnosis=diagnosis,
        save=save,
        mode=view_mode(spawn, serve),
        force=force,
    )

"""The demo run by ``make demo``: ``python -m ditherlab.app.demo --out DIR``.

The paper's experiment on the built-in simulator, end to end:

1. simulate paired push campaigns (the same pushes without and with dither) for identification
   (seed 1) and, separately, for evaluation (seed 0), so that the model is never scored on the
   data it was fitted to;
2. ``identify`` the bands, noise and sliding friction from the identification pair;
3. ``replay`` the estimator variants over the evaluation pair;
4. ``report``: the detection statistics beside the paper's §VI-C numbers, with figures, in
   ``DIR/report/``; the table is printed;
5. the sample recording of ``recordings/`` through every file format and back.

Each step is a small function; :func:`run_pipeline` is what the tests call with small sizes.
"""

from __future__ import annotations

import argparse
import copy
import multiprocessing
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Mapping
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import ditherlab.io as dio
from ditherlab.analysis.detection import AXES, PAPER
from ditherlab.analysis.estimation import replay
from ditherlab.analysis.identification import identify
from ditherlab.analysis.overview import describe, format_info
from ditherlab.app.identify import add_effect
from ditherlab.app.report import make_report
from ditherlab.app.view import save_view_files
from ditherlab.core.errors import DitherlabError, ModelError
from ditherlab.core.names import FORCE_AXES, WRENCH_COLUMNS
from ditherlab.core.progress import progress_bar
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.output.report_page import summary_text
from ditherlab.output.rerun.rerun_log import save_view
from ditherlab.sim import simulate

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"
SAMPLE = RECORDINGS / "ur10e-static.parquet"

#: Output name per format; the bags are folders.
TARGETS = (
    ("parquet", "sample.parquet", {}),
    ("csv", "sample.csv", {}),
    ("mcap", "sample.mcap", {}),
    ("rosbag (mcap storage)", "sample_bag_mcap", {"storage": "mcap"}),
    ("rosbag (sqlite3 storage)", "sample_bag_sqlite3", {"storage": "sqlite3"}),
)


@dataclass
class RoundTrip:
    """Result of writing one format and reading it back."""

    fmt: str
    path: Path
    size_bytes: int
    seconds: float
    exact: bool
    max_error: float  # largest |difference| over t, q, dq, tau and the wrench [SI]


def folder_size(path: Path) -> int:
    """Size of a file, or of all files in a folder [bytes]."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def max_difference(a: Recording, b: Recording) -> float:
    """Largest absolute difference of the columns a ROS 2 bag keeps (t, q, dq, tau, wrench)."""
    if len(a) != len(b):
        return float("inf")
    cols = ["t"] + [f"{p}_{j + 1}" for p in ("q", "dq", "tau") for j in range(a.n)]
    cols = [c for c in cols if c in a.data.columns]
    if a.has_wrench:
        cols += list(WRENCH_COLUMNS)
    missing = [c for c in cols if c not in b.data.columns]
    if missing:
        return float("inf")
    return float(np.max(np.abs(a.data[cols].to_numpy() - b.data[cols].to_numpy())))


def round_trip(rec: Recording, out: Path, fmt: str, name: str, options: dict) -> RoundTrip:
    """Write ``rec`` to ``out/name``, read it back and compare."""
    path = out / name
    t0 = time.perf_counter()
    kind = "rosbag" if fmt.startswith("rosbag") else None
    dio.write(rec, path, format=kind, **options)
    back = dio.read(path)
    seconds = time.perf_counter() - t0
    exact = rec.equals(back)
    return RoundTrip(fmt, path, folder_size(path), seconds, exact, max_difference(rec, back))


def report(results: list[RoundTrip]) -> str:
    """One line per format."""
    lines = [f"{'format':<26} {'size':>10}  {'write+read':>10}  result"]
    for r in results:
        verdict = "identical" if r.exact else f"max |diff| {r.max_error:.2e}"
        lines.append(
            f"{r.fmt:<26} {r.size_bytes / 1024:>8.0f} kB  {r.seconds:>8.2f} s  {verdict}"
            f"  ({r.path.name})"
        )
    return "\n".join(lines)


@dataclass
class PipelineResult:
    """What :func:`run_pipeline` produced: files, the analysis, and seconds per step.

    ``recordings`` and ``estimates`` name the evaluation pair's files (written only with
    ``keep_data``; the report names them either way); ``data`` holds the objects themselves
    (``"recordings"``, ``"estimates"``, ``"model"``); ``view`` the view's future when one was
    asked for (:func:`run_pipeline`'s ``view``)."""

    out: Path
    model: Path
    recordings: list[Path]
    estimates: list[Path]
    report: Path
    analysis: dict
    seconds: dict[str, float]
    data: dict[str, Any] = field(default_factory=dict)
    view: Future | None = None


class Inline(Executor):
    """An executor that runs each job when it is submitted, in this process (``--jobs 1``:
    the steps in the order of a serial run)."""

    def submit(self, fn, /, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN201
        f: Future = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by result()
            f.set_exception(exc)
        return f


def process_pool(jobs: int) -> Executor:
    """``jobs`` worker processes (spawned: a fresh interpreter each, nothing inherited but the
    arguments), or :class:`Inline` for ``jobs <= 1``."""
    if jobs <= 1:
        return Inline()
    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"))


def default_jobs() -> int:
    """Worker processes: the processors this process may run on, at most 4 (four campaigns)."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 4))


def bare(rec: Recording) -> Recording:
    """``rec`` without its cached robot and signals (a copy sharing the table), to send to
    another process: the caches are large and rebuilt there on demand."""
    out = copy.copy(rec)
    out.__dict__.pop("_robot", None)
    out.__dict__.pop("_signals", None)
    return out


def simulate_campaign(
    path: str, seed: int, dither: bool, pushes: int, config: Mapping[str, Any] | None
) -> tuple[Recording, float]:
    """One push campaign simulated, written to ``path`` and read back (the recording every
    later step sees is the file's); and the seconds it took."""

    t0 = time.perf_counter()
    rec = simulate(
        "push-campaign", seed=seed, dither=dither, pushes_per_direction=pushes, config=config
    )
    return dio.read(dio.write(rec, Path(path))), time.perf_counter() - t0


def replay_campaign(rec: Recording, model: Any) -> tuple[Any, float]:
    """The estimator variants over one recording (:func:`ditherlab.analysis.estimation.replay`), seconds."""

    t0 = time.perf_counter()
    return replay(rec, model), time.perf_counter() - t0


def write_view(
    rrd: Path,
    rec: Recording | Path,
    est: Any,
    model: Path,
    series_rate: float | None,
    rate_3d: float | None,
) -> tuple[Path, float]:
    """The Rerun view of one recording with its estimates and model: from the files
    (``rec`` and ``est`` paths, read in pieces) or from the objects; seconds."""
    t0 = time.perf_counter()
    kw = {"rate_3d": rate_3d, "series_rate": series_rate}
    if isinstance(rec, Path):
        save_view_files(rec, rrd, estimates=est, model=model, **kw)
    else:
        save_view(rec, rrd, estimates=est, model=TorqueModel.load(model), **kw)
    return rrd, time.perf_counter() - t0


def sample_round_trips(recording: Path, out: Path) -> tuple[str, list[RoundTrip]]:
    """``ditherlab info`` of the sample recording and its round trips through every format."""
    rec = dio.read(recording)
    return format_info(describe(rec)), [round_trip(rec, out, *target) for target in TARGETS]


def _done(desc: str, seconds: float, quiet: bool) -> None:
    if not quiet:
        print(f"{desc}: done in {seconds:.1f} s", file=sys.stderr, flush=True)


def run_pipeline(
    out: Path,
    *,
    pushes_per_direction: int = 25,
    seed: int = 0,
    n_boot: int = 30,
    report_boot: int = 200,
    quiet: bool = False,
    config: Mapping[str, Any] | None = None,
    executor: Executor | None = None,
    keep_data: bool = True,
    view: Mapping[str, Any] | None = None,
) -> PipelineResult:
    """Simulate, identify, replay and report (see the module docstring).

    Parameters
    ----------
    out : output folder
    pushes_per_direction : pushes per axis and sign in each campaign (the paper: about 50 per
        direction, i.e. 25 per sign)
    seed : seed of the evaluation campaigns (identification uses ``seed + 1``)
    n_boot : bootstrap replicates of the identification
    report_boot : bootstrap replicates of the detection curves
    quiet : no progress bars
    config : simulator parameters overriding ``irb140.toml`` (tables and keys as in that file),
        for both campaigns
    executor : runs the campaigns, the band fits, the replays and the view (e.g.
        :func:`process_pool`); None: all here, one after the other. Every result is the same,
        bit for bit: each job is a pure function of its arguments.
    keep_data : write the four campaigns' recordings and the two estimates files to ``out``
        (else the recordings go through a scratch folder, removed, and the estimates stay in
        memory; the report and the model name the files either way)
    view : ``{"path": .rrd, "series_rate": ..., "rate_3d": ...}``: the view of the dithered
        evaluation campaign, written by the executor while the report is made
        (:func:`write_view`; ``PipelineResult.view`` is its future)
    """

    out.mkdir(parents=True, exist_ok=True)
    ex = executor if executor is not None else Inline()
    pool = None if isinstance(ex, Inline) else ex  # the band fits: here, one at a time
    seconds: dict[str, float] = {}
    t_start = time.perf_counter()
    scratch = None if keep_data else Path(tempfile.mkdtemp(prefix=".demo-", dir=out))
    futures = _submit_campaigns(ex, scratch or out, seed, pushes_per_direction, config)

    def campaign(name: str) -> Recording:
        return _campaign(futures[name], out / f"{name}.parquet", f"simulate {name}", quiet)

    try:
        ids = [campaign("identification_nodither"), campaign("identification_dither")]
        seconds["simulate"] = time.perf_counter() - t_start
        t0 = time.perf_counter()
        model = _identify_model(ids, seed, n_boot, pool, quiet)
        model_path = model.save(out / "model.toml")
        seconds["identify"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        evals = [campaign("evaluation_nodither"), campaign("evaluation_dither")]
        seconds["simulate, rest"] = time.perf_counter() - t0
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    paths = [Path(r.name) for r in evals]
    t0 = time.perf_counter()
    est_paths, ests = _replay_evaluations(ex, evals, model, out, keep_data, quiet)
    seconds["replay"] = time.perf_counter() - t0
    view_job = None
    if view is not None:
        src = (paths[1], est_paths[1]) if keep_data else (bare(evals[1]), ests[1])
        rates = (view.get("series_rate"), view.get("rate_3d", 25.0))
        view_job = ex.submit(write_view, Path(view["path"]), *src, Path(model_path), *rates)
    t0 = time.perf_counter()
    with progress_bar("report", quiet) as progress:
        analysis = make_report(
            ests, out / "report", n_boot=report_boot, seed=seed, recordings=evals,
            progress=progress,
        )  # fmt: skip
    seconds["report"] = time.perf_counter() - t0
    return PipelineResult(
        out, Path(model_path), paths, est_paths, out / "report", analysis, seconds,
        {"recordings": evals, "estimates": ests, "model": model},
        view_job,
    )  # fmt: skip


def _submit_campaigns(
    ex: Executor,
    folder: Path,
    seed: int,
    pushes_per_direction: int,
    config: Mapping[str, Any] | None,
) -> dict[str, Future]:
    """The four campaigns, submitted to ``ex`` (identification: ``seed + 1``, evaluation:
    ``seed``; each without and with dither), their recordings written into ``folder``."""
    futures = {}
    for role, s in (("identification", seed + 1), ("evaluation", seed)):
        for dither in (False, True):
            name = f"{role}_{'dither' if dither else 'nodither'}"
            path = folder / f"{name}.parquet"
            args = (str(path), s, dither, pushes_per_direction, config)
            futures[name] = ex.submit(simulate_campaign, *args)
    return futures


def _campaign(job: Future, name: Path, desc: str, quiet: bool) -> Recording:
    """A submitted campaign's recording, named ``name`` (the file's, kept or not)."""
    rec, sec = job.result()
    object.__setattr__(rec, "name", str(name))
    _done(desc, sec, quiet)
    return rec


def _identify_model(
    ids: list[Recording], seed: int, n_boot: int, pool: Executor | None, quiet: bool
) -> TorqueModel:
    """The model of the identification pair ``ids``: the bands, then the dither's extraction."""
    with progress_bar("identify", quiet) as progress:
        # the bands' point estimates: what add_effect starts from. Its re-fit replaces every
        # band with its own (and its bootstrap's standard errors), so the bootstrap of this
        # first fit is run only for a model that keeps it (add_effect refused)
        model = identify(ids, n_boot=0, seed=seed, progress=progress)
        # how the dither's extraction shows a push (late, in part): identified from the
        # identification campaign's dithered pushes, used by replay
        # (docs/design/extraction-underestimates.md); a campaign where it cannot be told apart
        # from the bands keeps the model, then with its bootstrap
        try:
            return add_effect(ids, model, "dither_extraction", executor=pool)
        except ModelError:
            return identify(ids, n_boot=n_boot, seed=seed, executor=pool)


def _replay_evaluations(
    ex: Executor,
    evals: list[Recording],
    model: TorqueModel,
    out: Path,
    keep_data: bool,
    quiet: bool,
) -> tuple[list[Path], list[Any]]:
    """The estimates of the evaluation pair (replayed on ``ex``) and their files' paths (written
    when ``keep_data``)."""
    jobs = [ex.submit(replay_campaign, bare(r), model) for r in evals]
    est_paths, ests = [], []
    for name, job in zip(("evaluation_nodither", "evaluation_dither"), jobs, strict=True):
        est, sec = job.result()
        p = out / f"estimates_{name.split('_')[1]}.parquet"
        if keep_data:
            p = Path(est.save(p))
        est.name = str(p)
        est_paths.append(p)
        ests.append(est)
        _done(f"replay {name}", sec, quiet)
    return est_paths, ests


#: The two readings of the paper's second §VI-C statistic ("how much force that was needed to
#: estimate a force significantly different from zero ... an applied force of 40 N was needed"):
#: the analysis key of each (thresholds.direction_stats).
ABOVE10_READINGS = {
    "every": "above10_from",  # the force beyond which every push's estimate exceeded 10 N
    "needed": "above10_min",  # the smallest force whose estimate exceeded 10 N
}


def paper_agreement(
    analysis: dict, tol: float = 0.3, reading: str = "every"
) -> tuple[int, int, list[str]]:
    """How many of the paper's 12 §VI-C numbers ours match within ``tol`` (relative).

    Compares ``nodither_band`` with the paper's no-dither row and ``dither_band`` with its
    dither row, per axis: the smallest force with a response and, for the 10 N statistic,
    ``reading`` "every" (the default: the force beyond which every estimate exceeded 10 N) or
    "needed" (the smallest force whose estimate exceeded 10 N: "no force smaller than 32 N gave
    any response", said of the first statistic, read the same way for the second) [N].

    Returns
    -------
    (within, total, misses) : counts, and one ``"condition axis statistic: ours vs paper"`` line
    per cell outside (or missing)
    """
    within, total, misses = 0, 0, []
    for cond, label in (("nodither_band", "no dither"), ("dither_band", "dither")):
        dirs = analysis["conditions"].get(cond, {}).get("directions", {})
        for a in AXES:
            for key, stat in (("response_min", "response"), (ABOVE10_READINGS[reading], "above10")):
                total += 1
                paper = PAPER[label][stat][a]
                ours = (dirs.get(a) or {}).get(key)
                if ours is not None and abs(ours - paper) <= tol * paper:
                    within += 1
                else:
                    got = "none" if ours is None else f"{ours:.0f} N"
                    misses.append(f"{cond} {a} {stat}: {got} vs {paper:.0f} N")
    return within, total, misses


def pipeline_text(res: PipelineResult) -> str:
    """The printed summary: the table against the paper's, coverage, files and timings."""

    a = res.analysis
    lines = [
        summary_text(a),
        "(each cell: smallest applied force whose estimate rose above the noise level / "
        "smallest force beyond which every estimate exceeded 10 N; the minimum is an extreme "
        "statistic, the detection curve's F50 below shows the bulk)",
    ]
    for reading, head in (
        ("every", "within ±30 % of the paper"),
        (
            "needed",
            "with the 10 N statistic read as the smallest force whose estimate exceeded 10 N "
            "(docs/method.md, the paper's detection statistics)",
        ),
    ):
        within, total, misses = paper_agreement(a, reading=reading)
        lines.append(
            f"{head}: {within} / {total} cells"
            + (f" (outside: {'; '.join(misses)})" if misses else "")
        )
    lines.append("")
    lines.append("noise level (99.9 % of |F_hat| at rest, >= 1 N), x/y/z:")
    for name, c in a["conditions"].items():
        nl = c["noise_level"]
        lines.append(
            f"  {name:<30} {nl['x']:.1f} / {nl['y']:.1f} / {nl['z']:.1f} N,"
            f" interval coverage {c['coverage_all']:.1%} (all samples),"
            f" {c['coverage_rest']:.1%} (rest)"
        )
    lines.append("")
    lines.append("F50 / F90 of the detection curve (90 % bootstrap interval), x | y | z:")
    for name in ("nodither_band", "dither_band", "dither_noband"):
        c = a["conditions"].get(name)
        if not c:
            continue
        cells = []
        for ax in FORCE_AXES:
            d = c["directions"].get(ax)
            if d and d["curve"].get("bound"):
                cv = d["curve"]
                sign = "<" if cv["bound"] == "below" else ">"
                cells.append(
                    f"{sign} {cv['bound_force']:.0f} N (every push {'' if sign == '<' else 'un'}seen)"
                )
            elif d:
                cv = d["curve"]
                cells.append(
                    f"{cv['F50']:.0f} [{cv['F50_ci'][0]:.0f}, {cv['F50_ci'][1]:.0f}] / "
                    f"{cv['F90']:.0f} [{cv['F90_ci'][0]:.0f}, {cv['F90_ci'][1]:.0f}] N"
                )
        lines.append(f"  {name:<16} " + " | ".join(cells))
    npush = {r["file"]: len(r["pushes"]) for r in a["recordings"]}
    lines.append("")
    lines.append("pushes found: " + ", ".join(f"{Path(k).name} {v}" for k, v in npush.items()))
    lines.append(f"model: {res.model}; report: {res.report}/report.md (+ .html, .json, PNG)")
    lines.append("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in res.seconds.items()))
    return "\n".join(lines)


#: The default view's resolution: the time series' envelope in bins of 0.5 s
#: (:func:`ditherlab.output.rerun.columns.envelope_mask`) and the 3D scene at 10 Hz (``--full-view``:
#: every sample, 3D at 25 Hz).
VIEW_SERIES_RATE = 2.0
VIEW_RATE_3D = 10.0


def main(argv: list[str] | None = None) -> int:
    """Run the demo; returns the exit status (0 when every step and round trip holds)."""
    args = _parser().parse_args(argv)
    t_start = time.perf_counter()
    view = {
        "path": args.out / "demo.rrd",
        "series_rate": None if args.full_view else VIEW_SERIES_RATE,
        "rate_3d": 25.0 if args.full_view else VIEW_RATE_3D,
    }
    ex = process_pool(args.jobs)
    try:
        results = _run_demo(args, ex, view)
    except DitherlabError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        ex.shutdown(cancel_futures=True)
    print(report(results))
    # Parquet, CSV and MCAP are exact; a ROS 2 bag keeps t (ns stamps), q, dq, tau, wrench.
    ok = all(r.exact if not r.fmt.startswith("rosbag") else r.max_error < 1e-6 for r in results)
    print("\nall round trips hold" if ok else "\nA ROUND TRIP FAILED")
    print(f"demo finished in {time.perf_counter() - t_start:.0f} s")
    return 0 if ok else 1


def _parser() -> argparse.ArgumentParser:
    """The demo's command line."""
    parser = argparse.ArgumentParser(prog="python -m ditherlab.app.demo", description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("demo-out"), help="output folder")
    parser.add_argument("--recording", type=Path, default=SAMPLE, help="sample recording")
    parser.add_argument(
        "--pushes", type=int, default=25, help="pushes per axis and sign in each simulated campaign"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--jobs",
        type=int,
        default=default_jobs(),
        help="worker processes for the campaigns, band fits, replays and view "
        "(default: the processors available, at most 4; 1: all in this process, one after "
        "the other); the outputs are the same",
    )
    parser.add_argument(
        "--keep-data",
        action="store_true",
        help="also write the four campaigns' recordings and the two estimates files "
        "(about 350 MB; `ditherlab report` and `ditherlab view` read them)",
    )
    parser.add_argument(
        "--full-view",
        action="store_true",
        help="write demo.rrd with every sample of the time series and the 3D scene at 25 Hz "
        f"(about 360 MB) instead of their envelope over {1 / VIEW_SERIES_RATE:g} s bins and "
        f"{VIEW_RATE_3D:g} Hz",
    )
    return parser


def _run_demo(args: argparse.Namespace, ex: Executor, view: Mapping[str, Any]) -> list[RoundTrip]:
    """The pipeline, its view and the sample recording's round trips on ``ex``, printed as they
    finish; the round trips."""
    print(
        "== push campaigns without and with dither on the built-in simulator "
        f"({args.pushes} pushes per axis and sign) -> identify -> replay -> report",
        flush=True,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    # the sample recording's round trips need nothing of the pipeline: queued behind the
    # campaigns, for a worker that would otherwise wait
    trips = ex.submit(sample_round_trips, args.recording, args.out)
    res = run_pipeline(
        args.out,
        pushes_per_direction=args.pushes,
        quiet=args.quiet,
        executor=ex,
        keep_data=args.keep_data,
        view=view,
    )
    print(pipeline_text(res), flush=True)
    if not args.keep_data:
        print(
            "(recordings and estimates kept in memory, not written: --keep-data writes "
            "them under the names above)",
            flush=True,
        )
    assert res.view is not None
    rrd, _ = res.view.result()
    print(f"\n== Rerun view of {res.recordings[1].name}: open it with: rerun {rrd}", flush=True)
    info, results = trips.result()
    print(f"\n== ditherlab info {args.recording}")
    print(info)
    print(f"\n== round trips through every format, in {args.out}/")
    return results


if __name__ == "__main__":
    sys.exit(main())

"""Many recordings of many robots at once, on Dask distributed (``ditherlab fleet``).

:func:`run` resolves the inputs (files, folders, glob patterns, or a manifest CSV with
``file, robot, date, notes`` and each recording's own settings: :func:`read_manifest`), runs
:func:`ditherlab.analysis.fleet_job.analyse_recording` on each as one Dask task
(:func:`ditherlab.core.tasks.run_tasks`: a LocalCluster in this process by default), and writes,
atomically, into the output folder:

- ``fleet.parquet``: one row per recording, regime and joint (:data:`ditherlab.analysis.fleet_job.COLUMNS`);
- ``fleet.json`` and ``fleet.md``: the fleet report (:mod:`ditherlab.analysis.fleet_summary`), failures
  included;
- ``models/<robot>__<file stem>.toml``: each recording's identified model.

One recording's failure is reported in the summary and the others go on (:attr:`Fleet.failed`
then says so: the CLI exits with status 1); an optional step that fails on a recording (the
thresholds) is reported and its rows stand.
"""

from __future__ import annotations

import glob
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from ditherlab.analysis.fleet_job import COLUMNS, analyse_recording
from ditherlab.analysis.fleet_summary import summarise, to_markdown
from ditherlab.app.workflow import ReadOptions, guard
from ditherlab.core.errors import ConfigError, DitherlabError
from ditherlab.core.files import atomic_path, atomic_write_json, atomic_write_text
from ditherlab.core.tasks import TaskResult, run_tasks
from ditherlab.data.recording import robot_label
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io import csv as csv_io
from ditherlab.io.stream import Source

__all__ = ["Fleet", "FleetOptions", "collect_inputs", "read_manifest", "run"]

#: file suffixes taken from a folder (ROS 2 bag folders are taken whole)
SUFFIXES = (".parquet", ".pq", ".csv", ".mcap", ".db3")


def _is_bag(p: Path) -> bool:
    """A ROS 2 bag folder (``metadata.yaml`` or ``.db3`` storage inside). Narrower than
    :func:`ditherlab.io.detect_format`, which also takes a folder holding ``.mcap`` files for a
    bag: here such a folder is searched and each ``.mcap`` read on its own (a folder of
    recordings)."""
    return p.is_dir() and ((p / "metadata.yaml").is_file() or any(p.glob("*.db3")))


def _from_folder(folder: Path) -> list[Path]:
    out: list[Path] = []
    for p in sorted(folder.iterdir()):
        if p.name.startswith("."):
            continue
        if _is_bag(p):
            out.append(p)
        elif p.is_dir():
            out.extend(_from_folder(p))
        elif p.suffix.lower() in SUFFIXES:
            out.append(p)
    return out


#: the manifest's columns: the recording, its identity, and its own read and identify settings
MANIFEST_COLUMNS = (
    "file",
    "robot",
    "date",
    "notes",
    "mapping",
    "description",
    "sensor",
    "joint_topic",
    "wrench_topic",
)
#: a ``sensor`` cell: yes (an F/T sensor, f_x..m_z) or no (``--assume-no-force``)
_SENSOR = {"yes": False, "true": False, "1": False, "no": True, "false": True, "0": True}


def read_manifest(path: str | Path) -> list[tuple[Path, dict[str, Any]]]:
    """``(file, info)`` per row of a manifest CSV (:data:`MANIFEST_COLUMNS`).

    Columns: ``file`` (required; relative paths are taken from the manifest's folder),
    ``robot`` (the robot's identity: a serial number, a cell name), ``date`` (any date pandas
    parses; stored as ``YYYY-MM-DD``), ``notes``, and the recording's own settings, an empty
    cell leaving the command's option: ``mapping`` (``--mapping``), ``description``
    (``--robot``: a built-in name or a URDF path), ``sensor`` (``yes``: an F/T sensor; ``no``:
    ``--assume-no-force``), ``joint_topic`` and ``wrench_topic`` (a ROS 2 bag's topics;
    ``wrench_topic`` ``none`` reads no wrench). A relative path of a mapping or URDF file is
    taken from the manifest's folder. ``info`` holds ``robot``, ``date``, ``notes``, ``read``
    (reader options) and ``assume_no_force`` (None: the command's).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such manifest file")
    try:
        m = pd.read_csv(p, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a manifest CSV ({str(exc).splitlines()[0]})") from None
    if "file" not in m.columns:
        raise ConfigError(
            f"{p}: column 'file' is missing (found {', '.join(m.columns) or 'none'}); expected "
            f"file, and optionally {', '.join(MANIFEST_COLUMNS[1:])}"
        )
    unknown = [c for c in m.columns if c not in MANIFEST_COLUMNS]
    if unknown:
        raise ConfigError(
            f"{p}: unknown column {unknown[0]!r}; expected {', '.join(MANIFEST_COLUMNS)}"
        )
    return [_manifest_row(p, i + 2, r) for i, r in m.iterrows()]


def _manifest_row(p: Path, line: int, r: pd.Series) -> tuple[Path, dict[str, Any]]:
    """One manifest row (file line ``line``) as ``(file, info)`` (:func:`read_manifest`)."""
    f = Path(r["file"])
    f = f if f.is_absolute() else p.parent / f
    if not f.exists():
        raise ConfigError(
            f"{p}: row {line}, column 'file' is {r['file']!r}: no such file or folder"
            + (f" ({f})" if str(f) != r["file"] else "")
            + "; expected a recording"
        )
    date = r.get("date", "") or None
    if date is not None:
        try:
            date = pd.Timestamp(date).date().isoformat()
        except ValueError:
            raise ConfigError(
                f"{p}: row {line}, column 'date' is {r['date']!r}; expected a date such "
                "as 2026-11-24"
            ) from None
    sensor = str(r.get("sensor", "")).strip().lower()
    if sensor and sensor not in _SENSOR:
        raise ConfigError(
            f"{p}: row {line}, column 'sensor' is {r['sensor']!r}; expected yes (an F/T sensor) "
            "or no (no sensor and no external force, as --assume-no-force), or empty"
        )
    read: dict[str, str] = {}
    for col, opt in (("mapping", "mapping"), ("description", "robot")):
        if r.get(col, ""):
            near = p.parent / r[col]
            read[opt] = str(near) if not Path(r[col]).is_absolute() and near.is_file() else r[col]
    if r.get("joint_topic", ""):
        read["joint_topic"] = r["joint_topic"]
    if r.get("wrench_topic", ""):  # none: the bag's wrench is not read
        read["wrench_topic"] = "" if r["wrench_topic"].lower() == "none" else r["wrench_topic"]
    info = {"robot": r.get("robot", "") or None, "date": date, "notes": r.get("notes", "")}
    return f, {**info, "read": read, "assume_no_force": _SENSOR.get(sensor)}


#: the info of a recording given without a manifest: the command's settings
_NO_INFO: dict[str, Any] = {
    "robot": None,
    "date": None,
    "notes": "",
    "read": {},
    "assume_no_force": None,
}


def collect_inputs(
    inputs: Sequence[str | Path], manifest: str | Path | None = None
) -> list[tuple[Path, dict[str, Any]]]:
    """The recordings to analyse: files, folders (searched recursively; ROS 2 bag folders whole),
    glob patterns (``'logs/**/*.parquet'``) and a manifest; each file once, in the order given."""
    found: list[tuple[Path, dict[str, Any]]] = list(read_manifest(manifest)) if manifest else []
    for item in inputs:
        s = str(item)
        if any(c in s for c in "*?["):
            hits = sorted(Path(h) for h in glob.glob(s, recursive=True))
            if not hits:
                raise ConfigError(f"{s}: the pattern matches no file")
            paths = []
            for h in hits:
                paths.extend([h] if (h.is_file() or _is_bag(h)) else _from_folder(h))
        else:
            p = Path(s)
            if not p.exists():
                raise ConfigError(f"{p}: no such file or folder")
            paths = [p] if (p.is_file() or _is_bag(p)) else _from_folder(p)
            if not paths:
                raise ConfigError(
                    f"{p}: a folder without recordings (expected {', '.join(SUFFIXES)} files or "
                    "ROS 2 bag folders)"
                )
        found.extend((q, dict(_NO_INFO)) for q in paths)
    seen: set[Path] = set()
    out = []
    for p, info in found:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            out.append((p, info))
    if not out:
        raise ConfigError("fleet: no recordings given (files, folders, patterns or --manifest)")
    return out


def _check_robots(
    items: list[tuple[Path, dict[str, Any]]], model: TorqueModel, read: dict[str, Any]
) -> None:
    """One model for the whole fleet: every recording must be of its robot. Checked before any
    task runs, on the recordings whose metadata is read without their samples (Parquet, CSV,
    ditherlab MCAP), with their own reader options (``read`` updated by the manifest's); bags,
    mapped logs and unreadable files are checked (or reported) in their task."""
    for p, info in items:
        own = {**read, **info.get("read", {})}
        suffix = p.suffix.lower()
        if "mapping" in own or _is_bag(p) or suffix not in (".parquet", ".csv", ".mcap"):
            continue
        try:  # a CSV's sidecar alone (a Source would read its `t` column too)
            meta = csv_io.read_meta(p, own) if suffix == ".csv" else Source(p, **own).meta
            spec = meta.get("robot")
        except DitherlabError:
            continue  # its task reports what is wrong with it
        if spec is not None and not model.same_robot(spec):
            raise ConfigError(
                f"{p}: the recording's robot is {robot_label(spec)} but the model "
                f"{model.source or ''} is for {robot_label(model.robot)}; one model serves one "
                "robot: run the fleet once per robot, or without --model".replace("  ", " ")
            )


def _setting_files(items: list[tuple[Path, dict[str, Any]]]) -> list[Path]:
    """The mapping files the manifest's rows name, which no output may overwrite."""
    return [f for _, info in items for f in ReadOptions(info["read"].get("mapping")).files()]


def _model_name(robot: str, path: Path) -> str:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{robot}__{path.stem}")
    return f"{safe}.toml"


@dataclass(frozen=True)
class FleetOptions:
    """The options of ``ditherlab fleet``.

    Attributes
    ----------
    recordings : files, folders (searched recursively) or glob patterns (``'logs/**/*.parquet'``)
    out : the output folder: ``fleet.parquet``, ``fleet.md``, ``fleet.json``, ``models/``
        (created; must not be, contain or lie in an input)
    manifest : a CSV with ``file, robot, date, notes`` (robot ids and dates for drift)
    scheduler : None (a LocalCluster here, one worker per core), ``"serial"`` (a plain loop) or
        a Dask scheduler address ``tcp://HOST:PORT``
    workers : the LocalCluster's workers
    model : a model file every recording starts from (its effects kept, its bands re-fitted)
    assume_no_force : no F/T sensor and no external force (as ``ditherlab identify``)
    n_boot : bootstrap replicates per recording
    thresholds : replay the estimator on recordings with pushes for F50 / F90 per axis
    seed : the bootstrap's seed
    read : how to read a foreign log (``--mapping``, ``--robot``)
    force : write into an existing non-empty folder
    """

    recordings: tuple[str, ...] = ()
    out: str | Path = "fleet-out"
    manifest: Path | None = None
    scheduler: str | None = None
    workers: int | None = None
    model: Path | None = None
    assume_no_force: bool = False
    n_boot: int = 0
    thresholds: bool = True
    seed: int = 0
    read: ReadOptions = ReadOptions()
    force: bool = False


@dataclass
class Fleet:
    """The fleet report (``fleet.json``'s content, with ``table``: the Parquet path) and the
    output folder."""

    summary: dict[str, Any]
    out: Path

    def text(self) -> str:
        """Recordings, failures, effects found per robot, growing quantities and outliers, and
        the files written (what the CLI prints)."""
        s = self.summary
        lines = [
            f"{s['recordings']} recordings of {len(s['robots'])} robots, "
            f"{len(s['failures'])} failed"
        ]
        for f in s["failures"]:
            msg = f["error"] if f["error"].startswith(f["file"]) else f"{f['file']}: {f['error']}"
            lines.append(f"  failed: {msg}")
        for k in s.get("skipped", []):
            lines.append(f"  {k['step']} not computed: {k['file']}: {k['error']}")
        if s.get("named_by_file"):
            n = len(s["named_by_file"])
            lines.append(
                f"  {n} recording{'s' if n > 1 else ''} named by {'their' if n > 1 else 'its'} "
                "file (no manifest robot, no metadata robot_id): each its own robot"
            )
        for e, robots in s["effects"].items():
            lines.append(f"  {e}: {', '.join(robots)}")
        for d in (d for d in s["drift"] if d["growing"]):
            lines.append(
                f"  growing: {d['robot']} joint {d['joint']} {d['regime']} {d['quantity']} "
                f"{d['slope_per_30d']:+.3g} N·m per 30 days"
            )
        for o in s["outliers"]:
            lines.append(
                f"  outlier: {o['robot']} joint {o['joint']} {o['regime']} {o['quantity']} "
                f"{o['value']:.3g} (fleet median {o['fleet_median']:.3g}, z {o['z']:+.1f})"
            )
        lines.append(f"wrote {s['table']}, {self.out / 'fleet.md'}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """The fleet report."""
        return self.summary

    @property
    def failed(self) -> str | None:
        """None when every recording was analysed; else the line that says how many failed
        (the command then exits with status 1, its outputs holding the others)."""
        s = self.summary
        n = len(s["failures"])
        if not n:
            return None
        done = s["given"] - n
        return f"fleet: {n} of {s['given']} recordings failed (listed above); " + (
            f"{self.out} holds the other {done}" if done else "no recording was analysed"
        )


def run(
    options: FleetOptions,
    *,
    progress: bool = False,
    on_result: Callable[[TaskResult], None] | None = None,
) -> Fleet:
    """Analyse every recording as a Dask task and write the fleet table and report.

    Parameters
    ----------
    options : :class:`FleetOptions`
    progress : Dask's progress bar on stderr
    on_result : called as each recording finishes

    Returns
    -------
    Fleet
    """
    o = options
    items = collect_inputs(o.recordings, o.manifest)
    extra = [Path(o.manifest), *_setting_files(items)] if o.manifest else []
    if o.model is not None:
        extra.append(Path(o.model))
    out = guard(o.out, [p for p, _ in items] + extra, read=o.read, folder=True, force=o.force)
    base_text = None
    if o.model is not None:
        b = Path(o.model)
        if not b.is_file():
            raise ConfigError(f"{b}: no such model file")
        base_text = b.read_text(encoding="utf-8")
        _check_robots(items, TorqueModel.load(b), o.read.kwargs())
    job = {
        "read": o.read.kwargs(),
        "base": base_text,
        "base_name": str(o.model) if o.model is not None else None,
        "assume_no_force": o.assume_no_force,
        "n_boot": o.n_boot,
        "seed": o.seed,
        "thresholds": o.thresholds,
    }
    tasks = [(str(p), (str(p), info, job)) for p, info in items]
    results = run_tasks(
        analyse_recording,
        tasks,
        scheduler=o.scheduler,
        workers=o.workers,
        progress=progress,
        on_result=on_result,
    )
    return Fleet(_write(results, items, out), out)


def _write(
    results: list[TaskResult], items: list[tuple[Path, dict[str, Any]]], out: Path
) -> dict[str, Any]:
    """Write each recording's model, the table and the report; returns the report."""
    rows: list[dict[str, Any]] = []
    failures, skipped, by_file = [], [], []
    out.mkdir(parents=True, exist_ok=True)
    (out / "models").mkdir(exist_ok=True)
    for r, (p, _) in zip(results, items, strict=True):
        if not r.ok:
            failures.append({"file": str(p), "error": r.error})
            continue
        rows.extend(r.value["rows"])
        skipped += [{"file": str(p), **k} for k in r.value.get("skipped", [])]
        if r.value.get("robot_from") == "file name":
            by_file.append(str(p))
        robot = r.value["rows"][0]["robot"] if r.value["rows"] else p.stem
        atomic_write_text(out / "models" / _model_name(robot, p), r.value["model"])
    table = pd.DataFrame(rows, columns=COLUMNS)
    with atomic_path(out / "fleet.parquet") as tmp:
        table.to_parquet(tmp, index=False)
    s = summarise(table, failures, skipped, by_file)
    atomic_write_json(out / "fleet.json", s)
    atomic_write_text(out / "fleet.md", to_markdown(s))
    return {**s, "table": str(out / "fleet.parquet"), "given": len(items)}

"""The one output guard (:func:`ditherlab.core.files.check_output`), as every writing command
meets it: an output equal to, inside or holding an input, an unwritable place, a folder where a
file goes (and the reverse), an existing non-empty output folder without ``--force``. Each is
one exact line on stderr, exit status 2, before any work, and the inputs keep their bytes and
modification times."""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import pytest

import ditherlab.io as dio
from ditherlab.core.files import check_output, companions
from ditherlab.io import csv as csv_io

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "recordings" / "ur10e-static.parquet"


def assert_refused(res, line: str) -> None:
    """Exit 2, nothing on stdout, exactly ``error: LINE`` on stderr."""
    assert (res.code, res.out, res.err) == (2, "", f"error: {line}\n"), (res.code, res.err)


def snapshot(*paths: Path) -> dict[Path, tuple[bytes, int]]:
    """Bytes and mtime of every file under ``paths``."""
    out = {}
    for p in paths:
        for f in [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file()):
            out[f] = (f.read_bytes(), f.stat().st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A recording (Parquet, CSV with sidecar, a ROS 2 bag folder), a model and estimates."""
    d = tmp_path_factory.mktemp("inputs")
    whole = dio.read(SAMPLE)
    rec = whole.slice(whole.t0, whole.t0 + 2.0)
    out = {
        "rec": dio.write(rec, d / "rec.parquet"),
        "csv": dio.write(rec, d / "rec.csv"),
        "bag": dio.write(rec, d / "bag"),
    }
    # the guard runs before anything is read: these need not be valid for the refusals
    for name, text in (("model", "not read\n"), ("est", "not read\n"), ("config", "x = 1\n")):
        out[name] = d / f"{name}.{'toml' if name != 'est' else 'parquet'}"
        out[name].write_text(text)
    return out


@pytest.fixture
def guarded(files):
    """Check after the test that no input changed (bytes and mtime)."""
    before = snapshot(*files.values())
    yield files
    assert snapshot(*files.values()) == before


def test_output_equal_to_an_input_every_command(cli, guarded):
    """`-o` naming an input, for every writing command: one line, exit 2 (not a FileExistsError
    traceback)."""
    f = guarded
    rec, model, est = f["rec"], f["model"], f["est"]
    cases = [
        (["identify", rec, "-o", rec], f"{rec}: refusing to write over the input file {rec}"),
        (
            ["identify", rec, "--model", model, "-o", model],
            f"{model}: refusing to write over the input file {model}",
        ),
        (
            ["replay", rec, "--model", model, "-o", model],
            f"{model}: refusing to write over the input file {model}",
        ),
        (["report", est, "-o", est], f"{est}: refusing to write over the input file {est}"),
        (
            ["diagnose", rec, "--model", model, "-o", rec],
            f"{rec}: refusing to write over the input file {rec}",
        ),
        (
            ["diagnose", rec, "--model", model, "-o", model, "--no-history"],
            f"{model}: refusing to write over the input file {model}",
        ),
        (["view", rec, "--save", rec], f"{rec}: refusing to write over the input file {rec}"),
        (["convert", rec, rec], f"{rec}: refusing to write over the input file {rec}"),
        (
            ["simulate", "push-campaign", "--config", f["config"], "-o", f["config"]],
            f"{f['config']}: refusing to write over the input file {f['config']}",
        ),
    ]
    for args, line in cases:
        assert_refused(cli(*args, "-q") if args[0] not in ("convert",) else cli(*args), line)


def test_output_inside_or_holding_a_bag_folder(cli, guarded):
    """ROS 2 bags: `convert BAG BAG/its_own.mcap` overwrote the bag's storage file and
    `convert BAG/x.mcap BAG` wrote into the input bag's folder; both are refused."""
    bag = guarded["bag"]
    storage = next(bag.glob("*.mcap"))
    assert_refused(
        cli("convert", bag, storage),
        f"{storage}: refusing to write inside the input folder {bag}",
    )
    assert_refused(
        cli("convert", bag, bag / "its_own.mcap"),
        f"{bag / 'its_own.mcap'}: refusing to write inside the input folder {bag}",
    )
    assert_refused(
        cli("convert", storage, bag),
        f"{bag}: refusing to write over the input folder {bag} (the ROS 2 bag of {storage})",
    )
    assert_refused(
        cli("convert", storage, bag / "x.parquet"),
        f"{bag / 'x.parquet'}: refusing to write inside the input folder {bag} "
        f"(the ROS 2 bag of {storage})",
    )
    assert_refused(
        cli("convert", bag, bag), f"{bag}: refusing to write over the input folder {bag}"
    )
    up = bag.parent
    assert_refused(
        cli("report", guarded["est"], "-o", up, "-q"),
        f"{up}: refusing to write a folder that holds the input file {guarded['est']}",
    )
    assert not (bag / "its_own.mcap").exists() and not (bag / "x.parquet").exists()


def test_output_over_a_csv_sidecar(cli, guarded):
    """A CSV input brings its sidecar: writing over `<stem>.json` is writing over the input."""
    c = guarded["csv"]
    side = csv_io.sidecar_path(c)
    assert companions(c) == [c, side]  # atomic's rule is csv's
    assert_refused(
        cli("replay", c, "--model", guarded["model"], "-o", side, "-q"),
        f"{side}: refusing to write over the input file {side} (the sidecar of {c})",
    )


UNDER_A_FILE = [
    (["identify", "{rec}", "-o", "{out}.toml", "-q"], "{out}.toml"),
    (["replay", "{rec}", "--model", "{model}", "-o", "{out}.parquet", "-q"], "{out}.parquet"),
    (["report", "{est}", "-o", "{out}", "-q"], "{out}"),
    (["diagnose", "{rec}", "--model", "{model}", "-o", "{out}", "-q"], "{out}"),
    (["view", "{rec}", "--save", "{out}.rrd", "-q"], "{out}.rrd"),
    (["convert", "{rec}", "{out}.csv"], "{out}.csv"),
    (["convert", "{rec}", "{out}"], "{out}"),
    (["simulate", "push-campaign", "-o", "{out}.parquet", "-q"], "{out}.parquet"),
    (["fleet", "{rec}", "-o", "{out}", "-q", "--scheduler", "serial"], "{out}"),
]
UNDER_A_FILE_IDS = [f"{a[0]}-{k}" for k, (a, _) in enumerate(UNDER_A_FILE)]


@pytest.mark.parametrize("args, shown", UNDER_A_FILE, ids=UNDER_A_FILE_IDS)
def test_output_under_a_regular_file(cli, guarded, tmp_path, args, shown):
    """A path under a regular file (replay, identify, view, diagnose, report): one line naming
    the file in the way, not a FileExistsError or NotADirectoryError traceback."""
    blocker = tmp_path / "plain"
    blocker.write_text("a file")
    out = blocker / "sub" / "x"
    fill = {k: str(v) for k, v in guarded.items()} | {"out": str(out)}
    res = cli(*[a.format(**fill) for a in args])
    assert_refused(
        res, f"{shown.format(**fill)}: cannot write there: {blocker} is a file, not a folder"
    )
    assert blocker.read_text() == "a file"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only (555) folder")
@pytest.mark.parametrize("args, shown", UNDER_A_FILE, ids=UNDER_A_FILE_IDS)
def test_output_in_a_read_only_folder(cli, guarded, tmp_path, args, shown):
    """A folder without write permission (chmod 555): one line, nothing created."""
    ro = tmp_path / "ro"
    ro.mkdir()
    out = ro / "x"
    fill = {k: str(v) for k, v in guarded.items()} | {"out": str(out)}
    ro.chmod(0o555)
    try:
        res = cli(*[a.format(**fill) for a in args])
        assert_refused(
            res, f"{shown.format(**fill)}: cannot write in the folder {ro} (permission denied)"
        )
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_a_folder_where_a_file_goes_and_the_reverse(cli, guarded, tmp_path):
    """A file output naming a folder, a folder output naming a file: one line each."""
    d = tmp_path / "d"
    d.mkdir()
    assert_refused(
        cli("identify", guarded["rec"], "-o", d, "-q"),
        f"{d}: is a folder; expected a file name such as {d / 'model.toml'}",
    )
    f = tmp_path / "f.json"
    f.write_text("{}")
    assert_refused(cli("report", guarded["est"], "-o", f, "-q"), f"{f}: exists and is not a folder")
    assert f.read_text() == "{}"


def test_a_non_empty_output_folder_needs_force(cli, guarded, tmp_path):
    """report, diagnose, fleet and convert (a bag folder) refuse a non-empty folder without
    --force; convert never replaces a non-empty folder that is not a bag, even with --force (it
    replaced, and so deleted, any folder)."""
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    msg = f"{full}: the folder is not empty; use --force to write into it"
    f = guarded
    for args in (
        ["report", f["est"], "-o", full, "-q"],
        ["diagnose", f["rec"], "--model", f["model"], "-o", full, "-q"],
        ["fleet", f["rec"], "-o", full, "-q", "--scheduler", "serial"],
        ["convert", f["rec"], full],
    ):
        assert_refused(cli(*args), msg)
    assert_refused(
        cli("convert", f["rec"], full, "--force"),
        f"{full}: the folder is not empty and not a ROS 2 bag (no metadata.yaml); refusing to "
        "replace it, even with --force",
    )
    assert (full / "keep.txt").read_text() == "mine"
    # an existing bag is replaced with --force, and only then
    bag = tmp_path / "out_bag"
    shutil.copytree(f["bag"], bag)
    assert_refused(
        cli("convert", f["rec"], bag),
        f"{bag}: the folder is not empty; use --force to write into it",
    )
    res = cli("convert", f["rec"], bag, "--force")
    assert res.code == 0 and res.out == f"wrote {bag}\n", res.err
    assert len(dio.read(bag)) == len(dio.read(f["rec"]))


def test_guard_library_refusals(tmp_path):
    """check_output itself: an empty existing folder is fine, --force lets a report folder be
    written into, a missing chain of folders under a writable one is fine."""
    d = tmp_path / "empty"
    d.mkdir()
    assert check_output(d, folder=True) == d
    (d / "a").write_text("x")
    assert check_output(d, folder=True, force=True) == d
    assert (
        check_output(tmp_path / "new" / "deeper" / "m.toml")
        == tmp_path / "new" / "deeper" / "m.toml"
    )


def test_numerical_warnings_never_precede_an_error(cli, monkeypatch):
    """A RuntimeWarning raised before a DitherlabError: the error line alone; after a success
    the warning is printed (once, as one line)."""
    import numpy as np

    import ditherlab.app.info as info
    from ditherlab.core.errors import RecordingError

    real = info.describe

    def overflow(*args, **kwargs):
        np.float64(1e308) * 10  # RuntimeWarning: overflow encountered in scalar multiply
        raise RecordingError("x.parquet: q_1 is wrong")

    def numpy_warned(caught) -> bool:
        return any(issubclass(w.category, RuntimeWarning) for w in caught)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        monkeypatch.setattr(info, "describe", overflow)
        assert_refused(cli("info", SAMPLE), "x.parquet: q_1 is wrong")
    assert not numpy_warned(caught)  # held, then dropped: never shown

    def warn_then_work(*args, **kwargs):
        np.float64(1e308) * 10
        return real(*args, **kwargs)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        monkeypatch.setattr(info, "describe", warn_then_work)
        res = cli("info", SAMPLE)
    assert res.code == 0 and numpy_warned(caught)  # released after the success


def _writer_process(target: Path):
    """A process holding an atomic write of ``target`` open (its temporary file made)."""
    import subprocess
    import sys

    code = (
        "import sys, time\n"
        "from ditherlab.core.files import atomic_path\n"
        "with atomic_path(sys.argv[1]) as tmp:\n"
        "    tmp.write_bytes(b'partial')\n"
        "    print(tmp, flush=True)\n"
        "    time.sleep(600)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE, text=True
    )
    return proc, Path(proc.stdout.readline().strip())


def test_a_killed_writers_temporary_file_is_cleared_by_the_next_write(tmp_path):
    """``kill -9`` during a write leaves the hidden temporary file; the next write of the same
    target removes it, and never the temporary file of a writer that still runs."""
    import signal

    from ditherlab.core.files import atomic_path

    target = tmp_path / "est.parquet"
    killed, left = _writer_process(target)
    running, live = _writer_process(target)
    try:
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        assert left.exists() and live.exists() and left.name.startswith(".est.parquet.")
        other = tmp_path / ".est.parquet.notes.txt"  # not of the pattern: never touched
        other.write_text("x")
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"whole")
        assert not left.exists(), "the killed writer's temporary file stayed"
        assert live.exists() and other.exists()
        assert target.read_bytes() == b"whole"
    finally:
        running.kill()
        running.wait()

"""Run one fuzz case and check the promise (the package docstring of :mod:`tests.fuzz`)."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import re
import shlex
import signal
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from tests.fuzz.inputs import REPO, Base, Case

TIMEOUT_S = 60.0
#: what a non-TTY run prints on stderr around long work (cli.progress_bar): not the error
PROGRESS = re.compile(r"^[\w][\w -]* \.\.\.$|^[\w][\w -]*: done in [\d.]+ s$")
#: finding classes, most serious first
CLASSES = (
    "hang",
    "traceback",
    "input modified",
    "partial output",
    "multi-line error",
    "warning before error",
    "no 'error:' prefix",
    "wrongly accepted",
    "stdout on error",
)


@dataclass
class Result:
    case: Case
    argv: list[str]
    code: int | None
    out: str
    err: str
    seconds: float
    findings: list[str] = field(default_factory=list)
    #: what was seen, per finding class
    details: dict[str, str] = field(default_factory=dict)

    def note(self, cls: str, detail: str) -> None:
        """Record a finding of class ``cls``."""
        self.findings.append(cls)
        self.details.setdefault(cls, detail)

    @property
    def error_line(self) -> str:
        lines = [x for x in self.err.splitlines() if x.strip() and not PROGRESS.match(x)]
        return lines[-1] if lines else ""


def argv_for(case: Case, base: Base, inp: Path, out: Path) -> list[str]:
    """The command line of ``case``: its input in ``inp``, its outputs in ``out`` (paths are
    absolute)."""
    target = str(inp / case.target)
    v = case.variant
    model = str(inp / "_model.toml")
    if case.command == "info":
        return ["info", target, *case.args, *(["--json"] if v % 2 else [])]
    if case.command == "convert":
        suffix = (".parquet", ".csv", ".mcap", "")[v % 4]
        return ["convert", target, str(out / f"converted{suffix}"), *case.args]
    if case.command == "identify":
        force = ["--assume-no-force"] if v % 2 or case.robot == "ur10e" else []
        return [
            "identify",
            target,
            "-o",
            str(out / "model.toml"),
            "--bootstrap",
            "0",
            *force,
            *case.args,
        ]
    if case.command == "replay":
        return ["replay", target, "--model", model, "-o", str(out / "est.parquet"), *case.args]
    if case.command == "diagnose":
        return [
            "diagnose",
            target,
            "--model",
            model,
            "--no-history",
            "-o",
            str(out / "diag"),
            *case.args,
        ]
    if case.command == "report":
        est = str(inp / "_est.parquet")
        if case.kind == "parquet" and v % 2:  # the damaged file as the estimates
            return ["report", target, "-o", str(out / "report"), "--bootstrap", "5"]
        return ["report", est, "--recording", target, "-o", str(out / "report"), "--bootstrap", "5"]
    if case.command == "view":
        return ["view", target, "--save", str(out / "view.rrd"), *case.args]
    raise ValueError(case.command)


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def materialise(case: Case, base: Base, work: Path) -> tuple[Path, Path]:
    """Write the case's files into ``work/in`` (plus the model and estimates it is paired with)
    and make an empty ``work/out``."""
    inp, out = work / "in", work / "out"
    inp.mkdir(parents=True)
    out.mkdir()
    for rel, data in case.files.items():
        (inp / rel).parent.mkdir(parents=True, exist_ok=True)
        (inp / rel).write_bytes(data)
    (inp / "_model.toml").write_bytes(base.models[case.robot].read_bytes())
    if base.estimates is not None:
        (inp / "_est.parquet").write_bytes(base.estimates.read_bytes())
    return inp, out


def run_subprocess(argv: list[str], cwd: Path, timeout: float) -> tuple[int | None, str, str]:
    """``python -m ditherlab ARGV`` in its own process group; None as the code on a timeout."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("FORCE_COLOR", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "ditherlab", *argv],
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
        return proc.returncode, out, err
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        return None, out, err


#: modules the commands import lazily: imported once in the campaign's process, so that each
#: forked case starts in milliseconds instead of the CLI's second of imports
PRELOAD = (
    "ditherlab.cli",
    "ditherlab.io",
    "ditherlab.io.stream",
    "ditherlab.io.parquet",
    "ditherlab.io.mcap",
    "ditherlab.io.rosbag",
    "ditherlab.app.info",
    "ditherlab.app.convert",
    "ditherlab.app.identify",
    "ditherlab.app.replay",
    "ditherlab.app.report",
    "ditherlab.app.diagnose",
    "ditherlab.app.view",
)


def preload() -> None:
    """Import :data:`PRELOAD` (before the first fork)."""
    import importlib

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    for m in PRELOAD:
        importlib.import_module(m)


def run_forked(argv: list[str], cwd: Path, timeout: float) -> tuple[int | None, str, str]:
    """``ditherlab ARGV`` in a child process forked from this one (after :func:`preload`): its
    own process, stdout and stderr (files, not a TTY) and exit status, as ``python -m
    ditherlab`` would give, without the imports; None as the code on a timeout (the child's
    process group is killed)."""
    import tempfile

    with tempfile.TemporaryFile() as fo, tempfile.TemporaryFile() as fe:
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the child: never returns
            code = 1
            try:
                os.setsid()
                os.chdir(cwd)
                os.dup2(fo.fileno(), 1)
                os.dup2(fe.fileno(), 2)
                sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
                sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
                from ditherlab.cli import main

                try:
                    main(argv)
                    code = 0
                except SystemExit as exc:
                    c = exc.code
                    code = c if isinstance(c, int) else (0 if c is None else 1)
                    if isinstance(c, str):
                        print(c, file=sys.stderr)
                except BaseException:  # noqa: BLE001 - what Python prints for an uncaught error
                    traceback.print_exc()
                    code = 1
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(code)
        deadline = time.monotonic() + timeout
        status = None
        while True:
            done, st = os.waitpid(pid, os.WNOHANG)
            if done:
                status = os.waitstatus_to_exitcode(st)
                break
            if time.monotonic() > deadline:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                break
            time.sleep(0.02)
        fo.seek(0)
        fe.seek(0)
        out = fo.read().decode("utf-8", "replace")
        err = fe.read().decode("utf-8", "replace")
    if status is not None and status < 0:
        err += f"\n(killed by signal {-status})"
        status = 128 - status
    return status, out, err


def run_inprocess(argv: list[str], cwd: Path, timeout: float) -> tuple[int | None, str, str]:
    """``main(ARGV)`` in this process (fast; no hang detection): an exception that escapes is a
    traceback on stderr and exit status 1, as Python would print it."""
    from ditherlab.cli import main

    out, err = io.StringIO(), io.StringIO()
    code = 0
    old = os.getcwd()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        os.chdir(cwd)
        try:
            main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:  # noqa: BLE001 - the finding itself
            err.write(traceback.format_exc())
            code = 1
        finally:
            os.chdir(old)
    return code, out.getvalue(), err.getvalue()


def run_case(
    case: Case, base: Base, work: Path, *, mode: str = "fork", timeout: float = TIMEOUT_S
) -> Result:
    """Run ``case`` in the empty folder ``work`` and classify what happened (``Result.findings``,
    empty when the promise held). ``mode``: ``fork`` (:func:`run_forked`), ``subprocess``
    (``python -m ditherlab``) or ``inprocess`` (:func:`run_inprocess`)."""
    inp, out = materialise(case, base, work)
    argv = argv_for(case, base, inp, out)
    before = _digest(inp)
    t0 = time.perf_counter()
    runner = {"inprocess": run_inprocess, "fork": run_forked, "subprocess": run_subprocess}[mode]
    code, sout, serr = runner(argv, work, timeout)
    res = Result(case, argv, code, sout, serr, time.perf_counter() - t0)
    classify(res, before, _digest(inp), out)
    lossless = Path(argv[-1] if case.command == "convert" else "").suffix in (".parquet", ".mcap")
    if code == 0 and case.origin is not None and case.command == "convert" and lossless:
        _check_same_data(res, Path(argv[2]))
    return res


_ORIGINS: dict[Path, object] = {}


def _check_same_data(res: Result, converted: Path) -> None:
    """A damaged Parquet or ditherlab MCAP file that converts without an error must hold the
    undamaged file's data (page checksums, chunk CRCs): else "wrongly accepted"."""
    import ditherlab.io as dio

    origin = res.case.origin
    assert origin is not None
    try:
        if origin not in _ORIGINS:
            _ORIGINS[origin] = dio.read(origin)
        got = dio.read(converted)
        same = got.data.equals(_ORIGINS[origin].data)  # type: ignore[attr-defined]
    except Exception as exc:  # noqa: BLE001 - the output of an accepted conversion must read
        same, why = False, f"its output does not read back: {type(exc).__name__}: {exc}"
    else:
        why = "the damaged file was read as different data"
    if not same:
        res.note("wrongly accepted", why)


def classify(res: Result, before: dict[str, str], after: dict[str, str], out: Path) -> list[str]:
    """The finding classes of one run (:data:`CLASSES`), noted on ``res``."""
    lines = [x for x in res.err.splitlines() if x.strip() and not PROGRESS.match(x)]
    if res.code is None:
        res.note("hang", f"no exit within the time limit; stderr: {' | '.join(lines[-2:])}")
    elif "Traceback" in res.err or res.code not in (0, 2):
        tb = [x for x in res.err.splitlines() if x.strip()]
        res.note("traceback", tb[-1] if tb else f"exit status {res.code}")
    if before != after:
        changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
        res.note("input modified", f"changed: {', '.join(changed)}")
    left = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    if res.code != 0 and left:
        res.note("partial output", f"left: {', '.join(left[:5])}")
    elif res.code == 0:
        tmp = [x for x in left if re.search(r"(^|/)\.|\.tmp|tmp[a-z0-9_]{6,}", x)]
        if tmp:
            res.note("partial output", f"temporary files left: {', '.join(tmp[:5])}")
    if res.code == 2 and "traceback" not in res.findings:
        if len(lines) != 1:
            only_warnings = len(lines) > 1 and all(x.startswith("warning:") for x in lines[:-1])
            cls = "warning before error" if only_warnings else "multi-line error"
            res.note(cls, " | ".join(lines[:4])[:400])
        elif not lines[0].startswith("error: "):
            res.note("no 'error:' prefix", lines[0])
        if res.out.strip():
            res.note("stdout on error", res.out.strip().splitlines()[0])
    if res.code == 0 and res.case.must_refuse:
        res.note("wrongly accepted", f"accepted despite {res.case.must_refuse}")
    return res.findings


def signature(res: Result, cls: str) -> str:
    """What makes two findings the same: the class, the command and the message with numbers,
    paths and quoted values blurred."""
    detail = res.details.get(cls, "")
    msg = detail if cls != "multi-line error" else detail.split(" | ")[0]
    if cls in ("wrongly accepted",):
        msg = res.case.must_refuse or ""
    msg = re.sub(r"/\S+", "PATH", msg)
    msg = re.sub(r"'[^']*'|\"[^\"]*\"", "Q", msg)
    msg = re.sub(r"\d+(\.\d+)?(e[-+]?\d+)?", "N", msg)
    return f"{cls} | {res.case.command} | {msg[:160]}"


def reproduction(res: Result, keep: Path) -> str:
    """Keep the case's input in ``keep`` and return a shell command that reproduces it."""
    from tests.fuzz.inputs import copy_tree

    inp = next(Path(a.split("/in/")[0]) / "in" for a in res.argv if "/in/" in a)
    copy_tree(inp, keep / "in")
    argv = [a.replace(str(inp), str(keep / "in")) for a in res.argv]
    argv = [re.sub(r"^.*/out/", str(keep / "out") + "/", a) if "/out/" in a else a for a in argv]
    return (
        f"mkdir -p {keep}/out && cd {keep} && PYTHONPATH={REPO} {shlex.quote(sys.executable)} -m ditherlab "
        + " ".join(shlex.quote(a) for a in argv)
    )

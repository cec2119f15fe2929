"""The fuzz suite's inputs: the real base files, hypothesis strategies for recordings (valid and
invalid) and mutations of real files.

A :class:`Case` is one input (the bytes of every file it consists of, a bag folder being several)
and one command to run on it; :func:`cases` is the strategy of cases of one command and one
input kind (:data:`KINDS`).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data"

COMMANDS = ("info", "convert", "identify", "replay", "diagnose", "report", "view")
#: input kinds: hypothesis recordings written as Parquet or CSV, and mutations of real files
KINDS = ("synth-parquet", "synth-csv", "parquet", "csv", "mcap", "bag-mcap", "bag-db3")


@dataclass
class Base:
    """The real files every mutation starts from, and models and estimates to pair them with.

    ``sources[kind]``: ``(name, path, robot)`` per real input of that kind (a path relative to
    ``root``; a bag is a folder); ``models[robot]``: a torque model of that robot;
    ``estimates``: estimates of ``sim.parquet`` (for ``report``).
    """

    root: Path
    sources: dict[str, list[tuple[str, Path, str]]] = field(default_factory=dict)
    models: dict[str, Path] = field(default_factory=dict)
    estimates: Path | None = None


def _cli(*args: object, cwd: Path) -> None:
    cmd = [sys.executable, "-m", "ditherlab", *map(str, args)]
    subprocess.run(cmd, cwd=cwd, check=True, capture_output=True, text=True)


def prepare_base(root: Path, simulate: bool = True) -> Base:
    """Make (once: kept in ``root``) the base files: a 3.2 s cut (with a push) of ``ditherlab
    simulate push-campaign`` as Parquet, CSV, ditherlab MCAP and ROS 2 bags (MCAP and SQLite
    storage); models of the IRB140, the hopper and the UR10e; estimates of the cut.
    ``simulate=False``: the cut is taken from the repository's ``recordings/sim-push-dither``
    (made by the simulator too), and no models or estimates are made (for ``make test``)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    done = root / ".ready"
    if not done.exists():
        import ditherlab.io as dio
        from ditherlab.analysis.identification import identify
        from ditherlab.app.replay import ReplayOptions
        from ditherlab.app.replay import run as replay_run
        from ditherlab.data.recording import Recording

        if simulate:
            args = ("push-campaign", "-o", "push.parquet", "--pushes-per-direction", 1, "-q")
            _cli("simulate", *args, cwd=root)
            rec = dio.read(root / "push.parquet")
            (root / "push.parquet").unlink()
            cut = Recording(rec.data.iloc[1600:2400].reset_index(drop=True), rec.meta, name="sim")
        else:
            rec = dio.read(REPO / "recordings" / "sim-push-dither.parquet")
            cut = Recording(rec.data.iloc[1600:2400].reset_index(drop=True), rec.meta, name="sim")
        dio.write(cut, root / "sim.parquet")
        dio.write(cut, root / "sim.csv")
        dio.write(cut, root / "sim.mcap")
        dio.write(cut, root / "sim_bag_mcap", storage="mcap")
        dio.write(cut, root / "sim_bag_db3", storage="sqlite3")
        if simulate:
            identify([rec], n_boot=0).save(root / "irb140.toml")
            hop = dio.read(DATA / "hopper" / "hopper_short.parquet")
            identify([hop], n_boot=0).save(root / "hopper.toml")
            ur = dio.read(DATA / "ur10e" / "no_torque.csv", mapping="ur10e")
            identify([ur], n_boot=0, assume_no_force=True).save(root / "ur10e.toml")
            replay_run(
                ReplayOptions(root / "sim.parquet", root / "irb140.toml", root / "est.parquet")
            )
        else:  # make test runs info, convert and view only: no model, no estimates
            for r in ("irb140", "hopper", "ur10e"):
                (root / f"{r}.toml").write_text("# no model\n")
        done.touch()
    base = Base(root)
    base.models = {r: root / f"{r}.toml" for r in ("irb140", "hopper", "ur10e")}
    base.estimates = root / "est.parquet" if (root / "est.parquet").exists() else None
    base.sources = {
        "parquet": [
            ("sim.parquet", root / "sim.parquet", "irb140"),
            ("hopper_short.parquet", DATA / "hopper" / "hopper_short.parquet", "hopper"),
        ]
        + ([("est.parquet", base.estimates, "irb140")] if base.estimates else []),
        "csv": [
            ("sim.csv", root / "sim.csv", "irb140"),
            ("no_torque.csv", DATA / "ur10e" / "no_torque.csv", "ur10e"),
        ],
        "mcap": [("sim.mcap", root / "sim.mcap", "irb140")],
        "bag-mcap": [
            ("sim_bag_mcap", root / "sim_bag_mcap", "irb140"),
            ("talker.mcap", DATA / "rosbag2" / "talker.mcap", "irb140"),
            ("cdr_test_0.mcap", DATA / "rosbag2" / "cdr_test_0.mcap", "irb140"),
        ],
        "bag-db3": [("sim_bag_db3", root / "sim_bag_db3", "irb140")],
    }
    return base


@dataclass
class Case:
    """One input and one command.

    files : relative path -> bytes, what the case's input folder holds
    target : the relative path given to the command (a file or a bag folder)
    robot : which model (``Base.models``) to pair it with
    args : reader options for the command (``--mapping``, ``--robot``)
    must_refuse : why a reader must refuse this input (None when it may be accepted)
    variant : a number the command's arguments are chosen by (output suffix, flags)
    """

    kind: str
    command: str
    label: str
    files: dict[str, bytes]
    target: str
    robot: str = "irb140"
    args: list[str] = field(default_factory=list)
    must_refuse: str | None = None
    variant: int = 0
    #: the undamaged file of a damaged Parquet or ditherlab MCAP recording: what a reader that
    #: accepts the damaged one must read (both formats carry checksums)
    origin: Path | None = None


# ------------------------------------------------------------------ synthetic recordings
#: defects a synthetic recording may carry; True: a reader must refuse the recording
DEFECTS: dict[str, bool] = {
    "nan": True,
    "inf": True,
    "t_back": True,
    "t_dup": True,
    "drop_required": True,
    "drop_one_of_family": True,
    "dup_column": True,
    "word_in_number": True,
    "text_numbers": True,  # refused in Parquet only (CSV is text)
    "no_meta": True,
    "int_dtype": False,
    "huge_gap": False,
    "constant": False,
    "huge_values": False,
    "extra_text_column": False,
    "long_row": True,  # CSV only: one row of 200 000 extra fields
    "bad_meta_json": True,
    "wrong_joint_count": True,
    "meta_robot_number": True,
}


@dataclass
class Synth:
    """A recording table that may break the contract: column names may repeat."""

    names: list[str]
    columns: list[list]  # python values per column
    meta: dict | None
    defects: list[str]
    meta_text: str | None = None  # replaces the metadata JSON (invalid JSON)


def _signals(rng: np.random.Generator, rows: int, n: int, constant: bool) -> dict[str, np.ndarray]:
    k = np.arange(rows)
    out: dict[str, np.ndarray] = {}
    for j in range(1, n + 1):
        amp = 0.0 if constant else rng.uniform(0, 0.5)
        out[f"q_{j}"] = rng.uniform(-1, 1) + amp * np.sin(2 * np.pi * k / max(rows, 2))
        out[f"tau_{j}"] = rng.uniform(-5, 5) + (0 if constant else 1) * rng.normal(0, 0.1, rows)
    return out


@st.composite
def synth_recordings(draw, csv: bool = False) -> Synth:
    """A small recording of the built-in IRB140 (6 joints), valid, or with one or two defects."""
    allowed = [d for d in DEFECTS if csv or d != "long_row"]
    defects = draw(st.lists(st.sampled_from(allowed), max_size=2, unique=True))
    if draw(st.booleans()):
        defects = []
    rows = draw(st.sampled_from([1, 2, 3, 50, 300, 600]))
    n = draw(st.sampled_from([5, 7])) if "wrong_joint_count" in defects else 6
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    t0 = draw(st.sampled_from([0.0, -3.0, 1234.5, 1.7e9]))
    dt = draw(st.sampled_from([0.004, 0.001, 0.01]))
    t = t0 + dt * np.arange(rows) + draw(st.sampled_from([0.0, 1e-5])) * rng.uniform(size=rows)
    sig = _signals(rng, rows, n, "constant" in defects)
    cols: dict[str, np.ndarray] = {"t": t}
    for fam in ("q", "tau"):
        cols.update({f"{fam}_{j}": sig[f"{fam}_{j}"] for j in range(1, n + 1)})
    if draw(st.booleans()):
        cols.update(
            {
                f"dq_{j}": np.gradient(sig[f"q_{j}"]) / dt if rows > 1 else np.zeros(1)
                for j in range(1, n + 1)
            }
        )
    if draw(st.booleans()):
        for c in ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z"):
            cols[c] = rng.normal(0, 5, rows)
    if draw(st.booleans()):
        cols["dither"] = (np.arange(rows) // 50) % 2 == 0
    names = list(cols)
    values: list[list] = [cols[c].tolist() for c in names]
    meta: dict | None = {"schema": "ditherlab.recording/1", "robot": "irb140", "source": "fuzz"}
    synth = Synth(names, values, meta, defects)
    for d in defects:
        _apply(draw, synth, d, rows, n)
    return synth


def _apply(draw, s: Synth, d: str, rows: int, n: int) -> None:
    numeric = [i for i, c in enumerate(s.names) if c == "t" or c.startswith(("q_", "tau_"))]
    pick = draw(st.sampled_from(numeric))
    r = draw(st.integers(0, rows - 1))
    if d in ("nan", "inf"):
        s.columns[pick] = list(s.columns[pick])
        s.columns[pick][r] = (
            math.nan if d == "nan" else draw(st.sampled_from([math.inf, -math.inf]))
        )
    elif d == "t_back" and rows > 1:
        r = max(r, 1)
        back = draw(st.sampled_from([1e-9, 0.5, 1e6]))
        if _finite(s.columns[0][r - 1]):
            s.columns[0][r] = s.columns[0][r - 1] - back
    elif d == "t_dup" and rows > 1:
        r = max(r, 1)
        s.columns[0][r] = s.columns[0][r - 1]
    elif d == "drop_required":
        del s.names[pick], s.columns[pick]
    elif d == "drop_one_of_family":
        fam = [
            i
            for i, c in enumerate(s.names)
            if c.startswith(("q_", "tau_", "dq_")) and c not in ("q_1",)
        ]
        i = draw(st.sampled_from(fam))
        del s.names[i], s.columns[i]
    elif d == "dup_column":
        i = draw(st.sampled_from(numeric))
        same = draw(st.booleans())
        s.names.append(s.names[i])
        s.columns.append(list(s.columns[i]) if same else [v + 1 for v in s.columns[i]])
    elif d == "word_in_number":
        s.columns[pick] = list(s.columns[pick])
        s.columns[pick][r] = draw(st.sampled_from(["abc", "1,5", "", "nan?", "0x10"]))
    elif d == "text_numbers":
        s.columns[pick] = [repr(float(v)) if _finite(v) else str(v) for v in s.columns[pick]]
    elif d == "no_meta":
        s.meta = None
    elif d == "int_dtype":
        s.columns[pick] = (
            [int(round(v)) if _finite(v) else v for v in s.columns[pick]]
            if s.names[pick] != "t"
            else s.columns[pick]
        )
    elif d == "huge_gap" and rows > 1:
        gap = [1e7 if i >= rows // 2 and _finite(v) else 0 for i, v in enumerate(s.columns[0])]
        s.columns[0] = [v + g if g else v for v, g in zip(s.columns[0], gap, strict=True)]
    elif d == "huge_values":
        tau = [i for i, c in enumerate(s.names) if c.startswith("tau_")]
        if tau:
            i = draw(st.sampled_from(tau))
            big = draw(st.sampled_from([1e308, -1e308, 1e300]))
            # a defect drawn before (NaN, a word) stays: it must still be refused
            s.columns[i] = [big if _finite(v) else v for v in s.columns[i]]
    elif d == "extra_text_column":
        s.names.append(draw(st.sampled_from(["comment", "q_x", "Unnamed: 3", "tau"])))
        s.columns.append([f"note {i}" for i in range(rows)])
    elif d == "bad_meta_json":
        s.meta_text = draw(st.sampled_from(['{"robot": "irb140"', "[1, 2]", "", "\x00\xff"]))
    elif d == "meta_robot_number" and s.meta is not None:
        s.meta["robot"] = draw(st.sampled_from([140, None, ["irb140"], {"urdf": 3}]))


def _finite(v: object) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def must_refuse(s: Synth, csv: bool) -> str | None:
    """Why a reader must refuse ``s`` (None: it may accept it)."""
    rows = len(s.columns[0]) if s.columns else 0
    for d in s.defects:
        if not DEFECTS[d]:
            continue
        if d in ("t_back", "t_dup") and rows < 2:
            continue
        if d == "text_numbers" and csv:
            continue
        if d == "word_in_number" and csv:
            continue  # "" and "nan?" are NaN-like in CSV: covered by the nan/other checks
        if d == "meta_robot_number":
            continue  # another team's area (metadata schema)
        return d
    return None


def parquet_bytes(s: Synth) -> bytes:
    """``s`` as a Parquet file written by pyarrow as it stands (duplicate names, text columns)."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = []
    for col in s.columns:
        kinds = {type(v) for v in col}
        if kinds <= {float, int} and float in kinds:
            arrays.append(pa.array([float(v) for v in col], pa.float64()))
        elif str in kinds and kinds != {str}:
            arrays.append(pa.array([str(v) for v in col], pa.string()))
        else:
            arrays.append(pa.array(col))
    table = pa.Table.from_arrays(arrays, names=s.names)
    if s.meta_text is not None:
        table = table.replace_schema_metadata(
            {b"ditherlab": s.meta_text.encode("utf-8", "surrogateescape")}
        )
    elif s.meta is not None:
        table = table.replace_schema_metadata({b"ditherlab": json.dumps(s.meta).encode()})
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def csv_text(s: Synth) -> str:
    """``s`` as a CSV file (header line, one line per row; a ``long_row`` defect adds 200 000
    fields to a row)."""
    lines = [",".join(s.names)]
    rows = len(s.columns[0]) if s.columns else 0
    for r in range(rows):
        lines.append(",".join(_cell(col[r]) for col in s.columns))
    if "long_row" in s.defects and rows:
        k = 1 + rows // 2
        lines[k] = lines[k] + ",0" * 200_000
    return "\n".join(lines) + "\n"


def _cell(v: object) -> str:
    if isinstance(v, float):
        return repr(v)
    return str(v)


@st.composite
def synth_case(draw, kind: str, command: str) -> Case:
    csv = kind == "synth-csv"
    s = draw(synth_recordings(csv=csv))
    files: dict[str, bytes] = {}
    if csv:
        files["rec.csv"] = csv_text(s).encode()
        if s.meta_text is not None:
            files["rec.json"] = s.meta_text.encode("utf-8", "surrogateescape")
        elif s.meta is not None:
            files["rec.json"] = json.dumps(s.meta).encode()
        target = "rec.csv"
    else:
        files["rec.parquet"] = parquet_bytes(s)
        target = "rec.parquet"
    args = ["--robot", "irb140"] if s.meta is None and draw(st.booleans()) else []
    why = must_refuse(s, csv)
    if why == "no_meta" and args:
        why = None
    label = f"synthetic {len(s.columns[0]) if s.columns else 0} rows, defects {s.defects or 'none'}"
    return Case(kind, command, label, files, target, "irb140", args, why, draw(st.integers(0, 7)))


# ------------------------------------------------------------------ mutations of real files
def _bag_files(path: Path) -> dict[str, bytes]:
    if path.is_dir():
        return {f"{path.name}/{p.name}": p.read_bytes() for p in sorted(path.iterdir())}
    return {path.name: path.read_bytes()}


@st.composite
def mutation(draw, data: bytes) -> tuple[bytes, str]:
    """``data`` damaged: bytes flipped, truncated, a block zeroed, garbage appended or a block
    removed; returns the new bytes and what was done."""
    size = len(data)
    op = draw(st.sampled_from(["flip", "flip", "flip_tail", "truncate", "zero", "append", "cut"]))
    buf = bytearray(data)
    if op in ("flip", "flip_tail"):
        k = draw(st.integers(1, 8))
        lo = int(size * 0.9) if op == "flip_tail" else 0
        where = [draw(st.integers(lo, size - 1)) for _ in range(k)]
        for p in where:
            buf[p] ^= draw(st.integers(1, 255))
        return bytes(buf), f"{k} byte(s) flipped at {sorted(where)}"
    if op == "truncate":
        n = draw(st.integers(0, size - 1))
        return bytes(buf[:n]), f"truncated to {n} of {size} bytes"
    a = draw(st.integers(0, size - 1))
    b = min(size, a + draw(st.integers(1, 4096)))
    if op == "zero":
        buf[a:b] = bytes(b - a)
        return bytes(buf), f"bytes {a}..{b} zeroed"
    if op == "append":
        junk = bytes(draw(st.lists(st.integers(0, 255), min_size=1, max_size=64)))
        return data + junk, f"{len(junk)} garbage bytes appended"
    return bytes(buf[:a] + buf[b:]), f"bytes {a}..{b} removed"


@st.composite
def text_mutation(draw, text: str) -> tuple[str, str]:
    """A CSV damaged as a person or a tool might: a line dropped or repeated, a cell replaced, a
    header name duplicated, a row of 200 000 extra fields, the lines shuffled."""
    lines = text.split("\n")
    op = draw(
        st.sampled_from(["drop", "repeat", "cell", "dup_header", "long_row", "swap", "bom", "crlf"])
    )
    i = draw(st.integers(0, max(len(lines) - 2, 0)))
    if op == "drop":
        del lines[i]
    elif op == "repeat":
        lines.insert(i, lines[i])
    elif op == "cell":
        cells = lines[i].split(",")
        c = draw(st.integers(0, len(cells) - 1))
        cells[c] = draw(
            st.sampled_from(["", "x", "1e999", "nan", "-inf", '"', "1;2", "0x1F", " 3 "])
        )
        lines[i] = ",".join(cells)
    elif op == "dup_header":
        cells = lines[0].split(",")
        c = draw(st.integers(0, len(cells) - 1))
        d = draw(st.integers(0, len(cells) - 1))
        cells[d] = cells[c]
        lines[0] = ",".join(cells)
    elif op == "long_row":
        lines[i] += ",0" * 200_000
    elif op == "swap" and len(lines) > 3:
        j = draw(st.integers(1, len(lines) - 2))
        lines[i], lines[j] = lines[j], lines[i]
    elif op == "bom":
        lines[0] = "\ufeff" + lines[0]
    elif op == "crlf":
        return "\r\n".join(lines), "CRLF line ends"
    return "\n".join(lines), f"{op} at line {i + 1}"


@st.composite
def mutated_case(draw, base: Base, kind: str, command: str) -> Case:
    name, path, robot = draw(st.sampled_from(base.sources[kind]))
    files = _bag_files(path)
    args = ["--mapping", "ur10e"] if name == "no_torque.csv" else []
    keys = sorted(files)
    target_key = keys[0]
    if kind == "csv" and path.with_suffix(".json").exists():  # the sidecar goes with it
        files[path.with_suffix(".json").name] = path.with_suffix(".json").read_bytes()
    victim = draw(st.sampled_from(sorted(files)))
    if kind == "csv" and victim.endswith(".csv") and draw(st.booleans()):
        text, what = draw(text_mutation(files[victim].decode()))
        files[victim] = text.encode()
    else:
        files[victim], what = draw(mutation(files[victim]))
    target = target_key.split("/")[0] if "/" in target_key else target_key
    if "/" in target_key and draw(st.booleans()):  # the bag's storage file instead of its folder
        target = next(k for k in keys if not k.endswith("metadata.yaml"))
    label = f"{name}: {victim.split('/')[-1]} {what}"
    v = draw(st.integers(0, 7))
    # files ditherlab wrote (page checksums, chunk CRCs); the hopper's Parquet has no page
    # checksums, so a damaged value in it cannot be told from a true one
    origin = path if name in ("sim.parquet", "sim.mcap") else None
    return Case(kind, command, label, files, target, robot, args, None, v, origin)


def cases(base: Base, kind: str, command: str) -> st.SearchStrategy[Case]:
    """Cases of ``command`` on inputs of ``kind``."""
    if kind.startswith("synth-"):
        return synth_case(kind, command)
    return mutated_case(base, kind, command)


def copy_tree(src: Path, dst: Path) -> None:
    """Copy a file or folder (for the reproduction of a finding)."""
    if src.is_dir():
        shutil.copytree(src, dst, dirs_exist_ok=True)
    else:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)

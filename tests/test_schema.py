"""Schema validation at every boundary, through the CLI: a model file, a recording's
metadata (CSV sidecar, Parquet, MCAP), a mapping file, ``simulate --config`` and a URDF with a
wrong type or an out-of-range value end in exactly one line on stderr naming the file, the key,
the value and what was expected, exit status 2, no traceback and no warning before it."""

from __future__ import annotations

import copy
import json
import math
import os
import shutil
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ditherlab.io as dio
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.io.mcap import write_frames
from ditherlab.robot import builtin_urdf
from tests.conftest import run_cli

REPO = Path(__file__).resolve().parents[1]
#: examples per property test: small in ``make test``; raise it for a long campaign
EXAMPLES = int(os.environ.get("DITHERLAB_SCHEMA_EXAMPLES", "50"))
SAMPLE = REPO / "recordings" / "sim-push-dither.parquet"
IRB140_ROBOT = (
    "a built-in robot name such as 'irb140' or an object {urdf, tool_frame}"  # ROBOT_NODE
)


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A 2 s IRB140 recording as CSV + sidecar and as Parquet, and a model file for it."""
    d = tmp_path_factory.mktemp("schema")
    rec = dio.read(SAMPLE)
    short = rec.slice(rec.t0, rec.t0 + 2.0)
    dio.write(short, d / "r.csv")
    dio.write(short, d / "r.parquet")
    n = 6
    still = Band(tau_min=-np.full(n, 5.0), tau_max=np.full(n, 5.0), sigma=np.full(n, 0.3))
    moving = Band(
        tau_min=-np.ones(n),
        tau_max=np.ones(n),
        sigma=np.full(n, 0.3),
        coulomb=np.ones(n),
        viscous=np.ones(n),
    )
    model = TorqueModel(
        robot="irb140", n=n, regimes={"still": still, "dither": still, "moving": moving}
    )
    model.save(d / "m.toml")
    return {"dir": d, "csv": d / "r.csv", "parquet": d / "r.parquet", "model": d / "m.toml"}


def assert_one_line(res, line: str) -> None:
    """Exit 2, nothing on stdout, exactly ``error: <line>`` on stderr (no warning before it)."""
    assert res.code == 2, (res.code, res.out, res.err)
    assert res.err == f"error: {line}\n", res.err
    assert res.out == ""


def model_dict(files) -> dict[str, Any]:
    return tomllib.loads(files["model"].read_text())


def write_model(path: Path, d: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(d))
    return path


def replay(files, model: Path, rec: Path | None = None, *extra: str):
    out = files["dir"] / "e.parquet"  # every replay's scratch output: replaced
    args = ("-o", out, "--force", "-q", *extra)
    return run_cli("replay", rec or files["csv"], "--model", model, *args)


def test_the_valid_files_replay(files):
    """The fixtures themselves pass: every case below fails because of its one mutation."""
    res = replay(files, files["model"])
    assert res.code == 0 and res.err == "", res.err


# ------------------------------------------------------------------------------- model files
def _set(d: dict, dotted: str, value: Any) -> None:
    *head, last = dotted.split(".")
    for k in head:
        d = d[k]
    d[last] = value


MODEL_CASES = [
    # (key, value, the message after "<file>: ")
    ("n_joints", "six", "n_joints: got 'six'; expected an integer in [1, 64]"),
    ("effects", [1, 2], "effects[1]: got 1; expected a table {name, joints, params}"),
    ("robot", 140, f"robot: got 140; expected {IRB140_ROBOT}"),
    ("version", "one", "version: got 'one'; expected an integer >= 1"),
    (
        "regimes.still.tau_max",
        ["9.4", 5.0, 5.0, 5.0, 5.0, 5.0],
        "regimes.still.tau_max[1]: got '9.4'; expected a number in [-1e+06, 1e+06] [N·m]",
    ),
    (
        "regimes.still.tau_min",
        [-1e308] * 6,
        "regimes.still.tau_min[1]: got -1e+308; expected a number in [-1e+06, 1e+06] [N·m]",
    ),
    (
        "regimes.still.sigma",
        [0.3, 1e300, 0.3, 0.3, 0.3, 0.3],
        "regimes.still.sigma[2]: got 1e+300; expected a number <= 1e+06 [N·m]",
    ),
    (
        "regimes.still.sigma",
        [0.3, 0.3, 1e-300, 0.3, 0.3, 0.3],
        "regimes.still.sigma of joint 3 is 1e-300 N·m, expected a positive noise level "
        "(at least 1e-09 N·m)",
    ),
    (
        "regimes.moving.sigma",
        [0.3] * 5,
        "regimes.moving.sigma: got 5 values; expected 6 (one per joint)",
    ),
    (
        "regimes.still.sigma",
        [math.nan] * 6,
        "regimes.still.sigma[1]: got nan; expected a number <= 1e+06 [N·m]",
    ),
    (
        "prior.sigma",
        [20.0, 20.0, 20.0, 0.3, 0.3, -math.inf],
        "prior.sigma[6]: got -inf; expected a number in [0, 1e+06] or inf [N, N·m]",
    ),
    ("regimes.sliding", {}, "regimes.sliding: unknown key; expected one of dither, moving, still"),
    (
        "effects",
        [{"name": "viscous", "joints": [2, 7], "params": {"coef": [1.0, 2.0]}}],
        "effects[1].joints[2]: got 7; expected an integer in [1, 6]",
    ),
    (
        "effects",
        [{"name": "viscous", "joints": [2, 3], "params": {"coef": [1.0]}}],
        "effects[1].params.coef: got 1 value; expected 2 (one per joint in effects[1].joints)",
    ),
    (
        "payload",
        {"mass": "two"},
        "payload.mass: got 'two'; expected a number in [0, 10000] [kg]",
    ),
    (
        "priors",
        {},
        "priors: unknown key; expected one of effects, history, n_joints, notes, payload, prior, "
        "regimes, robot, schema, tool_offset, version",
    ),
]


@pytest.mark.parametrize(("key", "value", "message"), MODEL_CASES, ids=[c[0] for c in MODEL_CASES])
def test_model_file_wrong_type_or_range_is_one_line(files, key, value, message):
    """Each model file with a wrong type or an out-of-range value: one line naming file, key,
    value."""
    d = model_dict(files)
    _set(d, key, value)
    p = write_model(files["dir"] / "bad.toml", d)
    assert_one_line(replay(files, p), f"{p}: {message}")


def test_a_key_with_a_line_break_stays_on_one_line(files):
    """Found by the property test below: an unknown key "\\r" printed raw split the line."""
    d = model_dict(files)
    d["\r"] = ""
    p = write_model(files["dir"] / "cr.toml", d)
    assert_one_line(
        replay(files, p),
        f"{p}: '\\r': unknown key; expected one of effects, history, n_joints, notes, payload, "
        "prior, regimes, robot, schema, tool_offset, version",
    )


def test_model_file_missing_key_and_not_utf8(files):
    """A missing required key and a file that is not text are one line each."""
    d = model_dict(files)
    del d["robot"]
    p = write_model(files["dir"] / "norobot.toml", d)
    assert_one_line(replay(files, p), f"{p}: robot: missing; expected {IRB140_ROBOT}")
    b = files["dir"] / "binary.toml"
    b.write_bytes(SAMPLE.read_bytes()[:4096])
    assert_one_line(replay(files, b), f"{b}: not a valid TOML file (not UTF-8 text)")


def test_model_file_is_checked_by_every_command_that_reads_one(files):
    """identify --model, diagnose and view read the model through the same check."""
    d = model_dict(files)
    d["n_joints"] = "six"
    p = write_model(files["dir"] / "six.toml", d)
    line = f"{p}: n_joints: got 'six'; expected an integer in [1, 64]"
    out = files["dir"] / "out"
    assert_one_line(run_cli("diagnose", files["csv"], "--model", p, "-q"), line)
    rrd = files["dir"] / "v.rrd"
    assert_one_line(run_cli("view", files["csv"], "--model", p, "--save", rrd, "-q"), line)
    res = run_cli("identify", files["csv"], "--model", p, "-o", out / "m.toml", "-q")
    assert_one_line(res, line)


# ------------------------------------------------------------------- same robot, other spelling
def _with_robot(files, name: str, robot: Any) -> Path:
    d = files["dir"] / name
    d.mkdir(exist_ok=True)
    shutil.copy(files["csv"], d / "r.csv")
    meta = json.loads(files["csv"].with_suffix(".json").read_text())
    meta["robot"] = robot
    (d / "r.json").write_text(json.dumps(meta))
    return d / "r.csv"


def test_a_recording_embedding_the_builtin_urdf_is_the_builtin_robot(files):
    """The contradictory refusal: a sidecar with the unchanged IRB140 URDF is the IRB140 of a
    model that names it ("irb140 with 6 joints but ... for irb140 with 6 joints" before)."""
    csv = _with_robot(files, "same", {"urdf": builtin_urdf("irb140"), "tool_frame": "tool0"})
    res = replay(files, files["model"], csv)
    assert res.code == 0 and res.err == "", res.err


def test_an_edited_urdf_of_the_same_name_is_refused_saying_why(files):
    """Another URDF that calls itself irb140 is refused, and the message says the texts differ."""
    urdf = builtin_urdf("irb140").replace('<mass value="18.0"/>', '<mass value="19.0"/>', 1)
    assert urdf != builtin_urdf("irb140")
    csv = _with_robot(files, "edited", {"urdf": urdf, "tool_frame": "tool0"})
    assert_one_line(
        replay(files, files["model"], csv),
        f"{csv}: the recording's robot irb140 (URDF in the metadata) is not the model "
        f"{files['model']}'s irb140 (built-in): their URDF texts differ",
    )


# ----------------------------------------------------------------- a recording's metadata
SIDECAR_CASES = [
    ("payload", {"mass": "two"}, "payload.mass: got 'two'; expected a number in [0, 10000] [kg]"),
    (
        "payload",
        {"mass": 1.0, "com": [0, 0]},
        "payload.com: got 2 values; expected 3 (one per axis)",
    ),
    (
        "tool_offset",
        ["a", 0, 0],
        "tool_offset[1]: got 'a'; expected a number in [-100, 100] [m]",
    ),
    (
        "sample_rate_hz",
        "fast",
        "sample_rate_hz: got 'fast'; expected a number in (0, 1e+06] [Hz]",
    ),
    ("robot", 140, f"robot: got 140; expected {IRB140_ROBOT}"),
    (
        "robot",
        {"urdf": "<robot/>"},
        "robot.tool_frame: missing; expected the name of a URDF link",
    ),
    ("notes", ["a"], "notes: got ['a']; expected text"),
    (
        "dither",
        {"period": -1},
        "dither.period: got -1; expected a number in (0, 1e+06] [s]",
    ),
]


@pytest.mark.parametrize(
    ("key", "value", "message"),
    SIDECAR_CASES,
    ids=[f"{c[0]}-{i}" for i, c in enumerate(SIDECAR_CASES)],
)
def test_sidecar_wrong_type_or_range_is_one_line(files, key, value, message):
    """A CSV's sidecar: info and replay name the sidecar and the key."""
    d = files["dir"] / f"side_{key}"
    d.mkdir(exist_ok=True)
    shutil.copy(files["csv"], d / "r.csv")
    meta = json.loads(files["csv"].with_suffix(".json").read_text())
    meta[key] = value
    (d / "r.json").write_text(json.dumps(meta))
    line = f"{d / 'r.json'}: metadata key {message}"
    assert_one_line(run_cli("info", d / "r.csv"), line)
    assert_one_line(replay(files, files["model"], d / "r.csv"), line)


def test_metadata_embedded_in_parquet_and_mcap_is_checked(files):
    """The same check on the metadata a Parquet file and an MCAP file embed."""
    meta = json.loads(files["csv"].with_suffix(".json").read_text())
    meta["payload"] = {"mass": "two"}
    msg = "metadata key payload.mass: got 'two'; expected a number in [0, 10000] [kg]"
    table = pq.read_table(files["parquet"])
    kv = dict(table.schema.metadata)
    kv[b"ditherlab"] = json.dumps(meta).encode()
    p = files["dir"] / "bad.parquet"
    pq.write_table(table.replace_schema_metadata(kv), p)
    assert_one_line(run_cli("info", p), f"{p}: {msg}")
    m = files["dir"] / "bad.mcap"
    write_frames([dio.read(files["parquet"]).data], meta, m)
    assert_one_line(run_cli("info", m), f"{m}: {msg}")


# ------------------------------------------------------------------------ simulate --config
def test_config_that_is_not_toml_is_one_line(files):
    """A --config that is not TOML (text, or a binary file such as a Parquet log)."""
    out = files["dir"] / "sim.parquet"
    text = files["dir"] / "cfg.toml"
    text.write_text("servo = = 3\n")
    res = run_cli("simulate", "push-campaign", "--config", text, "-o", out, "-q")
    assert_one_line(
        res,
        f"{text}: not valid TOML (Invalid value (at line 1, column 9))",
    )
    res = run_cli("simulate", "push-campaign", "--config", SAMPLE, "-o", out, "-q")
    assert_one_line(res, f"{SAMPLE}: not valid TOML (not UTF-8 text)")
    assert not out.exists()


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ("[servo]\nkp = '30'\n", "servo.kp: got '30'; expected a number >= 0"),
        (
            "[lead_through]\nsmoothing_s = inf\n",
            "lead_through.smoothing_s: got inf; expected a finite number",
        ),
        (
            "[push_campaign]\npushes_per_direction = 2.5\n",
            "push_campaign.pushes_per_direction: got 2.5; expected an integer >= 0",
        ),
        (
            "[servo]\nkpp = 1\n",
            "servo.kpp: unknown key; expected one of ki, kp, kv, standstill_freeze, standstill_leak, standstill_velocity",
        ),
        (
            "servo = 3\n",
            "servo: got 3; expected a table {kp, kv, ki, standstill_freeze, standstill_leak, standstill_velocity}",
        ),
        (
            "[friction]\nmotor_share = 1.5\n",
            "friction.motor_share: got 1.5; expected a number in [0, 1]",
        ),
        ("[friction]\nstatic = [1, 2]\n", "friction.static: got 2 values; expected 6"),
    ],
    ids=["text", "inf", "float-count", "unknown", "not-a-table", "range", "length"],
)
def test_config_value_of_the_wrong_kind_is_one_line(files, toml, message):
    """A value of the wrong kind in --config names the file and the key."""
    cfg = files["dir"] / "cfg.toml"
    cfg.write_text(toml)
    out = files["dir"] / "sim.parquet"
    res = run_cli("simulate", "push-campaign", "--config", cfg, "-o", out, "-q")
    assert_one_line(res, f"{cfg}: {message}")


# ---------------------------------------------------------------------------- mapping files
MAPPING = (
    '[input]\nheader = true\n[time]\ncolumn = "time"\n[robot]\nname = "irb140"\n'
    '[columns.q]\ncolumns = ["p1", "p2", "p3", "p4", "p5", "p6"]\n'
    '[columns.tau]\ncolumns = ["c1", "c2", "c3", "c4", "c5", "c6"]\n'
)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("header = true", 'header = "false"', "input.header: got 'false'; expected true or false"),
        (
            "header = true",
            "header = true\nskip_rows = 'x'",
            "input.skip_rows: got 'x'; expected an integer >= 0",
        ),
        (
            "header = true",
            "header = true\nencoding = 'klingon'",
            "input.encoding: got 'klingon'; expected a text encoding such as 'utf-8'",
        ),
        (
            'column = "time"',
            "column = 1.5",
            "time.column: got 1.5; expected a column number (1-based) or a header name",
        ),
        (
            'column = "time"',
            'column = "time"\noffset = "0"',
            "time.offset: got '0'; expected a number in [-1e+12, 1e+12] [s]",
        ),
        (
            'name = "irb140"',
            'name = "irb140"\npayload = { mass = -1.0 }',
            "robot.payload.mass: got -1.0; expected a number in [0, 10000] [kg]",
        ),
        (
            "[columns.tau]",
            "[columns.tau]\nscale = 'x'",
            "columns.tau.scale: got 'x'; expected a number or a list of numbers (one per column)",
        ),
        (
            "[columns.q]",
            "[meta]\nsample_rate_hz = 'fast'\n[columns.q]",
            "meta.sample_rate_hz: got 'fast'; expected a number in (0, 1e+06] [Hz]",
        ),
    ],
    ids=[
        "header",
        "skip_rows",
        "encoding",
        "time.column",
        "time.offset",
        "payload",
        "scale",
        "meta",
    ],
)
def test_mapping_file_wrong_type_is_one_line(files, old, new, message):
    """A mapping file's value of the wrong kind names the mapping file and the key."""
    log = files["dir"] / "vendor.csv"
    header = (
        "time,"
        + ",".join(f"p{j}" for j in range(1, 7))
        + ","
        + ",".join(f"c{j}" for j in range(1, 7))
    )
    log.write_text(
        header + "\n" + "\n".join(f"{i * 0.004}," + ",".join(["0.1"] * 12) for i in range(5)) + "\n"
    )
    m = files["dir"] / "map.toml"
    m.write_text(MAPPING.replace(old, new, 1))
    assert_one_line(run_cli("info", log, "--mapping", m), f"{m}: {message}")


# ------------------------------------------------------------------------------------ URDF
def test_negative_link_mass_in_a_urdf_is_refused(files):
    """A negative link mass (accepted before) is one line naming the URDF, link and value."""
    urdf = files["dir"] / "neg.urdf"
    urdf.write_text(builtin_urdf("irb140").replace('<mass value="18.0"/>', '<mass value="-3.0"/>'))
    line = (
        f"{urdf}: robot URDF link 'base_link' mass: got '-3.0'; expected a number in "
        "[0, 100000] [kg]"
    )
    assert_one_line(run_cli("robot", urdf), line)
    assert_one_line(run_cli("info", files["parquet"], "--robot", urdf), line)


# ----------------------------------------------------------------- property: random mutations
#: values of every kind a hand-edited file could hold (TOML and JSON alike)
HOSTILE = st.one_of(
    st.text(max_size=4),
    st.booleans(),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e308, -1e308, 1e-320, 64, 65, 7]),
    st.lists(st.one_of(st.integers(-3, 9), st.floats(-1e3, 1e3), st.text(max_size=2)), max_size=7),
    st.dictionaries(st.sampled_from(["mass", "com", "x", "name"]), st.integers(-2, 2), max_size=2),
)


def _paths(d: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path into nested dicts and lists (lists by index)."""
    out = [prefix] if prefix else []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw, base: dict) -> dict:
    """``base`` with one value replaced by a hostile one, one key deleted or one key added."""
    d = copy.deepcopy(base)
    paths = [p for p in _paths(d) if p[-1] != "urdf"]
    path = draw(st.sampled_from(paths))
    parent = d
    for k in path[:-1]:
        parent = parent[k]
    action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "add"]))
    if action == "delete" and isinstance(parent, dict):
        del parent[path[-1]]
    elif action == "add" and isinstance(parent, dict):
        parent[draw(st.text(min_size=1, max_size=4))] = draw(HOSTILE)
    else:
        parent[path[-1]] = draw(HOSTILE)
    return d


def assert_clean(res) -> None:
    """Success (warnings allowed, no traceback), or exactly one error line and exit 2."""
    assert "Traceback" not in res.err, res.err
    if res.code == 0:
        assert all(ln.startswith("warning: ") for ln in res.err.splitlines()), res.err
    else:
        assert res.code == 2, (res.code, res.err)
        lines = res.err.splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), res.err


@pytest.fixture(scope="module")
def base_model(files) -> dict:
    d = model_dict(files)
    d["effects"] = [{"name": "viscous", "joints": [2, 3], "params": {"coef": [0.1, 0.2]}}]
    d["payload"] = {"mass": 1.0, "com": [0.0, 0.0, 0.05]}
    return d


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_property_mutated_model_file_succeeds_or_is_one_line(files, base_model, data):
    """Random type, range and key mutations of a valid model file: replay succeeds or fails
    with one line and exit 2, never a traceback or a warning before the error."""
    d = data.draw(mutated(base_model))
    p = files["dir"] / "mutated.toml"
    try:
        p.write_text(tomli_w.dumps(d))
    except (TypeError, ValueError):  # a value TOML cannot hold
        return
    assert_clean(replay(files, p))


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_property_mutated_sidecar_succeeds_or_is_one_line(files, data):
    """Random type, range and key mutations of a valid sidecar: replay succeeds or fails with
    one line and exit 2."""
    base = json.loads(files["csv"].with_suffix(".json").read_text())
    base["payload"] = {"mass": 1.0, "com": [0.0, 0.0, 0.05]}
    base["tool_offset"] = [0.0, 0.0, 0.1]
    base["sim"] = {"dither": True}  # the simulator's whole parameter set is too big to walk
    d = data.draw(mutated(base))
    side = files["dir"] / "prop" / "r.json"
    side.parent.mkdir(exist_ok=True)
    shutil.copy(files["csv"], side.with_suffix(".csv"))
    side.write_text(json.dumps(d))
    assert_clean(replay(files, files["model"], side.with_suffix(".csv")))

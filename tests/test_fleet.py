"""``ditherlab fleet`` on a LocalCluster with two workers over a dozen simulated robots.

Everything is made through the CLI, as a user would: a reference robot's model (``identify``
then ``--add inertia``: the plant always has link and motor inertia) is the base every robot
starts from; each robot is a short excitation run (2 pose blocks, no dither) with its own seed,
friction level and hidden effect; robot ``r08`` is recorded on three dates with its friction
growing; robot ``r11``'s friction is twice the fleet's; one file is corrupt.

Checked: each robot's planted effect is its first suggestion, its joints' rows equal what
``ditherlab identify`` writes for the same file, the corrupt file is reported and the rest done,
the growing friction is flagged as drift, the doubled friction as an outlier, and the serial
loop gives the same table.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli

from ditherlab.data.torque_model import TorqueModel

PLAN = "[excitation]\nblocks = 2\npushes_per_block = 3\n"
STATIC = np.array([10.0, 9.5, 8.4, 2.5, 2.5, 1.5])
VISCOUS = np.array([3.0, 2.85, 2.52, 0.75, 0.75, 0.45])

#: robot id, seed, hidden effect, friction scale, date
ROBOTS = [
    ("r01", 21, "load_friction", 1.0, "2026-01-10"),
    ("r02", 22, "position_ripple", 0.9, "2026-01-11"),
    ("r03", 23, "payload", 1.1, "2026-01-12"),
    ("r04", 24, "stribeck", 1.0, "2026-01-13"),
    ("r05", 25, "drive_gain", 0.95, "2026-01-14"),
    ("r06", 26, None, 1.05, "2026-01-15"),
    ("r07", 27, None, 0.9, "2026-01-16"),
    ("r08", 28, None, 1.0, "2026-01-01"),
    ("r08", 29, None, 1.25, "2026-03-01"),
    ("r08", 30, None, 1.5, "2026-05-01"),
    ("r09", 31, "dynamics", 1.0, "2026-01-17"),
    ("r10", 32, None, 1.1, "2026-01-18"),
    ("r11", 33, None, 2.0, "2026-01-19"),
]
#: the joints (1-based) where each planted effect must be suggested (None: shared)
JOINTS = {"load_friction": {2, 3}, "drive_gain": {2, 3}}


def _config(path, scale):
    fr = (
        "[friction]\n"
        f"static = {[round(float(v), 4) for v in STATIC * scale]}\n"
        f"viscous = {[round(float(v), 4) for v in VISCOUS * scale]}\n"
    )
    path.write_text(PLAN + fr, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    cli = run_cli
    d = tmp_path_factory.mktemp("fleet")
    ref = d / "reference.parquet"
    cfg1 = _config(d / "c1.toml", 1.0)
    assert (
        cli(
            "simulate", "excitation", "-o", ref, "--seed", 3, "--no-dither", "--config", cfg1, "-q"
        ).code
        == 0
    )
    m0, base = d / "m0.toml", d / "base.toml"
    assert cli("identify", ref, "-o", m0, "--bootstrap", 0, "-q").code == 0
    r = cli("identify", ref, "--model", m0, "--add", "inertia", "-o", base, "--bootstrap", 0, "-q")
    assert r.code == 0, r.err
    logs = d / "logs"
    logs.mkdir()
    rows = []
    for i, (rid, seed, hidden, scale, date) in enumerate(ROBOTS):
        f = logs / f"{rid}_{date}.parquet"
        cfg = _config(d / f"c{i}.toml", scale)
        extra = ["--hidden", hidden] if hidden else []
        r = cli(
            "simulate",
            "excitation",
            "-o",
            f,
            "--seed",
            seed,
            "--no-dither",
            "--config",
            cfg,
            "-q",
            *extra,
        )
        assert r.code == 0, r.err
        rows.append(
            {"file": f"logs/{f.name}", "robot": rid, "date": date, "notes": hidden or "clean"}
        )
    bad = logs / "r12_2026-01-20.parquet"
    bad.write_bytes(ref.read_bytes()[:20000])  # a truncated copy
    rows.append(
        {"file": f"logs/{bad.name}", "robot": "r12", "date": "2026-01-20", "notes": "corrupt"}
    )
    manifest = d / "manifest.csv"
    pd.DataFrame(rows).to_csv(manifest, index=False)
    out = d / "out"
    r = cli(
        "fleet",
        "--manifest",
        manifest,
        "-o",
        out,
        "--model",
        base,
        "--workers",
        2,
        "--no-thresholds",
        "-q",
    )
    return d, base, out, r


def test_every_robot_done_and_the_corrupt_file_reported(fleet):
    _, _, out, r = fleet
    assert r.code == 1, r.err  # a recording failed: status 1, the outputs hold the others
    assert r.err.splitlines()[-1] == (
        f"error: fleet: 1 of {len(ROBOTS) + 1} recordings failed (listed above); {out} holds "
        f"the other {len(ROBOTS)}"
    )
    s = json.loads((out / "fleet.json").read_text())
    assert s["recordings"] == len(ROBOTS)
    assert [f["file"].endswith("r12_2026-01-20.parquet") for f in s["failures"]] == [True]
    assert "not a readable Parquet file" in s["failures"][0]["error"]
    assert "1 failed" in r.out and "r12_2026-01-20.parquet" in r.out
    t = pd.read_parquet(out / "fleet.parquet")
    assert set(t["robot"]) == {rid for rid, *_ in ROBOTS}
    assert len(list((out / "models").glob("*.toml"))) == len(ROBOTS)


def test_each_planted_effect_is_the_first_suggestion(fleet):
    """The robot's planted effect is its recording's first suggestion, on the joints where the
    plant has it; clean robots (nothing but a different friction) get none."""
    _, _, out, _ = fleet
    t = pd.read_parquet(out / "fleet.parquet")
    for rid, _, hidden, _, date in ROBOTS:
        rows = t[(t["robot"] == rid) & (t["date"] == date)]
        first = set(rows["effect"])
        assert first == {hidden or ""}, (rid, date, first, set(rows["effects"]))
        if hidden in JOINTS:
            on = set(rows.loc[rows["effect_on_joint"], "joint"])
            assert JOINTS[hidden] <= on, (rid, on)


def test_rows_are_what_identify_writes(fleet, cli):
    """A robot's rows hold the bands, noise and sliding friction ``ditherlab identify --model
    base`` writes for the same file."""
    d, base, out, _ = fleet
    f = d / "logs" / "r07_2026-01-16.parquet"
    m = d / "r07.toml"
    assert cli("identify", f, "--model", base, "-o", m, "--bootstrap", 0, "-q").code == 0
    model = TorqueModel.load(m)
    t = pd.read_parquet(out / "fleet.parquet")
    rows = t[t["robot"] == "r07"]
    for regime, band in model.regimes.items():
        g = rows[rows["regime"] == regime].sort_values("joint")
        assert np.allclose(g["tau_min"], band.tau_min) and np.allclose(g["tau_max"], band.tau_max)
        assert np.allclose(g["sigma"], band.sigma)
        if band.coulomb is not None:
            assert np.allclose(g["coulomb"], band.coulomb)


def test_growing_friction_is_drift_and_doubled_friction_an_outlier(fleet):
    """r08's still band grows 1.0 -> 1.25 -> 1.5 x over four months: flagged growing on the big
    joints; r11 (2 x the fleet's friction) is an outlier of the still half-width."""
    _, _, out, r = fleet
    s = json.loads((out / "fleet.json").read_text())
    grow = {(g["robot"], g["joint"]) for g in s["drift"] if g["growing"] and g["regime"] == "still"}
    assert {("r08", 1), ("r08", 2)} <= grow, s["drift"]
    assert {g[0] for g in grow} == {"r08"}
    out_robots = {(o["robot"], o["quantity"]) for o in s["outliers"] if o["regime"] == "still"}
    assert ("r11", "half_width") in out_robots, s["outliers"]
    assert "growing: r08" in r.out and "outlier: r11" in r.out
    md = (out / "fleet.md").read_text()
    assert "## Drift over dates" in md and "r08" in md


def test_serial_loop_gives_the_same_table(fleet, cli):
    """The same fleet run as a plain loop in this process (``--scheduler serial``), on three of
    the recordings: identical rows."""
    d, base, out, _ = fleet
    files = sorted((d / "logs").glob("r0[1-3]_*.parquet"))
    o2 = d / "serial"
    r = cli(
        "fleet", *files, "-o", o2, "--model", base, "--scheduler", "serial", "--no-thresholds", "-q"
    )
    assert r.code == 0, r.err
    a = pd.read_parquet(o2 / "fleet.parquet")
    b = pd.read_parquet(out / "fleet.parquet")
    b = b[b["file"].isin({str(f) for f in files})]
    cols = ["tau_min", "tau_max", "sigma", "torque_rms", "noise_floor"]
    a = a.sort_values(["file", "regime", "joint"]).reset_index(drop=True)
    b = b.sort_values(["file", "regime", "joint"]).reset_index(drop=True)
    assert list(a["effects"]) == list(b["effects"])
    assert np.allclose(a[cols].to_numpy(), b[cols].to_numpy(), rtol=0, atol=0)


def test_bad_fleet_input_one_line_exit_2(fleet, cli, tmp_path):
    """A manifest without a ``file`` column, a manifest naming a missing file, a pattern
    matching nothing, an output folder that holds the inputs, an unreachable scheduler, and one
    model for recordings of two robots: one line each, exit 2, nothing written."""
    from ditherlab.data.recording import Recording
    from ditherlab.io import read, write

    d, base, _, _ = fleet
    m = tmp_path / "m.csv"
    m.write_text("path,robot\nx.parquet,r1\n")
    m2 = tmp_path / "m2.csv"
    m2.write_text(f"file,robot\n{d / 'logs' / 'r01_2026-01-10.parquet'},r1\nnope.parquet,r2\n")
    one = read(d / "logs" / "r01_2026-01-10.parquet")
    other = write(Recording(one.data, {**one.meta, "robot": "ur10e"}), tmp_path / "ur.parquet")
    cases = [
        (["--manifest", m, "-o", tmp_path / "o1"], "column 'file' is missing"),
        (
            ["--manifest", m2, "-o", tmp_path / "o4"],
            f"{m2}: row 3, column 'file' is 'nope.parquet': no such file or folder",
        ),
        (
            [d / "logs" / "r01_2026-01-10.parquet", other, "--model", base, "-o", tmp_path / "o5"],
            f"{other}: the recording's robot is ur10e but the model {base} is for irb140",
        ),
        ([str(tmp_path / "nothing*.parquet"), "-o", tmp_path / "o2"], "matches no file"),
        (
            [d / "logs", "-o", d],
            f"{d}: refusing to write a folder that holds the input file {d / 'logs'}",
        ),
        (
            [
                d / "logs" / "r01_2026-01-10.parquet",
                "-o",
                tmp_path / "o3",
                "--scheduler",
                "tcp://127.0.0.1:9",
            ],
            "cannot connect",
        ),
    ]
    for args, msg in cases:
        r = cli("fleet", *args, "-q")
        assert r.code == 2, (args, r.out, r.err)
        assert r.err.count("\n") == 1 and msg in r.err, r.err
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    assert not (tmp_path / "o3").exists()
    assert not (tmp_path / "o4").exists() and not (tmp_path / "o5").exists()


def test_local_cluster_quiet_when_8787_is_taken():
    """Another Dask on port 8787 (its dashboard): the embedded cluster takes a free port for its
    health page without the three-line warning distributed prints on stderr."""
    import socket
    import warnings

    from ditherlab.core.tasks import _client

    holder = socket.socket()
    try:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("", 8787))
        holder.listen()
    except OSError:
        pass  # taken already: the same situation
    try:
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            client, cluster = _client(None, 1)
        try:
            assert client.submit(sum, [1, 2]).result() == 3
        finally:
            client.close()
            cluster.close()
        assert not [w for w in seen if "8787" in str(w.message)]
    finally:
        holder.close()

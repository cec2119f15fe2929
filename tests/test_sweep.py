"""``ditherlab sweep``: a grid of simulated paired campaigns over simulator parameters.

The grid's parsing and every bad input through the CLI (one line on stderr, exit status 2); the
vibration measure on a synthetic recording; and, slow, a small sweep through the CLI on a
LocalCluster with two workers: two good points and two that fail (no pushes), the table's
columns and rows, the failures reported, the files written, and the same row from the serial
loop.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli

from ditherlab.app.sweep import COLUMNS, RUN_COLUMNS, grid_points, parse_grid, vibration
from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording, RecordingArrays

DITHER_KEYS = (
    "amplitude_cap, amplitude_fraction, amplitude_gain, centre_gain, frequency, hold_fraction, "
    "joints, periods, ramp_s, update_every, waveform"
)


# ------------------------------------------------------------------ the grid
def test_parse_grid_types_and_order():
    """Values take the default's type; a per-joint list one value or six; keys keep their order."""
    g = parse_grid(
        [
            "dither.waveform=square,sine",
            "dither.frequency=40,80",
            "dither.periods=3",
            "dither.joints=true:true:true:false:false:false",
            "pose.q0=0:0.3:0:0:1.5708:0,0.1",
        ]
    )
    assert list(g) == ["dither.waveform", "dither.frequency", "dither.periods", "dither.joints",
                       "pose.q0"]  # fmt: skip
    assert g["dither.waveform"] == ["square", "sine"]
    assert g["dither.frequency"] == [40.0, 80.0] and isinstance(g["dither.frequency"][0], float)
    assert g["dither.periods"] == [3] and isinstance(g["dither.periods"][0], int)
    assert g["dither.joints"] == [[True, True, True, False, False, False]]
    assert g["pose.q0"] == [[0.0, 0.3, 0.0, 0.0, 1.5708, 0.0], 0.1]


def test_grid_points_cartesian_product_over_the_base_config():
    """Every combination, the first key slowest, merged over the base config."""
    g = parse_grid(["dither.waveform=square,sine", "dither.frequency=40,80,160"])
    pts = grid_points(g, {"push_campaign": {"pushes_per_direction": 2}})
    assert len(pts) == 6
    assert [p.label for p in pts[:2]] == [
        "dither.waveform=square dither.frequency=40",
        "dither.waveform=square dither.frequency=80",
    ]
    assert pts[-1].config == {
        "push_campaign": {"pushes_per_direction": 2},
        "dither": {"waveform": "sine", "frequency": 160.0},
    }
    with pytest.raises(ConfigError, match="grid is empty"):
        parse_grid([])


def test_pose_joints_as_grid_keys():
    """``pose.qJ`` and ``KEY[J]`` sweep one joint of a per-joint list; the other joints keep the
    base config's (or the default's) values, and two joints of one list combine."""
    g = parse_grid(["pose.q2=-0.3,0.3", "pose.q0[3]=0.5", "dither.amplitude_fraction[1]=0.95"])
    assert g == {
        "pose.q2": [-0.3, 0.3],
        "pose.q0[3]": [0.5],
        "dither.amplitude_fraction[1]": [0.95],
    }
    pts = grid_points(g, {"pose": {"q0": [0.1, 0.0, 0.0, 0.2, 1.2, 0.0]}})
    assert [p.label for p in pts] == [
        "pose.q2=-0.3 pose.q0[3]=0.5 dither.amplitude_fraction[1]=0.95",
        "pose.q2=0.3 pose.q0[3]=0.5 dither.amplitude_fraction[1]=0.95",
    ]
    assert pts[1].config["pose"]["q0"] == [0.1, 0.3, 0.5, 0.2, 1.2, 0.0]
    assert pts[1].config["dither"]["amplitude_fraction"] == [0.95, 0.8, 0.5, 0.6, 0.6, 0.6]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            [],
            "sweep: the grid is empty; expected at least one --grid KEY=V1,V2,... "
            "(e.g. --grid dither.frequency=40,80,160)",
        ),
        (
            ["--grid", "dither.frequency="],
            "sweep: --grid dither.frequency has no values (the grid is empty); expected "
            "dither.frequency=V1,V2,...",
        ),
        (
            ["--grid", "dither.freq=40,80"],
            "sweep: --grid key 'dither.freq' does not exist; expected a key of the simulator's "
            f"parameters (irb140.toml; under dither: {DITHER_KEYS})",
        ),
        (
            ["--grid", "nosuch=1"],
            "sweep: --grid key 'nosuch' does not exist; expected a key of the simulator's "
            "parameters (irb140.toml; under the top level: dither, environment, excitation, "
            "friction, hidden, joints, lead_through, noise, pose, push_campaign, servo, timing)",
        ),
        (
            ["--grid", "dither.waveform=square,saw"],
            "sweep: --grid dither.waveform value 'saw' is unknown; expected one of square, sine, "
            "triangle",
        ),
        (
            ["--grid", "dither.frequency=80,fast"],
            "sweep: --grid dither.frequency value 'fast' is not a finite number such as 80",
        ),
        (
            ["--grid", "dither.periods=2.5"],
            "sweep: --grid dither.periods value '2.5' is not an integer such as 5",
        ),
        (
            ["--grid", "dither.joints=yes"],
            "sweep: --grid dither.joints value 'yes' is not true or false",
        ),
        (
            ["--grid", "pose.q0=0:1"],
            "sweep: --grid pose.q0 value '0:1' has 2 entries; expected one value or 6 separated "
            "by ':'",
        ),
        (
            ["--grid", "dither.frequency=-5"],
            "sweep: --grid point dither.frequency=-5: dither.frequency: got -5.0; expected a "
            "number > 0",
        ),
        (["--grid", "dither"], "sweep: --grid 'dither' is not KEY=V1,V2,..."),
        (
            ["--grid", "dither=1"],
            "sweep: --grid key 'dither' is a table; expected one of its keys ("
            + ", ".join(f"dither.{k}" for k in DITHER_KEYS.split(", "))
            + ")",
        ),
        (
            ["--grid", "excitation.poses=1"],
            "sweep: --grid key 'excitation.poses' holds a list of lists; it cannot be swept "
            "(give it in --config)",
        ),
        (
            ["--grid", "dither.frequency=80", "--grid", "dither.frequency=40"],
            "sweep: --grid key 'dither.frequency' is given twice; expected it once",
        ),
        (
            ["--grid", "pose.q0=0:0:0:0:3:0"],
            "sweep: --grid point pose.q0=0:0:0:0:3:0: pose.q0 joint 5 is 3 rad, outside its "
            "limits [-2.007, 2.007] rad",
        ),
        (
            ["--grid", "pose.q2=0,2"],
            "sweep: --grid point pose.q2=2: pose.q0 joint 2 is 2 rad, outside its limits "
            "[-1.571, 1.92] rad",
        ),
        (
            ["--grid", "pose.q7=0"],
            "sweep: --grid key 'pose.q7': joint 7 does not exist; expected 1..6",
        ),
        (
            ["--grid", "dither.frequency[1]=40"],
            "sweep: --grid key 'dither.frequency[1]': dither.frequency is not a per-joint list; "
            "expected KEY[J] of a list such as dither.amplitude_fraction[1] or pose.q2",
        ),
        (
            ["--grid", "pose.q0=0", "--grid", "pose.q3=0.2"],
            "sweep: --grid keys 'pose.q0' and 'pose.q3' both set pose.q0; expected the whole "
            "list or single joints of it",
        ),
    ],
)
def test_bad_grid_is_one_line_and_exit_2(tmp_path, args, message):
    """Each grid mistake: exactly one line on stderr naming the key and value and what was
    expected, exit status 2, nothing on stdout, nothing written."""
    out = tmp_path / "sw"
    r = run_cli("sweep", *args, "-o", out)
    assert r.code == 2
    assert r.err == f"error: {message}\n"
    assert r.out == "" and not out.exists()


def test_bad_config_names_the_file(tmp_path):
    """A --config with an unknown key names the file and the key (exit 2)."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[dither]\nwaveform = 'saw'\n", encoding="utf-8")
    r = run_cli("sweep", "--grid", "dither.frequency=80", "--config", cfg, "-o", tmp_path / "o")
    assert r.code == 2
    assert r.err == (
        f"error: {cfg}: dither.waveform: got 'saw'; expected one of 'square', 'sine', 'triangle'\n"
    )


# ------------------------------------------------------------------ the vibration
def test_vibration_is_the_half_peak_to_peak_at_rest_without_drift():
    """A sine of known amplitude on a slow drift, with pushes in between: the measure is the
    amplitude (sampled, within 3 %) per joint, the drift and the pushes' motion left out."""
    fs, omega = 250.0, 80.0
    t = np.arange(int(20 * fs)) / fs
    amp = np.array([1e-4, 3e-5])
    q = np.sin(omega * t)[:, None] * amp + 2e-3 * t[:, None]  # drift 2 mrad/s
    pushes = [{"t0": 6.0, "duration": 2.0}, {"t0": 11.0, "duration": 2.0}]
    for p in pushes:  # the pushes move the arm by a lot
        m = (t >= p["t0"]) & (t < p["t0"] + p["duration"])
        q[m] += 0.01 * np.sin(np.pi * (t[m] - p["t0"]) / p["duration"])[:, None]
    meta = {
        "robot": "irb140",
        "dither": {"omega": omega},
        "sim": {"timeline": {"dither_on": 1.0}, "pushes": pushes, "params": {"dither": {"ramp_s": 1.0}}},
    }  # fmt: skip
    qq = np.zeros((len(t), 6))
    qq[:, :2] = q
    extra = {f"q_link_{j + 1}": qq[:, j] for j in range(6)}
    rec = Recording.from_arrays(
        RecordingArrays(t, qq, np.zeros((len(t), 6)), dither=np.ones(len(t), bool), extra=extra),
        meta,
    )
    for angle in ("link", "motor"):
        v = vibration(rec, angle)
        assert v.shape == (6,)
        np.testing.assert_allclose(v[:2], amp, rtol=0.03)
        assert np.all(v[2:] == 0)
    rec2 = Recording.from_arrays(
        RecordingArrays(t, qq, np.zeros((len(t), 6)), dither=np.ones(len(t), bool)), meta
    )
    with pytest.raises(ConfigError, match="no q_link_j columns"):
        vibration(rec2, "link")


# ------------------------------------------------------------------ a small sweep
@pytest.fixture(scope="module")
def small_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "out"
    r = run_cli(
        "sweep",
        "--grid", "dither.waveform=square,sine",
        "--grid", "push_campaign.pushes_per_direction=2,0",
        "--bootstrap", "5",
        "--workers", "2",
        "-o", out,
    )  # fmt: skip
    return r, out


@pytest.mark.slow
def test_small_sweep_table_and_failures(small_sweep):
    """Four points on a LocalCluster with two workers: the table's columns and rows, the two
    points without pushes reported as failed (the others done), the files written."""
    r, out = small_sweep
    assert r.code == 0, r.err
    table = pd.read_parquet(out / "sweep.parquet")
    grid = ["dither.waveform", "push_campaign.pushes_per_direction"]
    assert list(table.columns) == grid + COLUMNS
    assert len(table) == 4 and table["runs"].tolist() == [1, 0, 1, 0]
    runs = pd.read_parquet(out / "sweep_runs.parquet")
    assert list(runs.columns) == grid + RUN_COLUMNS and (runs["seed"] == 0).all()
    assert table["dither.waveform"].tolist() == ["square", "square", "sine", "sine"]
    assert table["push_campaign.pushes_per_direction"].tolist() == [2, 0, 2, 0]
    assert table["ok"].tolist() == [True, False, True, False]
    bad = table[~table["ok"]]
    assert bad["error"].str.contains("no pushes found").all()
    assert bad["f50_x"].isna().all()
    good = table[table["ok"]]
    assert (good["error"] == "").all() and (good["pushes"] == 12).all()
    for a in "xyz":
        assert np.isfinite(good[f"f50_{a}"]).all() and (good[f"f50_{a}"] > 0).all()
    assert ((good["vibration"] > 1e-7) & (good["vibration"] < 1e-3)).all()
    assert ((good["vibration_motor"] > 1e-7) & (good["vibration_motor"] < 1e-3)).all()
    assert good["within_limit"].tolist() == (good["vibration"] <= 1e-4).tolist()
    assert good["coverage_push"].between(0, 1).all() and good["coverage_rest"].between(0, 1).all()
    for f in ("sweep.md", "sweep.json", "f50_vs_vibration.png", "f50_per_point.png",
              "f50_predicted.png"):  # fmt: skip
        assert (out / f).stat().st_size > 0
    s = json.loads((out / "sweep.json").read_text())
    assert s["points"] == 4 and len(s["failures"]) == 2
    assert (
        s["failures"][0]["point"] == "dither.waveform=square push_campaign.pushes_per_direction=0"
    )
    assert r.out.count("failed: ") == 4  # two in the table, two below it
    assert "4 points, 2 failed" in r.out and "best under the vibration limit" in r.out


@pytest.mark.slow
def test_small_sweep_is_reproducible_in_the_serial_loop(small_sweep, tmp_path):
    """The sine point run alone in the serial loop gives the same row (same --seed)."""
    _, out = small_sweep
    r = run_cli(
        "sweep",
        "--grid", "dither.waveform=sine",
        "--grid", "push_campaign.pushes_per_direction=2",
        "--bootstrap", "5",
        "--scheduler", "serial",
        "-o", tmp_path / "serial",
        "--quiet",
    )  # fmt: skip
    assert r.code == 0, r.err
    a = pd.read_parquet(out / "sweep.parquet").iloc[2]
    b = pd.read_parquet(tmp_path / "serial" / "sweep.parquet").iloc[0]
    for c in COLUMNS:
        if c != "seconds":
            assert a[c] == b[c] or (pd.isna(a[c]) and pd.isna(b[c])), c


def test_aggregate_means_over_the_runs_that_did_not_fail():
    """A point's row: the mean over its good runs, their standard error, a bound kept only when
    every run had it, the limit on the mean vibration, failures named by seed."""
    from ditherlab.app.sweep import METRICS, aggregate

    def run(point, seed, ok, f50=(np.nan,) * 3, vib=np.nan, bound=("", "", ""), error=""):
        r = dict.fromkeys(METRICS, np.nan)
        r.update({f"f50_{a}_bound": b for a, b in zip("xyz", bound, strict=True)})
        r.update({f"f50_{a}": f for a, f in zip("xyz", f50, strict=True)})
        r.update(f50_mean=float(np.mean(f50)), vibration=vib, vibration_joint=1,
                 vibration_motor_joint=2, within_limit=False, seconds=2.0)  # fmt: skip
        return {"k": point, "point": f"k={point}", "seed": seed, "ok": ok, "error": error, **r}

    runs = pd.DataFrame(
        [
            run("a", 0, True, (10.0, 4.0, 3.0), 5e-5, ("", "below", "below")),
            run("a", 2, True, (14.0, 6.0, 4.0), 7e-5, ("", "below", "")),
            run("a", 4, False, error="boom"),
            run("b", 0, False, error="no pushes"),
        ],
        columns=["k", *RUN_COLUMNS],
    )
    t = aggregate(runs, ["k"], 1e-4)
    assert list(t.columns) == ["k", *COLUMNS]
    a, b = t.iloc[0], t.iloc[1]
    assert a["runs"] == 2 and a["ok"] and a["error"] == "seed 4: boom"
    assert a["f50_x"] == 12.0 and a["f50_y"] == 5.0 and a["f50_z"] == 3.5
    assert a["f50_y_bound"] == "below" and a["f50_z_bound"] == ""
    assert a["f50_mean_sem"] == pytest.approx(np.std([17 / 3, 8.0], ddof=1) / np.sqrt(2))
    assert a["vibration"] == pytest.approx(6e-5) and a["within_limit"] and a["seconds"] == 6.0
    assert not b["ok"] and b["runs"] == 0 and b["error"] == "no pushes"  # one run: no seed named
    assert np.isnan(b["f50_x"]) and not b["within_limit"]

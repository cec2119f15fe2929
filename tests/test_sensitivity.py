"""``ditherlab robot --sensitivity``: predicted detection thresholds per push direction at a pose.

The prediction against a case derived by hand (one joint alone carries a direction: F50 =
(W/2 + m)/l, F90 = (0.9 W + m)/l, so the threshold scales with 1/lever), the bands' sources,
the CLI's table, JSON and map, every bad input as one line with exit status 2, and the
prediction against a small simulated campaign at a pose other than the paper's through
``ditherlab sweep`` (10-20 s, so not marked slow).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli

from ditherlab.analysis.sensitivity import (
    Bands,
    campaign_states,
    centre_loop_gain,
    condition_bands,
    noise_levels,
    peak_noise_factor,
    predict,
    shared_fraction,
    transmission_table,
)
from ditherlab.analysis.sensitivity_plant import extraction_peak
from ditherlab.core.errors import ConfigError
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.physics.dither import extract_dither
from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim import simulate
from ditherlab.sim.params import load_params

ROBOT = RobotModel.from_spec("irb140")


def one_joint_bands(width: float = 10.0, sigma: float = 1e-6) -> Bands:
    """Joint 1 with a band of ``width`` [N·m]; the others so wide they never leave it."""
    lo = np.full(6, -1e4)
    lo[0] = -width / 2
    return Bands(lo, -lo, np.full(6, sigma), False, "test", np.zeros(6), np.full(6, 20.0))


# ------------------------------------------------------------------ the prediction
@pytest.mark.parametrize("q2", [0.0, 0.4])
def test_one_joint_alone_gives_the_hand_derived_thresholds(q2):
    """At the paper's pose (and with the upper arm tilted) a push along y loads joint 1 with
    lever l (its distance to the base axis); with the other joints' bands wide, the estimate
    is the excess over the edge divided by l, so a response at noise level m0 [N] needs
    P l > v W + m0 l with v ~ U[0, 1]: F50 = (W/2)/l + m0, F90 = 0.9 W/l + m0 — the threshold
    scales with 1 / lever."""
    q = PAPER_POSE.copy()
    q[1] = q2
    lever = abs(ROBOT.jacobian(q[None])[0][1, 0])  # joint 1's lever for a force along y [m]
    W, m0 = 10.0, 1.0
    pred = predict(
        ROBOT, q, one_joint_bands(W), noise_level=[m0] * 3, draws=400, forces=400,
        states="independent",
    )  # fmt: skip
    for d in ("+y", "-y"):
        r = pred["directions"][d]
        assert r["f50"] == pytest.approx(W / 2 / lever + m0, rel=0.01)
        assert r["f90"] == pytest.approx(0.9 * W / lever + m0, rel=0.01)
        assert r["joints"][0] == 1
    if q2 == 0.0:
        assert lever == pytest.approx(0.450, abs=1e-3)  # docs/design/shared-joint.md


def test_campaign_states_one_joint_hand_derived():
    """The plant's band behind the gear spring (link share lam = 0.9) and the servo's return
    after a slip to the sliding level (c = 0.85): one joint alone carrying y, the campaign
    leaves it only at mid -+ c W/2, held along the last push that slipped it, so a push the
    other way must break (lam + c) W/2 and one the same way (lam - c) W/2 before the logged
    torque moves; then the torque carries the whole push and responds beyond the band's
    edge plus the noise level. Hence p(P) = 0 below W/(2l) + m0, about one half (the last y push
    went either way) up to (lam + c) W/(2l), 1 beyond: F90 = (lam + c) W / (2l), and F50 between
    the two — not the estimator's uniform-state F50 = W/(2l) + m0 (``states="independent"``)."""
    W, m0 = 10.0, 1.0
    b = one_joint_bands(W)
    q = PAPER_POSE
    J = ROBOT.jacobian(q[None])[0]
    lever = abs(J[1, 0])
    d, mag, st = campaign_states(J, b, (10.0, 60.0), pushes=2000, seed=3)
    assert set(np.round(st[:, 0], 9)) == {-0.85 * W / 2, 0.85 * W / 2}
    # hard for the direction opposite to the last y push: p(hard) close to one half
    ys = [k for k in range(len(d)) if d[k] in (2, 3)]
    sg = np.sign(J[1, 0])  # +y loads joint 1 with sign sg; its residual moves by -sg P l
    hard = [st[k, 0] * sg * (1 if d[k] == 2 else -1) < 0 for k in ys[1:]]
    assert 0.4 < np.mean(hard) < 0.6
    pred = predict(ROBOT, q, b, noise_level=[m0] * 3, draws=400, forces=400, states="campaign")
    uniform = predict(
        ROBOT, q, b, noise_level=[m0] * 3, draws=400, forces=400, states="independent"
    )
    for dn in ("+y", "-y"):
        r = pred["directions"][dn]
        assert r["f90"] == pytest.approx((0.9 + 0.85) * W / 2 / lever, rel=0.01)
        assert W / 2 / lever + m0 - 0.2 <= r["f50"] <= (0.9 + 0.85) * W / 2 / lever + 0.2
        assert r["f90"] > 1.5 * uniform["directions"][dn]["f90"] - 20  # far from 0.9 W/l + m0
    with pytest.raises(ConfigError, match="campaign"):
        predict(ROBOT, q, condition_bands(6, dither=True), states="campaign")


def test_the_slip_rule_against_the_simulator():
    """The rule :func:`campaign_states` plays, against the plant itself (a no-dither campaign
    at the paper's pose with the link angle logged): the link moves during a push exactly when
    the push's torque on it exceeds 0.9 Fs - sign(l)(s - 0) with s the logged residual before
    the push (outside a margin of 0.15 Fs around the rule's threshold), and after a push beyond
    1.9 Fs the logged residual rests near the sliding level along it, +sign(l) 0.85 Fs."""
    rec = simulate("push-campaign", seed=7, dither=False, pushes_per_direction=6,
                   config={"push_campaign": {"log_link_angle": True}})  # fmt: skip
    sim = rec.meta["sim"]
    fs = np.asarray(sim["params"]["friction"]["static"], float)
    t, q = rec.t, rec.q
    r = rec.tau - ROBOT.gravity(q)
    ql = np.column_stack([rec.data[f"q_link_{j + 1}"].to_numpy() for j in range(6)])
    J = ROBOT.jacobian(PAPER_POSE[None])[0]
    agree = checked = 0
    after = []
    for pu in sim["pushes"]:
        u = np.zeros(3)
        u["xyz".index(pu["axis"])] = pu["sign"]
        lev = J[:3].T @ u
        pre = (t >= pu["t0"] - 0.3) & (t < pu["t0"])
        dur = (t >= pu["t0"]) & (t < pu["t0"] + pu["duration"])
        end = (t >= pu["t0"] + pu["duration"] + pu["rest"] - 0.3) & (
            t < pu["t0"] + pu["duration"] + pu["rest"]
        )
        s = r[pre].mean(0)
        moved = np.abs(ql[dur] - ql[pre].mean(0)).max(0) > 1e-6
        for j in range(3):  # the big joints
            if abs(lev[j]) * 10.0 < 0.05 * fs[j]:
                continue
            brk = 0.9 * fs[j] - np.sign(lev[j]) * s[j]
            if abs(pu["magnitude"] * abs(lev[j]) - brk) > 0.15 * fs[j]:
                checked += 1
                agree += bool(moved[j]) == bool(pu["magnitude"] * abs(lev[j]) > brk)
            if moved[j] and pu["magnitude"] * abs(lev[j]) > 1.9 * fs[j]:
                after.append(np.sign(lev[j]) * r[end, j].mean() / fs[j])
    assert checked >= 30 and agree / checked >= 0.9, (agree, checked)
    assert len(after) >= 8 and np.median(after) == pytest.approx(0.85, abs=0.1), after


POSE_C = np.array([0.3, 0.3, -0.7, 0.4, 1.0, -0.4])


def test_dithered_transmission_against_the_simulator():
    """The plant's push transmission with dither (:func:`transmission_table`, each joint
    simulated alone with the other links held) against the whole plant: a dithered campaign
    at pose C without torque noise (so the extracted signal's drop is the push's own), pushes
    of 1-25 N. Per push and big joint, the drop of the extracted residual within the push and
    0.3 s after it against the table's at the push's torque and length: joints 1 and 2 (whose
    links the dither frees every period) follow within 0.3 N·m RMS, joint 3 (0.5 Fs of dither
    leaves its link's friction holding) shows no more than the extraction's ripple at rest
    (the square wave's period is not a whole number of samples) below 1.5 N·m (the table frees
    it from about 1.7 N·m, the whole plant from 2-3 N·m); a uniform model (every joint shows
    0.87 of the push torque) is off by several times more."""
    cfg = {"pose": {"q0": POSE_C.tolist()}, "noise": {"tau_sigma_fraction": 0.0},
           "push_campaign": {"magnitude_min": 1.0, "magnitude_max": 25.0}}  # fmt: skip
    rec = simulate("push-campaign", seed=5, dither=True, pushes_per_direction=3, config=cfg)
    ex = extract_dither(rec)
    r = ex.signal - ROBOT.gravity(rec.q)
    t = rec.t
    J = ROBOT.jacobian(POSE_C[None])[0]
    bands = condition_bands(6, dither=True)
    durs, tq, drop, what = transmission_table(ROBOT, POSE_C, bands)
    assert "plant" in what
    errs, uniform, held = [], [], []
    for pu in rec.meta["sim"]["pushes"]:
        u = np.zeros(3)
        u["xyz".index(pu["axis"])] = pu["sign"]
        lev = J[:3].T @ u
        pre = (t >= pu["t0"] - 0.3) & (t < pu["t0"])
        win = (t >= pu["t0"]) & (t <= pu["t0"] + pu["duration"] + 0.3)
        seen = (-np.sign(lev) * (r[win] - r[pre].mean(0))).max(0)
        rest = (t >= pu["t0"] - 1.5 - pu["duration"]) & (t < pu["t0"])  # the extraction's
        wobble = (-np.sign(lev) * (r[rest] - r[rest].mean(0))).max(0)  # ripple at rest
        for j in range(3):
            T = pu["magnitude"] * abs(lev[j])
            if T < 0.5:
                continue
            table = [np.interp(T, np.r_[0.0, tq[:, j]], np.r_[0.0, drop[d, :, j]])
                     for d in range(len(durs))]  # fmt: skip
            pred = float(np.interp(pu["duration"], durs, table))
            if j < 2:
                errs.append(seen[j] - pred)
                uniform.append(seen[j] - 0.87 * T)
            elif T < 1.5:
                held.append((seen[j] - wobble[j], pred, 0.87 * T))
    errs, uniform = np.array(errs), np.array(uniform)
    assert len(errs) >= 20 and len(held) >= 3
    rms, rms_uniform = np.sqrt(np.mean(errs**2)), np.sqrt(np.mean(uniform**2))
    assert rms < 0.3 and rms < 0.4 * rms_uniform, (rms, rms_uniform)
    held = np.array(held)
    assert held[:, 0].max() < 0.2 and held[:, 1].max() < 0.2 and held[:, 2].max() > 0.8


def test_dithered_prediction_one_joint_hand_derived():
    """With dither the centre loop holds the extracted signal at the gravity torque, so every
    push meets joint 1 in the band's middle: with the model's dither_extraction law on every
    joint (gain g, lag 0: the push's peak through the one-period mean, pk(D)), a push along y
    responds once g pk(D) P l exceeds W/2 + m0 l. Hence F50 and F90 lie within the push lengths'
    spread of (W/2 + m0 l) / (g pk l), a step (F90 - F50 < 0.3 N) — where a state uniform over
    the band (``states="mixed"``) spreads the detection over it, F90 - F50 = 0.4 W / (0.87 l)."""
    W, m0, g = 4.0, 1.0, 0.8
    b = one_joint_bands(W)
    b.dithered = True
    b.extraction_gain, b.extraction_lag = np.full(6, g), np.zeros(6)
    q = PAPER_POSE
    lever = abs(ROBOT.jacobian(q[None])[0][1, 0])
    pred = predict(ROBOT, q, b, noise_level=[m0] * 3)
    durs, _, _, what = transmission_table(ROBOT, q, b)
    assert "dither_extraction (gain, lag) on joint(s) 1, 2, 3, 4, 5, 6" in what
    assert pred["transmission"] == what and pred["states"] == "plant"
    pk = np.array([extraction_peak(D, 0.0, 20, 250.0) for D in durs])
    assert 0.9 < pk.min() < pk.max() < 1.0  # the one-period mean flattens a short push more
    edge = (W / 2 + m0 * lever) / (g * lever)
    for d in ("+y", "-y"):
        r = pred["directions"][d]
        assert edge / pk.max() - 0.2 <= r["f50"] <= r["f90"] <= edge / pk.min() + 0.2
        assert r["f90"] - r["f50"] < 0.3
    uniform = predict(ROBOT, q, b, noise_level=[m0] * 3, states="mixed", draws=400, forces=400)
    assert uniform["directions"]["+y"]["f90"] - uniform["directions"]["+y"]["f50"] > 2.0


def test_peak_noise_lowers_the_threshold_by_the_noise_maximum():
    """With noise sigma on joint 1 the largest estimate over a push's top is the median maximum
    of K noise values higher: F50 drops by z_K sigma / l exactly."""
    sigma = 0.3
    b = one_joint_bands(10.0, sigma)
    z = peak_noise_factor(b)
    assert 1.5 < z < 2.5  # K ~ 45 samples of a 1.25 s push's top at 250 Hz
    q = PAPER_POSE
    kw = {"noise_level": [1.0] * 3, "draws": 400, "forces": 400, "states": "independent"}
    quiet = predict(ROBOT, q, one_joint_bands(10.0), **kw)
    noisy = predict(ROBOT, q, b, **kw)
    drop = quiet["directions"]["+y"]["f50"] - noisy["directions"]["+y"]["f50"]
    assert drop == pytest.approx(z * sigma / 0.45, rel=0.03)


def test_centre_loop_gain_high_passes_the_push():
    """The dither's centre loop eats part of a push: none without the loop, more for a faster
    loop and for longer pushes (a first-order high-pass of time constant 1/Kc); the
    simulator's loop and 0.5-2 s pushes keep 0.87 of it at the peak; the dithered bands carry
    it, the undithered do not."""
    p = load_params()
    g = centre_loop_gain(p)
    assert g == pytest.approx(0.873, abs=0.005)
    assert centre_loop_gain(load_params(overrides={"dither": {"centre_gain": 0.0}})) == 1.0
    assert centre_loop_gain(load_params(overrides={"dither": {"centre_gain": 2.0}})) < g - 0.05
    longer = {"push_campaign": {"duration_min": 3.0, "duration_max": 4.0}}
    assert centre_loop_gain(load_params(overrides=longer)) < g - 0.1
    assert condition_bands(6, dither=True).gain == g and condition_bands(6).gain == 1.0


def test_shared_fraction_counts_the_pushes_two_joints_share():
    """Two joints with the same levers are slipped by the same pushes (1); a joint seeing x
    only and one seeing x and y equally share the x pushes and not the y ones (1/2); the mixed
    draw lies between the shared and the independent limits."""
    b = Bands(np.full(2, -5.0), np.full(2, 5.0), np.full(2, 0.1), False, "t", np.zeros(6),
              np.full(6, 20.0))  # fmt: skip
    J = np.zeros((6, 2))
    J[0] = [0.3, 0.3]
    assert shared_fraction(J, b, (5.0, 60.0), 2)["+x"] == pytest.approx(1.0)
    J[1] = [0.0, 0.3]
    rho = shared_fraction(J, b, (5.0, 60.0), 2)
    assert rho["+x"] == pytest.approx(0.5) and rho["+y"] == 1.0  # y: joint 2 alone
    bands = condition_bands(6)
    f = {s: predict(ROBOT, PAPER_POSE, bands, states=s)["axes"]["x"]["f50"]
         for s in ("shared", "mixed", "independent")}  # fmt: skip
    assert f["independent"] < f["mixed"] < f["shared"]


def test_noise_level_at_rest_floor_and_edges():
    """At rest the estimate is zero inside the band: the noise level is the 1 N floor for a
    tiny noise; a noise comparable to the band's width raises it above the floor."""
    J = ROBOT.jacobian(PAPER_POSE[None])[0]
    assert noise_levels(J, one_joint_bands(10.0, 1e-6)).tolist() == [1.0, 1.0, 1.0]
    loud = noise_levels(J, one_joint_bands(1.0, 1.0))
    assert loud[1] > 2.0 and loud[0] == 1.0  # only y sees joint 1 at this pose


def test_bands_from_the_simulator_and_from_a_model():
    """Without a model: the simulator's still band ±Fs and dither band ±(1 - a)·Fs; with a
    model its still and dither regimes (a model without a dither regime: the still band shrunk
    by the simulator's dither amplitude)."""
    fs = np.array([10.0, 9.5, 8.4, 2.5, 2.5, 1.5])
    a = np.array([0.7, 0.8, 0.5, 0.6, 0.6, 0.6])  # irb140.toml dither.amplitude_fraction
    still = condition_bands(6)
    assert np.allclose(still.hi, fs) and np.allclose(still.lo, -fs)
    assert np.allclose(still.sigma, 0.03 * fs) and "simulator defaults" in still.source
    dith = condition_bands(6, dither=True)
    assert np.allclose(dith.hi, (1 - a) * fs) and dith.dithered
    m = paper_model(dither=False)
    b = condition_bands(6, m, dither=True)
    assert np.allclose(b.hi, 9.0 - a * fs) and "shrunk" in b.source
    m2 = paper_model(dither=True)
    assert np.allclose(condition_bands(6, m2, dither=True).hi, 0.5)


def paper_model(dither: bool = True) -> TorqueModel:
    """A model of the IRB140: still band ±9 N·m, dither band ±0.5 N·m."""
    regimes = {"still": Band(np.full(6, -9.0), np.full(6, 9.0), np.full(6, 0.3))}
    if dither:
        regimes["dither"] = Band(np.full(6, -0.5), np.full(6, 0.5), np.full(6, 0.1))
    return TorqueModel(robot="irb140", n=6, regimes=regimes)


# ------------------------------------------------------------------ the CLI
def test_cli_table_and_json_agree_with_the_library(tmp_path):
    """The table prints every direction's F50/F90 as predict() gives them (model file: its
    bands, and it says so); --json holds the same numbers."""
    mpath = paper_model().save(tmp_path / "m.toml")
    r = run_cli("robot", "irb140", "--q", "paper", "--sensitivity", "--model", mpath, "--no-dither")
    assert r.code == 0, r.err
    lines = r.out.splitlines()
    assert lines[0].startswith("pose sensitivity at q = (0.0, 0.0, 0.0, 0.0, 90.0, 0.0) deg, ")
    assert f"bands from model {mpath}" in lines[0] and "without dither" in lines[0]
    bands = condition_bands(6, TorqueModel.load(mpath), dither=False)
    pred = predict(ROBOT, PAPER_POSE, bands)
    row = next(line for line in lines if line.startswith("+y"))
    f50, f90 = (float(x) for x in row.split()[1:3])
    assert f50 == pytest.approx(pred["directions"]["+y"]["f50"], abs=0.05)
    assert f90 == pytest.approx(pred["directions"]["+y"]["f90"], abs=0.05)
    rj = run_cli("robot", "irb140", "--q", "paper", "--sensitivity", "--model", mpath, "--json")
    d = json.loads(rj.out)
    assert [p["dithered"] for p in d["predictions"]] == [False, True]
    assert d["predictions"][0]["directions"]["+y"]["f50"] == pytest.approx(
        pred["directions"]["+y"]["f50"]
    )
    # dither: the narrow band gives a far lower threshold
    assert d["predictions"][1]["directions"]["+y"]["f50"] < 0.3 * f50


def test_cli_map_writes_table_and_png(tmp_path):
    """--map over a one-joint grid: one row per pose and condition, F50 per direction, the
    PNG beside the table; the rows equal predict() at those poses with the map's settings."""
    out = tmp_path / "map.csv"
    r = run_cli(
        "robot", "irb140", "--q", "paper", "--sensitivity", "--dither", "--grid",
        "q2=-0.2:0.2:3", "--map", out, "-q",
    )  # fmt: skip
    assert r.code == 0, r.err
    t = pd.read_csv(out)
    assert len(t) == 3 and t["dither"].all()
    assert np.allclose(t["q2"], [-0.2, 0.0, 0.2]) and np.allclose(t["q5"], math.pi / 2)
    assert (tmp_path / "map.png").stat().st_size > 10_000
    q = PAPER_POSE.copy()
    q[1] = 0.2
    pred = predict(ROBOT, q, condition_bands(6, dither=True), forces=80, draws=120,
                   rest_samples=5000)  # fmt: skip
    assert t["f50_+y"].iloc[2] == pytest.approx(pred["directions"]["+y"]["f50"])
    assert "wrote" in r.out and "simulator defaults" in r.out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--grid", "q7=0:1:3", "--map", "{tmp}/m.csv"],
            "--grid joint 'q7' is unknown; expected q1..q6 (irb140)",
        ),
        (
            ["--grid", "q2=0.5:-0.5:3", "--map", "{tmp}/m.csv"],
            "--grid q2=0.5:-0.5:3: expected START < STOP and COUNT >= 2 (got 0.5, -0.5, 3)",
        ),
        (
            ["--grid", "q2=-3:0.5:3", "--map", "{tmp}/m.csv"],
            "--grid q2=-3:0.5:3: [-3, 0.5] rad leaves joint 2's limits [-1.571, 1.92] rad",
        ),
        (
            ["--grid", "q2=a:0.5:3", "--map", "{tmp}/m.csv"],
            "--grid q2='a:0.5:3' is not START:STOP:COUNT (rad, rad, an integer)",
        ),
        (["--map", "{tmp}/m.csv"], "--map needs --grid qJ=START:STOP:COUNT[,qK=...] (the poses)"),
        (["--grid", "q2=0:1:2"], "--grid needs --map FILE (the table to write)"),
        (
            ["--grid", "q2=0:1:2", "--map", "{tmp}/m.txt"],
            "{tmp}/m.txt: expected a file name ending in .csv or .parquet (a sensitivity map "
            "table), not .txt",
        ),
        (
            ["--q", "0,0,0,0,3,0"],
            "--q: q5 = 3 rad is outside joint 5's limits [-2.007, 2.007] rad",
        ),
        (
            ["--force-range", "60:5"],
            "--force-range is '60:5'; expected MIN:MAX in N with 0 <= MIN < MAX",
        ),  # fmt: skip
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    """Each mistake: one line on stderr naming the option, the value and what was expected,
    exit status 2, nothing on stdout, nothing written."""
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    r = run_cli("robot", "irb140", "--sensitivity", *args)
    assert r.code == 2
    assert r.err == f"error: {message.replace('{tmp}', str(tmp_path))}\n"
    assert r.out == "" and not list(tmp_path.iterdir())


def test_model_of_another_robot_and_robot_without_defaults(tmp_path):
    """A model of the IRB140 for the UR10e, and the UR10e without a model (the simulator's
    bands are the IRB140's): one line each, exit 2."""
    mpath = paper_model().save(tmp_path / "m.toml")
    r = run_cli("robot", "ur10e", "--sensitivity", "--model", mpath)
    assert r.code == 2 and r.err == (
        f"error: {mpath}: the model is for robot irb140, not ur10e; expected a model "
        "identified on this robot\n"
    )
    r = run_cli("robot", "ur10e", "--sensitivity")
    assert r.code == 2 and r.err == (
        "error: the simulator's friction and noise are those of its 6-joint irb140, not of "
        "robot 'ur10e'; expected --model (a model file of this robot from ditherlab identify)\n"
    )
    r = run_cli("robot", "irb140", "--map", tmp_path / "x.csv")
    assert r.code == 2 and r.err == (
        "error: robot: --map, --grid, --model, --dither, --noise-level and --report need "
        "--sensitivity\n"
    )


def test_map_output_guard(tmp_path):
    """The map's outputs go through the output guard before any work: never over the model it
    reads (even with a table's suffix), never under a regular file."""
    mpath = paper_model().save(tmp_path / "m.parquet")
    before = mpath.read_bytes()
    r = run_cli("robot", "irb140", "--sensitivity", "--model", mpath, "--map", mpath,
                "--grid", "q2=0:1:2")  # fmt: skip
    assert (
        r.code == 2 and r.err == f"error: {mpath}: refusing to write over the input file {mpath}\n"
    )
    assert mpath.read_bytes() == before
    (tmp_path / "f").write_text("x")
    r = run_cli("robot", "irb140", "--sensitivity", "--map", tmp_path / "f" / "x.csv",
                "--grid", "q2=0:1:2")  # fmt: skip
    assert r.code == 2 and r.err == (
        f"error: {tmp_path / 'f' / 'x.csv'}: cannot write there: {tmp_path / 'f'} is a file, "
        "not a folder\n"
    )


# ------------------------------------------------------------------ against the simulator
@pytest.mark.study
def test_prediction_against_a_simulated_campaign_at_another_pose(tmp_path):
    """Paired campaigns (identification seed 41, evaluation seed 40, 40 pushes per direction
    and sign, one seed) at a pose far from the paper's, through ``ditherlab sweep``.
    40 pushes, not 20: with 20 the measured F50 is too loose a figure for a 25 % check — a
    change in the plant's last bit (docs/design/reproducible-plant.md) moves y between 21.6 and
    18.3 N (prediction 23.5 N: +28 %), and seed 42 gives z 12.4 N against seed 40's 24.6 N.
    With 40: x / y / z 36.0 / 22.8 / 22.0 N measured, 36.7 / 24.4 / 23.2 predicted (+2, +7,
    +5 %); seed 42 +8, -1, +11 %. The prediction plays the states a campaign leaves on this
    plant (``campaign_states``: the link's friction behind the spring must break before the
    torque moves); states uniform over the band predict 35-41 % low here (20 pushes: x 19.6 /
    33.0 N, y 14.1 / 21.6 N, z 14.1 / 23.1 N predicted / measured, against the campaign states'
    +11, +13, +0 %). Checked: every axis within 25 % without dither, and dither lowering the
    threshold, predicted (below 0.7) as measured (below 0.6)."""
    out = tmp_path / "sw"
    r = run_cli(
        "sweep", "--grid", "pose.q0=-0.4:0.35:-0.6:0.5:1.1:0.4", "--pushes-per-direction", "40",
        "--seed", "40", "--scheduler", "serial", "--bootstrap", "5", "-q", "-o", out,
    )  # fmt: skip
    assert r.code == 0, r.err
    row = pd.read_parquet(out / "sweep.parquet").iloc[0]
    for a in "xyz":
        meas, pred = row[f"nodither_f50_{a}"], row[f"pred_nodither_f50_{a}"]
        assert abs(pred - meas) <= 0.25 * meas, (a, pred, meas)
        assert row[f"pred_f50_{a}"] < 0.7 * pred and row[f"f50_{a}"] < 0.6 * meas

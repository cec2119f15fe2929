"""The LuGre plant (``ditherlab.sim_lugre``, ``simulate --plant lugre``): its friction's
presliding, hysteresis and steady state from the state equation, the drive's coloured noise and
LSB, the sensor's low-pass and drift, determinism, every planted effect on its joints only with
its recorded size, and its independence of the built-in plant."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ditherlab.io import read
from ditherlab.robot import RobotModel
from ditherlab.sim_lugre import EFFECTS, simulate_lugre
from ditherlab.sim_lugre.lugre_effects import SHARED, Planted
from ditherlab.sim_lugre.lugre_kernel import lugre_block
from ditherlab.sim_lugre.lugre_log import ar1, logged_torque, logged_wrench
from ditherlab.sim_lugre.lugre_params import draw_params
from ditherlab.sim_lugre.lugre_run import TrueRun

PKG = Path(__file__).resolve().parents[1] / "ditherlab"
NSUB, DT = 20, 2e-4  # substeps per 4 ms block, [s]
FS, FC, VS, S0, J, S2 = 2.0, 1.5, 0.01, 2e4, 0.1, 0.3  # one joint [N·m, rad/s, N·m/rad, kg m²]


def one_joint(kp: float = 0.0, kd: float = 0.0):
    """(state, fric, servo, block, mass) of a single joint without gravity: LuGre with Fs 2 N·m,
    Fc 1.5 N·m, vs 0.01 rad/s, sigma0 2e4 N·m/rad, sigma2 0.3 N·m·s/rad, inertia 0.1 kg m²."""
    s1 = 2 * 0.7 * np.sqrt(S0 * J)
    fric = np.array([[S0], [s1], [S2], [FC], [FS], [VS], [0.0], [1.0]])
    servo = np.zeros((11, 1))
    servo[0], servo[1], servo[3], servo[4], servo[10] = kp, kd, 1e9, 1e9, J
    return np.zeros((5, 1)), fric, servo, np.zeros((3, 1)), np.zeros((1, 1))


def drive_torque(torque: np.ndarray) -> np.ndarray:
    """q (N,) [rad] of the free joint under the applied torque (N,) [N·m], one per 4 ms block."""
    state, fric, servo, block, mass = one_joint()
    ref, wave, q = np.zeros((2, NSUB, 1)), np.zeros(NSUB), np.empty(len(torque))
    for k, tk in enumerate(torque):
        block[1, 0] = tk
        lugre_block(state, ref, fric, servo, block, mass, wave, DT)
        q[k] = state[0, 0]
    return q


def test_presliding_below_the_static_level_and_sliding_above():
    """Half of Fs held: the joint moves by LuGre's presliding law ``q = -(Fs/sigma0) ln(1 -
    T/Fs)`` (a displacement of the bristles' order, no sliding) and, released, comes back by
    ``(Fs/sigma0) ln(1 + T/Fs)``: part of it stays (LuGre's plastic drift below breakaway).
    1.2 Fs held: it slides away, far beyond the bristles."""
    ramp = np.linspace(0, 1, 125)
    profile = np.concatenate([ramp, np.ones(125), ramp[::-1], np.zeros(125)])
    q = drive_torque(0.5 * FS * profile)
    reach = -(FS / S0) * np.log(1 - 0.5)
    back = (FS / S0) * np.log(1 + 0.5)
    assert np.max(q) == pytest.approx(reach, rel=0.03)
    assert q[-1] == pytest.approx(reach - back, rel=0.05)
    q_slide = drive_torque(1.2 * FS * profile)
    assert np.max(q_slide) > 100 * reach


def test_hysteresis_loop_dissipates_energy():
    """A torque of 0.9 Fs back and forth at 1 Hz: the torque-displacement curve is a loop (the
    same torque at different displacements going up and down) with positive work per cycle."""
    t = np.arange(1000) * NSUB * DT
    torque = 0.9 * FS * np.sin(2 * np.pi * t)
    q = drive_torque(torque)
    last = t >= 3.0
    work = np.sum(torque[last][1:] * np.diff(q[last]))
    assert work > 0.02 * 0.9 * FS * np.ptp(q[last])
    up = last & (np.gradient(torque) > 0) & (np.abs(torque) < 0.1)
    down = last & (np.gradient(torque) < 0) & (np.abs(torque) < 0.1)
    assert abs(np.mean(q[up]) - np.mean(q[down])) > 0.05 * np.ptp(q[last])


@pytest.mark.parametrize("v", [0.003, 0.01, 0.03, 0.2])
def test_steady_sliding_friction_is_the_stribeck_curve(v):
    """Driven at constant velocity by a stiff servo, the motor torque settles on
    ``Fc + (Fs - Fc) exp(-(v/vs)²) + sigma2 v``."""
    state, fric, servo, block, mass = one_joint(kp=4e4, kd=800.0)
    ref, wave = np.zeros((2, NSUB, 1)), np.zeros(NSUB)
    for k in range(500):  # 2 s
        ts = (k * NSUB + np.arange(NSUB)) * DT
        ref[0, :, 0], ref[1, :, 0] = v * ts, v
        lugre_block(state, ref, fric, servo, block, mass, wave, DT)
    expected = FC + (FS - FC) * np.exp(-((v / VS) ** 2)) + S2 * v
    assert state[4, 0] == pytest.approx(expected, rel=0.01)


@pytest.fixture(scope="module")
def drawn():
    """The IRB140's parameters of seed 7."""
    robot = RobotModel.from_spec("irb140")
    return robot, draw_params(robot, np.random.default_rng(7))


def _true_run(n_samples: int, n: int, wrench: np.ndarray | None = None) -> TrueRun:
    t = np.arange(n_samples) * 0.004
    tau = 20 * np.sin(0.5 * t)[:, None] * np.ones(n)
    w = np.zeros((n_samples, 6)) if wrench is None else wrench
    rot = np.tile(np.eye(3), (n_samples, 1, 1))
    z = np.zeros((n_samples, n))
    return TrueRun(z, z, tau, z, w, rot, np.zeros(n_samples, bool), np.ones((n_samples, n)))


def test_torque_noise_is_coloured_with_the_drawn_coefficient(drawn):
    """The logged torque's noise (logged minus delivered torque) has the lag-1 autocorrelation
    of the drawn AR(1) coefficient, diluted by the LSB's white rounding error."""
    robot, p = drawn
    run = _true_run(40000, robot.n)
    e = logged_torque(run, p, Planted(robot.n), np.random.default_rng(1)) - run.tau_m
    lag1 = np.array([np.corrcoef(e[1:, j], e[:-1, j])[0, 1] for j in range(robot.n)])
    var_q = p.lsb**2 / 12
    expected = p.noise_ar * p.noise_std**2 / (p.noise_std**2 + var_q)
    assert np.allclose(lag1, expected, atol=0.03)
    assert np.all(lag1 > 0.2)  # not white
    x = ar1(np.random.default_rng(2), 40000, np.array([0.8]), np.array([2.0]))
    assert np.std(x) == pytest.approx(2.0, rel=0.05)


def test_logged_torque_is_whole_counts_of_the_lsb(drawn):
    robot, p = drawn
    planted = Planted(robot.n)
    planted.log_gain[1] = 1.1
    tau = logged_torque(_true_run(2000, robot.n), p, planted, np.random.default_rng(3))
    counts = tau / (p.lsb * planted.log_gain)
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(np.min(np.diff(np.unique(tau[:, 0]))) >= p.lsb[0] * (1 - 1e-9))


def test_sensor_low_pass_and_drift(drawn):
    """A 20 N step: the reading follows the first-order low-pass of the drawn cutoff exactly
    (noise, walk and warm-up off); with only the warm-up on, the zero reading drifts by the
    drawn amount; with only the random walk on, its spread grows as sqrt(t)."""
    robot, p = drawn
    n_samples = 25000
    t = np.arange(n_samples) * 0.004
    step = np.zeros((n_samples, 6))
    step[250:, 0] = 20.0
    quiet = {**p.ft, "force_noise": 0.0, "walk": 0.0, "warmup": 0.0}
    p.ft, saved = quiet, p.ft
    try:
        y = logged_wrench(_true_run(n_samples, robot.n, step), p, Planted(robot.n), t,
                          np.random.default_rng(0))  # fmt: skip
        k = np.arange(0, 100)
        expected = 20 * (1 - np.exp(-2 * np.pi * quiet["cutoff_hz"] * 0.004 * (k + 1)))
        assert np.allclose(y[250 + k, 0], expected, rtol=1e-9)
        p.ft = {**quiet, "warmup": 1.0, "warmup_time": 50.0}
        drift = logged_wrench(_true_run(n_samples, robot.n), p, Planted(robot.n), t,
                              np.random.default_rng(4))  # fmt: skip
        norm = np.linalg.norm(drift[:, :3], axis=1) / np.linalg.norm(drift[-1, :3])
        expected = (1 - np.exp(-1)) / (1 - np.exp(-t[-1] / 50.0))
        assert norm[0] < 1e-3 and norm[12500] == pytest.approx(expected, rel=0.01)
        p.ft = {**quiet, "walk": 0.05}
        short = _true_run(10000, robot.n)
        ends = [logged_wrench(short, p, Planted(robot.n), t[:10000],
                              np.random.default_rng(s))[[1000, -1], 0] for s in range(40)]  # fmt: skip
        spread = np.std(np.array(ends), axis=0)
        assert spread[1] / spread[0] == pytest.approx(np.sqrt(10), rel=0.35)
    finally:
        p.ft = saved


def test_same_seed_same_recording_bit_for_bit_through_the_cli(cli, tmp_path):
    """Twice the same seed: the same file, byte for byte; another seed: another file."""
    args = ["simulate", "push-campaign", "--plant", "lugre", "--pushes-per-direction", "1",
            "--external-load", "cable", "-q"]  # fmt: skip
    for name, seed in (("a", 4), ("b", 4), ("c", 5)):
        r = cli(*args, "--seed", seed, "-o", tmp_path / f"{name}.parquet")
        assert r.code == 0, r.err
    a, b, c = (tmp_path / f"{x}.parquet" for x in "abc")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_same_seed_same_arrays_with_effects_and_loads():
    kw = {"seed": 9, "duration": 4.0, "hidden": ["viscous:3@2", "ft_frame"],
          "external_loads": ["hose", "hand"]}  # fmt: skip
    a, b = simulate_lugre("excitation", **kw), simulate_lugre("excitation", **kw)
    assert a.data.equals(b.data) and a.meta == b.meta


@pytest.fixture(scope="module")
def base():
    """A clean 20 s excitation of the IRB140 on the LuGre plant (seed 5, dither on)."""
    return simulate_lugre("excitation", seed=5, duration=20.0)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_each_planted_effect_acts_on_its_joints_with_its_recorded_size(base, name):
    """Each effect changes the logged torque (or the F/T columns) against the same seed without
    it; per-joint effects on joints 2 and 3 alone (others < 5 % of them; an encoder offset or a
    heavier link also moves the gravity of the joints beyond: < 5 % of the larger); the recorded
    RMS per joint is the RMS of that difference."""
    rec = simulate_lugre("excitation", seed=5, duration=20.0, hidden=[name])
    truth = rec.meta["sim"]["hidden"][0]
    diff = np.sqrt(np.mean((rec.tau - base.tau) ** 2, axis=0))
    assert np.allclose(truth["tau_rms"], diff, rtol=1e-12, atol=1e-12)
    noise = np.asarray(rec.meta["sim"]["noise_std"])
    if name in ("ft_bias", "ft_drift", "ft_frame"):
        assert np.all(diff == 0)
        w = np.sqrt(np.mean((rec.wrench - base.wrench) ** 2, axis=0))
        assert np.allclose(truth["wrench_rms"], w) and np.max(w) > 0.1
        return
    assert np.max(diff / noise) > 0.5, diff / noise
    if name not in SHARED:
        assert truth["joints"] == [2, 3]
        pose = name in ("joint_offset", "dynamics")
        chosen = np.max(diff[[1, 2]]) if pose else np.min(diff[[1, 2]])
        assert np.max(diff[[0, 3, 4, 5]]) < 0.05 * chosen, diff


def test_temperature_columns_follow_log_temperature():
    on = simulate_lugre("standing", seed=1, duration=3.0, hidden=["temperature_friction:20@4"])
    off = simulate_lugre("standing", seed=1, duration=3.0, hidden=["temperature_friction:20@4"],
                         log_temperature=False)  # fmt: skip
    assert "temp_4" in on.data.columns and "temp_4" not in off.data.columns
    assert on.data["temp_4"].iloc[-1] > on.data["temp_4"].iloc[0] + 1
    assert on.data["temp_1"].iloc[-1] == on.data["temp_1"].iloc[0]
    assert "f_x" not in on.data.columns  # standing: no sensor


def test_external_loads_reach_the_sensor_and_the_torque():
    """A cable's pull shows in the F/T columns (5..15 N) and in the motors' torque."""
    clean = simulate_lugre("push-campaign", seed=2, duration=6.0)
    cable = simulate_lugre("push-campaign", seed=2, duration=6.0, external_loads=["cable"])
    pull = np.linalg.norm((cable.wrench - clean.wrench)[:, :3], axis=1)
    assert 3.0 < np.median(pull) < 20.0
    assert np.max(np.abs(cable.tau - clean.tau)) > 1.0


def test_refusals_are_one_line_and_write_nothing(cli, tmp_path):
    out = tmp_path / "x.parquet"
    cases = [
        (
            ["--plant", "lugre", "--hidden", "viscous@9"],
            r"joints '9'; expected joint numbers 1\.\.6",
        ),
        (["--plant", "lugre", "--hidden", "payload@2"], "payload acts on the whole arm"),
        (["--plant", "lugre", "--external-load", "rope"], "--external-load rope: unknown load"),
        (["--external-load", "cable"], "expected --plant lugre"),
        (["--plant", "wood"], "--plant wood: unknown plant"),
        (["--plant", "lugre", "--config", tmp_path], "expected --config only with --plant band"),
    ]
    for extra, pattern in cases:
        r = cli("simulate", "standing" if "lugre" in extra else "excitation", *extra, "-o", out)
        assert r.code == 2 and r.out == "" and "Traceback" not in r.err, r.err
        assert len(r.err.splitlines()) == 1 and __import__("re").search(pattern, r.err), r.err
        assert not out.exists()
    r = cli("simulate", "lead-through", "--plant", "lugre", "-o", out)
    assert r.code == 2 and "unknown for --plant lugre" in r.err and not out.exists()


def test_the_plant_imports_nothing_of_sim_or_physics():
    """Neither its modules' imports nor what they load pull in ditherlab.sim or physics."""
    for path in sorted((PKG / "sim_lugre").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            for name in names:
                assert not name.startswith(("ditherlab.sim.", "ditherlab.physics")), path
                assert name != "ditherlab.sim", path
    code = (
        "import sys, ditherlab.sim_lugre\n"
        "print(sorted(m for m in sys.modules if m.startswith(('ditherlab.sim.', "
        "'ditherlab.physics')) or m == 'ditherlab.sim'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=PKG.parent).stdout  # fmt: skip
    assert out.strip() == "[]"


def test_dither_feedforward_and_the_controllers_own_gravity():
    """--dither: while standing, the feedforward carries a square wave of the drawn amplitude
    per joint at 78.54 rad/s; --no-dither: none. With a planted payload the feedforward is
    still the description's gravity at the encoder angles (the controller's model lacks the
    payload) while the torque carries it."""
    on = simulate_lugre("push-campaign", seed=3, duration=4.0)
    off = simulate_lugre("push-campaign", seed=3, duration=4.0, dither=False)
    heavy = simulate_lugre("push-campaign", seed=3, duration=4.0, dither=False, hidden=["payload"])
    amp = np.asarray(on.meta["sim"]["params"]["dither_amp"])
    d = on.data["dither"].to_numpy(bool)
    assert d[-1] and not d[0] and not off.data["dither"].any()
    wave = on.tau_ffw[d] - off.tau_ffw[d]
    assert np.allclose(np.abs(wave), amp, rtol=0.02)
    assert on.meta["dither"]["omega"] == pytest.approx(2 * np.pi / 0.08)
    # the feedforward of each 4 ms step: the description's gravity at the encoder angles logged
    # at the end of the step before
    ctrl = RobotModel.from_spec("irb140").gravity(heavy.q[:-1])
    assert np.allclose(heavy.tau_ffw[1:], ctrl, atol=1e-9)
    assert np.median(np.abs(heavy.tau - off.tau)[:, 1]) > 5.0


def test_time_stamps_jitter_about_the_250_hz_grid():
    rec = simulate_lugre("standing", seed=4, duration=8.0)
    step = np.diff(rec.t)
    jitter = rec.meta["sim"]["params"]["jitter"]
    assert np.all(step > 0)
    assert np.std(step) == pytest.approx(np.sqrt(2) * jitter, rel=0.1)
    assert np.mean(step) == pytest.approx(0.004, abs=1e-5)


def test_noise_and_jitter_ranges_against_the_real_ur10e_log():
    """The figures docs/simulator.md quotes from the real UR10e log at rest
    (``recordings/ur10e-static.parquet``: current × drive gain, 100 Hz): the torque noise of its
    quietest tenth of 1 s windows, the lag-1 autocorrelation in its quietest window, the spread
    of its time steps; and the LuGre plant's UR10e noise range (0.01..0.08 Fs, Fs 2..5 % of the
    rated torque) holds each joint's figure."""
    rec = read(Path(__file__).resolve().parents[1] / "recordings" / "ur10e-static.parquet")
    w = 100  # 1 s
    std, lag1 = [], []
    for j in range(rec.n):
        x = rec.tau[:, j]
        spread = np.array([x[i : i + w].std() for i in range(0, len(x) - w, w)])
        i = int(np.argmin(spread)) * w
        seg = x[i : i + w] - x[i : i + w].mean()
        std.append(np.percentile(spread, 10))
        lag1.append(np.corrcoef(seg[1:], seg[:-1])[0, 1])
    assert np.allclose(std, [0.44, 0.42, 0.21, 0.11, 0.10, 0.13], atol=0.006)
    assert -0.09 < min(lag1) and max(lag1) < 0.14
    assert np.std(np.diff(rec.t)) == pytest.approx(0.94e-3, abs=0.01e-3)
    effort = RobotModel.from_spec("ur10e").effort_limit
    assert np.all(0.01 * 0.02 * effort < std) and np.all(np.array(std) < 0.08 * 0.05 * effort)

"""The compiled kernel agrees with the plain numpy reference step; the pieces both share (friction
law, window levels, dither mode switch) hold on their own."""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim.engine import Engine, Inputs, PlantExtras
from ditherlab.sim.params import default_params, load_params
from ditherlab.sim.plant import (
    ACT_NONE,
    ACT_RAMP_DOWN,
    ACT_UPDATE,
    EV_NONE,
    EV_START,
    EV_STOP,
    F_CLOCK,
    F_R,
    F_RD,
    I_MODE,
    X_I,
    _advance_ramps,
    _gear_torque,
    _stick_slip,
    _switch_mode,
    _window_levels,
    gear_twist,
)
from ditherlab.sim.scenarios import _plan_pushes, push_shape


def _short_run(reference: bool, overrides: dict | None = None):
    p = load_params(overrides={"dither": {"ramp_s": 0.06}, **(overrides or {})})
    ex = PlantExtras(
        load=np.full(6, 0.1),
        stribeck=np.full(6, 0.3),
        stribeck_v=0.02,
        ripple_amp=np.full(6, 0.3),
        ripple_freq=np.full(6, 36.0),
    )
    eng = Engine(p, RobotModel.from_spec("irb140"), extras=ex)
    N = 50
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(N, q0)
    inp.dither_cmd[3:45] = 1.0
    inp.tau_ext[20:, 1] = 4.0
    inp.push[12:, 2] = -15.0
    inp.dq_ref[:, 0] = 0.05  # joint 1 moves (it does not dither-hold: its Kp is 0 -> drift only)
    inp.q_ref[:, 0] += 0.05 * np.arange(N) / 250.0
    inp.fscale[:] = 0.9
    inp.noise[:] = np.random.default_rng(3).normal(size=(N, 6)) * 0.1
    state = eng.initial_state(q0)
    return eng.run(inp, state, reference=reference), state


def test_kernel_matches_reference():
    """Compiled kernel and numpy reference give the same torques, angles and loop signals."""
    a, sa = _short_run(False)
    b, sb = _short_run(True)
    assert np.allclose(a.tau, b.tau, atol=1e-6, rtol=0)
    assert np.allclose(a.q_motor, b.q_motor, atol=1e-9, rtol=0)
    assert np.allclose(a.q_link, b.q_link, atol=1e-9, rtol=0)
    assert np.allclose(a.amp_ffw, b.amp_ffw, atol=1e-6) and np.allclose(
        a.centre_ffw, b.centre_ffw, atol=1e-6
    )
    assert np.array_equal(a.dither, b.dither) and a.dither[10] and not a.dither[0]
    assert np.abs(a.amp_ffw).max() > 0  # the loops acted in this short run


#: the physics that is off by default (docs/design/sim-defaults.md, "Options that are off"), all
#: switched on
_OPTIONS_OFF = {
    "joints": {"lost_motion": 4e-4, "lost_motion_stiffness": 0.2},
    "servo": {"standstill_freeze": True, "standstill_leak": 2.0, "standstill_velocity": 0.02},
}


def test_kernel_matches_reference_with_the_options_off_by_default():
    """Lost motion and the standstill integral go into both steps alike, and they act: the
    torques differ from the run without them."""
    a, _ = _short_run(False, _OPTIONS_OFF)
    b, _ = _short_run(True, _OPTIONS_OFF)
    base, _ = _short_run(False)
    assert np.allclose(a.tau, b.tau, atol=1e-6, rtol=0)
    assert np.allclose(a.q_motor, b.q_motor, atol=1e-9, rtol=0)
    assert np.allclose(a.q_link, b.q_link, atol=1e-9, rtol=0)
    assert np.abs(a.tau - base.tau).max() > 0.1


def test_lost_motion_spring_and_its_inverse():
    """Inside the lost motion the spring has the inner stiffness, outside the full one from its
    edge; gear_twist inverts it (the initial state's twist under gravity)."""
    k, lm, lmk = 1.0e5, 2e-4, 0.25
    d = np.array([-1e-3, -2e-4, -1e-4, 0.0, 5e-5, 2e-4, 3e-4])
    ts = _gear_torque.py_func(k, 0.0, d, 0.0, 0.0, 0.0, lm, lmk)
    expect = np.where(np.abs(d) <= lm, k * lmk * d, k * (d - np.sign(d) * lm * (1 - lmk)))
    assert np.allclose(ts, expect, rtol=1e-12, atol=1e-9)
    assert np.isclose(ts[-1], k * lmk * lm + k * 1e-4)  # continuous at the edge, then k
    assert np.allclose(gear_twist(ts, k, lm, lmk), d, atol=1e-15)
    # pure backlash: the twist that carries a torque is the gap's half-width plus torque / k
    assert np.allclose(gear_twist(ts, k, lm, 0.0)[[0, -1]], [ts[0] / k - lm, ts[-1] / k + lm])
    # no lost motion: the plain spring, bit for bit
    assert np.array_equal(_gear_torque.py_func(k, 0.0, d, 0.0, 0.0, 0.0, 0.0, 0.0), k * d)


def test_standstill_freeze_holds_the_integral_and_leak_drains_it():
    """A reference step of 3e-5 rad on joint 1 (no gravity there) while standing still: the
    normal integral builds up and turns the motor against its own friction; frozen, the P-V loop
    alone gives Kv Kp e and the stuck motor stays; leaking at L, the integral settles where
    Ki Kp e = L I."""
    q0 = np.asarray(PAPER_POSE, dtype=float)
    step, runs = 3e-5, {}
    for name, servo in (
        ("normal", {}),
        ("freeze", {"standstill_freeze": True, "standstill_velocity": 1.0}),
        ("leak", {"standstill_leak": 5.0, "standstill_velocity": 1.0}),
    ):
        p = load_params(overrides={"servo": servo})
        eng = Engine(p, RobotModel.from_spec("irb140"))
        inp = Inputs.still(500, q0)
        inp.q_ref[10:, 0] += step  # after the first tick (its bumpless offset holds q0)
        state = eng.initial_state(q0)
        out = eng.run(inp, state)
        runs[name] = (out, state["x"][X_I, 0])
    kv, ki, kp = p["servo"]["kv"][0], p["servo"]["ki"][0], p["servo"]["kp"]
    out, i_end = runs["normal"]
    assert i_end > 2.0 and out.q_motor[-1, 0] - q0[0] > 0.3 * step
    out, i_end = runs["freeze"]
    assert i_end == 0.0 and np.allclose(out.tau[12:, 0], kv * kp * step, rtol=1e-6)
    assert np.array_equal(out.q_motor[:, 0], np.full(500, q0[0]))
    out, i_end = runs["leak"]
    assert abs(i_end - ki * kp * step / 5.0) < 0.03 * ki * kp * step / 5.0


def test_stick_slip_holds_inside_band_and_slips_outside():
    """A stuck body holds any torque up to Fs; beyond it slips with Fc + viscous (implicitly)."""
    h, m = 1e-3, 2.0
    assert _stick_slip(m, 0.99 * h * 5.0, h, 5.0, 4.0, 1.0, True, 0.0) == (0.0, True)
    v, stuck = _stick_slip(m, 1.01 * h * 5.0, h, 5.0, 4.0, 1.0, True, 0.0)
    assert not stuck and np.isclose(v, (1.01 * h * 5.0 - h * 4.0) / (m + h * 1.0))


def test_stick_slip_sticks_instead_of_reversing():
    """A slipping body whose update would reverse its velocity sticks (no chatter)."""
    h, m = 1e-3, 2.0
    v, stuck = _stick_slip(m, m * 1e-4 - h * 1.0, h, 5.0, 4.0, 0.0, False, 1e-4)
    assert v == 0.0 and stuck


def test_window_levels_follow_the_pseudo_code():
    """Centre = window mean; upper/lower = means of the samples above/below it (the centre when
    there are none); only the ``fill`` filled samples count."""
    hist = np.random.default_rng(5).normal(size=(3, 40))
    hist[2] = 1.5  # flat: no sample above or below the centre
    for fill in (1, 7, 40):
        for j in range(3):
            w = hist[j, :fill]
            c, up, lo = _window_levels(hist, j, fill)
            assert np.isclose(c, w.mean())
            assert np.isclose(up, w[w > c].mean() if (w > c).any() else c)
            assert np.isclose(lo, w[w < c].mean() if (w < c).any() else c)


def test_dither_mode_switch_and_ramps():
    """Off -> ramp up (clock reset) -> on -> ramp down -> off; updates every ``upd`` samples; a
    command during the ramp-down restarts the ramp up without resetting the clock."""
    ist, fst = np.zeros(4, dtype=np.int64), np.zeros(3)
    fst[F_CLOCK] = 9.0
    assert _switch_mode(ist, fst, False) == EV_NONE and ist[I_MODE] == 0
    assert _advance_ramps(ist, fst, 4.0, 2) == ACT_NONE
    assert _switch_mode(ist, fst, True) == EV_START
    assert ist[I_MODE] == 1 and fst[F_CLOCK] == 0.0
    acts = [_advance_ramps(ist, fst, 4.0, 2) for _ in range(6)]
    assert acts == [ACT_NONE, ACT_UPDATE] * 3
    assert ist[I_MODE] == 2 and fst[F_R] == 1.0
    assert _switch_mode(ist, fst, True) == EV_NONE
    assert _switch_mode(ist, fst, False) == EV_STOP and ist[I_MODE] == 3
    assert _advance_ramps(ist, fst, 4.0, 2) == ACT_RAMP_DOWN and fst[F_RD] == 0.25
    fst[F_CLOCK] = 3.0
    assert _switch_mode(ist, fst, True) == EV_START
    assert ist[I_MODE] == 1 and fst[F_CLOCK] == 3.0 and fst[F_R] == 0.0
    _switch_mode(ist, fst, False)
    for _ in range(4):
        assert _advance_ramps(ist, fst, 4.0, 2) == ACT_RAMP_DOWN
    assert ist[I_MODE] == 0 and fst[F_RD] == 1.0


def test_plant_coriolis_is_pinocchios():
    """The plant's Coriolis and centrifugal torque ``sum_ab Gam[j, a, b] v_a v_b`` (Christoffel
    symbols from the mass matrix's finite differences) equals pinocchio's
    ``ID(q, v, 0) - g(q)`` at random poses and velocities; without it the plant lacked the
    0.4-0.6 N·m RMS (up to 4 N·m) that the excitation's velocities give on joints 1-2, which the
    links' regressor of ``dynamics`` then could not fit away."""
    robot = RobotModel.from_spec("irb140")
    eng = Engine(load_params(), robot)
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, 6)
        v = rng.uniform(-1.0, 1.0, 6)
        Gam = eng._dynamics(q, q)[-1]
        c = np.einsum("jab,a,b->j", Gam, v, v)
        want = (
            robot.inverse_dynamics(q[None], v[None], np.zeros((1, 6)))[0]
            - robot.gravity(q[None])[0]
        )
        assert np.allclose(c, want, atol=1e-4 * max(1.0, np.abs(want).max())), (c, want)
        assert np.abs(want).max() > 0.05  # the check is not vacuous


def test_push_shape_release_fraction():
    """The operator's let-go: 0.5 is the symmetric raised cosine; 0.8 rises over the first 0.2
    of the push to its full size and falls over the rest, continuously and monotonically."""
    T = 1.0
    tau = np.arange(0, 1000) / 1000.0
    assert np.array_equal(push_shape(tau, T, 0.5), 0.5 * (1 - np.cos(2 * np.pi * tau / T)))
    s = push_shape(tau, T, 0.8)
    assert s[200] == pytest.approx(1.0) and s[0] == 0.0 and s[-1] < 1e-4
    assert np.all(np.diff(s[:200]) > 0) and np.all(np.diff(s[200:]) < 0)
    assert np.abs(np.diff(s)).max() < 0.02  # no jump at the peak
    assert s[100] == pytest.approx(0.5) and s[600] == pytest.approx(0.5)


def test_cli_release_fraction_out_of_range_is_one_line(cli, tmp_path):
    """A share outside [0, 1] names the file, the key, the value and the range; exit 2."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[push_campaign]\nrelease_fraction = 1.5\n")
    r = cli("simulate", "push-campaign", "-o", tmp_path / "x.parquet", "--config", cfg, "-q")
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.code == 2 and len(lines) == 1
    assert f"{cfg}: push_campaign.release_fraction: got 1.5; expected a number" in lines[0]
    assert not (tmp_path / "x.parquet").exists()


def test_push_order_experiments_keep_the_shuffled_plan():
    """``push_campaign.order``: "shuffled" is the plan as before (the same pushes, durations and
    rests for a seed); "per-axis" and "per-direction" are the same pushes run as one experiment
    per axis or per axis and sign, each in the shuffled order."""
    pc = default_params()["push_campaign"] | {"pushes_per_direction": 4}
    plans = {}
    for how in ("shuffled", "per-axis", "per-direction"):
        plans[how] = _plan_pushes(pc | {"order": how}, np.random.default_rng(7))
    legacy = {k: v for k, v in pc.items() if k != "order"}
    assert plans["shuffled"] == _plan_pushes(legacy, np.random.default_rng(7))
    key = lambda p: (p["axis"], p["sign"], p["magnitude"])  # noqa: E731
    shuffled = [key(p) for p in plans["shuffled"]]
    for plan in plans.values():
        assert sorted(key(p) for p in plan) == sorted(shuffled)
    axes = [p["axis"] for p in plans["per-axis"]]
    assert axes == ["x"] * 8 + ["y"] * 8 + ["z"] * 8
    dirs = [(p["axis"], p["sign"]) for p in plans["per-direction"]]
    assert dirs == [(a, s) for a in "xyz" for s in (1, -1) for _ in range(4)]
    # within an experiment, the shuffled order
    x_shuffled = [key(p) for p in plans["shuffled"] if p["axis"] == "x"]
    assert [key(p) for p in plans["per-axis"][:8]] == x_shuffled
    assert len({p["sign"] for p in plans["per-axis"][:8]}) == 2


def test_cli_push_order_unknown_is_one_line(cli, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[push_campaign]\norder = "by-size"\n')
    r = cli("simulate", "push-campaign", "-o", tmp_path / "x.parquet", "--config", cfg, "-q")
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert r.code == 2 and len(lines) == 1, r.err
    assert lines[0].endswith(
        f"{cfg}: push_campaign.order: got 'by-size'; expected one of 'shuffled', 'per-axis', "
        "'per-direction'"
    ), lines[0]
    assert not (tmp_path / "x.parquet").exists()

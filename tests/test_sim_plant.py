"""The compiled kernel agrees with the plain numpy reference step; the pieces both share (friction
law, window levels, dither mode switch) hold on their own."""

from __future__ import annotations

import numpy as np

from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim.engine import Engine, Inputs, PlantExtras
from ditherlab.sim.params import load_params
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
    _advance_ramps,
    _stick_slip,
    _switch_mode,
    _window_levels,
)


def _short_run(reference: bool):
    p = load_params(overrides={"dither": {"ramp_s": 0.06}})
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

"""The simulator shows the paper's phenomena (Figs. 2, 4, 5) because of its physics.

Runs: the IRB140 standing in the paper's pose, one joint (2) dithering, an external torque
applied at that joint's link with a smooth 0.3 s onset (held 2 s). Numbers measured with the
defaults are in the module docstring of ditherlab/sim/plant.py and in the final report.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim import plant as K
from ditherlab.sim.engine import Engine, Inputs
from ditherlab.sim.params import load_params

J = 1  # joint 2 (0-based)
FS_HZ = 250.0
T_PUSH, T_RISE, T_HOLD = 4.0, 0.3, 2.0


@functools.lru_cache(maxsize=1)
def _robot() -> RobotModel:
    return RobotModel.from_spec("irb140")


@functools.lru_cache(maxsize=32)
def _run(
    share: float | None = None,
    ext: float = 0.2,
    dither: bool = True,
    afrac: float = 0.9,
    noise: bool = False,
    substeps: int = 2,
    T: float = 7.0,
):
    """(t, outputs, engine) for an external torque of ``ext`` x Fs on joint 2 (``share``:
    the friction's motor share, None for the default of irb140.toml)."""
    if share is None:
        share = load_params()["friction"]["motor_share"]
    p = load_params(
        overrides={
            "friction": {"motor_share": share},
            "dither": {"joints": [i == J for i in range(6)], "amplitude_fraction": afrac},
            "timing": {"plant_substeps": substeps},
        }
    )
    eng = Engine(p, _robot())
    N = int(T * FS_HZ)
    t = np.arange(N) / FS_HZ
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(N, q0)
    if dither:
        inp.dither_cmd[int(0.5 * FS_HZ) :] = 1.0
    if noise:
        inp.noise[:] = np.random.default_rng(0).normal(size=(N, 6)) * 0.03 * eng.fs
    prof = 0.5 * (1 - np.cos(np.pi * np.clip((t - T_PUSH) / T_RISE, 0, 1)))
    inp.tau_ext[:, J] = ext * eng.fs[J] * prof * (t < T_PUSH + T_RISE + T_HOLD)
    out = eng.run(inp, eng.initial_state(q0))
    return t, out, eng


def _extract(tau: np.ndarray, period: int = 20) -> np.ndarray:
    """Paper Fig. 4: per one-period window, the mean of the upper and the lower means."""
    sig = np.full(len(tau), np.nan)
    for k in range(period, len(tau) + 1):
        w = tau[k - period : k]
        c = w.mean()
        sig[k - 1] = 0.5 * (w[w > c].mean() + w[w < c].mean()) if np.ptp(w) > 0 else c
    return sig


def _shift(t, sig, fs, ext, lo, hi):
    base = np.nanmean(sig[(t > T_PUSH - 0.8) & (t < T_PUSH)])
    during = np.nanmean(sig[(t > T_PUSH + lo) & (t < T_PUSH + hi)])
    return (base - during) / (ext * fs)  # the external torque lowers the torque reference


def test_no_dither_half_band_leaves_torque_flat():
    """Without dither a steady external torque of half the band leaves the mean torque unchanged."""
    t, o, eng = _run(ext=0.5, dither=False, noise=True)
    fs = eng.fs[J]
    before = o.tau[(t > 3.0) & (t < T_PUSH), J].mean()
    during = o.tau[(t > T_PUSH + 1.0) & (t < T_PUSH + 2.2), J].mean()
    sem = 0.03 * fs / np.sqrt(250)  # noise standard error of a 1 s mean
    assert abs(during - before) < 4 * sem
    # the logged (motor) angle stays put; the link moves only by the gear spring's deflection
    assert np.ptp(o.q_motor[(t > 3.0) & (t < 6.0), J]) < 1e-6
    assert np.ptp(o.q_link[(t > 3.0) & (t < 6.0), J]) < 0.5 * fs / eng.jp[1, J]


def test_no_dither_beyond_band_moves_and_torque_follows():
    """Without dither an external torque beyond the band moves the joint and the torque follows."""
    t, o, eng = _run(ext=1.3, dither=False)
    fs = eng.fs[J]
    before = o.tau[(t > 3.0) & (t < T_PUSH), J].mean()
    during = o.tau[(t > T_PUSH + 1.0) & (t < T_PUSH + 2.2), J].mean()
    assert before - during > (1.3 - 1.0) * fs  # at least the part beyond the band
    assert np.ptp(o.q_motor[(t > 3.0) & (t < 6.0), J]) > 1e-5


def test_dither_extracts_a_fifth_of_the_band_with_lag_and_underestimate():
    """With dither at 90 % an external torque of 20 % of the band shifts the extracted signal by
    at least half of it, late and (while the push builds up) less than fully."""
    t, o, eng = _run(ext=0.2, noise=True)
    fs = eng.fs[J]
    sig = _extract(o.tau[:, J])
    early = _shift(t, sig, fs, 0.2, 0.3, 0.8)
    late = _shift(t, sig, fs, 0.2, 1.6, 2.2)
    assert early >= 0.5 and late >= 0.5
    assert early < 1.0  # the underestimate while the push builds up
    # lag: the extracted signal reaches half of its shift after the torque does
    base = np.nanmean(sig[(t > T_PUSH - 0.8) & (t < T_PUSH)])
    half = base - 0.5 * late * 0.2 * fs
    k = np.flatnonzero((t > T_PUSH) & (sig < half))[0]
    lag = t[k] - (T_PUSH + T_RISE / 2)
    assert 0.03 < lag < 0.4


def test_no_dither_hides_what_dither_shows():
    """The same sub-band torque that dither extracts leaves the undithered torque flat."""
    t, o, eng = _run(ext=0.2, dither=False)
    sig = _extract(o.tau[:, J])
    assert abs(_shift(t, sig, eng.fs[J], 0.2, 0.3, 2.2)) < 0.02


def test_dither_loops_settle_within_two_seconds_and_hold():
    """Centre and amplitude loops reach their set-points within about 2 s of the start and hold."""
    t, o, eng = _run(ext=0.0, noise=True)
    fs = eng.fs[J]
    start = 0.5
    settled = (t > start + 2.0) & (t < T_PUSH)
    assert np.all(np.abs(o.amp_meas[settled, J] - 0.9 * fs) < 0.06 * fs)
    assert np.all(np.abs(o.centre_meas[settled, J] - o.centre_ref[settled, J]) < 0.06 * fs)
    # held: the feedforward hardly moves once settled (hold band of 2 % of the band)
    assert np.ptp(o.amp_ffw[settled, J]) < 0.1 * fs
    # ramped: no dither amplitude at the first sample, full set-point only after the ramp
    k0 = int(start * FS_HZ)
    assert o.amp_ffw[k0, J] == 0.0 and o.amp_ref[k0 + 125, J] < 0.6 * 0.9 * fs


def test_servo_counteracts_dither_and_vibration_is_small():
    """The feedforward must exceed the measured amplitude (servo counteracts) and the arm
    vibrates less than about 1e-4 rad (0.01 motor rad)."""
    t, o, eng = _run(ext=0.0)
    fs = eng.fs[J]
    settled = (t > 3.0) & (t < T_PUSH)
    assert o.amp_ffw[settled, J].mean() > 1.02 * o.amp_meas[settled, J].mean()
    assert o.amp_ffw[settled, J].max() <= eng.params["dither"]["amplitude_cap"] * fs
    k = np.flatnonzero(settled)
    vib_link = np.mean([np.ptp(o.q_link[i : i + 20, J]) / 2 for i in range(k[0], k[-1] - 20, 20)])
    vib_motor = np.mean([np.ptp(o.q_motor[i : i + 20, J]) / 2 for i in range(k[0], k[-1] - 20, 20)])
    assert 1e-6 < vib_link < 1.2e-4 and vib_motor < 1.2e-4


def test_band_location_changes_results_qualitatively():
    """With all friction on the motor side the dither never moves the joint and the servo does
    not counteract it, unlike the paper; the split default shows both."""
    t, o, eng = _run(share=1.0, ext=0.0)
    settled = (t > 3.0) & (t < T_PUSH)
    assert np.ptp(o.q_motor[settled, J]) == 0.0
    assert o.amp_ffw[settled, J].mean() < 1.01 * o.amp_meas[settled, J].mean()


def test_friction_is_step_independent():
    """Halving the plant step leaves the logged torque essentially unchanged (no chatter)."""
    t, a, eng = _run(ext=0.2, substeps=2, T=5.5)
    _, b, _ = _run(ext=0.2, substeps=4, T=5.5)
    fs = eng.fs[J]
    sa, sb = _extract(a.tau[:, J]), _extract(b.tau[:, J])
    assert abs(_shift(t, sa, fs, 0.2, 0.3, 1.4) - _shift(t, sb, fs, 0.2, 0.3, 1.4)) < 0.1
    ok = ~np.isnan(sa)
    assert np.allclose(sa[ok], sb[ok], atol=0.05 * fs)


@pytest.mark.parametrize("ext", [0.1, 0.5])
def test_dither_extracts_other_sub_band_torques(ext):
    """Torques of 10 % and 50 % of the band are extracted by at least half, not more than 1.2x."""
    t, o, eng = _run(ext=ext)
    shift = _shift(t, _extract(o.tau[:, J]), eng.fs[J], ext, 0.3, 0.8)
    assert 0.5 < shift < 1.2


def _six_dithering_vibration(fractions) -> tuple[np.ndarray, np.ndarray, float]:
    """All six joints dithering at ``fractions`` of their bands: mean half peak-to-peak per
    dither period of the motor and the link angles (6,) [arm rad], and of the tool (m)."""
    p = load_params(overrides={"dither": {"amplitude_fraction": list(fractions)}})
    eng = Engine(p, _robot())
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(1500, q0)
    inp.dither_cmd[125:] = 1.0
    o = eng.run(inp, eng.initial_state(q0))
    ks = range(750, 1480, 20)

    def vib(q):
        return np.array([[np.ptp(q[i : i + 20, j]) / 2 for i in ks] for j in range(6)]).mean(1)

    tool = _robot().tool_pose(o.q_link[750:])[:, :3, 3]
    return vib(o.q_motor), vib(o.q_link), float(np.ptp(tool, axis=0).max() / 2)


def test_all_six_dithering_set_points_follow_the_papers_vibration_rule():
    """The default set-points are the paper's rule (§III-B, §IV-B) with all six dithering: every
    motor vibrates about 1e-4 arm rad (0.01 motor rad) at most, the tool less than 0.1 mm, and
    raising any one joint by 10 % of its band makes that joint's motor exceed it."""
    default = load_params()["dither"]["amplitude_fraction"]
    motor, link, tool = _six_dithering_vibration(default)
    assert np.all(motor < 1.1e-4) and np.all(link < 1.1e-4) and tool < 1e-4
    assert np.all(motor > 1e-5)  # the motors do move on their gear springs
    for j in range(6):
        if default[j] >= 0.9:
            continue
        raised = list(default)
        raised[j] += 0.1
        assert _six_dithering_vibration(raised)[0][j] > 1.15e-4, j
    # all six at 90 % (the one-joint set-point of Fig. 4) would shake the wrist visibly
    assert np.all(_six_dithering_vibration([0.9] * 6)[0][3:] > 5e-4)


# --- lost motion of the gear, off by default (docs/design/sim-defaults.md, "Options that are off")
def _state_after_push(joints: dict, axis: int, magnitude: float, j: int) -> float:
    """The link-side friction torque of joint ``j`` (0-based) as a fraction of its static level,
    4.5 s after a 1 s raised-cosine push of ``magnitude`` N along base ``axis`` (0 x, 1 y) at the
    paper's pose: the gear spring's torque minus gravity (none on joints 1, 4-6 there)."""
    eng = Engine(load_params(overrides={"joints": joints}), _robot())
    N = int(6 * FS_HZ)
    t = np.arange(N) / FS_HZ
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(N, q0)
    m = (t >= 0.5) & (t < 1.5)
    inp.push[m, axis] = magnitude * 0.5 * (1 - np.cos(2 * np.pi * (t[m] - 0.5)))
    state = eng.initial_state(q0)
    eng.run(inp, state)
    x, jp = state["x"], eng.jp
    ts = K._gear_torque.py_func(
        jp[K.KG, j], 0.0, x[K.X_QM, j], x[K.X_Q, j], 0.0, 0.0, jp[K.LM, j], jp[K.LMK, j]
    )
    return float(ts / jp[K.FS_O, j])


def test_lost_motion_recentres_a_joint_without_gravity_after_a_push():
    """Measured mechanism of the lost-motion option: a 35 N push along y slips joint 1 (no
    gravity at the paper's pose); on the plain spring the servo's return leaves its link friction
    at 0.58 of the static level, with a 2e-4 rad gap the motor returns into the gap and the link
    is unloaded (0); a 50 N push still leaves the sliding level (0.85) on both."""
    assert _state_after_push({}, 1, 35.0, 0) == pytest.approx(0.58, abs=0.05)
    assert abs(_state_after_push({"lost_motion": 2e-4}, 1, 35.0, 0)) < 0.05
    for lm in (0.0, 2e-4):
        assert abs(_state_after_push({"lost_motion": lm}, 1, 50.0, 0)) > 0.8


def test_lost_motion_rattles_the_motor_beyond_the_vibration_rule():
    """Why the lost motion is off by default: with a 1e-4 rad gap the motors of the joints without
    gravity load (1, 4-6) rattle in it at 1.45-1.61e-4 arm rad with the default set-points (0.75-
    0.89e-4 without), beyond the paper's ~1e-4, while their arm side moves less than half that."""
    assert load_params()["joints"]["lost_motion"] == [0.0] * 6  # the default: the plain spring
    eng = Engine(load_params(overrides={"joints": {"lost_motion": 1e-4}}), _robot())
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(1500, q0)
    inp.dither_cmd[125:] = 1.0
    o = eng.run(inp, eng.initial_state(q0))
    ks = range(750, 1480, 20)

    def vib(q):
        return np.array([[np.ptp(q[i : i + 20, j]) / 2 for i in ks] for j in range(6)]).mean(1)

    motor, link = vib(o.q_motor), vib(o.q_link)
    assert np.all(motor[[0, 3, 4, 5]] > 1.4e-4)
    assert np.all(link[[0, 3, 4, 5]] < 0.5 * motor[[0, 3, 4, 5]])

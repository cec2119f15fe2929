"""simulate(): scenarios, determinism, pairing, metadata, hidden effects, CLI errors."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from ditherlab.core.errors import ConfigError
from ditherlab.sim import simulate

SEED = 3


@functools.lru_cache(maxsize=32)
def _sim(dither: bool = False, hidden: tuple = (), per: int = 1, seed: int = SEED, **kw):
    cfg = kw.pop("config", None)
    return simulate(
        "push-campaign",
        seed=seed,
        dither=dither,
        hidden=hidden,
        pushes_per_direction=per,
        config=dict(cfg) if cfg else None,
        **kw,
    )


def _exc(rec):
    """Mask of the excitation segment (joints moving)."""
    return rec.t < rec.meta["sim"]["timeline"]["excitation_end"]


def _rest(rec):
    """Mask of the still time before the first push."""
    tl = rec.meta["sim"]["timeline"]
    return (rec.t > tl["excitation_end"] + 0.5) & (rec.t < tl["first_push"])


def test_same_seed_identical_output():
    """Two runs with the same seed and options are identical."""
    a = simulate("push-campaign", seed=SEED, dither=True, pushes_per_direction=1)
    b = _sim(dither=True)
    assert a.data.equals(b.data)
    assert a.meta == b.meta


def test_dithered_and_undithered_campaigns_are_paired():
    """With and without dither the push plan and the F/T columns are identical."""
    a, b = _sim(dither=False), _sim(dither=True)
    assert a.meta["sim"]["pushes"] == b.meta["sim"]["pushes"]
    assert np.array_equal(a.wrench, b.wrench)
    assert not a.dither.any() and b.dither.any()


def test_campaign_plan_and_columns():
    """Pushes cover ±x, ±y, ±z with the requested count, magnitudes in range, F = -push."""
    rec = _sim(per=2)
    pushes = rec.meta["sim"]["pushes"]
    assert len(pushes) == 12
    assert sorted({(p["axis"], p["sign"]) for p in pushes}) == sorted(
        (a, s) for a in "xyz" for s in (1, -1)
    )
    assert all(5.0 <= p["magnitude"] <= 60.0 and 0.5 <= p["duration"] <= 2.0 for p in pushes)
    p = pushes[0]
    k = np.argmin(np.abs(rec.t - (p["t0"] + p["duration"] / 2)))
    axis = "xyz".index(p["axis"])
    assert np.isclose(rec.wrench[k, axis], -p["sign"] * p["magnitude"], atol=1.5)
    for col in ("dq_1", "tau_ffw_6", "f_x", "m_z", "dither", "push"):
        assert col in rec.data.columns
    assert rec.sample_rate == pytest.approx(250.0)


def test_meta_holds_parameters_and_truth():
    """meta['sim'] holds the parameters, bands, dither amplitudes and the seed."""
    rec = _sim(dither=True)
    sim = rec.meta["sim"]
    assert sim["seed"] == SEED and sim["scenario"] == "push-campaign"
    assert sim["params"]["friction"]["static"] == sim["bands"]["static"]
    amps = sim["dither_amplitudes"]
    assert all(
        ff > 0.9 * sp for ff, sp in zip(amps["feedforward_mean"], amps["set_point"], strict=True)
    )
    assert all(
        abs(m - sp) < 0.1 * sp
        for m, sp in zip(amps["measured_mean"], amps["set_point"], strict=True)
    )


def test_still_torque_without_dither_is_gravity_within_band():
    """Standing still, the logged torque is gravity plus friction inside the band."""
    rec = _sim()
    g = rec.robot().gravity(rec.q)
    fs = np.asarray(rec.meta["sim"]["bands"]["static"])
    resid = (rec.tau - g)[_rest(rec)]
    assert np.all(np.abs(resid.mean(axis=0)) < fs)


def _moving_friction(rec, j, lo=0.05, hi=10.0):
    """Mean of (tau - gravity) * sign(dq) for joint j while moving at lo..hi rad/s."""
    m = _exc(rec) & (np.abs(rec.dq[:, j]) > lo) & (np.abs(rec.dq[:, j]) < hi)
    g = rec.robot().gravity(rec.q[m])
    return np.mean((rec.tau[m, j] - g[:, j]) * np.sign(rec.dq[m, j]))


def test_excitation_shows_coulomb_and_viscous():
    """While moving, the torque carries friction of about Fc + Fv |v| against the motion."""
    rec = _sim()
    fc = np.asarray(rec.meta["sim"]["bands"]["coulomb"])
    for j in range(3):
        f = _moving_friction(rec, j, 0.1)
        assert 0.7 * fc[j] < f < 1.6 * fc[j] + 1.0


def test_hidden_load_friction_raises_friction_of_loaded_joints():
    """load_friction raises the moving friction of joint 2 (gravity loaded) by about size*|g|."""
    base, hid = _sim(), _sim(hidden=("load_friction:0.1",))
    d2 = _moving_friction(hid, 1, 0.1) - _moving_friction(base, 1, 0.1)
    d1 = _moving_friction(hid, 0, 0.1) - _moving_friction(base, 0, 0.1)
    g2 = abs(base.robot().gravity(base.q[0])[0, 1])
    assert 0.5 * 0.1 * g2 * 0.85 < d2 < 1.5 * 0.1 * g2
    assert abs(d1) < 0.3 * d2
    assert hid.meta["sim"]["hidden"][0]["name"] == "load_friction"


def test_hidden_temperature_friction_falls_as_joint_warms():
    """temperature_friction: the joints warm up, the logged temperature rises, friction falls."""
    cfg_dict = {"hidden": {"temperature_friction": {"time_constant": 0.5}}}
    base = _sim()
    hid = simulate(
        "push-campaign",
        seed=SEED,
        dither=False,
        pushes_per_direction=1,
        hidden=["temperature_friction:40"],
        config=cfg_dict,
    )
    assert hid.temp is not None and hid.temp[-1, 0] - hid.temp[0, 0] > 39.0
    late = 1.5
    m = _exc(base) & (base.t > late)
    for j in range(3):
        mm = m & (np.abs(base.dq[:, j]) > 0.1)
        fb = np.mean(
            (base.tau[mm, j] - base.robot().gravity(base.q[mm])[:, j]) * np.sign(base.dq[mm, j])
        )
        mh = m & (np.abs(hid.dq[:, j]) > 0.1)
        fh = np.mean(
            (hid.tau[mh, j] - hid.robot().gravity(hid.q[mh])[:, j]) * np.sign(hid.dq[mh, j])
        )
        assert fh < 0.75 * fb
    no_log = simulate(
        "push-campaign",
        seed=SEED,
        dither=False,
        pushes_per_direction=1,
        hidden=["temperature_friction:40"],
        config=cfg_dict,
        log_temperature=False,
    )
    assert no_log.temp is None and np.array_equal(no_log.tau, hid.tau)


def test_hidden_position_ripple_is_periodic_in_angle():
    """position_ripple adds a torque periodic in the joint angle with the injected amplitude."""
    base, hid = _sim(hidden=("position_ripple:0",)), _sim(hidden=("position_ripple:1.0",))
    assert hid.duration > _sim().duration  # a longer excitation sweeps the ripple
    m = _exc(hid) & (np.abs(hid.dq[:, 0]) > 0.05)
    z = hid.meta["sim"]["params"]["hidden"]["position_ripple"]["periods_per_rev"]
    q = hid.q[m, 0]
    resid = hid.tau[m, 0] - hid.robot().gravity(hid.q[m])[:, 0]
    A = np.column_stack(
        [
            np.sin(z * q),
            np.cos(z * q),
            np.sign(hid.dq[m, 0]),
            hid.dq[m, 0],
            hid.ddq[m, 0],
            np.ones(m.sum()),
        ]
    )
    coef = np.linalg.lstsq(A, resid, rcond=None)[0]
    assert 0.7 < np.hypot(coef[0], coef[1]) < 1.3
    mb = _exc(base) & (np.abs(base.dq[:, 0]) > 0.05)
    Ab = np.column_stack(
        [
            np.sin(z * base.q[mb, 0]),
            np.cos(z * base.q[mb, 0]),
            np.sign(base.dq[mb, 0]),
            base.dq[mb, 0],
            base.ddq[mb, 0],
            np.ones(mb.sum()),
        ]
    )
    cb = np.linalg.lstsq(Ab, base.tau[mb, 0] - base.robot().gravity(base.q[mb])[:, 0], rcond=None)[
        0
    ]
    assert np.hypot(cb[0], cb[1]) < 0.2


def test_hidden_payload_adds_gravity_torque():
    """payload: an unmodelled 2 kg at the tool shifts the still torque of joint 2 by ~m g 0.45 m."""
    base, hid = _sim(), _sim(hidden=("payload:2",))
    d = hid.tau[_exc(hid), 1].mean() - base.tau[_exc(base), 1].mean()
    assert 0.7 * 2 * 9.81 * 0.45 < abs(d) < 1.3 * 2 * 9.81 * 0.45
    assert hid.meta["robot"] == "irb140"  # the controller's model knows nothing of it


def test_hidden_attenuation_lag_weakens_and_delays_the_torque():
    """attenuation_lag: the arm's torque responds less to the same sensed push, and later."""
    cfg = {"push_campaign": {"magnitude_min": 55.0, "magnitude_max": 60.0}}
    base = simulate("push-campaign", seed=SEED, dither=True, pushes_per_direction=1, config=cfg)
    hid = simulate(
        "push-campaign",
        seed=SEED,
        dither=True,
        pushes_per_direction=1,
        config=cfg,
        hidden=["attenuation_lag:0.5"],
    )
    assert np.array_equal(base.wrench, hid.wrench)  # the sensor sees the whole push
    resp_b, resp_h, lag_b, lag_h = [], [], [], []
    for p in base.meta["sim"]["pushes"]:
        m = (base.t >= p["t0"]) & (base.t < p["t0"] + p["duration"] + 0.5)
        pre = (base.t > p["t0"] - 0.5) & (base.t < p["t0"])
        for rec, resp, lag in ((base, resp_b, lag_b), (hid, resp_h, lag_h)):
            d = np.abs(rec.tau[m] - rec.tau[pre].mean(axis=0)).sum(axis=1)
            resp.append(d.max())
            lag.append(np.sum(rec.t[m] * d) / np.sum(d))
    assert np.mean(resp_h) < 0.8 * np.mean(resp_b)
    assert np.all(np.subtract(lag_h, lag_b) > 0) and np.mean(np.subtract(lag_h, lag_b)) > 0.01


def test_hidden_stribeck_raises_low_speed_friction():
    """stribeck: friction near zero speed rises, at high speed it does not."""
    base, hid = _sim(), _sim(hidden=("stribeck:0.5",))
    fc = np.asarray(base.meta["sim"]["bands"]["coulomb"])
    low = _moving_friction(hid, 0, 0.002, 0.02) - _moving_friction(base, 0, 0.002, 0.02)
    high = _moving_friction(hid, 0, 0.2) - _moving_friction(base, 0, 0.2)
    assert low > 0.1 * fc[0] and abs(high) < 0.05 * fc[0]


def test_hidden_ft_bias_offsets_the_sensor_only():
    """ft_bias: the F/T columns carry a constant offset of the given size; torques are unchanged."""
    base, hid = _sim(), _sim(hidden=("ft_bias:4",))
    d = (hid.wrench - base.wrench).mean(axis=0)
    assert np.linalg.norm(d[:3]) == pytest.approx(4.0, rel=1e-6)
    assert np.allclose(d, hid.meta["sim"]["hidden"][0]["bias"])
    assert np.array_equal(hid.tau, base.tau)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scenario": "jump"}, "scenario 'jump' is unknown"),
        ({"hidden": ["warp"]}, "--hidden warp: unknown effect"),
        ({"hidden": ["payload:-2"]}, "negative size"),
        ({"magnitude_min": -5.0}, "option 'magnitude_min' = -5.0 is negative"),
        ({"bogus": 1}, "option 'bogus' is unknown"),
        ({"config": {"servo": {"kpp": 1}}}, "servo.kpp: unknown key; expected one of ki, kp, kv"),
        ({"config": {"friction": {"static": [1, 2]}}}, "friction.static: got 2 values; expected 6"),
    ],
)
def test_bad_options_raise_config_error(kwargs, message):
    """Bad scenario, effect, size, option or config key raise ConfigError naming it."""
    scenario = kwargs.pop("scenario", "push-campaign")
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(".", r"\.")):
        simulate(scenario, pushes_per_direction=1, **kwargs)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"moving_pushes": -1}, "excitation.moving_pushes: got -1; expected an integer >= 0"),
        ({"stroke_min_s": 0}, "excitation.stroke_min_s: got 0; expected a number > 0"),
    ],
)
def test_bad_excitation_config_raises_config_error(table, message):
    """A negative count or a zero duration in the excitation table is refused by name (rather
    than ending in a numpy traceback or a division by zero)."""
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        simulate("excitation", config={"excitation": table})


def test_cli_writes_a_readable_recording(cli, tmp_path):
    """`ditherlab simulate` writes a recording that reads back with the same data."""
    out = tmp_path / "sim.parquet"
    r = cli(
        "simulate",
        "push-campaign",
        "-o",
        out,
        "--seed",
        SEED,
        "--no-dither",
        "--pushes-per-direction",
        "1",
        "--hidden",
        "ft_bias:2",
        "-q",
    )
    assert r.code == 0, r.err
    from ditherlab.io import read

    rec = read(out)
    ref = _sim(hidden=("ft_bias:2",))
    assert np.array_equal(rec.tau, ref.tau)
    assert rec.meta["sim"]["hidden"][0]["size"] == 2.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "nope"], "error: scenario 'nope' is unknown"),
        (["simulate", "push-campaign", "--hidden", "warp"], "error: --hidden warp: unknown"),
        (["simulate", "push-campaign", "--pushes-per-direction", "-1"], "is negative"),
        (["simulate", "push-campaign", "--hidden", "payload:-1"], "negative size"),
    ],
)
def test_cli_bad_options_one_line_exit_2(cli, tmp_path, args, message):
    """Bad CLI options end in one error line on stderr and exit status 2."""
    r = cli(*args, "-o", tmp_path / "x.parquet", "-q")
    assert r.code == 2
    lines = [ln for ln in r.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0]
    assert not (tmp_path / "x.parquet").exists()


def test_cli_unknown_config_key(cli, tmp_path):
    """A config file with an unknown key names the file and the key, exit 2."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[dither]\nfrequence = 70\n")
    r = cli("simulate", "push-campaign", "-o", tmp_path / "x.parquet", "--config", cfg, "-q")
    assert r.code == 2 and f"{cfg}: dither.frequence: unknown key; expected one of " in r.err


@functools.lru_cache(maxsize=1)
def _lead():
    return simulate("lead-through", seed=SEED)


def test_lead_through_follows_the_operator_and_stops_when_released():
    """Lead-through: the tool moves along each push (z, y, x, combined) and stops after release."""
    rec = _lead()
    tool = rec.robot().tool_pose(rec.q)[:, :3, 3]
    for s in rec.meta["sim"]["operator"]:
        t_release = s["t0"] + 0.8 + s["flat"]
        i0, i1 = np.searchsorted(rec.t, [s["t0"], t_release])
        move = tool[i1] - tool[i0]
        along = move @ np.asarray(s["direction"])
        assert along > 0.05 and along > 0.9 * np.linalg.norm(move)
        i2, i3 = np.searchsorted(rec.t, [t_release + 1.0, t_release + 2.4])
        assert np.linalg.norm(tool[i3] - tool[i2]) / (rec.t[i3] - rec.t[i2]) < 0.005  # [m/s]


def test_lead_through_dithers_only_when_still():
    """Lead-through: dither is on while standing still and ramped off once the tool moves."""
    rec = _lead()
    assert rec.dither[(rec.t > 1.5) & (rec.t < 4.0)].all()
    for s in rec.meta["sim"]["operator"]:
        late = (rec.t > s["t0"] + 0.4 + s["flat"] - 0.5) & (rec.t < s["t0"] + 0.4 + s["flat"])
        assert not rec.dither[late].any()  # off by the end of each push (1 s ramp)
    est = rec.data[["fhat_x", "fhat_y", "fhat_z"]].to_numpy()
    s = rec.meta["sim"]["operator"][2]  # the x push, mid-way
    k = np.searchsorted(rec.t, s["t0"] + 0.4 + s["flat"] / 2)
    assert abs(est[k, 0] - s["magnitude"]) < 0.25 * s["magnitude"]


def test_cli_no_log_temperature(cli, tmp_path):
    """--no-log-temperature hides the temperature columns of temperature_friction."""
    out = tmp_path / "t.parquet"
    r = cli(
        "simulate",
        "push-campaign",
        "-o",
        out,
        "--pushes-per-direction",
        "1",
        "--hidden",
        "temperature_friction:10",
        "--no-log-temperature",
        "-q",
    )
    assert r.code == 0, r.err
    from ditherlab.io import read

    rec = read(out)
    assert rec.temp is None and rec.meta["sim"]["hidden"][0]["log_temperature"] is False


def test_cli_cable_pull_is_carried_and_measured(cli, tmp_path):
    """``environment.cable_force`` pulls the tool with a constant force: the F/T columns read
    the force the robot exerts (minus the pull) between pushes, and the standing joints carry
    it: the logged torque minus gravity is ``J^T F`` within the friction band of the still
    regime (here the mean over the rest after the last push, against ``J^T F`` per joint,
    within the band ±Fs)."""
    from ditherlab.core.timeseries import jtf
    from ditherlab.io import read

    cfg = tmp_path / "cable.toml"
    cfg.write_text("[environment]\ncable_force = [0.0, 12.0, -20.0]\n")
    out = tmp_path / "c.parquet"
    r = cli(
        "simulate",
        "push-campaign",
        "-o",
        out,
        "--config",
        cfg,
        "--no-dither",
        "--pushes-per-direction",
        "1",
        "--seed",
        "5",
        "-q",
    )
    assert r.code == 0, r.err
    rec = read(out)
    assert rec.meta["sim"]["params"]["environment"]["cable_force"] == [0.0, 12.0, -20.0]
    rest = rec.data["push"].to_numpy() < 0
    rest &= rec.t > rec.meta["sim"]["timeline"]["first_push"]
    np.testing.assert_allclose(rec.wrench[rest, :3].mean(axis=0), [0.0, -12.0, 20.0], atol=0.1)
    robot = rec.robot()
    ext = jtf(robot.jacobian(rec.q[rest]), rec.wrench[rest])
    fric = rec.tau[rest] - robot.gravity(rec.q[rest]) - ext
    fs = np.array(rec.meta["sim"]["params"]["friction"]["static"])
    assert np.all(np.abs(fric.mean(axis=0)) <= fs), fric.mean(axis=0)

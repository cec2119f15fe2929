"""Rest stretches and departures from rest without a sensor (ditherlab.analysis.rest), identify's
--window / --exclude, and the no-sensor report's events (ditherlab.analysis.no_sensor)."""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.analysis.no_sensor import _events, variant_label
from ditherlab.analysis.rest import kept_rows, parse_span, scan_rest
from ditherlab.app.identify import _outside
from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.robot import RobotModel
from ditherlab.sim import simulate

#: a simulated push campaign whose pushes are 0 N: a clean standing log
NO_PUSHES = {"push_campaign": {"magnitude_min": 0.0, "magnitude_max": 0.0}}


def _standing(x: np.ndarray, rate: float = 100.0) -> Recording:
    """An IRB140 standing at one pose whose torque residual (tau - gravity) is ``x (N, 6)``."""
    t = np.arange(len(x)) / rate
    q = np.tile([0.0, 0.3, 0.2, 0.0, 1.0, 0.0], (len(x), 1))
    tau = RobotModel.from_spec("irb140").gravity(q) + x
    return Recording.from_arrays(RecordingArrays(t, q, tau), {"robot": "irb140"}, name="s")


def test_pushes_depart_and_rest_levels_after_them_do_not():
    """Two pushes of 15 N·m on joint 2 in noise of 0.4 N·m depart; the static friction's rest
    points between them (shifts of 1 N·m) do not, nor the quiet joints."""
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.4, (6000, 6))  # 60 s at 100 Hz
    x[1000:1400, 1] += 15.0  # 10-14 s
    x[1400:, 1] += 1.0  # the rest point after the push
    x[2500:, 1] -= 1.5  # and after a small nudge
    x[4000:4300, 1] -= 15.0  # 40-43 s
    x[4300:, 1] += 0.8
    events = scan_rest(_standing(x)).events
    assert [(e.start, e.end, e.joints) for e in events] == [(10.0, 14.0, (2,)), (40.0, 43.0, (2,))]


def test_no_departure_in_pure_noise():
    """The false-alarm rate is stated at 1 % per log: 20 logs of noise alone give at most one."""
    alarms = 0
    for seed in range(20):
        x = np.random.default_rng(seed).normal(0, 0.3, (3000, 6))
        alarms += int(bool(scan_rest(_standing(x)).events))
    assert alarms <= 1


@pytest.mark.parametrize("dither", [True, False])
def test_a_clean_simulated_standing_log_has_no_departure(dither):
    """A simulated standing log whose pushes are 0 N (start-up motion, the dither switched on and
    off, creep after the servo settles): nothing departs."""
    rec = simulate(
        "push-campaign", seed=31, dither=dither, pushes_per_direction=2, config=NO_PUSHES
    )
    assert scan_rest(rec).events == []


def test_simulated_pushes_the_torque_shows_are_found():
    """A dithered push campaign: at least 60 % of the pushes of 30 N or more overlap a departure
    (a push the static friction holds leaves no trace in the torque to find), and the
    departures cover little besides pushes."""
    rec = simulate("push-campaign", seed=32, dither=True, pushes_per_direction=2)
    found = scan_rest(rec)
    F = np.linalg.norm(rec.wrench[:, :3], axis=1)
    on = F > 5.0
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(int), 0]))
    big = [(rec.t[a], rec.t[b - 1]) for a, b in zip(edges[::2], edges[1::2], strict=True)
           if F[a:b].max() >= 30.0]  # fmt: skip
    hit = [any(x0 <= t1 and x1 >= t0 for x0, x1 in found.spans()) for t0, t1 in big]
    assert len(big) >= 6 and np.mean(hit) >= 0.6, (hit, found.lines())
    assert found.event_s < 3.0 * on.sum() * (rec.t[1] - rec.t[0])


def test_spans_and_windows():
    t = np.arange(0, 10, 0.5)
    keep = kept_rows(t, [(1, 3), (6, 8)], [(2, 2.5)])
    assert set(t[keep]) == {1.0, 1.5, 3.0, 6.0, 6.5, 7.0, 7.5, 8.0}
    out = _outside([(1, 3), (6, 8)], 0.0, 9.5)
    dropped = ~kept_rows(t, (), out)
    assert (dropped == ~kept_rows(t, [(1, 3), (6, 8)])).all()
    assert parse_span("12.5:40", "--window") == (12.5, 40.0)
    for bad in ("abc", "5:1", "1:2:3", "nan:4"):
        with pytest.raises(ConfigError, match="--window"):
            parse_span(bad, "--window")


def test_events_of_the_estimate():
    """An event is where the interval excludes zero, merged across short gaps, with its peak."""
    t = np.arange(0, 10, 0.01)
    F = np.zeros((len(t), 3))
    det = np.zeros((len(t), 3), bool)
    F[200:300, 0] = 20.0
    det[200:300, 0] = True
    det[320:340, 1] = True  # 0.2 s after: the same event
    det[800:805, 2] = True  # 0.05 s: too short
    events, mask = _events(t, F, det)
    assert len(events) == 1
    assert events[0]["start"] == pytest.approx(2.0) and events[0]["end"] == pytest.approx(3.39)
    assert events[0]["peak"] == pytest.approx(20.0)
    assert mask.sum() == 140
    assert variant_label("nodither_band") == "without dither"
    assert "ignores the dither" in variant_label("nodither_band", True)


def test_ur10e_hand_pushes_are_found_and_left_out(cli, shared_data, tmp_path):
    """The UR10e standing and pushed by hand four times (no sensor): identify lists the four
    pushes (their starts within 0.5 s of where the residual leaves rest) and leaves them out;
    a window outside the log is one line, exit 2, nothing written."""
    rec = shared_data / "ur10e" / "ur-static.csv"
    m = tmp_path / "m.toml"
    r = cli("identify", rec, "--mapping", "ur10e", "--assume-no-force", "-o", m,
            "--bootstrap", "0", "-q")  # fmt: skip
    assert r.code == 0, r.err
    starts = [float(x.split("-")[0]) for x in r.out.splitlines() if x.startswith("  3")]
    for push in (336.85, 345.3, 358.9, 371.8):  # where the residual leaves rest, by eye
        assert min(abs(s - push) for s in starts) < 0.5, r.out
    assert "departures from rest left out" in m.read_text()
    bad = tmp_path / "bad.toml"
    r = cli("identify", rec, "--mapping", "ur10e", "--assume-no-force", "-o", bad,
            "--window", "1:5", "-q")  # fmt: skip
    assert r.code == 2 and r.err.count("\n") == 1 and "--window 1:5 lies outside" in r.err
    assert not bad.exists()


def test_the_python_api_leaves_the_pushes_out_too(shared_data):
    """dl.identify(..., assume_no_force=True) leaves the same four pushes out as the CLI and
    notes them; without that the still band of joint 2 spans the pushes (-30 .. +19 N·m)."""
    import ditherlab as dl

    rec = dl.read(shared_data / "ur10e" / "ur-static.csv", mapping="ur10e")
    m = dl.identify(rec, assume_no_force=True, n_boot=0)
    assert m.notes.count("ur-static.csv 3") == 4
    band = m.regimes["still"]
    assert band.tau_max[1] - band.tau_min[1] < 10.0
    w = dl.identify(rec, assume_no_force=True, n_boot=0, windows=[(333.0, 336.0)])
    assert w.regimes["still"].tau_max[1] - w.regimes["still"].tau_min[1] < 3.0

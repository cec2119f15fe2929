"""Rest stretches and departures from rest without a sensor (ditherlab.analysis.rest), identify's
--window / --exclude, and the no-sensor report's events (ditherlab.analysis.no_sensor)."""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.analysis.no_sensor import _events, variant_label
from ditherlab.analysis.rest import (
    BLOCK,
    _block_means,
    _departures,
    _segments,
    kept_rows,
    parse_span,
)
from ditherlab.app.identify import _outside
from ditherlab.core.errors import ConfigError
from ditherlab.estimator.formulation import normal_quantile


def _scan(x: np.ndarray, rate: float = 100.0):
    """The rule's steps 1-4 on a residual (N, n) at rest throughout."""
    t = np.arange(len(x)) / rate
    idx = ((t - t[0]) // BLOCK).astype(np.int64)
    means, valid = _block_means(x, np.ones(len(x), bool), idx)
    z = normal_quantile(1 - 0.01 / (2 * valid.sum() * x.shape[1]))
    segs, sd = _segments(means, valid, z)
    zs = normal_quantile(1 - 0.01 / (2 * len(segs) * x.shape[1]))
    loc, scale, dep = _departures(means, segs, sd / np.sqrt(2), zs)
    return segs, dep, loc


def test_pushes_depart_and_rest_levels_after_them_do_not():
    """Two pushes of 15 N·m on joint 2 in noise of 0.4 N·m depart; the static friction's rest
    points between them (shifts of 1 N·m) do not, nor the quiet joint 1."""
    rng = np.random.default_rng(0)
    N = 6000  # 60 s at 100 Hz
    x = rng.normal(0, 0.4, (N, 2))
    x[1000:1400, 1] += 15.0  # 10-14 s
    x[1400:, 1] += 1.0  # the rest point after the push
    x[2500:, 1] -= 1.5  # and after a small nudge
    x[4000:4300, 1] -= 15.0  # 40-43 s
    x[4300:, 1] += 0.8
    segs, dep, _ = _scan(x)
    spans = [(a * BLOCK, b * BLOCK) for (a, b), d in zip(segs, dep, strict=True) if d]
    assert len(spans) == 2
    assert spans[0][0] == pytest.approx(10.0, abs=0.3) and spans[0][1] == pytest.approx(14, abs=0.3)
    assert spans[1][0] == pytest.approx(40.0, abs=0.3) and spans[1][1] == pytest.approx(43, abs=0.3)


def test_no_departure_in_pure_noise():
    """The false-alarm rate is stated at 1 % per log: 20 logs of noise alone give at most one."""
    alarms = 0
    for seed in range(20):
        x = np.random.default_rng(seed).normal(0, 0.3, (3000, 3))
        _, dep, _ = _scan(x)
        alarms += int(dep.any())
    assert alarms <= 1


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

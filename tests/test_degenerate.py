"""Degenerate logs through every command: one or two rows, a gap of 10⁷ s in ``t``, constant
signals, a single regime (never still), no pushes, estimates of another recording. Each is
handled (exit 0) or refused with one exact line and exit status 2, in bounded time."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from synthetic import Q0, push_recording

import ditherlab.io as dio
from ditherlab.analysis.diagnosis_sums import Windows
from ditherlab.core.timeseries import smooth_derivative
from ditherlab.data.recording import Recording, derivative_by_segment

#: CPU seconds any command may take on these small logs: a bound on the work (a gap of 10⁷ s must
#: not turn into 10⁹ samples), counted in this process's CPU time so that a busy machine does not
#: fail it
BOUND_S = 60.0


def run(cli, *args):
    t0 = time.process_time()
    res = cli(*args)
    assert time.process_time() - t0 < BOUND_S, args
    return res


def assert_refused(res, line: str) -> None:
    assert (res.code, res.out, res.err) == (2, "", f"error: {line}\n"), (res.code, res.err)


def assert_ok(res) -> None:
    assert res.code == 0 and "Traceback" not in res.err and "error" not in res.err, res.err


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A short synthetic push log (robot at rest, 4 pushes), its model and its estimates."""
    from ditherlab.analysis.identification import identify

    d = tmp_path_factory.mktemp("degenerate")
    rec, _ = push_recording(0, magnitudes=(20.0, 40.0), axes=("x",))
    path = dio.write(rec, d / "rec.parquet")
    model = identify([rec], n_boot=0).save(d / "model.toml")
    return d, rec, path, model


def _write(rec: Recording, data, path):
    return dio.write(Recording(data.reset_index(drop=True), rec.meta), path)


@pytest.mark.parametrize("rows", [1, 2])
def test_one_or_two_rows_every_command(cli, base, tmp_path, rows):
    """One or two rows: info, replay, view and convert work; identify, diagnose and report
    refuse with one line (moving_mask once broadcast a window longer than the log)."""
    _, rec, _, model = base
    p = _write(rec, rec.data.iloc[:rows], tmp_path / "short.parquet")
    info = run(cli, "info", p)
    assert_ok(info)
    if rows == 1:
        assert "rate       unknown (one sample)" in info.out
        assert json.loads(run(cli, "info", p, "--json").out)["sample_rate_hz"] is None
    assert_refused(
        run(cli, "identify", p, "-o", tmp_path / "m.toml", "-q"),
        f"{p}: no joint has 200 samples in any regime (still, dither, moving); record longer",
    )
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", p, "--model", model, "-o", est, "-q"))
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q", "--recording", p),
        f"{est}: no pushes found (the F/T force never rose above the push threshold); the "
        "report needs push experiments",
    )
    assert_refused(
        run(cli, "diagnose", p, "--model", model, "-o", tmp_path / "diag", "-q", "--no-history"),
        f"{p}: no sample left to score ({rows} rows; stick transitions, velocity reversals and "
        "the first dither period are not scored); expected a longer recording",
    )
    assert_ok(run(cli, "view", p, "--model", model, "--save", tmp_path / "v.rrd", "-q"))
    for out in ("c.csv", "bag"):
        assert_ok(run(cli, "convert", p, tmp_path / out))
        assert len(dio.read(tmp_path / out)) == rows
    assert not (tmp_path / "m.toml").exists() and not (tmp_path / "rep").exists()


def test_a_huge_gap_in_t(cli, base, tmp_path):
    """A gap of 10⁷ s in the middle of ``t``: identify and diagnose work (identify and
    diagnose raised LinAlgError: Singular matrix from the derivative across the gap, and
    diagnose allocated 2·10⁷ window slots per joint: 6.5 GB, minutes)."""
    _, rec, _, model = base
    data = rec.data.copy()
    t = data["t"].to_numpy().copy()
    t[len(t) // 2 :] += 1e7
    data["t"] = t
    p = _write(rec, data, tmp_path / "gap.parquet")
    assert_ok(run(cli, "info", p))
    assert_ok(run(cli, "identify", p, "-o", tmp_path / "m.toml", "-q", "--bootstrap", "2"))
    res = run(cli, "diagnose", p, "--model", model, "-q", "--no-history", "--json")
    assert_ok(res)
    worst = json.loads(res.out)["residual"]["worst_windows"]
    assert worst and all(w["t0"] < 1e3 or w["t0"] >= 1e7 for w in worst)
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", p, "--model", model, "-o", est, "-q"))
    assert_ok(run(cli, "report", est, "-o", tmp_path / "rep", "-q", "--bootstrap", "5"))
    assert_ok(run(cli, "view", p, "--save", tmp_path / "v.rrd", "-q"))


def test_derivative_by_segment_and_sparse_windows():
    """The derivative is taken on each stretch between gaps (the whole log's call when there
    is none); the worst windows keep only the half-windows that hold samples."""
    rng = np.random.default_rng(0)
    t = np.arange(2000) * 0.004
    x = rng.normal(size=(2000, 2))
    same = derivative_by_segment(t, x, 0.004, True)
    assert np.array_equal(same, smooth_derivative(t, x, dt=0.004, uniform=True))
    tg = t.copy()
    tg[1000:] += 1e7
    d = derivative_by_segment(tg, x, 0.004, False)
    assert np.isfinite(d).all()
    for a, b in ((0, 1000), (1000, 2000)):
        ref = smooth_derivative(tg[a:b], x[a:b], dt=0.004, uniform=False)
        assert np.array_equal(d[a:b], ref)
    w = Windows("gap", tg[0], tg[-1], 2)
    assert w.nwin == int(np.ceil((tg[-1] - tg[0]) / 0.5))  # 2·10⁷ windows in the span...
    assert w.parts == [] and w.result() == []  # ...and no memory for them


def test_constant_signals(cli, base, tmp_path):
    """Every column constant: identify and diagnose refuse with the same sentence, rather than
    fitting a noise of 1e-9 N·m (a model that trusts the torque absolutely) or warning of a
    division by zero. info, replay, view and convert work."""
    _, rec, _, model = base
    data = rec.data.copy()
    for c in data.columns:
        if c != "t":
            data[c] = data[c].iloc[0]
    p = _write(rec, data, tmp_path / "const.parquet")
    assert_ok(run(cli, "info", p))
    assert_refused(
        run(cli, "identify", p, "-o", tmp_path / "m.toml", "-q", "--bootstrap", "2"),
        f"{p}: the torque residual of joint 1 does not vary (noise 1e-09 N·m); expected a "
        "measured tau_1, which always has noise: is it constant or not logged?",
    )
    assert_refused(
        run(cli, "diagnose", p, "--model", model, "-q", "--no-history"),
        f"{p}: the torque residual of joint 1 does not vary (noise 0 N·m); expected a "
        "measured tau_1, which always has noise: is it constant or not logged?",
    )
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", p, "--model", model, "-o", est, "-q"))
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q"),
        f"{est}: no pushes found (the F/T force never rose above the push threshold); the "
        "report needs push experiments",
    )
    assert_ok(run(cli, "view", p, "--save", tmp_path / "v.rrd", "-q"))
    assert_ok(run(cli, "convert", p, tmp_path / "c.csv"))


def test_never_still_report_refuses(cli, base, tmp_path):
    """A single regime, the robot always moving, with pushes: there is no rest to take a noise
    level from, so the report refuses with one line (rather than three numpy warnings, "All-NaN
    axis", "Mean of empty slice", and every push judged against a NaN noise level). identify,
    diagnose, replay work."""
    _, rec, _, _ = base
    data = rec.data.copy()
    t = data["t"].to_numpy()
    for j in range(6):  # 0.05 rad/s on every joint, all the time
        data[f"q_{j + 1}"] = Q0[j] + 0.05 * t
        data[f"dq_{j + 1}"] = 0.05
    p = _write(rec, data, tmp_path / "moving.parquet")
    m = tmp_path / "m.toml"
    assert_ok(run(cli, "identify", p, "-o", m, "-q", "--bootstrap", "2"))
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", p, "--model", m, "-o", est, "-q"))
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q"),
        f"{est}: 4 pushes but no rest (the robot never stands still more than 1 s from a "
        "push); the noise level that every detection is judged against is measured at rest; "
        "for the force error of a log without push experiments: ditherlab diagnose REC --model M",
    )
    assert not (tmp_path / "rep").exists()
    assert_ok(run(cli, "diagnose", p, "--model", m, "-q", "--no-history"))


def test_never_moving_and_no_pushes(cli, base, tmp_path):
    """The robot never moves (the base log) and a log without pushes: identify, replay,
    diagnose work; the report refuses the one without pushes."""
    _, rec, path, model = base
    data = rec.data.copy()
    for c in ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z"):
        data[c] = 0.0
    p = _write(rec, data, tmp_path / "nopush.parquet")
    for src in (path, p):
        assert_ok(run(cli, "identify", src, "-o", tmp_path / f"m_{src.stem}.toml", "-q",
                      "--bootstrap", "2"))  # fmt: skip
        assert_ok(run(cli, "diagnose", src, "--model", model, "-q", "--no-history"))
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", p, "--model", model, "-o", est, "-q"))
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q"),
        f"{est}: no pushes found (the F/T force never rose above the push threshold); the "
        "report needs push experiments",
    )


def test_report_refuses_estimates_of_another_recording(cli, base, tmp_path):
    """`report EST --recording OTHER` would build a report from the estimates of one recording
    and the figures of another; it refuses as `view --estimates` does (the same check)."""
    _, rec, path, model = base
    est = tmp_path / "est.parquet"
    assert_ok(run(cli, "replay", path, "--model", model, "-o", est, "-q"))
    other = _write(rec, rec.data.iloc[:3000], tmp_path / "other.parquet")
    line = (
        f"{est}: the estimates come from another recording: column t has {len(rec)} samples, "
        f"{other} has 3000"
    )
    assert_refused(run(cli, "view", other, "--estimates", est, "--save", tmp_path / "v.rrd"), line)
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q", "--recording", other), line
    )
    assert not (tmp_path / "rep").exists()
    # a recording with the same time stamps and metadata but other F/T columns
    data = rec.data.copy()
    data["f_x"] = -data["f_x"]
    twin = _write(rec, data, tmp_path / "twin.parquet")
    assert_refused(
        run(cli, "report", est, "-o", tmp_path / "rep", "-q", "--recording", twin),
        f"{est}: the estimates come from another recording: the dither flag or the F/T columns "
        f"differ from those of {twin}",
    )
    assert_ok(run(cli, "report", est, "-o", tmp_path / "rep", "-q", "--recording", path))

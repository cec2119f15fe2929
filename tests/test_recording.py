"""Tests of the Recording: validation messages, slicing, differentiation, regimes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ditherlab.core.errors import RecordingError, RobotError
from ditherlab.core.names import DITHER, MOVING, STILL
from ditherlab.data.recording import SCHEMA, Recording, RecordingArrays, differentiate, regimes

META = {"schema": SCHEMA, "robot": "irb140"}


def table(n_rows: int = 50, n: int = 2, dt: float = 0.004) -> pd.DataFrame:
    t = np.arange(n_rows) * dt
    cols = {"t": t}
    for j in range(n):
        cols[f"q_{j + 1}"] = np.sin(t + j)
    for j in range(n):
        cols[f"tau_{j + 1}"] = np.cos(t + j)
    return pd.DataFrame(cols)


def test_valid_table_is_kept_with_float64():
    """A valid table passes, its integer columns become float64 and the joint count is found."""
    df = table()
    df["q_1"] = np.arange(len(df))  # integers
    rec = Recording(df, META, name="a.csv")
    assert rec.n == 2 and len(rec) == 50
    assert rec.data["q_1"].dtype == np.float64
    assert rec.q.shape == (50, 2) and rec.tau.shape == (50, 2)


def test_missing_required_column():
    """A missing tau column is named, with the joint count that implies it."""
    df = table().drop(columns="tau_2")
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == (
        "run.csv: required column tau_2 is missing (found q_1..q_2, so tau_1..tau_2 [N·m] are "
        "expected)"
    )


def test_missing_time_column():
    """A table without t is refused with the column named."""
    with pytest.raises(RecordingError, match=r"^run.csv: required column t is missing$"):
        Recording(table().drop(columns="t"), META, name="run.csv")


def test_nan_is_reported_with_its_time_span():
    """NaN values are counted and located by their first and last time stamps."""
    df = table(dt=0.01)
    df.loc[10:14, "q_2"] = np.nan
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == "run.csv: q_2 has 5 NaN values between t=0.10 s and t=0.14 s"


def test_infinite_value_is_reported():
    """An infinite torque is reported as NaN or infinite with its time."""
    df = table(dt=0.01)
    df.loc[7, "tau_1"] = np.inf
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == "run.csv: tau_1 has 1 NaN or infinite values at t=0.07 s"


def test_time_not_increasing():
    """A repeated time stamp is named with both values and the row."""
    df = table(dt=0.5)
    df.loc[3, "t"] = 1.0  # equals row 2
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == (
        "run.csv: t is not strictly increasing: t=1.0 s in row 4 follows t=1.0 s "
        "(expected increasing sample times)"
    )


def test_non_numeric_cell():
    """A text cell in a numeric column is named with its row and value."""
    df = table().astype({"q_1": object})
    df.loc[4, "q_1"] = "abc"
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == (
        "run.csv: column q_1 has a non-numeric value 'abc' in row 5 (expected a number)"
    )


def test_incomplete_wrench():
    """Five of the six F/T columns are refused, naming the missing one."""
    df = table()
    for c in ("f_x", "f_y", "f_z", "m_x", "m_z"):
        df[c] = 0.0
    with pytest.raises(RecordingError) as exc:
        Recording(df, META, name="run.csv")
    assert str(exc.value) == (
        "run.csv: column m_y is missing: the F/T sensor needs all of f_x, f_y, f_z, m_x, m_y, m_z"
    )


def test_unknown_schema():
    """Metadata of another schema version is refused."""
    with pytest.raises(RecordingError) as exc:
        Recording(table(), {"schema": "ditherlab.recording/9", "robot": "irb140"}, name="r")
    assert str(exc.value) == (
        "r: metadata key schema: got 'ditherlab.recording/9'; expected 'ditherlab.recording/1'"
    )


def test_missing_robot():
    """Metadata without a robot is refused with what is expected."""
    with pytest.raises(RecordingError) as exc:
        Recording(table(), {"schema": SCHEMA}, name="r")
    assert str(exc.value) == (
        "r: metadata key robot: missing; expected a built-in robot name such as 'irb140' or an "
        "object {urdf, tool_frame}"
    )


def test_unknown_robot_name_raises_robot_error():
    """An unknown robot name fails when the robot model is built."""
    rec = Recording(table(n=6), {"schema": SCHEMA, "robot": "irb9999"}, name="r")
    with pytest.raises(RobotError, match="'irb9999' is not a built-in robot"):
        rec.robot()


def test_joint_count_must_match_robot():
    """A 2-joint recording of a 6-joint robot is refused when the robot is built."""
    rec = Recording(table(n=2), META, name="r")
    with pytest.raises(RobotError, match="has 6 joints but the recording has 2"):
        rec.robot()


def test_slice_keeps_half_open_interval():
    """slice(t0, t1) keeps exactly t0 <= t < t1 and the metadata."""
    rec = Recording(table(n_rows=100, dt=0.01), META)
    part = rec.slice(0.2, 0.5)
    assert part.t[0] == pytest.approx(0.2) and part.t[-1] == pytest.approx(0.49)
    assert len(part) == 30 and part.meta == rec.meta
    np.testing.assert_array_equal(part.q, rec.q[20:50])


def test_slice_outside_raises():
    """An empty slice is an error that names the recording's span."""
    rec = Recording(table(n_rows=10, dt=0.1), META, name="r")
    with pytest.raises(RecordingError, match=r"no samples with 5 <= t < 6 s"):
        rec.slice(5, 6)


def test_dq_differentiated_from_analytic_sine():
    """Without dq columns, dq is the derivative of q: A w cos(w t) within O(dt²) on jittered t."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.0035, 0.0045, 2000))
    amp, w = 0.3, 2 * np.pi * 0.7
    q = np.stack([amp * np.sin(w * t), 2 * amp * np.sin(w * t + 1)], axis=1)
    rec = Recording.from_arrays(RecordingArrays(t, q, np.zeros_like(q)), {"robot": "irb140"})
    assert not rec.has_dq
    truth = np.stack([amp * w * np.cos(w * t), 2 * amp * w * np.cos(w * t + 1)], axis=1)
    err = np.abs(rec.dq - truth).max()
    assert err < 2e-4  # second order: ~ A w^3 dt^2
    ddq_truth = -(w**2) * q
    # ddq is a quadratic fitted over 40 ms (noise 20x lower than differencing): on a 0.7 Hz sine
    # it reads ~0.1 % low (the fit's bias, ~(w T)^2), here 0.013 of an amplitude of 11.6
    assert np.abs(rec.ddq[5:-5] - ddq_truth[5:-5]).max() < 2e-3 * np.abs(ddq_truth).max()


def test_ddq_exact_on_a_quadratic_with_jitter():
    """ddq fits a quadratic on the real time stamps: exact for q'' constant, jitter or not, and
    the uniform-grid fast path (Savitzky-Golay) equals the general fit."""
    from ditherlab.core.timeseries import local_quadratic_derivative, smooth_derivative

    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.0035, 0.0045, 800))
    dq = np.stack([1.5 * t - 0.2, -0.7 * t + 1.0], axis=1)  # ddq = (1.5, -0.7)
    np.testing.assert_allclose(smooth_derivative(t, dq), [[1.5, -0.7]] * len(t), atol=1e-9)
    tu = np.arange(3000) * 0.004
    x = np.stack([np.sin(3 * tu), np.cos(7 * tu)], axis=1) + rng.normal(0, 1e-3, (3000, 2))
    np.testing.assert_allclose(
        smooth_derivative(tu, x), local_quadratic_derivative(tu, x, 11), atol=1e-9
    )


def test_differentiate_is_exact_on_a_quadratic():
    """Second-order differences are exact for a quadratic, at the ends too."""
    t = np.array([0.0, 0.1, 0.25, 0.3, 0.42, 0.5])
    x = 3 * t**2 - t + 2
    np.testing.assert_allclose(differentiate(t, x), 6 * t - 1, atol=1e-12)


def test_logged_dq_is_used_as_is():
    """Logged dq columns are returned unchanged, not differentiated."""
    t = np.arange(20) * 0.01
    dq = np.full((20, 6), 0.5)
    rec = Recording.from_arrays(
        RecordingArrays(t, np.zeros((20, 6)), np.zeros((20, 6)), dq=dq), {"robot": "irb140"}
    )
    np.testing.assert_array_equal(rec.dq, dq)


def test_regimes_still_dither_moving():
    """A still joint is STILL, or DITHER while the flag is on; a moving joint is MOVING."""
    t = np.arange(500) * 0.004
    q = np.zeros((500, 2))
    q[:, 1] = 0.2 * t  # joint 2 moves at 0.2 rad/s
    dither = t >= 1.0
    rec = Recording.from_arrays(
        RecordingArrays(t, q, np.zeros_like(q), dither=dither), {"robot": "irb140"}
    )
    r = regimes(rec)
    assert (r[:, 1] == MOVING).all()
    assert (r[t < 1.0, 0] == STILL).all() and (r[t >= 1.0, 0] == DITHER).all()

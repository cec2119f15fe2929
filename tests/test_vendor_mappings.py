"""The built-in vendor mappings (``ur_rtde``, ``franka``, ``iiwa_fri``, ``kinova_gen3``) end to
end, as a user runs them.

Each test writes a small log in the vendor's own layout (header and delimiter as the vendor's
tool writes them, realistic values), runs ``ditherlab info`` / ``ditherlab convert`` with
``--mapping`` and checks the values that arrive in the recording.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import ditherlab.io as dio
from ditherlab.io.mapping import MAPPINGS_DIR
from ditherlab.robot import RobotModel, builtin_urdf

#: UR10e drive gains [N·m/A] (ur10e.toml, ur_rtde.toml)
UR_K = np.array([10.0, 10.6956, 8.4566, 9.0029, 9.48, 10.1232])

#: record.py's default recipe (RTDE client library, examples/record_configuration.xml):
#: field name and number of elements; 0 = an integer scalar
RTDE_DEFAULT_RECIPE = [
    ("timestamp", 1),
    ("target_q", 6),
    ("target_qd", 6),
    ("target_qdd", 6),
    ("target_current", 6),
    ("target_moment", 6),
    ("actual_q", 6),
    ("actual_qd", 6),
    ("actual_current", 6),
    ("joint_control_output", 6),
    ("actual_TCP_pose", 6),
    ("actual_TCP_speed", 6),
    ("actual_TCP_force", 6),
    ("target_TCP_pose", 6),
    ("target_TCP_speed", 6),
    ("actual_digital_input_bits", 0),
    ("joint_temperatures", 6),
    ("actual_execution_time", 1),
    ("robot_mode", 0),
    ("joint_mode", 6),
    ("safety_mode", 0),
    ("actual_tool_accelerometer", 3),
    ("speed_scaling", 1),
    ("target_speed_fraction", 1),
    ("actual_momentum", 1),
    ("actual_main_voltage", 1),
    ("actual_robot_voltage", 1),
    ("actual_robot_current", 1),
    ("actual_joint_voltage", 6),
    ("actual_digital_output_bits", 0),
    ("runtime_state", 0),
]
#: a user's own recipe with only the fields the mapping needs, in another order
RTDE_MINIMAL_RECIPE = [
    ("actual_current", 6),
    ("timestamp", 1),
    ("target_moment", 6),
    ("actual_qd", 6),
    ("actual_TCP_force", 6),
    ("actual_q", 6),
]
#: ur_rtde.toml's turn of actual_TCP_force (UR base, force on the tool) into the F/T columns'
#: frame and sign (URDF base_link, the wrench the robot exerts)
UR_TCP_SCALE = np.array([1.0, 1.0, -1.0, 1.0, 1.0, -1.0])


def _smooth_motion(pose: np.ndarray, t: np.ndarray, amp: float) -> tuple[np.ndarray, np.ndarray]:
    """q (N, n) [rad] around ``pose`` (one sinusoid per joint) and its exact derivative dq."""
    n = len(pose)
    w = 2 * np.pi * np.linspace(0.3, 0.8, n)  # [rad/s]
    ph = np.linspace(0, 2, n)
    tt = (t - t[0])[:, None]
    return pose + amp * np.sin(w * tt + ph), amp * w * np.cos(w * tt + ph)


def write_rtde_csv(path: Path, recipe: list[tuple[str, int]], n_rows: int = 400) -> dict:
    """A record.py file: csv.writer with delimiter ' ', header ``<field>_<k>`` for vectors.

    Returns the arrays written, by field name ((N,) or (N, size)).
    """
    rng = np.random.default_rng(3)
    t = np.round(8123.456 + 0.002 * np.arange(n_rows), 3)  # controller time [s], 500 Hz
    q, dq = _smooth_motion(np.array([0.1, -1.6, 1.4, -1.4, -1.57, 0.0]), t, 0.2)
    robot = RobotModel.from_spec("ur10e")
    tau = robot.gravity(q)
    cur = tau / UR_K + rng.normal(0, 0.05, tau.shape)  # [A]
    values = {
        "timestamp": t,
        "actual_q": q,
        "actual_qd": dq,
        "actual_current": cur,
        "target_moment": tau + rng.normal(0, 0.02, tau.shape),  # [N·m]
        "actual_TCP_force": rng.normal(0, [3, 3, 3, 0.3, 0.3, 0.3], (n_rows, 6)),  # [N, N·m]
        "target_q": q + rng.normal(0, 1e-4, q.shape),
        "target_qd": dq + rng.normal(0, 1e-4, q.shape),
        "joint_temperatures": 31.0 + rng.normal(0, 0.1, q.shape),  # [°C]
        "robot_mode": np.full(n_rows, 7),  # RUNNING
        "joint_mode": np.full((n_rows, 6), 253),  # RUNNING
        "safety_mode": np.full(n_rows, 1),  # NORMAL
        "runtime_state": np.full(n_rows, 2),  # PLAYING
        "speed_scaling": np.ones(n_rows),
        "actual_main_voltage": 48.0 + rng.normal(0, 0.05, n_rows),
    }
    header: list[str] = []
    for name, size in recipe:
        if name not in values:  # a field the mapping ignores: plausible noise
            shape = (n_rows,) if size <= 1 else (n_rows, size)
            values[name] = rng.integers(0, 2**8, shape) if size == 0 else rng.normal(0, 0.1, shape)
        header += [name] if size <= 1 else [f"{name}_{k}" for k in range(size)]
    with path.open("w") as fh:  # as record.py: open(..., "w"), csv.writer(delimiter=" ")
        writer = csv.writer(fh, delimiter=" ")
        writer.writerow(header)
        for i in range(n_rows):
            row: list = []
            for name, size in recipe:
                v = values[name][i]
                row += [v.item()] if size <= 1 else [x.item() for x in v]
            writer.writerow(row)
    return values


def franka_header() -> list[str]:
    """The Franka robot state export of ``franka.toml``: RobotState field names, element k as
    ``<field>_k``."""
    return (
        ["time"]
        + [f"{f}_{k}" for f in ("q", "dq", "tau_J", "tau_ext_hat_filtered") for k in range(7)]
        + [f"O_F_ext_hat_K_{k}" for k in range(6)]
    )


def write_franka_csv(path: Path, n_rows: int = 500) -> dict:
    """A Franka state export at 1 kHz (time = RobotState::time.toSec(), whole milliseconds)."""
    rng = np.random.default_rng(5)
    t = (2_345_678 + np.arange(n_rows)) / 1000.0  # [s]
    ready = np.array([0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4])
    q, dq = _smooth_motion(ready, t, 0.1)
    tau_j = RobotModel.from_spec("panda").gravity(q) + rng.normal(0, 0.05, q.shape)  # [N·m]
    wrench = rng.normal(0, [0.5, 0.5, 0.5, 0.05, 0.05, 0.05], (n_rows, 6))  # [N, N·m]
    tau_ext = rng.normal(0, 0.2, q.shape)  # [N·m]
    table = np.column_stack([t, q, dq, tau_j, tau_ext, wrench])
    lines = [",".join(franka_header())] + [",".join(repr(float(x)) for x in row) for row in table]
    path.write_text("\n".join(lines) + "\n")
    return {
        "time": t,
        "q": q,
        "dq": dq,
        "tau_J": tau_j,
        "tau_ext_hat_filtered": tau_ext,
        "O_F_ext_hat_K": wrench,
    }


def _info(cli, path: Path, mapping: str) -> dict:
    res = cli("info", path, "--mapping", mapping, "--json")
    assert res.code == 0, res.err
    return json.loads(res.out)


def _convert(cli, path: Path, mapping: str) -> dio.Recording:
    dst = path.with_name("out.parquet")
    res = cli("convert", path, dst, "--mapping", mapping)
    assert res.code == 0, res.err
    assert res.out.strip() == f"wrote {dst}"
    return dio.read(dst)


# ------------------------------------------------------------------ UR RTDE record.py
@pytest.mark.parametrize("recipe", ["default", "minimal"])
def test_ur_rtde_recording_through_info_and_convert(cli, tmp_path, recipe):
    """A record.py CSV (the default recipe, or only the needed fields in another order) reads by
    header name: t = timestamp [s], q/dq = actual_q/qd, tau = actual_current × K exactly,
    tau_desired_j = target_moment_(j-1), the UR10e URDF embedded."""
    src = tmp_path / "robot_data.csv"
    v = write_rtde_csv(src, RTDE_DEFAULT_RECIPE if recipe == "default" else RTDE_MINIMAL_RECIPE)
    assert src.read_text().startswith(
        "timestamp target_q_0 " if recipe == "default" else "actual_current_0 actual_current_1 "
    )

    d = _info(cli, src, "ur_rtde")
    assert d["samples"] == 400 and d["joints"] == 6 and d["robot"] == "ur10e"
    assert d["t_start_s"] == 8123.456 and d["sample_rate_hz"] == pytest.approx(500.0)
    assert d["columns"]["dq"] and not d["columns"]["wrench"] and d["columns"]["vendor"]
    assert d["extra_columns"] == [f"tau_desired_{j}" for j in range(1, 7)]

    rec = _convert(cli, src, "ur_rtde")
    np.testing.assert_array_equal(rec.t, v["timestamp"])
    np.testing.assert_array_equal(rec.q, v["actual_q"])
    np.testing.assert_array_equal(rec.dq, v["actual_qd"])
    np.testing.assert_array_equal(rec.tau, v["actual_current"] * UR_K)
    desired = rec.data[[f"tau_desired_{j}" for j in range(1, 7)]].to_numpy()
    np.testing.assert_array_equal(desired, v["target_moment"])
    assert rec.meta["robot"]["urdf"] == builtin_urdf("ur10e")
    assert rec.meta["robot"]["tool_frame"] == "tool0" and rec.robot_label == "ur10e"
    assert rec.meta["mapping"] == "ur_rtde.toml"
    assert not any(c in rec.data for c in ("f_x", "temp_1", "tau_ffw_1"))
    # actual_TCP_force is the vendor's estimate, turned into the F/T columns' frame and sign
    np.testing.assert_array_equal(rec.vendor_wrench, v["actual_TCP_force"] * UR_TCP_SCALE)


# ------------------------------------------------------------------ Franka robot state export
def test_franka_state_export_through_info_and_convert(cli, tmp_path):
    """A Franka state CSV: t = time [s], q/dq/tau = q/dq/tau_J exactly, 7 joints on the built-in
    Panda, O_F_ext_hat_K as the vendor's wrench and tau_ext_hat_filtered as its joint torques,
    both in libfranka's sign (that of the F/T columns), and NOT as the F/T columns."""
    src = tmp_path / "panda_state.csv"
    v = write_franka_csv(src)

    d = _info(cli, src, "franka")
    assert d["samples"] == 500 and d["joints"] == 7 and d["robot"] == "panda"
    assert d["t_start_s"] == 2345.678 and d["sample_rate_hz"] == pytest.approx(1000.0)
    assert d["columns"]["wrench"] is False

    rec = _convert(cli, src, "franka")
    np.testing.assert_array_equal(rec.t, v["time"])
    np.testing.assert_array_equal(rec.q, v["q"])
    np.testing.assert_array_equal(rec.dq, v["dq"])
    np.testing.assert_array_equal(rec.tau, v["tau_J"])
    np.testing.assert_array_equal(rec.vendor_wrench, v["O_F_ext_hat_K"])
    np.testing.assert_array_equal(rec.tau_ext_vendor, v["tau_ext_hat_filtered"])
    assert not any(c in rec.data for c in ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z"))
    assert rec.meta["robot"]["urdf"] == builtin_urdf("panda")
    assert rec.meta["robot"]["tool_frame"] == "panda_hand_tcp" and rec.robot_label == "panda"
    # the values are those of the Panda: its gravity explains the logged torque
    np.testing.assert_allclose(rec.robot().gravity(rec.q), rec.tau, atol=0.3)


# ------------------------------------------------------------------ bad input
def drop_column(path: Path, name: str, delimiter: str) -> None:
    """Rewrite the log without the column ``name`` (header cell and data)."""
    rows = [line.split(delimiter) for line in path.read_text().splitlines()]
    k = rows[0].index(name)
    path.write_text("\n".join(delimiter.join(r[:k] + r[k + 1 :]) for r in rows) + "\n")


@pytest.mark.parametrize(
    ("mapping", "key", "column", "hint"),
    [
        (
            "ur_rtde",
            "columns.dq.columns[4]",
            "actual_qd_3",
            "117 names; closest: actual_q_3, actual_qd_5, actual_qd_4",
        ),
        (
            "ur_rtde",
            "extra.tau_desired_6.column",
            "target_moment_5",
            "117 names; closest: target_moment_4, target_moment_3, target_moment_2",
        ),
        (
            "franka",
            "columns.tau.columns[7]",
            "tau_J_6",
            "34 names; closest: tau_J_5, tau_J_4, tau_J_3",
        ),
        (
            "ur_rtde",
            "columns.vendor_wrench.columns[3]",
            "actual_TCP_force_2",
            "117 names; closest: actual_TCP_force_5, actual_TCP_force_4, actual_TCP_force_3",
        ),
        (
            "franka",
            "columns.vendor_wrench.columns[1]",
            "O_F_ext_hat_K_0",
            "34 names; closest: O_F_ext_hat_K_5, O_F_ext_hat_K_4, O_F_ext_hat_K_3",
        ),
        (
            "franka",
            "time.column",
            "time",
            "34 names: q_0, q_1, q_2, q_3, q_4, q_5, q_6, dq_0, dq_1, dq_2, dq_3, dq_4, ...",
        ),
    ],
)
@pytest.mark.parametrize("command", ["info", "convert"])
def test_missing_column_is_one_line_and_writes_nothing(
    cli, tmp_path, mapping, key, column, hint, command
):
    """A column the mapping needs but the file's header lacks: exit 2, one stderr line naming
    the mapping and its key, the column, the file and what was expected; nothing written."""
    src = tmp_path / "log.csv"
    if mapping == "ur_rtde":
        write_rtde_csv(src, RTDE_DEFAULT_RECIPE, n_rows=300)
        drop_column(src, column, " ")
    else:
        write_franka_csv(src, n_rows=300)
        drop_column(src, column, ",")
    dst = tmp_path / "out.parquet"
    res = cli(command, src, *([dst] if command == "convert" else []), "--mapping", mapping)
    assert res.code == 2 and res.out == "", (res.code, res.out, res.err)
    assert res.err.count("\n") == 1 and "Traceback" not in res.err, res.err
    assert res.err == (
        f"error: {MAPPINGS_DIR / f'{mapping}.toml'}: {key} is {column!r}, but the header of "
        f"{src} has no such column (expected one of its {hint})\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv"]


# ------------------------------------------------------------------ KUKA iiwa FRI, Kinova Gen3
def write_lbr_state_csv(path: Path, n_rows: int = 400) -> dict:
    """``ros2 topic echo --csv /lbr/state`` of lbr_fri_ros2's LBRState: no header, the fields in
    message order (lbr_fri_idl/msg/LBRState), a fixed array element by element; 200 Hz."""
    rng = np.random.default_rng(8)
    stamp = 1_718_000_000 * 10**9 + 123_456_789 + 5_000_000 * np.arange(n_rows)  # [ns]
    sec, nsec = stamp // 10**9, stamp % 10**9
    q, _ = _smooth_motion(np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0]), stamp / 1e9, 0.1)
    msr = rng.normal(0, 5, q.shape)  # [N·m]
    ext = rng.normal(0, 0.5, q.shape)  # [N·m]
    lines = []
    for i in range(n_rows):
        state = [0.005, 4, 3, 0, 2, 1, 2, 1, 1, int(sec[i]), int(nsec[i])]  # sample_time .. nanosec
        arrays = [q[i], q[i] + 1e-4, msr[i], msr[i] + 0.1, ext[i], q[i]]
        cells = [repr(x) for x in state] + [repr(float(x)) for a in arrays for x in a] + ["0.0"]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return {"t": sec + nsec * 1e-9, "q": q, "measured_torque": msr, "external_torque": ext}


def test_iiwa_fri_state_through_convert(cli, tmp_path):
    """An LBRState CSV: 54 numbered columns, t = seconds + nanoseconds, q = measured position,
    tau = measured_torque, external_torque as tau_ext_vendor_1..7; the robot from --robot."""
    src = tmp_path / "lbr_state.csv"
    v = write_lbr_state_csv(src)
    assert len(src.read_text().splitlines()[0].split(",")) == 54
    dst = tmp_path / "out.parquet"
    res = cli("convert", src, dst, "--mapping", "iiwa_fri", "--robot", "panda")
    assert res.code == 0, res.err
    rec = dio.read(dst)
    np.testing.assert_allclose(rec.t, v["t"], rtol=0, atol=1e-6)
    assert np.median(np.diff(rec.t)) == pytest.approx(0.005, abs=1e-6)
    np.testing.assert_array_equal(rec.q, v["q"])
    np.testing.assert_array_equal(rec.tau, v["measured_torque"])
    np.testing.assert_array_equal(rec.tau_ext_vendor, v["external_torque"])
    assert rec.vendor_wrench is None and not rec.has_dq and rec.meta["mapping"] == "iiwa_fri.toml"


def test_iiwa_fri_without_robot_is_one_line(cli, tmp_path):
    """The iiwa mapping names no robot: without --robot one line asks for it, exit 2."""
    src = tmp_path / "lbr_state.csv"
    write_lbr_state_csv(src, n_rows=20)
    res = cli("info", src, "--mapping", "iiwa_fri")
    assert res.code == 2 and res.err.count("\n") == 1 and "expected --robot" in res.err, res.err


def write_gen3_csv(path: Path, n_rows: int = 300) -> dict:
    """A Kortex BaseCyclic feedback export: Kortex field paths as the header, degrees."""
    rng = np.random.default_rng(9)
    t = 100.0 + 0.001 * np.arange(n_rows)
    q = np.mod(rng.normal(0, 40, 7) + 0.5 * np.arange(n_rows)[:, None] * 1e-2, 360.0)  # [deg]
    dq = np.full((n_rows, 7), 0.5)  # [deg/s]
    tau = rng.normal(0, 3, (n_rows, 7))
    wrench = rng.normal(0, [2, 2, 2, 0.2, 0.2, 0.2], (n_rows, 6))
    head = ["time"] + [
        f"actuators[{k}].{f}" for f in ("position", "velocity", "torque") for k in range(7)
    ]
    head += [f"base.tool_external_wrench_{a}_{x}" for a in ("force", "torque") for x in "xyz"]
    table = np.column_stack([t, q, dq, tau, wrench])
    lines = [",".join(head)] + [",".join(repr(float(x)) for x in row) for row in table]
    path.write_text("\n".join(lines) + "\n")
    return {"t": t, "q": q, "dq": dq, "tau": tau, "wrench": wrench}


def test_kinova_gen3_feedback_through_convert(cli, tmp_path):
    """A Gen3 feedback CSV: q, dq from degrees, tau = actuator torque, the tool's external
    wrench as the vendor's estimate with its sign reversed (the wrench the robot exerts)."""
    src = tmp_path / "gen3.csv"
    v = write_gen3_csv(src)
    dst = tmp_path / "out.parquet"
    res = cli("convert", src, dst, "--mapping", "kinova_gen3", "--robot", "panda")
    assert res.code == 0, res.err
    rec = dio.read(dst)
    np.testing.assert_array_equal(rec.t, v["t"])
    np.testing.assert_allclose(rec.q, np.deg2rad(v["q"]), rtol=1e-15)
    np.testing.assert_allclose(rec.dq, np.deg2rad(v["dq"]), rtol=1e-15)
    np.testing.assert_array_equal(rec.tau, v["tau"])
    np.testing.assert_array_equal(rec.vendor_wrench, -v["wrench"])

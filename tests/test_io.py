"""Tests of ditherlab.io: round trips per format, bad files, ROS 2 bags, mapping files."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

import ditherlab
import ditherlab.io as dio
from ditherlab.core.errors import (
    ConfigError,
    DitherlabWarning,
    FormatError,
    RecordingError,
    RobotError,
)
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.io.mapping import builtin_mappings, load_mapping
from ditherlab.io.rosbag import merge_onto
from ditherlab.robot import RobotModel

REPO = Path(__file__).resolve().parents[1]
UR_URDF = REPO / "ditherlab" / "robot" / "descriptions" / "ur10e.urdf"
UR_K = np.array([10.0, 10.6956, 8.4566, 9.0029, 9.48, 10.1232])  # [N·m/A]
SMALL = [f"{p}_{j}" for p in ("q", "tau") for j in range(1, 7)]
IRB_JOINTS = RobotModel.from_spec("irb140").joint_names

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=64)
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=20)


@st.composite
def recordings(draw, *, text_columns: bool = True, nan_extra: bool = True) -> Recording:
    """Random valid 6-joint IRB140 recordings with random optional columns and metadata."""
    n_rows = draw(st.integers(2, 30))
    t0 = draw(st.floats(-100.0, 1e4))
    steps = draw(st.lists(st.floats(1e-3, 0.1), min_size=n_rows - 1, max_size=n_rows - 1))
    t = t0 + np.concatenate([[0.0], np.cumsum(steps)])

    def block(width: int, lo: float = -1e6, hi: float = 1e6) -> np.ndarray:
        vals = draw(
            st.lists(
                st.floats(lo, hi, allow_nan=False, width=64),
                min_size=n_rows * width,
                max_size=n_rows * width,
            )
        )
        return np.array(vals).reshape(n_rows, width)

    opt = {}
    if draw(st.booleans()):
        opt["dq"] = block(6, -10, 10)
    if draw(st.booleans()):
        opt["tau_ffw"] = block(6)
    if draw(st.booleans()):
        opt["temp"] = block(6, -40, 150)
    if draw(st.booleans()):
        opt["wrench"] = block(6)
    if draw(st.booleans()):
        opt["dither"] = np.array(draw(st.lists(st.booleans(), min_size=n_rows, max_size=n_rows)))
    extra = {}
    if draw(st.booleans()):
        x = block(1)[:, 0]
        if nan_extra and draw(st.booleans()):
            x[0] = np.nan
        extra["x_extra"] = x
    if draw(st.booleans()):
        extra["count"] = np.array(
            draw(st.lists(st.integers(-(2**40), 2**40), min_size=n_rows, max_size=n_rows)),
            dtype=np.int64,
        )
    if text_columns and draw(st.booleans()):
        extra["label"] = np.array(
            draw(
                st.lists(text.filter(lambda s: s.strip() != ""), min_size=n_rows, max_size=n_rows)
            ),
            dtype=object,
        )
    meta = {"robot": "irb140", "notes": draw(text)}
    if draw(st.booleans()):
        meta["tool_offset"] = [draw(st.floats(-0.5, 0.5)) for _ in range(3)]
    return Recording.from_arrays(
        RecordingArrays(t, block(6, -2.0, 2.0), block(6), extra=extra, **opt), meta
    )


settings.register_profile(
    "io",
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


def fresh(tmp_path: Path, name: str) -> Path:
    """A path in tmp_path that does not exist yet (hypothesis reuses the fixture)."""
    p = tmp_path / name
    if p.is_dir():
        shutil.rmtree(p)
    elif p.exists():
        p.unlink()
    return p


# ------------------------------------------------------------------ exact round trips
@settings(settings.get_profile("io"), max_examples=25)
@given(rec=recordings())
def test_parquet_round_trip_is_exact(tmp_path, rec):
    """Parquet keeps values, dtypes, column order, extra columns and metadata exactly."""
    p = fresh(tmp_path, "r.parquet")
    assert dio.write(rec, p) == p
    back = dio.read(p)
    assert back.equals(rec)
    assert list(back.data.dtypes) == list(rec.data.dtypes)


@settings(settings.get_profile("io"), max_examples=25)
@given(rec=recordings())
def test_mcap_round_trip_is_exact(tmp_path, rec):
    """ditherlab MCAP keeps values, dtypes, column order, extra columns and metadata exactly."""
    p = fresh(tmp_path, "r.mcap")
    dio.write(rec, p)
    assert dio.detect_format(p) == "mcap"
    back = dio.read(p)
    assert back.equals(rec)
    assert list(back.data.dtypes) == list(rec.data.dtypes)


@settings(settings.get_profile("io"), max_examples=25)
@given(rec=recordings(text_columns=False))
def test_csv_round_trip_is_exact(tmp_path, rec):
    """CSV + sidecar keeps float64 values bit for bit, the column order and the metadata."""
    p = fresh(tmp_path, "r.csv")
    dio.write(rec, p)
    assert (tmp_path / "r.json").is_file()
    back = dio.read(p)
    assert back.equals(rec)


@settings(settings.get_profile("io"), max_examples=8)
@given(rec=recordings(text_columns=False), storage=st.sampled_from(["mcap", "sqlite3"]))
def test_rosbag_round_trip_keeps_joint_and_wrench_values(tmp_path, rec, storage):
    """A ROS 2 bag keeps t (to 1 ns), q, dq, tau and the wrench, and the metadata."""
    p = fresh(tmp_path, "bag")
    dio.write(rec, p, storage=storage)
    assert dio.detect_format(p) == "rosbag"
    back = dio.read(p)
    assert len(back) == len(rec) and back.meta == rec.meta
    np.testing.assert_allclose(back.t, rec.t, rtol=0, atol=1e-9 + 1e-15 * np.abs(rec.t).max())
    np.testing.assert_array_equal(back.q, rec.q)
    np.testing.assert_array_equal(back.tau, rec.tau)
    assert back.has_dq == rec.has_dq
    if rec.has_dq:
        np.testing.assert_array_equal(back.dq, rec.dq)
    assert back.has_wrench == rec.has_wrench
    if rec.has_wrench:
        np.testing.assert_array_equal(back.wrench, rec.wrench)


def test_ditherlab_read_and_write_use_io(tmp_path):
    """The package-level read/write are the io functions."""
    rec = dio.read(REPO / "recordings" / "ur10e-static.parquet")
    p = ditherlab.write(rec, tmp_path / "x.mcap")
    assert ditherlab.read(p).equals(rec)


# ------------------------------------------------------------------ bad files
@pytest.fixture(scope="module")
def sample() -> Recording:
    return dio.read(REPO / "recordings" / "ur10e-static.parquet")


def test_truncated_mcap_names_the_file(tmp_path, sample):
    """A ditherlab MCAP cut in half is a FormatError naming the file."""
    p = tmp_path / "a.mcap"
    dio.write(sample, p)
    data = p.read_bytes()
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=rf"^{bad}: the MCAP file is truncated or corrupt \("):
        dio.read(bad)


def test_corrupt_mcap_chunk_fails_its_crc(tmp_path, sample):
    """A flipped byte inside a chunk is caught (CRC or decompression) and named."""
    p = tmp_path / "a.mcap"
    dio.write(sample, p)
    data = bytearray(p.read_bytes())
    data[1000] ^= 0xFF
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=rf"^{bad}: the MCAP file is truncated or corrupt"):
        dio.read(bad)


def test_mcap_with_only_a_header_is_refused(tmp_path):
    """Five bytes of MCAP magic are not a readable file."""
    bad = tmp_path / "head.mcap"
    bad.write_bytes(b"\x89MCAP")
    with pytest.raises(FormatError, match=rf"^{bad}: not a readable MCAP file"):
        dio.read(bad)


def test_truncated_parquet_names_the_file(tmp_path, sample):
    """A Parquet file cut in half is a FormatError naming the file."""
    p = tmp_path / "a.parquet"
    dio.write(sample, p)
    bad = tmp_path / "cut.parquet"
    bad.write_bytes(p.read_bytes()[:5000])
    with pytest.raises(FormatError, match=rf"^{bad}: not a readable Parquet file, truncated"):
        dio.read(bad)


def test_corrupt_parquet_page_fails_its_checksum(tmp_path, sample):
    """Altered bytes inside a data page are caught by the page checksum, not read silently."""
    p = tmp_path / "a.parquet"
    dio.write(sample, p)
    data = bytearray(p.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(b ^ 0x55 for b in data[mid : mid + 64])
    bad = tmp_path / "flip.parquet"
    bad.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"CRC checksum verification failed"):
        dio.read(bad)


def test_csv_non_numeric_cell_is_named(tmp_path, sample):
    """A text cell in a CSV is reported with file, column, row, line and value."""
    p = tmp_path / "a.csv"
    dio.write(sample.slice(None, 333.6), p)
    lines = p.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("q_3")] = "oops"
    lines[5] = ",".join(row)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as exc:
        dio.read(p)
    assert str(exc.value) == (
        f"{p}: column q_3 has a non-numeric value 'oops' in row 5 (line 6), expected a number"
    )


def test_csv_without_metadata_needs_a_robot(tmp_path, sample):
    """A CSV without sidecar and without robot= says what to pass; robot= makes it readable."""
    p = tmp_path / "a.csv"
    sample.data.loc[:19, ["t", *SMALL]].to_csv(p, index=False)
    with pytest.raises(
        FormatError,
        match=r"no robot given .* expected --robot with a built-in name \(irb140\) or the path",
    ):
        dio.read(p)
    rec = dio.read(p, robot=str(UR_URDF))
    assert rec.meta["robot"]["tool_frame"] == "tool0"
    assert rec.meta["robot"]["urdf"] == UR_URDF.read_text()
    assert rec.robot().n == 6


def test_unknown_robot_name_fails_on_read(tmp_path, sample):
    """An unknown built-in robot name is a RobotError when reading."""
    p = tmp_path / "a.csv"
    sample.data.loc[:19, ["t", *SMALL]].to_csv(p, index=False)
    with pytest.raises(RobotError, match="'ur99' is not a built-in robot"):
        dio.read(p, robot="ur99")


def test_unknown_option_is_refused(tmp_path, sample):
    """A misspelt option is a ConfigError listing the accepted ones."""
    p = tmp_path / "a.parquet"
    dio.write(sample, p)
    with pytest.raises(ConfigError, match=r"unknown option 'robto' for Parquet files"):
        dio.read(p, robto="irb140")


def test_degrees_are_refused(tmp_path):
    """Joint angles logged in degrees are a RecordingError that says degrees."""
    t = np.arange(50) * 0.004
    q = np.tile(np.array([10.0, 80.0, -120.0, 170.0, 95.0, 300.0]), (50, 1))
    rec = Recording.from_arrays(RecordingArrays(t, q, np.zeros_like(q)), {"robot": "irb140"})
    p = tmp_path / "deg.parquet"
    dio.write(rec, p)
    with pytest.raises(RecordingError, match=r"deg\.parquet: the joint log looks like degrees"):
        dio.read(p)


def test_unknown_suffix_is_sniffed_from_content(tmp_path, sample):
    """A Parquet file without its suffix is recognised by its magic bytes."""
    p = tmp_path / "a.parquet"
    dio.write(sample, p)
    q = tmp_path / "renamed.bin"
    shutil.copy(p, q)
    assert dio.detect_format(q) == "parquet"
    assert dio.read(q).equals(sample)
    other = tmp_path / "x.txt"
    other.write_text("hello")
    with pytest.raises(FormatError, match=r"unknown file format"):
        dio.read(other)


def test_failed_write_leaves_no_file(tmp_path, sample):
    """A writer that fails leaves neither the target nor a temporary file behind."""
    rec = sample.with_columns(bad=[object()] * len(sample))
    with pytest.raises(ConfigError, match="extra column bad has dtype object"):
        dio.write(rec, tmp_path / "x.mcap")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ ROS 2 bags
@pytest.mark.parametrize(
    ("name", "topics"),
    [
        (
            "cdr_test_0.mcap",
            "/array_topic [test_msgs/msg/Arrays], /test_topic [test_msgs/msg/BasicTypes]",
        ),
        (
            "talker.mcap",
            "/parameter_events [rcl_interfaces/msg/ParameterEvent], /rosout "
            "[rcl_interfaces/msg/Log], /topic [std_msgs/msg/String]",
        ),
    ],
)
def test_real_ros2_files_name_the_missing_joint_state(shared_data, name, topics):
    """Bags written by real ROS 2 are read and refused because they hold no JointState topic."""
    p = shared_data / "rosbag2" / name
    assert dio.detect_format(p) == "rosbag"
    with pytest.raises(FormatError) as exc:
        dio.read(p, robot="irb140")
    assert str(exc.value) == (
        f"{p}: no sensor_msgs/msg/JointState topic (needed for the joint positions and "
        f"torques); topics found: {topics}"
    )


def test_real_ros2_messages_deserialize(shared_data):
    """Every message of the real ROS 2 files deserializes with the reader's typestore."""
    from rosbags.highlevel import AnyReader

    for name in ("cdr_test_0.mcap", "talker.mcap"):
        with AnyReader([shared_data / "rosbag2" / name]) as r:
            count = sum(1 for c, _, raw in r.messages() if r.deserialize(raw, c.msgtype))
            assert count == r.message_count > 0


def write_foreign_bag(
    path: Path,
    storage: StoragePlugin,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    t_w: np.ndarray,
    w: np.ndarray,
) -> None:
    """A bag as a robot driver writes it: shuffled joint names plus a gripper joint, no dq."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    JS, WS = ts.types["sensor_msgs/msg/JointState"], ts.types["geometry_msgs/msg/WrenchStamped"]
    H, T = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    W, V = ts.types["geometry_msgs/msg/Wrench"], ts.types["geometry_msgs/msg/Vector3"]
    order = [3, 0, 5, 1, 4, 2]
    names = [IRB_JOINTS[k] for k in order] + ["gripper_joint"]

    def hdr(sec: float) -> object:
        ns = int(round(sec * 1e9))
        return H(stamp=T(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="tool0")

    with Writer(path, version=9, storage_plugin=storage) as wr:
        cj = wr.add_connection("/robot/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        cw = wr.add_connection("/ft/wrench", "geometry_msgs/msg/WrenchStamped", typestore=ts)
        cx = wr.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        wr.write(
            cx,
            1,
            ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"),
        )
        for i in range(len(t)):
            m = JS(
                header=hdr(t[i]),
                name=names,
                position=np.append(q[i, order], 0.01),
                velocity=np.zeros(0),
                effort=np.append(tau[i, order], 0.5),
            )
            wr.write(cj, int(t[i] * 1e9), ts.serialize_cdr(m, "sensor_msgs/msg/JointState"))
        for i in range(len(t_w)):
            m = WS(
                header=hdr(t_w[i]),
                wrench=W(
                    force=V(x=w[i, 0], y=w[i, 1], z=w[i, 2]),
                    torque=V(x=w[i, 3], y=w[i, 4], z=w[i, 5]),
                ),
            )
            wr.write(cw, int(t_w[i] * 1e9), ts.serialize_cdr(m, "geometry_msgs/msg/WrenchStamped"))


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_foreign_bag_is_reordered_and_merged(tmp_path, storage):
    """Joints are matched by name and the wrench follows the documented merge rule."""
    rng = np.random.default_rng(3)
    t = 10.0 + np.arange(100) * 0.004  # joint states at 250 Hz
    q = rng.uniform(-1, 1, (100, 6))
    tau = rng.normal(0, 20, (100, 6))
    # wrench at 100 Hz from t=10.0505 s: within 2 ms (half the joint period) of a wrench sample
    # that sample is taken, otherwise the two around are interpolated; joint samples more than
    # 2 ms before the first or after the last wrench sample are dropped.
    t_w = 10.0505 + np.arange(30) * 0.01
    w = np.cumsum(rng.normal(0, 1, (30, 6)), axis=0)
    bag = tmp_path / "drive_bag"
    write_foreign_bag(bag, storage, t, q, tau, t_w, w)
    with pytest.warns(DitherlabWarning, match=r"joint-state samples .* lie outside the wrench"):
        rec = dio.read(bag, robot="irb140")
    keep = (t >= t_w[0] - 0.002) & (t <= t_w[-1] + 0.002)
    assert len(rec) == keep.sum()
    np.testing.assert_array_equal(rec.q, q[keep])
    np.testing.assert_array_equal(rec.tau, tau[keep])
    assert not rec.has_dq
    assert rec.meta["wrench_frame"] == "tool0"
    expected, _ = merge_onto(t[keep], t_w, w, 0.002)
    np.testing.assert_allclose(rec.wrench, expected, atol=1e-12)
    # t=10.052 s is 1.5 ms from the first wrench sample: taken as it is
    i = int(np.flatnonzero(np.isclose(rec.t, 10.052))[0])
    np.testing.assert_array_equal(rec.wrench[i], w[0])
    # t=10.056 s is 5.5 ms from it: on the line between the first two samples
    i = int(np.flatnonzero(np.isclose(rec.t, 10.056))[0])
    np.testing.assert_allclose(rec.wrench[i], w[0] + 0.55 * (w[1] - w[0]), atol=1e-9)


def test_merge_rule_nearest_interpolate_drop():
    """merge_onto: nearest within tol, linear inside the span, uncovered outside it."""
    t_w = np.array([1.0, 2.0, 3.0])
    w = np.tile(np.array([[0.0], [10.0], [40.0]]), (1, 6))
    W, covered = merge_onto(np.array([0.5, 0.99, 1.5, 2.04, 2.5, 3.05, 3.5]), t_w, w, 0.05)
    np.testing.assert_array_equal(covered, [False, True, True, True, True, True, False])
    np.testing.assert_allclose(W[1:6, 0], [0.0, 5.0, 10.0, 25.0, 40.0])


def test_bag_topic_options(tmp_path):
    """A wrong joint_topic lists the topics; wrench_topic='' ignores the wrench."""
    t = np.arange(20) * 0.004
    bag = tmp_path / "b"
    write_foreign_bag(
        bag, StoragePlugin.MCAP, t, np.zeros((20, 6)), np.ones((20, 6)), t, np.ones((20, 6))
    )
    with pytest.raises(
        FormatError, match=r"--joint-topic \(joint_topic=\) names topic /joint_states, which"
    ):
        dio.read(bag, robot="irb140", joint_topic="/joint_states")
    rec = dio.read(bag, robot="irb140", wrench_topic="")
    assert not rec.has_wrench and len(rec) == 20
    with pytest.raises(FormatError, match=r"no robot given"):
        dio.read(bag)


def test_bag_missing_a_robot_joint_is_named(tmp_path):
    """A JointState without one of the robot's joints names it and the names it has."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "b"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as wr:
        c = wr.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        m = ts.types["sensor_msgs/msg/JointState"](
            header=ts.types["std_msgs/msg/Header"](
                stamp=ts.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=""
            ),
            name=["a", "b"],
            position=np.zeros(2),
            velocity=np.zeros(0),
            effort=np.zeros(2),
        )
        wr.write(c, 1, ts.serialize_cdr(m, "sensor_msgs/msg/JointState"))
    with pytest.raises(
        FormatError,
        match=rf"message 1 has no joint {IRB_JOINTS[0]} \(names in "
        r"the message: a, b;",
    ):
        dio.read(bag, robot="irb140")


# ------------------------------------------------------------------ mapping files
def test_ur10e_mapping_reads_the_static_log(shared_data):
    """The shipped UR10e mapping gives 6 joints, tau = current × K, and the embedded URDF."""
    csv = shared_data / "ur10e" / "ur-static.csv"
    rec = dio.read(csv, mapping="ur10e")
    raw = np.loadtxt(csv, delimiter=",")
    assert len(rec) == len(raw) and rec.n == 6
    np.testing.assert_array_equal(rec.t, raw[:, 0])
    np.testing.assert_array_equal(rec.q, raw[:, 1:7])
    np.testing.assert_array_equal(rec.dq, raw[:, 7:13])
    np.testing.assert_allclose(rec.tau, raw[:, 13:19] * UR_K, rtol=1e-15)
    assert rec.meta["robot"]["urdf"] == UR_URDF.read_text()
    assert rec.robot_label == "ur10e"


def test_ur10e_urdf_gravity_matches_the_controller(shared_data):
    """The UR10e URDF's gravity equals the controller's desired torque while still (< 0.1 N·m)."""
    rec = dio.read(shared_data / "ur10e" / "ur-static.csv", mapping="ur10e")
    g = rec.robot().gravity(rec.q)
    desired = rec.data[[f"tau_desired_{j}" for j in range(1, 7)]].to_numpy()
    rms = np.sqrt(((desired - g) ** 2).mean(axis=0))
    assert (rms < 0.1).all(), rms
    # the measured torque (current × K) has gravity's sign and size where gravity is large:
    # shoulder (~50 N·m) and elbow (~12 N·m) differ from it by less than a quarter (friction
    # holds part of the load while the arm stands still)
    med = np.median(rec.tau, axis=0)
    gm = g.mean(axis=0)
    assert abs(gm[1]) > 40 and abs(gm[2]) > 10
    assert (np.sign(med[1:3]) == np.sign(gm[1:3])).all()
    assert (np.abs(med[1:3] - gm[1:3]) < 0.25 * np.abs(gm[1:3])).all()


def test_mapping_with_header_units_factors_offsets(tmp_path):
    """Header names, degrees, ms, per-joint factors and offsets give the documented values."""
    n_rows = 5
    time_ms = np.arange(n_rows) * 4.0
    deg = np.linspace(-30, 30, n_rows)
    cur = np.linspace(-1, 1, n_rows)
    df = pd.DataFrame({"time": time_ms})
    for j in range(6):
        df[f"pos{j}"] = deg + j
        df[f"cur{j}"] = cur * (j + 1)
    data = tmp_path / "log.txt"
    data.write_text("# exported by the vendor\n" + df.to_csv(index=False, sep=";"))
    (tmp_path / "robots").mkdir()
    shutil.copy(UR_URDF, tmp_path / "robots" / "arm.urdf")
    m = tmp_path / "vendor.toml"
    m.write_text(
        '[input]\nheader = true\ndelimiter = ";"\ncomment = "#"\n'
        '[time]\ncolumn = "time"\nunit = "ms"\n'
        '[robot]\nurdf = "robots/arm.urdf"\ntool_frame = "flange"\ntool_offset = [0, 0, 0.1]\n'
        '[meta]\nsource = "vendor X"\n'
        f'[columns.q]\ncolumns = {[f"pos{j}" for j in range(6)]}\nunit = "deg"\n'.replace("'", '"')
        + f"[columns.tau]\ncolumns = {[f'cur{j}' for j in range(6)]}\n".replace("'", '"')
        + "scale = 2.0\nfactors = [[1, 2, 3, 4, 5, 6], 0.5]\noffset = [0, 0, 0, 0, 0, 1.5]\n"
    )
    rec = dio.read(data, mapping=m)
    np.testing.assert_allclose(rec.t, time_ms * 1e-3)
    np.testing.assert_allclose(rec.q[:, 2], np.deg2rad(deg + 2))
    k = 2.0 * np.arange(1, 7) * 0.5
    expected = cur[:, None] * np.arange(1, 7) * k + np.array([0, 0, 0, 0, 0, 1.5])
    np.testing.assert_allclose(rec.tau, expected)
    assert rec.meta["robot"]["tool_frame"] == "flange"
    assert rec.meta["tool_offset"] == [0, 0, 0.1] and rec.meta["source"] == "vendor X"


def test_mapping_errors_name_the_key(tmp_path, shared_data):
    """Unknown keys, wrong list lengths and columns out of range name the mapping key."""
    base = (REPO / "ditherlab" / "io" / "mappings" / "ur10e.toml").read_text()
    base = base.replace('"../../robot/descriptions/ur10e.urdf"', f'"{UR_URDF}"')
    csv = shared_data / "ur10e" / "no_torque.csv"
    cases = [
        (
            base.replace("[columns.q]", "[columns.q]\nscal = 2"),
            r"columns\.q\.scal: unknown key; expected one of columns, factors, offset, scale, unit$",
        ),
        (
            base.replace("scale = [10.0, 10.6956,", "scale = ["),
            r"columns\.tau\.scale has 4 values, expected 6 \(one per column\)",
        ),
        (
            base.replace(
                "columns = [14, 15, 16, 17, 18, 19]", "columns = [14, 15, 16, 17, 18, 40]"
            ),
            r"columns\.tau\.columns\[6\] is 40, but .*no_torque\.csv has 31 columns",
        ),
        (
            base.replace('unit = "rad"', 'unit = "grad"'),
            r"columns\.q\.unit: got 'grad'; expected one of 'rad', 'deg'$",
        ),
    ]
    for i, (text_, pattern) in enumerate(cases):
        m = tmp_path / f"m{i}.toml"
        m.write_text(text_)
        with pytest.raises(ConfigError, match=pattern):
            dio.read(csv, mapping=m)


def test_mapping_header_name_missing_says_what_was_expected(tmp_path):
    """A header name the file lacks names the key, the file and the header's names (all of a
    short header; the closest few of a long one, see test_vendor_mappings)."""
    data = tmp_path / "log.csv"
    data.write_text("time,pos,cur\n0.0,0.1,0.2\n0.004,0.1,0.2\n")
    m = tmp_path / "m.toml"
    m.write_text(
        '[input]\nheader = true\n[time]\ncolumn = "time"\n[robot]\nname = "irb140"\n'
        '[columns.q]\ncolumns = ["pos"]\n[columns.tau]\ncolumns = ["current"]\n'
    )
    with pytest.raises(ConfigError) as exc:
        dio.read(data, mapping=m)
    assert str(exc.value) == (
        f"{m}: columns.tau.columns[1] is 'current', but the header of {data} has no such column "
        "(expected one of: time, pos, cur)"
    )


def test_mapped_non_numeric_cell_is_named(tmp_path):
    """A text cell in a mapped log names the file, column, target and row."""
    rows = [
        "0.0," + ",".join(["0.1"] * 30),
        "0.01," + ",".join(["0.1"] * 12) + ",x," + ",".join(["0.1"] * 17),
    ]
    p = tmp_path / "ur.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(FormatError) as exc:
        dio.read(p, mapping="ur10e")
    assert str(exc.value) == (
        f"{p}: column 14 (tau_1) has a non-numeric value 'x' in data row 2, expected a number"
    )


def test_builtin_mappings_parse():
    """Every shipped mapping file passes the mapping checks."""
    assert {"franka", "ur10e", "ur_rtde"} <= set(builtin_mappings())
    for name in builtin_mappings():
        spec, path = load_mapping(name)
        assert path.suffix == ".toml" and "q" in spec["columns"]


def test_no_warnings_on_the_sample():
    """The sample recording reads without a unit warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DitherlabWarning)
        dio.read(REPO / "recordings" / "ur10e-static.parquet")


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_storage_file_alone_reads_robot_from_description(tmp_path, sample, storage):
    """The storage file of a bag, read without its folder, takes the URDF from /robot_description."""
    rec = sample.slice(None, 334.0)
    dio.write(rec, tmp_path / "bag", storage=storage)
    f = next(p for p in (tmp_path / "bag").iterdir() if p.suffix in (".mcap", ".db3"))
    back = dio.read(f)
    assert back.meta["robot"]["urdf"] == rec.meta["robot"]["urdf"]
    assert back.meta["source"] == f"ROS 2 bag {f.name}"
    np.testing.assert_array_equal(back.tau, rec.tau)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_damaged_bag_is_a_format_error(tmp_path, sample, storage):
    """A bag whose storage file is cut or overwritten in the middle is a FormatError, never a
    shorter recording."""
    dio.write(sample.slice(None, 336.0), tmp_path / "bag", storage=storage)
    f = next(p for p in (tmp_path / "bag").iterdir() if p.suffix in (".mcap", ".db3"))
    data = f.read_bytes()
    for damaged in (
        data[: len(data) // 2],
        data[: len(data) // 2] + b"\0" * 200 + data[len(data) // 2 + 200 :],
    ):
        f.write_bytes(damaged)
        with pytest.raises(FormatError) as e:
            dio.read(tmp_path / "bag")
        assert str(e.value).startswith(f"{tmp_path / 'bag'}: ")
        # the reader's own error, a storage file shorter than its header says, or fewer
        # messages than the bag's index counts
        assert "not a readable ROS 2 bag" in str(e.value) or "cut off" in str(e.value)


def test_mcap_layout_is_plain_json_with_jsonschema(tmp_path, sample):
    """Other MCAP tools see json channels with jsonschema schemas, a summary and a metadata record."""
    import json

    from mcap.reader import make_reader

    p = tmp_path / "a.mcap"
    dio.write(sample.slice(None, 334.0), p)
    with open(p, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ditherlab"
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes  # chunked and indexed
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {"/ditherlab/joints", "/ditherlab/extra"}
        for ch in topics.values():
            assert ch.message_encoding == "json"
            assert summary.schemas[ch.schema_id].encoding == "jsonschema"
        times = []
        for schema, _channel, message in reader.iter_messages(topics=["/ditherlab/joints"]):
            body = json.loads(message.data)
            required = json.loads(schema.data)["required"]
            assert set(required) <= set(body) and len(body["q"]) == 6
            times.append(message.log_time)
        assert times == sorted(times) and len(times) == len(sample.slice(None, 334.0))
        (meta,) = list(reader.iter_metadata())
        assert meta.name == "ditherlab"
        assert json.loads(meta.metadata["recording"]) == sample.meta


# ------------------------------------------------------------------ the format registry
def _npz_read(path: Path, **options) -> Recording:
    """A toy format: one array per column in a NumPy ``.npz`` file, the metadata as JSON."""
    import json

    from ditherlab.io.common import META_OPTIONS, check_options, meta_from_options

    check_options(options, META_OPTIONS, "npz", str(path))
    with np.load(path) as z:
        meta = json.loads(str(z["__meta__"]))
        data = pd.DataFrame({k: z[k] for k in z.files if k != "__meta__"})
    return Recording(data, meta_from_options(meta, options, where=str(path)), name=str(path))


class _NpzTable:
    """The toy format read in blocks of rows (a :class:`ditherlab.io.format.Table`)."""

    t = None
    rec = None

    def __init__(self, path: Path, **options):
        whole = _npz_read(path, **options)  # small: the toy keeps it, a real one would not
        self.name, self.meta, self._data = str(path), whole.meta, whole.data
        self.columns, self.n_rows = list(whole.data.columns), len(whole.data)

    def frames(self, rows: int, columns: list[str] | None = None):
        data = self._data if columns is None else self._data[columns]
        for a in range(0, self.n_rows, rows):
            yield data.iloc[a : a + rows].reset_index(drop=True)


def test_a_format_registered_at_run_time(tmp_path, sample):
    """A format added at run time (a toy .npz reader, read in blocks) is found by read,
    detect_format, open_source and convert, and refused by write (it has no writer); no other
    file knows it."""
    import json

    from ditherlab.io.format import Format
    from ditherlab.io.stream import open_source

    rec = sample.slice(None, sample.t[0] + 30.0)
    p = tmp_path / "rec.npz"
    np.savez(
        p, __meta__=json.dumps(rec.meta), **{c: rec.data[c].to_numpy() for c in rec.data.columns}
    )
    npz = Format(name="npz", title="a NumPy archive", read=_npz_read, suffixes=(".npz",))
    dio.register(npz)
    try:
        assert dio.detect_format(p) == "npz" and dio.read(p).equals(rec)
        src = open_source(p)
        assert src.kind == "npz" and not src.bounded and src.read().equals(rec)
        out = dio.convert(p, tmp_path / "rec.csv", rows=1000)
        assert dio.read(out).equals(rec)
        with pytest.raises(ConfigError, match=r"rec\.npz: cannot tell the output format"):
            dio.write(rec, tmp_path / "rec.npz")
        dio.unregister("npz")
        dio.register(
            Format(
                name="npz",
                title="a NumPy archive",
                read=_npz_read,
                suffixes=(".npz",),
                open=_NpzTable,
            )
        )
        src = open_source(p)
        assert src.bounded and src.n_rows == len(rec) and src.columns == list(rec.data.columns)
        owned = [piece.rec.data.iloc[piece.keep] for piece in src.pieces(1000)]
        pd.testing.assert_frame_equal(pd.concat(owned, ignore_index=True), rec.data)
        out = dio.convert(p, tmp_path / "rec.mcap", rows=1000)
        assert dio.read(out).equals(rec)
    finally:
        dio.unregister("npz")
    with pytest.raises(FormatError, match=r"rec\.npz: unknown file format"):
        dio.read(p)


def test_read_only_and_unknown_output_formats_are_refused(tmp_path, sample):
    """write names what it refuses: a read-only format, an unknown one, an unknown suffix."""
    with pytest.raises(ConfigError, match=r"read-only output format 'mapping' \(expected one of"):
        dio.write(sample, tmp_path / "x.csv", format="mapping")
    with pytest.raises(ConfigError, match=r"unknown output format 'xls' \(expected one of csv, "):
        dio.write(sample, tmp_path / "x.csv", format="xls")
    with pytest.raises(ConfigError, match=r"the suffix '\.db3' \(expected \.csv, \.parquet, "):
        dio.write(sample, tmp_path / "x.db3")


def test_what_a_path_holds_is_named_when_no_format_takes_it(tmp_path):
    """An MCAP file of another profile, a folder that is not a bag: one line each, naming what
    the path holds and what was expected."""
    from mcap.writer import Writer as McapWriter

    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = McapWriter(f)
        w.start(profile="other", library="test")
        w.finish()
    with pytest.raises(
        FormatError,
        match=r"^\S+other\.mcap: MCAP profile 'other' with schema encodings none; expected a "
        r"ditherlab MCAP file \(profile 'ditherlab'\) or a ROS 2 bag$",
    ):
        dio.read(p)
    d = tmp_path / "empty"
    d.mkdir()
    with pytest.raises(
        FormatError,
        match=r"^\S+empty: a folder without metadata\.yaml, \.mcap or \.db3 inside; expected a "
        r"ROS 2 bag$",
    ):
        dio.detect_format(d)


def test_the_builtin_formats_say_what_they_can():
    """One Format per file type; what each can do is an attribute of it: read in blocks of rows
    (``open``), written (``write``), written block by block (``write_stream``)."""
    from ditherlab.io.registry import formats

    can = {
        f.name: (f.open is not None, f.write is not None, f.write_stream is not None)
        for f in formats()
    }
    assert can == {
        "mapping": (False, False, False),
        "csv": (True, True, True),
        "parquet": (True, True, True),
        "mcap": (True, True, True),
        "rosbag": (True, True, False),
    }


def test_reading_csv_or_parquet_does_not_import_mcap_or_rosbags():
    """The registry imports a format's module when a path first reaches it: a process that
    reads and writes Parquet and CSV never imports the mcap or rosbags libraries."""
    import subprocess
    import sys

    code = (
        "import sys, tempfile, pathlib, ditherlab.io as dio\n"
        f"rec = dio.read({str(REPO / 'recordings' / 'ur10e-static.parquet')!r})\n"
        "d = pathlib.Path(tempfile.mkdtemp())\n"
        "dio.read(dio.write(rec, d / 'a.csv'))\n"
        "dio.read(dio.write(rec, d / 'a.parquet'))\n"
        "print(sorted(m for m in ('mcap', 'rosbags', 'ditherlab.io.mcap', 'ditherlab.io.rosbag')"
        " if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_mapping_none_chooses_no_format(tmp_path, sample):
    """``mapping=None`` (an option left unset) reads the file by its own format."""
    from ditherlab.io.stream import open_source

    p = dio.write(sample, tmp_path / "a.parquet")
    assert dio.read(p, mapping=None).equals(sample)
    assert open_source(p, mapping=None).read().equals(sample)


@pytest.mark.parametrize("suffix", [".csv", ".mcap"])
def test_convert_tells_progress_over_the_samples_written(tmp_path, suffix):
    """``convert`` tells ``progress(done, total)`` after each piece, rising to the recording's
    sample count; the file equals the one-piece write; ``-q`` prints nothing on stderr."""
    from conftest import run_cli

    from ditherlab.app import convert

    src = Path(__file__).resolve().parents[1] / "recordings" / "sim-push-no-dither.parquet"
    n = len(dio.read(src).t)
    calls = []
    opts = convert.ConvertOptions(src=src, dst=tmp_path / f"a{suffix}", chunk_rows=2000)
    convert.run(opts, lambda d, tot: calls.append((d, tot)))
    assert len(calls) > 1 and calls == [(min(k, n), n) for k in range(2000, n + 2000, 2000)]
    whole = convert.ConvertOptions(src=src, dst=tmp_path / f"b{suffix}", chunk_rows=10**6)
    convert.run(whole)
    assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()
    r = run_cli("convert", str(src), str(tmp_path / f"c{suffix}"), "-q")
    assert r.code == 0 and r.err == "", r.err

"""ROS 2 bags through the CLI: ``--joint-topic`` and ``--wrench-topic`` choose the topics of a
bag that has several, on every command that reads recordings, and a wrong choice is one line
naming the option and the topics found."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import one_error
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

import ditherlab.io as dio
from ditherlab.data.recording import Recording, RecordingArrays

META = {"schema": "ditherlab.recording/1", "robot": "irb140"}
JOINTS = [f"joint_{j}" for j in range(1, 7)]
N = 400


def _arrays(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t (N,) [s], q (N, 6) [rad], tau (N, 6) [N·m], w (N, 6) [N, N·m] of a small recording."""
    rng = np.random.default_rng(seed)
    t = 2.0 + np.arange(N) * 0.004
    q = 0.2 * np.sin(np.outer(t, np.arange(1, 7)))
    return t, q, rng.normal(0, 5, (N, 6)), rng.normal(0, 3, (N, 6))


def write_two_topic_bag(path: Path) -> dict[str, np.ndarray]:
    """A bag with two JointState topics (the measured ``/arm/joint_states`` and commands of
    zeros on ``/arm/joint_commands``) and two WrenchStamped topics (``/ft/wrench`` and
    ``/ft/wrench_raw``, twice the first); returns the arrays written."""
    t, q, tau, w = _arrays(0)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    JS, WS = ts.types["sensor_msgs/msg/JointState"], ts.types["geometry_msgs/msg/WrenchStamped"]
    H, T = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    W, V = ts.types["geometry_msgs/msg/Wrench"], ts.types["geometry_msgs/msg/Vector3"]

    def hdr(ns: int) -> object:
        return H(stamp=T(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="tool0")

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as wr:
        js = "sensor_msgs/msg/JointState"
        ws = "geometry_msgs/msg/WrenchStamped"
        c_meas = wr.add_connection("/arm/joint_states", js, typestore=ts)
        c_cmd = wr.add_connection("/arm/joint_commands", js, typestore=ts)
        c_w = wr.add_connection("/ft/wrench", ws, typestore=ts)
        c_raw = wr.add_connection("/ft/wrench_raw", ws, typestore=ts)
        zero = np.zeros(6)
        for i in range(N):
            ns = int(round(t[i] * 1e9))
            for c, pos, eff in ((c_meas, q[i], tau[i]), (c_cmd, zero, zero)):
                m = JS(header=hdr(ns), name=JOINTS, position=pos, velocity=zero, effort=eff)
                wr.write(c, ns, ts.serialize_cdr(m, js))
            for c, k in ((c_w, 1.0), (c_raw, 2.0)):
                f = w[i] * k
                wrench = W(force=V(x=f[0], y=f[1], z=f[2]), torque=V(x=f[3], y=f[4], z=f[5]))
                wr.write(c, ns, ts.serialize_cdr(WS(header=hdr(ns), wrench=wrench), ws))
    return {"t": t, "q": q, "tau": tau, "w": w}


@pytest.fixture(scope="module")
def two_topic_bag(tmp_path_factory) -> tuple[Path, dict[str, np.ndarray]]:
    path = tmp_path_factory.mktemp("bags") / "two_topics"
    return path, write_two_topic_bag(path)


@pytest.mark.parametrize("command", ["info", "convert", "replay", "identify", "diagnose"])
def test_several_joint_topics_name_the_option_and_the_topics(cli, two_topic_bag, tmp_path, command):
    """Every command that reads a bag with two JointState topics asks for --joint-topic and
    lists both topics; nothing is written."""
    bag, _ = two_topic_bag
    args = {
        "info": [bag],
        "convert": [bag, tmp_path / "o.parquet"],
        "replay": [bag, "--model", tmp_path / "m.toml", "-o", tmp_path / "e.parquet"],
        "identify": [bag, "-o", tmp_path / "m2.toml"],
        "diagnose": [bag, "--model", tmp_path / "m.toml"],
    }[command]
    if command in ("replay", "diagnose"):
        rec = Recording.from_arrays(RecordingArrays(*list(_arrays(1))[:3]), META)
        from ditherlab.analysis.identification import identify

        identify([rec], n_boot=0, assume_no_force=True).save(tmp_path / "m.toml")
    line = one_error(cli(command, *args, "--robot", "irb140"))
    assert "choose one with --joint-topic" in line
    assert "/arm/joint_commands" in line and "/arm/joint_states" in line
    assert not any(p.suffix == ".parquet" for p in tmp_path.iterdir())
    assert not (tmp_path / "m2.toml").exists()


def test_topics_chosen_by_option_are_the_ones_read(cli, two_topic_bag, tmp_path):
    """--joint-topic and --wrench-topic pick the measured joints and the raw wrench (twice the
    other topic's values); --wrench-topic '' reads no wrench; two wrench topics and no choice
    ask for --wrench-topic."""
    bag, truth = two_topic_bag
    out = tmp_path / "raw.parquet"
    r = cli("convert", bag, out, "--robot", "irb140", "--joint-topic", "/arm/joint_states",
            "--wrench-topic", "/ft/wrench_raw")  # fmt: skip
    assert r.code == 0, r.err
    rec = dio.read(out)
    np.testing.assert_array_equal(rec.q, truth["q"])
    np.testing.assert_array_equal(rec.tau, truth["tau"])
    np.testing.assert_allclose(rec.wrench, 2.0 * truth["w"], rtol=0, atol=1e-12)
    r = cli("info", bag, "--robot", "irb140", "--joint-topic", "/arm/joint_states",
            "--wrench-topic", "", "--json")  # fmt: skip
    assert r.code == 0, r.err
    assert json.loads(r.out)["columns"]["wrench"] is False
    r = cli("info", bag, "--robot", "irb140", "--joint-topic", "/arm/joint_states")
    assert "choose one with --wrench-topic (wrench_topic=)" in one_error(r)


def test_wrong_topic_names_the_option_and_lists_the_topics(cli, two_topic_bag):
    """A --joint-topic that is a wrench topic, or no topic of the bag, is one line naming the
    option, the value and every topic with its type."""
    bag, _ = two_topic_bag
    line = one_error(cli("info", bag, "--robot", "irb140", "--joint-topic", "/ft/wrench"))
    assert "--joint-topic (joint_topic=) names topic /ft/wrench of type" in line
    assert "/arm/joint_states [sensor_msgs/msg/JointState]" in line
    line = one_error(
        cli(
            "info",
            bag,
            "--robot",
            "irb140",
            "--joint-topic",
            "/arm/joint_states",
            "--wrench-topic",
            "/nope",
        )  # fmt: skip
    )
    assert "--wrench-topic (wrench_topic=) names topic /nope, which is not in the bag" in line
    assert "/ft/wrench_raw [geometry_msgs/msg/WrenchStamped]" in line


def test_topic_option_on_a_file_that_is_not_a_bag(cli, tmp_path):
    """--joint-topic for a Parquet recording is one line saying that it chooses a bag's
    topic."""
    rec = Recording.from_arrays(RecordingArrays(*list(_arrays(2))[:3]), META)
    p = dio.write(rec, tmp_path / "a.parquet")
    line = one_error(cli("info", p, "--joint-topic", "/arm/joint_states"))
    assert line.startswith(f"error: {p}: --joint-topic (joint_topic=) chooses a topic of a ROS 2")

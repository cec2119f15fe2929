"""Tests of ``ditherlab live`` and ``ditherlab publish`` over real DDS on the loopback interface:
the ROS 2 wire format, live equal to ``replay --causal`` bit for bit, and every fault of a
stream reported in one line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from rosbags.typesys import Stores, get_typestore
from test_causal import extraction_model, irb140_model

from ditherlab.core.errors import ConfigError
from ditherlab.io import read, write
from ditherlab.io.dds import LOOPBACK_URI as LOOPBACK
from ditherlab.io.dds import (
    DitherState,
    Header,
    JointState,
    Reader,
    Time,
    WrenchStamped,
    Writer,
    dds_topic,
    participant,
    wrench_stamped,
)
from ditherlab.robot import RobotModel

REPO = Path(__file__).resolve().parents[1]
os.environ["CYCLONEDDS_URI"] = LOOPBACK
#: a domain of this test run's own (other runs on the machine use others)
DOMAIN = 100 + os.getpid() % 100


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 1.2 s piece of the simulated dithered push campaign (motion, dither on, a push), a
    12 s piece from the same start, and the round-valued IRB140 model."""
    d = tmp_path_factory.mktemp("live")
    whole = read(REPO / "recordings" / "sim-push-dither.parquet")
    rec = whole.with_data(whole.data.iloc[900:1200].reset_index(drop=True))
    write(rec, d / "rec.parquet")
    # 12 s: still playing when a Ctrl-C sent 0.4 s in arrives on a loaded machine
    long = whole.with_data(whole.data.iloc[900:3900].reset_index(drop=True))
    write(long, d / "long.parquet")
    irb140_model().save(d / "model.toml")
    return {
        "rec": d / "rec.parquet",
        "model": d / "model.toml",
        "n": len(rec),
        "long": d / "long.parquet",
        "n_long": len(long),
    }


def _env() -> dict[str, str]:
    env = dict(os.environ, CYCLONEDDS_URI=LOOPBACK, PYTHONPATH=str(REPO))
    return env


def _publish(*args: str) -> subprocess.Popen:
    """``ditherlab publish ARGS`` in its own process."""
    cmd = [sys.executable, "-m", "ditherlab", "publish", *args, "--domain", str(DOMAIN), "-q"]
    return subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _columns(path: Path) -> dict[str, np.ndarray]:
    t = pq.read_table(path)
    return {c: t.column(c).to_numpy() for c in t.column_names}


def test_messages_are_ros2_cdr():
    """JointState and WrenchStamped serialise to the very bytes of rosbags' ROS 2 CDR."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    JS = ts.types["sensor_msgs/msg/JointState"]
    theirs = JS(
        header=H(stamp=T(sec=3, nanosec=7), frame_id="base"), name=["a", "bb"],
        position=np.array([0.1, 0.2]), velocity=np.array([], float), effort=np.array([1.0, 2.0]),
    )  # fmt: skip
    ours = JointState(Header(Time(3, 7), "base"), ["a", "bb"], [0.1, 0.2], [], [1.0, 2.0])
    assert bytes(ts.serialize_cdr(theirs, "sensor_msgs/msg/JointState")) == ours.serialize()
    W, V = ts.types["geometry_msgs/msg/Wrench"], ts.types["geometry_msgs/msg/Vector3"]
    WS = ts.types["geometry_msgs/msg/WrenchStamped"]
    theirs = WS(
        header=H(stamp=T(sec=1, nanosec=500), frame_id="tool0"),
        wrench=W(force=V(x=1.0, y=-2.0, z=3.5), torque=V(x=0.0, y=0.25, z=-1.0)),
    )
    ours = wrench_stamped(1.0000005, "tool0", np.array([1.0, -2.0, 3.5, 0.0, 0.25, -1.0]))
    assert bytes(ts.serialize_cdr(theirs, "geometry_msgs/msg/WrenchStamped")) == ours.serialize()


def test_topic_names():
    """ROS 2 topics map to DDS's rt/ names, in a namespace when relative; bad names refused."""
    assert dds_topic("/joint_states") == "rt/joint_states"
    assert dds_topic("joint_states", "/arm") == "rt/arm/joint_states"
    assert dds_topic("/joint_states", "arm") == "rt/joint_states"
    for bad in ("", "/a//b", "/a b", "/a/"):
        with pytest.raises(ConfigError, match="is not a ROS 2 topic name"):
            dds_topic(bad)


def test_live_over_dds_equals_replay_causal(files, tmp_path, cli):
    """A recording published over DDS (another process, in a namespace, with its F/T sensor)
    and estimated live gives replay --causal's estimates file: the same columns, rows and floats; the
    estimate then stops when the publisher does."""
    rc, lv = tmp_path / "rc.parquet", tmp_path / "live.parquet"
    r = cli("replay", files["rec"], "--model", files["model"], "-o", rc, "--causal", "-q")
    assert r.code == 0, r.err
    dp = participant(DOMAIN)
    topics = ("rt/ditherlab/wrench", "rt/ditherlab/wrench/lower", "rt/ditherlab/wrench/upper")
    readers = [Reader(dp, t, WrenchStamped) for t in topics]
    pub = _publish(str(files["rec"]), "--rate", "2", "--wrench-topic", "ft", "--namespace", "/arm")
    res = cli(
        "live", "--model", files["model"], "--source", "ros2:joint_states", "--namespace", "/arm",
        "--wrench-topic", "ft", "--sink", f"parquet:{lv}", "--sink", "ros2:/ditherlab/wrench",
        "--domain", DOMAIN, "--timeout", "1",
    )  # fmt: skip
    assert pub.wait(60) == 0, pub.stderr.read()
    assert res.code == 0, res.err
    assert "stopped: no sample for 1 s: the publisher stopped" in res.out
    a, b = _columns(rc), _columns(lv)
    assert list(a) == list(b) and len(b["t"]) == files["n"]
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # the ros2 sink: dither_band's estimate and its bounds, one WrenchStamped per sample each
    for reader, suffix in zip(readers, ("", "_lo", "_hi"), strict=True):
        got = [m for m in reader.take(10_000) if isinstance(m, WrenchStamped)]
        assert len(got) == files["n"]
        fx = np.array([m.wrench.force.x for m in got])
        mz = np.array([m.wrench.torque.z for m in got])
        np.testing.assert_array_equal(fx, b[f"dither_band/f_x{suffix}"])
        np.testing.assert_array_equal(mz, b[f"dither_band/m_z{suffix}"])
        stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in got])
        np.testing.assert_array_equal(stamps, b["t"])


def _crafted(names: list[str]) -> list[tuple[str, JointState]]:
    """Good joint states at 250 Hz with one of each fault among them: (what, message)."""
    q = [0.0, -0.3, 0.4, 0.0, 0.5, 0.0]

    def js(k: int, names=names, pos=q, eff=None) -> JointState:
        t = 0.004 * k
        return JointState(
            Header(Time(0, round(t * 1e9)), ""), list(names), list(pos), [0.0] * len(pos),
            list(eff if eff is not None else [0.0, 20.0, 5.0, 0.0, 1.0, 0.0]),
        )  # fmt: skip

    out = [("good", js(k)) for k in range(30)]
    out += [
        ("duplicated stamp", js(29)),
        ("out of order", js(20)),
        ("not finite", js(30, pos=[np.nan] + q[1:])),
        ("other joint names", js(31, names=[f"other_{j}" for j in range(6)])),
        ("joint count", js(32, eff=[1.0] * 5)),
    ]
    out += [("good", js(k)) for k in range(33, 60)]
    return out


def _send(msgs: list[tuple[str, JointState]]) -> None:
    """Publish ``msgs`` from this process once a reader matches."""
    w = Writer(participant(DOMAIN), "rt/joint_states", JointState)
    end = time.monotonic() + 20
    while w.matched() == 0 and time.monotonic() < end:
        time.sleep(0.02)
    time.sleep(0.2)
    for _, m in msgs:
        w.write(m)
        time.sleep(0.004)
    time.sleep(0.5)


def test_faults_are_one_line_each(files, tmp_path, cli):
    """Duplicated and out-of-order stamps, a NaN, other joint names and another joint count are
    each dropped with one line; the estimate goes on with the good samples only, in order."""
    names = list(RobotModel.from_spec("irb140").joint_names)
    msgs = _crafted(names)
    sender = threading.Thread(target=_send, args=(msgs,))
    sender.start()
    out = tmp_path / "f.parquet"
    res = cli(
        "live", "--model", files["model"], "--source", "ros2:/joint_states",
        "--sink", f"parquet:{out}", "--domain", DOMAIN, "--timeout", "0.5",
    )  # fmt: skip
    sender.join()
    assert res.code == 0, res.err
    assert "Traceback" not in res.err
    lines = [ln for ln in res.err.splitlines() if not ln.startswith("live: estimating")]
    kinds = ("duplicated stamp", "out of order", "NaN", "lack the model's", "expected one per name")
    assert len(lines) == len(kinds), res.err
    for kind in kinds:
        assert sum(kind in ln for ln in lines) == 1, (kind, res.err)
    t = _columns(out)["t"]
    good = [m.header.stamp.nanosec * 1e-9 for what, m in msgs if what == "good"]
    np.testing.assert_array_equal(t, good)


def test_no_publisher_is_one_line(files, tmp_path, cli):
    """Without a publisher the command says so in one line after --wait, exit 2, no file."""
    out = tmp_path / "none.parquet"
    res = cli(
        "live", "--model", files["model"], "--source", "ros2:/nobody_here",
        "--sink", f"parquet:{out}", "--domain", DOMAIN, "--wait", "0.5",
    )  # fmt: skip
    assert res.code == 2 and res.out == "" and "Traceback" not in res.err
    assert res.err.count("\n") == 1 and "no joint state" in res.err and "rt/nobody_here" in res.err
    assert not out.exists()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["--source", "udp:/x", "--sink", "parquet:o.parquet"], "--source 'udp:/x' is not"),
        (["--source", "ros2:/j", "--sink", "csv:o.csv"], "--sink 'csv:o.csv' is not"),
        (["--source", "ros2:/a b", "--sink", "parquet:o.parquet"], "not a ROS 2 topic name"),
        (["--source", "ros2:/j", "--sink", "parquet:o.csv"], "o.csv"),
    ],
)
def test_bad_options_are_one_line(files, tmp_path, cli, args, expected):
    """A source or sink that does not parse is refused in one line naming it, exit 2."""
    os.chdir(tmp_path)
    res = cli("live", "--model", files["model"], *args, "--domain", DOMAIN, "--wait", "0.2")
    assert res.code == 2 and res.out == "" and len(res.err.splitlines()) == 1, res.err
    assert expected in res.err


def test_slow_consumer_drops_are_counted(files, tmp_path, cli):
    """A queue of 2 samples behind a stream 20 times faster than real time drops samples, says
    so in one line and counts them; what is kept stays in order."""
    out = tmp_path / "slow.parquet"
    pub = _publish(str(files["rec"]), "--rate", "20")
    res = cli(
        "live", "--model", files["model"], "--source", "ros2:/joint_states", "--queue", "2",
        "--sink", f"parquet:{out}", "--domain", DOMAIN, "--timeout", "1",
    )  # fmt: skip
    assert pub.wait(60) == 0
    assert res.code == 0, res.err
    assert sum("fell 2 samples behind" in ln for ln in res.err.splitlines()) == 1, res.err
    dropped = int(res.out.split("slow consumer: ")[1].split(";")[0].split(",")[0])
    t = _columns(out)["t"]
    assert dropped > 0 and len(t) + dropped <= files["n"]
    assert (np.diff(t) > 0).all()


def test_ctrl_c_closes_the_file(files, tmp_path):
    """SIGINT during a live estimate of a file played in real time ends it cleanly: exit 0, a
    readable estimates file holding the first samples, equal to replay --causal's."""
    out, rc = tmp_path / "int.parquet", tmp_path / "rc.parquet"
    cmd = [
        sys.executable, "-m", "ditherlab", "live", "--model", str(files["model"]),
        "--source", f"file:{files['long']}", "--sink", f"parquet:{out}",
    ]  # fmt: skip
    p = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert "live: estimating" in p.stderr.readline()
    time.sleep(0.4)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=30)
    assert p.returncode == 0, stderr
    assert "stopped: interrupted (Ctrl-C)" in stdout and "Traceback" not in stderr
    got = _columns(out)
    assert 0 < len(got["t"]) < files["n_long"]
    from conftest import run_cli

    assert (
        run_cli("replay", files["long"], "--model", files["model"], "-o", rc, "--causal").code == 0
    )
    want = _columns(rc)
    for k in got:
        np.testing.assert_array_equal(got[k], want[k][: len(got["t"])], err_msg=k)


def test_file_source_and_duration(files, tmp_path, cli):
    """A file played at once is replay --causal's estimate; --duration stops after that much
    of the stream, the file closed whole with the rows up to then."""
    rc, a, b = tmp_path / "rc.parquet", tmp_path / "a.parquet", tmp_path / "b.parquet"
    assert cli("replay", files["rec"], "--model", files["model"], "-o", rc, "--causal").code == 0
    src = f"file:{files['rec']}"
    r = cli(
        "live", "--model", files["model"], "--source", src, "--rate", "0", "--sink", f"parquet:{a}"
    )
    assert r.code == 0 and "stopped: the end of the recording" in r.out, r.err
    want, got = _columns(rc), _columns(a)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    r = cli(
        "live", "--model", files["model"], "--source", src, "--rate", "0", "--duration", "0.5",
        "--sink", f"parquet:{b}",
    )  # fmt: skip
    assert r.code == 0 and "0.5 s of stream estimated (--duration)" in r.out, r.err
    t = _columns(b)["t"]
    assert t[-1] - t[0] >= 0.5 and len(t) < files["n"]
    np.testing.assert_array_equal(t, want["t"][: len(t)])


def test_file_source_with_dither_extraction(files, tmp_path, cli):
    """A model with ``dither_extraction`` (the demo's kind): live from a file played at once
    (motion, the dither's start, a push) is replay --causal's estimate bit for bit, and the
    effect moves the dither variants'."""
    m, rec = tmp_path / "m.toml", tmp_path / "rec.parquet"
    extraction_model().save(m)
    whole = read(REPO / "recordings" / "sim-push-dither.parquet")
    write(whole.with_data(whole.data.iloc[900:1500].reset_index(drop=True)), rec)  # a push
    rc, lv, plain = (tmp_path / f"{x}.parquet" for x in ("rc", "lv", "plain"))
    r = cli("replay", rec, "--model", m, "-o", rc, "--causal", "-q")
    assert r.code == 0, r.err
    src = f"file:{rec}"
    r = cli("live", "--model", m, "--source", src, "--rate", "0", "--sink", f"parquet:{lv}")
    assert r.code == 0, r.err
    want, got = _columns(rc), _columns(lv)
    assert list(got) == list(want)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)
    r = cli("replay", rec, "--model", files["model"], "-o", plain, "--causal", "-q")
    assert r.code == 0, r.err
    assert np.abs(_columns(plain)["dither_band/f_x"] - want["dither_band/f_x"]).max() > 0.5


def _send_with_dither(skip: int) -> None:
    """40 joint states at 250 Hz, each after its DitherState (dither off) but for number
    ``skip``."""
    dp = participant(DOMAIN)
    js = Writer(dp, "rt/joint_states", JointState)
    ds = Writer(dp, "rt/ditherlab/dither", DitherState)
    end = time.monotonic() + 20
    while js.matched() == 0 and time.monotonic() < end:
        time.sleep(0.02)
    time.sleep(0.2)
    names = list(RobotModel.from_spec("irb140").joint_names)
    for k in range(40):
        h = Header(Time(0, 4_000_000 * k), "")
        if k != skip:
            ds.write(DitherState(h, False, 0.08, names, []))
        q, tau = [0.0, -0.3, 0.4, 0.0, 0.5, 0.0], [0.0, 20.0, 5.0, 0.0, 1.0, 0.0]
        js.write(JointState(h, names, q, [0.0] * 6, tau))
        time.sleep(0.004)
    time.sleep(0.5)


def test_a_missing_dither_state_is_one_line(files, tmp_path, cli):
    """With the dither topic in use, a joint state whose DitherState never comes is dropped
    with one line; the dither variants run with the period the DitherState gives."""
    sender = threading.Thread(target=_send_with_dither, args=(20,))
    sender.start()
    out = tmp_path / "d.parquet"
    res = cli(
        "live", "--model", files["model"], "--source", "ros2:/joint_states",
        "--sink", f"parquet:{out}", "--domain", DOMAIN, "--timeout", "0.5",
    )  # fmt: skip
    sender.join()
    assert res.code == 0, res.err
    lines = [ln for ln in res.err.splitlines() if not ln.startswith("live: estimating")]
    assert len(lines) == 1 and "no DitherState with its stamp" in lines[0], res.err
    cols = _columns(out)
    assert len(cols["t"]) == 39 and "dither_band/f_x" in cols
    assert not cols["dither"].any()


def test_publish_without_subscriber_is_one_line(files, cli):
    """publish waits --wait seconds for a subscriber, then says so in one line, exit 2."""
    res = cli("publish", files["rec"], "--topic", "/nobody_listens", "--domain", DOMAIN,
              "--wait", "0.3", "-q")  # fmt: skip
    assert res.code == 2 and res.out == "" and len(res.err.splitlines()) == 1, res.err
    assert "no subscriber on rt/nobody_listens within 0.3 s" in res.err

"""ROS 2 bags read in pieces (ditherlab.io.rosbag through ditherlab.io.stream): a first pass keeps
the time stamps, a second reads the messages block by block with the wrench merge's neighbours
carried across each cut; the blocks equal the whole read, and the commands' results too."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from test_io import IRB_JOINTS, write_foreign_bag

from ditherlab.core.errors import DitherlabWarning, FormatError
from ditherlab.data.estimates import Estimates
from ditherlab.io import read
from ditherlab.io import rosbag as bag_io
from ditherlab.io.stream import open_source


def _foreign(path: Path, storage: StoragePlugin, seed: int = 5) -> dict[str, np.ndarray]:
    """A driver's bag: 3000 jittered joint states at 250 Hz (one stamp repeated), a 100 Hz wrench
    that starts late and ends early (one stamp repeated): rows dropped at both ends."""
    rng = np.random.default_rng(seed)
    n, m = 3000, 1000
    t = 10.0 + np.arange(n) * 0.004 + rng.uniform(0, 1e-3, n)
    t[100] = t[99]
    t_w = 10.0505 + np.arange(m) * 0.01 + rng.uniform(0, 2e-3, m)
    t_w[50] = t_w[49]
    arrays = {
        "t": t,
        "q": rng.uniform(-1, 1, (n, 6)),
        "tau": rng.normal(0, 20, (n, 6)),
        "t_w": t_w,
        "w": np.cumsum(rng.normal(0, 1, (m, 6)), axis=0),
    }
    write_foreign_bag(path, storage, **arrays)
    return arrays


def _quiet_read(path: Path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DitherlabWarning)
        return read(path, **options)


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_bag_blocks_equal_the_whole_read_and_the_merge_rule(tmp_path, storage):
    """Blocks of 1, 2, 3, 97, 1000 and more rows are the rows of the whole read, which is the
    merge rule applied to all the samples at once; n_rows, columns and t come from the first
    pass, with the whole read's warnings."""
    bag = tmp_path / "drive"
    a = _foreign(bag, storage)
    with pytest.warns(DitherlabWarning) as got:
        src = open_source(bag, robot="irb140")
    msgs = sorted(str(w.message) for w in got)
    assert "1 messages on /robot/joint_states repeat the previous time stamp" in msgs[0]
    assert "joint-state samples between" in msgs[1] and "lie outside the wrench" in msgs[1]
    whole = _quiet_read(bag, robot="irb140").data
    assert src.bounded and src.n_rows == len(whole) and src.columns == list(whole.columns)
    np.testing.assert_array_equal(src.times(), whole["t"].to_numpy())
    # the reference: the merge rule over all the samples (stamps as the bag holds them, in ns)
    t = np.round(a["t"] * 1e9).astype(np.int64)
    keep = np.r_[True, np.diff(t) > 0]
    tw = np.round(a["t_w"] * 1e9).astype(np.int64)
    kw = np.r_[True, np.diff(tw) > 0]
    W, covered = bag_io.merge_onto(t[keep] * 1e-9, tw[kw] * 1e-9, a["w"][kw], 0.002)
    assert 0 < covered.sum() < keep.sum()
    np.testing.assert_array_equal(whole["t"], (t[keep] * 1e-9)[covered])
    np.testing.assert_array_equal(whole[[f"q_{j}" for j in range(1, 7)]], a["q"][keep][covered])
    np.testing.assert_array_equal(whole[["f_x", "f_y", "f_z", "m_x", "m_y", "m_z"]], W[covered])
    for rows in (1, 2, 3, 97, 1000, len(whole) + 3):
        blocks = list(src.frames(rows))
        assert [len(b) for b in blocks[:-1]] == [rows] * (len(blocks) - 1), rows
        pd.testing.assert_frame_equal(pd.concat(blocks, ignore_index=True), whole, check_exact=True)
    got = pd.concat(list(src.frames(333, ["m_z", "t"])), ignore_index=True)
    pd.testing.assert_frame_equal(got, whole[["m_z", "t"]], check_exact=True)


def test_bag_blocks_are_read_as_the_messages_come(tmp_path, monkeypatch):
    """The first block of 200 rows is handed out after about 200 joint states and the wrench
    samples up to their end: the bag is not read ahead."""
    bag = tmp_path / "drive"
    a = _foreign(bag, StoragePlugin.MCAP)
    with pytest.warns(DitherlabWarning):  # the repeated stamp and the rows outside the wrench
        src = open_source(bag, robot="irb140")
    pulled = [0]
    messages = bag_io._Bag.__iter__

    def counting(self):
        for m in messages(self):
            pulled[0] += 1
            yield m

    monkeypatch.setattr(bag_io._Bag, "__iter__", counting)
    it = src.frames(200)
    first = next(it)
    assert len(first) == 200
    # the 13 joint states before the wrench are dropped as they come; the block needs the joint
    # states up to its last row and the wrench up to its first sample at or after it (the bag
    # interleaves the two by time)
    t = np.unique(np.round(a["t"] * 1e9)) * 1e-9
    assert first["t"].iloc[0] == t[13] and first["t"].iloc[-1] == t[212]
    end = t[212]
    need = int((a["t"] <= end + 1e-9).sum()) + int((a["t_w"] < end - 1e-9).sum()) + 1
    assert need <= pulled[0] <= need + 2, (need, pulled[0])
    assert pulled[0] < (len(a["t"]) + len(a["t_w"])) / 10  # not the whole bag
    it.close()
    # no merge holds more than a block: the ~500 joint states after the wrench's end are
    # dropped as they come, not held until the bag ends
    merged = []
    merge_onto = bag_io.merge_onto

    def recording(t, *args):
        merged.append(len(t))
        return merge_onto(t, *args)

    monkeypatch.setattr(bag_io, "merge_onto", recording)
    blocks = list(src.frames(200))
    assert sum(len(b) for b in blocks) == src.n_rows and max(merged) <= 200, merged


def _unordered_bag(path: Path, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Joint states whose header stamps go back now and then in the bag's (receive) order."""
    rng = np.random.default_rng(8)
    t = 5.0 + np.arange(n) * 0.004
    th = t + rng.uniform(-0.006, 0.006, n)
    q = rng.uniform(-1, 1, (n, 6))
    ts = get_typestore(Stores.ROS2_HUMBLE)
    JS, H = ts.types["sensor_msgs/msg/JointState"], ts.types["std_msgs/msg/Header"]
    T = ts.types["builtin_interfaces/msg/Time"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as wr:
        c = wr.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for i in range(n):
            ns = int(round(th[i] * 1e9))
            stamp = T(sec=ns // 10**9, nanosec=ns % 10**9)
            m = JS(
                header=H(stamp=stamp, frame_id=""),
                name=list(IRB_JOINTS),
                position=q[i],
                velocity=2 * q[i],
                effort=q[i] * 10,
            )
            wr.write(c, int(round(t[i] * 1e9)), ts.serialize_cdr(m, "sensor_msgs/msg/JointState"))
    return np.round(th * 1e9).astype(np.int64), q


def test_bag_whose_stamps_go_back_is_sorted_and_read_whole(tmp_path):
    """Sorting needs every message: such a bag is read whole (not bounded), the same table."""
    bag = tmp_path / "unordered"
    stamps, q = _unordered_bag(bag)
    src = open_source(bag, robot="irb140")
    assert not src.bounded
    order = np.argsort(stamps, kind="stable")
    whole = read(bag, robot="irb140").data
    np.testing.assert_array_equal(whole["t"], stamps[order] * 1e-9)
    np.testing.assert_array_equal(whole[[f"dq_{j}" for j in range(1, 7)]], 2 * q[order])
    pd.testing.assert_frame_equal(pd.concat(list(src.frames(300)), ignore_index=True), whole)


@pytest.fixture(scope="module")
def bag_campaign(tmp_path_factory):
    """A simulated push campaign written as a ROS 2 bag by convert, and a model."""
    from conftest import run_cli

    d = tmp_path_factory.mktemp("stream_bag")
    pq_path, bag, model = d / "rec.parquet", d / "rec_bag", d / "m.toml"
    r = run_cli(
        "simulate", "push-campaign", "--seed", "23", "--pushes-per-direction", "2", "-o", pq_path
    )
    assert r.code == 0, r.err
    assert run_cli("convert", pq_path, bag).code == 0
    r = run_cli("identify", pq_path, "-o", model, "--bootstrap", "0", "-q")
    assert r.code == 0, r.err
    return d, pq_path, bag, model


def test_cli_on_a_bag_in_pieces_equals_the_whole(bag_campaign, cli):
    """convert, info and replay of a bag with a small --chunk (cut inside a push) give the
    results of one piece; the bag's table is the Parquet recording's joint and wrench columns."""
    from test_stream import _awkward_cuts

    d, pq_path, bag, model = bag_campaign
    rec = read(pq_path)
    n, rows = len(rec), _awkward_cuts(rec)["push"]
    outs = {}
    for name, chunk in (("whole", n), ("cut", rows)):
        out = d / f"conv_{name}.parquet"
        r = cli("convert", bag, out, "--chunk", str(chunk))
        assert r.code == 0, r.err
        outs[name] = read(out)
    assert outs["whole"].equals(outs["cut"]) and outs["cut"].equals(read(bag))
    cols = list(outs["cut"].data.columns)
    assert "dq_6" in cols and "m_z" in cols
    got, want = outs["cut"].data, rec.data[cols]
    pd.testing.assert_frame_equal(got.drop(columns="t"), want.drop(columns="t"), check_exact=True)
    np.testing.assert_allclose(got["t"], want["t"], rtol=0, atol=1e-9)  # the bag's stamps: ns

    info = {}
    for name, chunk in (("whole", n), ("cut", 2222)):
        r = cli("info", bag, "--json", "--chunk", str(chunk))
        assert r.code == 0, r.err
        info[name] = json.loads(r.out)
    reg = {k: v.pop("regimes") for k, v in info.items()}
    assert info["whole"] == info["cut"] and info["cut"]["samples"] == n
    assert reg["cut"] == pytest.approx(reg["whole"], abs=1e-12)

    est = {}
    for name, chunk in (("whole", n), ("cut", rows)):
        out = d / f"est_{name}.parquet"
        r = cli("replay", bag, "--model", model, "-o", out, "-q", "--chunk", str(chunk))
        assert r.code == 0, r.err
        est[name] = Estimates.load(out).data
    pd.testing.assert_frame_equal(est["whole"], est["cut"], check_exact=True)


def test_damaged_bag_through_the_cli_is_one_line(bag_campaign, cli, tmp_path):
    """A bag whose storage file is cut in half: info and convert in pieces say so in one line."""
    import shutil

    _, _, bag, _ = bag_campaign
    bad = tmp_path / "bad_bag"
    shutil.copytree(bag, bad)
    f = next(bad.glob("*.mcap"))
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    for args in (("info", bad, "--chunk", "2222"), ("convert", bad, tmp_path / "o.parquet")):
        r = cli(*args)
        assert r.code == 2 and r.err.count("\n") == 1 and "Traceback" not in r.err, r.err
        assert r.err.startswith(f"error: {bad}: not a readable ROS 2 bag ("), r.err
    assert not (tmp_path / "o.parquet").exists()


@pytest.mark.parametrize("name", ["cdr_test_0.mcap", "talker.mcap"])
def test_real_ros2_bags_name_the_topics_they_hold(shared_data, name):
    """Bags written by ROS 2 itself (no JointState): opening one in pieces lists its topics."""
    with pytest.raises(
        FormatError, match=r"no sensor_msgs/msg/JointState topic .* topics found: /"
    ):
        open_source(shared_data / "rosbag2" / name, robot="irb140")

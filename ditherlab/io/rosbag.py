"""ROS 2 bags (MCAP or SQLite 3 storage; a bag folder or a single storage file) with ``rosbags``.

Reading
-------
- ``sensor_msgs/msg/JointState`` → ``q`` (position), ``dq`` (velocity, when every message has
  it), ``tau`` (effort, required). Joints are matched **by name** to the robot's joint names and
  reordered to the robot's order; messages may list extra joints (ignored) but must contain all
  of the robot's. The sample time is ``header.stamp`` (the bag's receive time when the stamp is
  zero). Messages with a repeated stamp are dropped (first one kept) with a warning.
- ``geometry_msgs/msg/WrenchStamped`` → ``f_x .. m_z``, taken as the wrench at the tool point in
  base-frame axes (RECORDING.md); no TF transform is applied, ``header.frame_id`` is recorded
  in the metadata (``wrench_frame``). **Merge rule** onto the joint-state time base: for each
  joint-state time, the nearest wrench sample when it lies within ``wrench_tolerance``
  (default: half the median joint-state period); otherwise linear interpolation between the two
  wrench samples around it; joint-state samples before the first or after the last wrench
  sample (beyond the tolerance) are **dropped with a DitherlabWarning** stating how many and
  where. No overlap at all is a FormatError.
- Topics: ``joint_topic=`` / ``wrench_topic=`` choose them; otherwise the single topic of each
  type is used (several JointState topics → FormatError asking to choose; no WrenchStamped
  topic → a recording without F/T columns; ``wrench_topic=""`` ignores the wrench).
- The robot: ``robot=`` (name or URDF path), else the ditherlab metadata stored by :func:`write`
  in the bag's ``custom_data``, else a ``/robot_description`` (``std_msgs/msg/String``) topic.

Writing
-------
:func:`write` makes a bag folder (``metadata.yaml`` + one storage file, rosbag2 version 9,
``storage="mcap"`` or ``"sqlite3"``) with ``/joint_states`` (JointState, names = the robot's
joint names), ``/wrench`` (WrenchStamped, frame ``base``) when F/T columns exist,
``/robot_description`` (the URDF) and the recording metadata as JSON under ``custom_data``
key ``ditherlab``. Columns other than q, dq, tau and the wrench are not stored.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import struct
import tempfile
import warnings
from pathlib import Path
from typing import Any

import apsw
import numpy as np
import pandas as pd
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from ditherlab.errors import ConfigError, DitherlabWarning, FormatError
from ditherlab.io.atomic import current_umask
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
    urdf_spec,
)
from ditherlab.recording import WRENCH_COLUMNS, Recording
from ditherlab.robot import RobotModel

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
STRING = "std_msgs/msg/String"
OPTIONS = (*META_OPTIONS, "joint_topic", "wrench_topic", "wrench_tolerance")
#: Message definitions used when a bag carries none (old sqlite3 bags), and for writing.
TYPESTORE = Stores.ROS2_HUMBLE


def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)  # [ns]


def _topic_list(topics: dict[str, str]) -> str:
    return ", ".join(f"{k} [{v}]" for k, v in sorted(topics.items())) or "none"


def _pick(
    topics: dict[str, str],
    wanted: str | None,
    msgtype: str,
    option: str,
    path: Path,
    required: bool,
) -> str | None:
    if wanted:
        if wanted not in topics:
            raise FormatError(
                f"{path}: topic {wanted} ({option}) is not in the bag; topics "
                f"found: {_topic_list(topics)}"
            )
        if topics[wanted] != msgtype:
            raise FormatError(
                f"{path}: topic {wanted} has type {topics[wanted]}, expected {msgtype}"
            )
        return wanted
    found = sorted(k for k, v in topics.items() if v == msgtype)
    if len(found) > 1:
        raise FormatError(
            f"{path}: several {msgtype} topics ({', '.join(found)}); choose one with {option}="
        )
    if not found:
        if required:
            raise FormatError(
                f"{path}: no {msgtype} topic (needed for the joint positions and torques); "
                f"topics found: {_topic_list(topics)}"
            )
        return None
    return found[0]


def read(path: Path, **options: Any) -> Recording:
    """Read a ROS 2 bag (folder, ``.mcap`` or ``.db3``) into a Recording (rules above)."""
    path = Path(path)
    check_options(options, OPTIONS, "ROS 2 bag", str(path))
    default_ts = get_typestore(TYPESTORE)
    try:
        with AnyReader([path], default_typestore=default_ts) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            jtopic = _pick(
                topics, options.get("joint_topic"), JOINT_STATE, "joint_topic", path, required=True
            )
            wopt = options.get("wrench_topic")
            wtopic = (
                None
                if wopt == ""
                else _pick(topics, wopt, WRENCH_STAMPED, "wrench_topic", path, required=False)
            )
            custom = _custom_data(reader)
            urdf_text = None
            joints: list[tuple[int, Any]] = []
            wrenches: list[tuple[int, Any]] = []
            conns = [
                c
                for c in reader.connections
                if c.topic in (jtopic, wtopic)
                or (c.topic == "/robot_description" and c.msgtype == STRING)
            ]
            for conn, stamp, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == jtopic:
                    joints.append((_stamp(msg.header) or stamp, msg))
                elif conn.topic == wtopic:
                    wrenches.append((_stamp(msg.header) or stamp, msg))
                else:
                    urdf_text = msg.data
    except FormatError:
        raise
    except (
        AnyReaderError,
        OSError,
        ValueError,
        KeyError,
        AssertionError,
        struct.error,
        sqlite3.Error,
        apsw.Error,
        OverflowError,
        IndexError,
    ) as exc:  # what rosbags raises on a damaged bag
        raise FormatError(f"{path}: not a readable ROS 2 bag ({exc})") from None
    if not joints:
        raise FormatError(f"{path}: topic {jtopic} [{JOINT_STATE}] has no messages")

    stored = loads_meta(custom["ditherlab"], str(path)) if "ditherlab" in custom else None
    if stored is None and urdf_text and options.get("robot") is None:
        robot = urdf_spec(urdf_text, options.get("tool_frame"), where=f"{path}: /robot_description")
        stored = {"robot": robot}
    foreign = "ditherlab" not in custom  # a bag that ditherlab did not write
    meta = meta_from_options(stored, options, where=str(path))
    if foreign:
        meta.setdefault("source", f"ROS 2 bag {path.name}")
    names = _joint_names(meta, path)
    data = _joint_table(joints, names, jtopic, path)
    if wtopic is not None and wrenches:
        data, frame = _merge_wrench(data, wrenches, options.get("wrench_tolerance"), wtopic, path)
        if frame and foreign:
            meta["wrench_frame"] = frame
    return Recording(data, meta, name=str(path))


def _custom_data(reader: AnyReader) -> dict[str, str]:
    out: dict[str, str] = {}
    for r in reader.readers:
        md = getattr(getattr(r, "storage", None), "metadata", None)
        custom = getattr(md, "custom", None)
        if isinstance(custom, dict):
            out.update(custom)
    return out


def _joint_names(meta: dict[str, Any], path: Path) -> list[str]:
    return list(RobotModel.from_spec(meta["robot"], where=str(path)).joint_names)


def _joint_table(
    joints: list[tuple[int, Any]], names: list[str], topic: str, path: Path
) -> pd.DataFrame:
    joints.sort(key=lambda x: x[0])
    stamps = np.array([s for s, _ in joints], dtype=np.int64)
    keep = np.ones(len(stamps), dtype=bool)
    keep[1:] = np.diff(stamps) > 0
    if not keep.all():
        warnings.warn(
            f"{path}: {int((~keep).sum())} messages on {topic} repeat the previous "
            "time stamp and were dropped",
            DitherlabWarning,
            stacklevel=3,
        )
    n = len(names)
    q = np.empty((len(joints), n))
    tau = np.empty((len(joints), n))
    dq: np.ndarray | None = np.empty((len(joints), n))
    for i, (_, msg) in enumerate(joints):
        index = {nm: k for k, nm in enumerate(msg.name)}
        missing = [nm for nm in names if nm not in index]
        if missing:
            raise FormatError(
                f"{path}: {topic} message {i + 1} has no joint {missing[0]} (names in the "
                f"message: {', '.join(msg.name) or 'none'}; the robot's joints: {', '.join(names)})"
            )
        order = [index[nm] for nm in names]
        pos, eff, vel = (np.asarray(msg.position), np.asarray(msg.effort), np.asarray(msg.velocity))
        if len(pos) != len(msg.name):
            raise FormatError(
                f"{path}: {topic} message {i + 1} has {len(pos)} positions for "
                f"{len(msg.name)} joint names"
            )
        if len(eff) != len(msg.name):
            raise FormatError(
                f"{path}: {topic} message {i + 1} has {len(eff)} efforts for "
                f"{len(msg.name)} joint names (tau needs the effort field)"
            )
        q[i], tau[i] = pos[order], eff[order]
        if dq is not None:
            if len(vel) == len(msg.name):
                dq[i] = vel[order]
            else:
                dq = None
    cols: dict[str, np.ndarray] = {"t": stamps[keep] * 1e-9}
    for prefix, arr in (("q", q), ("dq", dq), ("tau", tau)):
        if arr is not None:
            for j in range(n):
                cols[f"{prefix}_{j + 1}"] = arr[keep, j]
    return pd.DataFrame(cols)


def merge_onto(
    t: np.ndarray, t_w: np.ndarray, w: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Resample wrench samples onto joint-state times (the module's merge rule).

    Parameters
    ----------
    t : (N,) [s] joint-state times, increasing
    t_w : (M,) [s] wrench times, increasing
    w : (M, 6) [N, N·m]
    tol : [s] nearest-sample tolerance

    Returns
    -------
    W : (N, 6) [N, N·m] (NaN where not covered)
    covered : (N,) bool, False for joint samples outside the wrench's span (beyond ``tol``)
    """
    idx = (
        np.clip(np.searchsorted(t_w, t), 1, len(t_w) - 1)
        if len(t_w) > 1
        else np.zeros(len(t), dtype=int)
    )
    left = np.maximum(idx - 1, 0)
    d_left, d_right = np.abs(t - t_w[left]), np.abs(t_w[idx] - t)
    nearest = np.where(d_left <= d_right, left, idx)
    near_ok = np.abs(t_w[nearest] - t) <= tol
    inside = (t >= t_w[0]) & (t <= t_w[-1])
    out = np.full((len(t), 6), np.nan)
    for k in range(6):
        out[:, k] = np.interp(t, t_w, w[:, k])
    out[near_ok] = w[nearest[near_ok]]
    covered = near_ok | inside
    out[~covered] = np.nan
    return out, covered


def _merge_wrench(
    data: pd.DataFrame, wrenches: list[tuple[int, Any]], tol: float | None, topic: str, path: Path
) -> tuple[pd.DataFrame, str]:
    wrenches.sort(key=lambda x: x[0])
    stamps = np.array([s for s, _ in wrenches], dtype=np.int64)
    keep = np.ones(len(stamps), dtype=bool)
    keep[1:] = np.diff(stamps) > 0
    t_w = stamps[keep] * 1e-9
    w = np.array(
        [
            [
                m.wrench.force.x,
                m.wrench.force.y,
                m.wrench.force.z,
                m.wrench.torque.x,
                m.wrench.torque.y,
                m.wrench.torque.z,
            ]
            for _, m in wrenches
        ]
    )[keep]
    t = data["t"].to_numpy()
    if tol is None:
        tol = 0.5 * float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    elif float(tol) < 0:
        raise ConfigError(f"{path}: option wrench_tolerance is {tol}, expected >= 0 s")
    W, covered = merge_onto(t, t_w, w, float(tol))
    if not covered.any():
        raise FormatError(
            f"{path}: the wrench on {topic} (t={t_w[0]:.3f}..{t_w[-1]:.3f} s) does "
            f"not overlap the joint states (t={t[0]:.3f}..{t[-1]:.3f} s)"
        )
    if not covered.all():
        bad = np.flatnonzero(~covered)
        warnings.warn(
            f"{path}: {len(bad)} joint-state samples between t={t[bad[0]]:.3f} s and "
            f"t={t[bad[-1]]:.3f} s lie outside the wrench on {topic} and were dropped",
            DitherlabWarning,
            stacklevel=3,
        )
    data = data.loc[covered].reset_index(drop=True)
    for k, c in enumerate(WRENCH_COLUMNS):
        data[c] = W[covered, k]
    return data, str(wrenches[0][1].header.frame_id)


# ------------------------------------------------------------------------------ write
def write(rec: Recording, path: Path, storage: str = "mcap") -> Path:
    """Write ``rec`` as a ROS 2 bag folder at ``path`` (atomically: built beside it, renamed).

    Parameters
    ----------
    rec : Recording (its robot model gives the joint names)
    path : the bag folder to create (replaced when it exists)
    storage : ``"mcap"`` or ``"sqlite3"``
    """
    path = Path(path)
    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise ConfigError(f"{path}: option storage is {storage!r}, expected 'mcap' or 'sqlite3'")
    robot = rec.robot()
    names = list(robot.joint_names)
    ts = get_typestore(TYPESTORE)
    JointState = ts.types[JOINT_STATE]
    Wrench = ts.types["geometry_msgs/msg/Wrench"]
    WrenchStamped = ts.types[WRENCH_STAMPED]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    String = ts.types[STRING]

    ns = np.round(rec.t * 1e9).astype(np.int64)  # [ns]
    log = ns - min(0, int(ns[0]))
    q, tau = np.ascontiguousarray(rec.q), np.ascontiguousarray(rec.tau)
    dq = np.ascontiguousarray(rec.dq) if rec.has_dq else None
    wrench = rec.wrench

    def header(stamp: int, frame: str) -> Any:
        sec, nsec = divmod(int(stamp), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    path.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        bag = tmpdir / path.name
        with Writer(bag, version=9, storage_plugin=plugins[storage]) as w:
            w.set_custom_data("ditherlab", dumps_meta(rec.meta))
            c_desc = w.add_connection("/robot_description", STRING, typestore=ts)
            c_js = w.add_connection("/joint_states", JOINT_STATE, typestore=ts)
            c_w = (
                w.add_connection("/wrench", WRENCH_STAMPED, typestore=ts)
                if wrench is not None
                else None
            )
            w.write(c_desc, int(log[0]), ts.serialize_cdr(String(data=robot.urdf), STRING))
            empty = np.zeros(0)
            for i in range(len(ns)):
                msg = JointState(
                    header=header(ns[i], ""),
                    name=names,
                    position=q[i],
                    velocity=dq[i] if dq is not None else empty,
                    effort=tau[i],
                )
                w.write(c_js, int(log[i]), ts.serialize_cdr(msg, JOINT_STATE))
                if c_w is not None:
                    f = wrench[i]
                    m = WrenchStamped(
                        header=header(ns[i], "base"),
                        wrench=Wrench(
                            force=Vector3(x=f[0], y=f[1], z=f[2]),
                            torque=Vector3(x=f[3], y=f[4], z=f[5]),
                        ),
                    )
                    w.write(c_w, int(log[i]), ts.serialize_cdr(m, WRENCH_STAMPED))
        os.chmod(
            bag, 0o777 & ~current_umask()
        )  # mkdtemp's parent is 0700; the bag gets the usual mode
        old = tmpdir / ".old"
        if path.exists():
            os.replace(path, old)
        os.replace(bag, path)
    except WriterError as exc:
        raise FormatError(f"{path}: cannot write the ROS 2 bag ({exc})") from None
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(tmpdir)
    return path

"""ROS 2 bags (MCAP or SQLite 3 storage; a bag folder or a single storage file) with ``rosbags``.

Reading
-------
- ``sensor_msgs/msg/JointState`` → ``q`` (position), ``dq`` (velocity, when every message has
  it), ``tau`` (effort, required). Joints are matched **by name** to the robot's joint names and
  reordered to the robot's order; messages may list extra joints (ignored) but must contain all
  of the robot's. The sample time is ``header.stamp`` (the bag's receive time when the stamp is
  zero). Messages with a repeated stamp are dropped (first one kept) with a warning.
- ``geometry_msgs/msg/WrenchStamped`` → ``f_x .. m_z``, taken as the wrench at the tool point in
  base-frame axes (docs/recording-format.md); no TF transform is applied, ``header.frame_id``
  is recorded in the metadata (``wrench_frame``). **Merge rule** onto the joint-state time base:
  for each joint-state time, the nearest wrench sample when it lies within ``wrench_tolerance``
  (default: half the median joint-state period); otherwise linear interpolation between the two
  wrench samples around it; joint-state samples before the first or after the last wrench
  sample (beyond the tolerance) are **dropped with a DitherlabWarning** stating how many and
  where. No overlap at all is a FormatError.
- Topics: ``joint_topic=`` / ``wrench_topic=`` choose them; otherwise the single topic of each
  type is used (several JointState topics → FormatError asking to choose; no WrenchStamped
  topic → a recording without F/T columns; ``wrench_topic=""`` ignores the wrench).
- The robot: ``robot=`` (name or URDF path), else the ditherlab metadata stored by :func:`write`
  in the bag's ``custom_data``, else a ``/robot_description`` (``std_msgs/msg/String``) topic.
- In blocks (:func:`open_table`: :func:`layout` then :func:`frames`, for
  :class:`ditherlab.io.stream.Source`): a
  first pass keeps only the joint-state stamps (8 bytes a message), the wrench's first and last
  stamps and the URDF, which fix the rows, the tolerance and the dropped samples; a second pass
  reads the messages again and merges each block of joint states with the wrench samples from
  the last one before it to the first one at or after its end, carried across the cut, which
  gives the whole merge's values exactly. This needs the header stamps in the bag's order on
  each topic (they never go back); a bag whose stamps go back must be sorted and is read whole.
  :func:`read` is the same two passes over the messages held in memory, sorted.

Writing
-------
:func:`write` makes a bag folder (``metadata.yaml`` + one storage file, rosbag2 version 9,
``storage="mcap"`` or ``"sqlite3"``) with ``/joint_states`` (JointState, names = the robot's
joint names), ``/wrench`` (WrenchStamped, frame ``base``) when F/T columns exist,
``/robot_description`` (the URDF) and the recording metadata as JSON under ``custom_data``
key ``ditherlab`` (base64 of the JSON: :func:`custom_meta`). Columns other than q, dq, tau and
the wrench are not stored, and :func:`write` says which in a DitherlabWarning. A path without a
suffix is written as a bag (:data:`FORMAT`).
"""

from __future__ import annotations

import base64
import contextlib
import heapq
import os
import re
import shutil
import sqlite3
import struct
import warnings
from array import array
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import apsw
import numpy as np
import pandas as pd
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from ditherlab.core.errors import ConfigError, DitherlabWarning, FormatError, one_line
from ditherlab.core.files import current_umask, locked_temp_dir, try_lock
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.recording import Recording
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
    urdf_spec,
)
from ditherlab.io.format import Format, WholeTable, whole
from ditherlab.io.mcap import MAGIC, header_profile, profile_text
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


def _cli_option(option: str) -> str:
    """A reader option as the CLI spells it, with its API name: ``--joint-topic (joint_topic=)``."""
    return f"--{option.replace('_', '-')} ({option}=)"


def _pick(
    topics: dict[str, str],
    wanted: str | None,
    msgtype: str,
    option: str,
    path: Path,
    required: bool,
) -> str | None:
    """The topic of type ``msgtype`` to read: ``wanted`` (the reader option ``option``) when
    given, else the bag's only one; FormatError naming the option and the topics found when
    ``wanted`` is not a topic of that type or the choice is not unique."""
    if wanted:
        if wanted not in topics:
            raise FormatError(
                f"{path}: {_cli_option(option)} names topic {wanted}, which is not in the bag; "
                f"topics found: {_topic_list(topics)}"
            )
        if topics[wanted] != msgtype:
            raise FormatError(
                f"{path}: {_cli_option(option)} names topic {wanted} of type {topics[wanted]}; "
                f"expected a {msgtype} topic; topics found: {_topic_list(topics)}"
            )
        return wanted
    found = sorted(k for k, v in topics.items() if v == msgtype)
    if len(found) > 1:
        raise FormatError(
            f"{path}: several {msgtype} topics ({', '.join(found)}); choose one with "
            f"{_cli_option(option)}"
        )
    if not found:
        if required:
            raise FormatError(
                f"{path}: no {msgtype} topic (needed for the joint positions and torques); "
                f"topics found: {_topic_list(topics)}"
            )
        return None
    return found[0]


def check_sqlite_size(db: Path, bag: Path) -> None:
    """FormatError when the SQLite file ``db`` (a storage file of ``bag``) is shorter than its
    header says: a bag cut off in a copy or a download. SQLite then reads the pages that remain
    without a word, and the messages on the missing pages are lost. The header gives the page
    size (bytes 16-17) and, when its change counter (bytes 24-27) equals its version-valid-for
    number (bytes 92-95), the page count (bytes 28-31); without a valid page count a file is
    cut when its size is not a whole number of pages. Files that are not SQLite are left to the
    reader."""
    try:
        size = db.stat().st_size
        with open(db, "rb") as fh:
            head = fh.read(100)
    except OSError:
        return  # the reader says what is wrong with it
    if not head.startswith(_SQLITE[: len(head)]) or (len(head) < len(_SQLITE)):
        return
    if len(head) < 100:
        raise FormatError(
            f"{bag}: the SQLite file {db.name} is cut off ({size} bytes, shorter than its "
            "100-byte header); expected a whole bag (copy it again)"
        )
    (page,) = struct.unpack(">H", head[16:18])
    page = 65536 if page == 1 else page
    counter, pages, valid_for = struct.unpack(">I", head[24:28]), head[28:32], head[92:96]
    n_pages = struct.unpack(">I", pages)[0] if counter == struct.unpack(">I", valid_for) else 0
    expected = n_pages * page if n_pages else -(-size // page) * page if page else size
    if page and size < expected:
        raise FormatError(
            f"{bag}: the SQLite file {db.name} is cut off ({size} bytes of the {expected} its "
            f"header states, {page}-byte pages); expected a whole bag (copy it again)"
        )


_JOINT, _WRENCH, _URDF = 0, 1, 2
#: what rosbags raises on a damaged bag
_DAMAGE = (
    AnyReaderError,
    ReaderError,
    OSError,
    ValueError,
    KeyError,
    AssertionError,
    struct.error,
    sqlite3.Error,
    apsw.Error,
    OverflowError,
    IndexError,
    MemoryError,  # a damaged record length: rosbags reads that many bytes
)


class _Bag:
    """The messages of a bag that the reader needs, deserialized, in the bag's order: iterating
    yields ``(kind, stamp [ns], message)`` with kind ``_JOINT``, ``_WRENCH`` or ``_URDF``; the
    stamp is ``header.stamp`` (the receive time when it is zero). Once iteration has started,
    ``jtopic``, ``wtopic`` and ``custom`` (the bags' custom data) are set. A damaged bag is a
    FormatError naming it."""

    def __init__(self, path: Path, options: dict[str, Any]):
        self.path, self.options = path, options
        self.jtopic = ""
        self.wtopic: str | None = None
        self.custom: dict[str, str] = {}

    def __iter__(self) -> Iterator[tuple[int, int, Any]]:
        path, options = self.path, self.options
        for db in [path] if path.is_file() else sorted(path.glob("*.db3")):
            check_sqlite_size(db, path)
        try:
            with AnyReader([path], default_typestore=get_typestore(TYPESTORE)) as reader:
                topics = {c.topic: c.msgtype for c in reader.connections}
                jtopic = _pick(
                    topics, options.get("joint_topic"), JOINT_STATE, "joint_topic", path, True
                )
                assert jtopic is not None
                wopt = options.get("wrench_topic")
                wtopic = (
                    None
                    if wopt == ""
                    else _pick(topics, wopt, WRENCH_STAMPED, "wrench_topic", path, False)
                )
                self.jtopic, self.wtopic, self.custom = jtopic, wtopic, _custom_data(reader)
                conns = [
                    c
                    for c in reader.connections
                    if c.topic in (jtopic, wtopic)
                    or (c.topic == "/robot_description" and c.msgtype == STRING)
                ]
                seen = dict.fromkeys({c.topic for c in conns}, 0)
                for conn, stamp, raw in reader.messages(connections=conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    seen[conn.topic] += 1
                    if conn.topic == jtopic:
                        yield _JOINT, _stamp(msg.header) or stamp, msg
                    elif conn.topic == wtopic:
                        yield _WRENCH, _stamp(msg.header) or stamp, msg
                    else:
                        yield _URDF, stamp, msg
                _check_counts(path, conns, seen)
        except FormatError:
            raise
        except _DAMAGE as exc:
            raise FormatError(f"{path}: not a readable ROS 2 bag ({one_line(exc)})") from None


def _check_counts(path: Path, conns: list[Any], seen: dict[str, int]) -> None:
    """FormatError when a topic gave fewer messages than the bag's index counts (its
    metadata.yaml, or the MCAP summary's statistics): a damaged storage file whose reader
    skipped what it could not parse. A bag without counts (0) is not checked."""
    listed: dict[str, int] = {}
    for c in conns:
        listed[c.topic] = listed.get(c.topic, 0) + int(getattr(c, "msgcount", 0) or 0)
    for topic, n in sorted(listed.items()):
        if n and seen.get(topic, 0) < n:
            raise FormatError(
                f"{path}: topic {topic} gave {seen.get(topic, 0)} of the {n} messages the bag's "
                "index counts; the bag is cut off or damaged (expected a whole bag; copy it again)"
            )


@dataclass
class BagLayout:
    """What a bag holds, from one pass over its messages that keeps only their time stamps: the
    bag opened for reading in blocks of rows (:class:`ditherlab.io.format.Table`) when
    ``ordered``.

    Attributes
    ----------
    path : the bag ; meta : the metadata (reader options applied) ; columns : the table's columns
    ordered : True when the header stamps never go back in the bag's order on either topic
        (then :func:`frames` can read the bag in blocks; else it is read whole and sorted)
    t : (n_rows,) [s] the rows' times ; n_rows : rows of the table
    jtopic, wtopic : the topics read (``wtopic`` None when no wrench is merged)
    names : the robot's joint names ; has_dq : every message carries velocities
    tol : [s] the wrench merge's nearest-sample tolerance
    span : [ns] the first and last stamps of the rows kept (the others lie outside the wrench)
    w_count : the wrench samples with distinct stamps
    """

    path: Path
    meta: dict[str, Any]
    columns: list[str]
    ordered: bool
    t: np.ndarray
    n_rows: int
    jtopic: str
    wtopic: str | None
    names: list[str]
    has_dq: bool
    tol: float
    span: tuple[int, int] = (0, 0)
    w_count: int = 0
    rec = None

    @property
    def name(self) -> str:
        """The bag, for messages."""
        return str(self.path)

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """:func:`frames` of this bag."""
        return frames(self, rows, columns)


def layout(path: Path, **options: Any) -> BagLayout:
    """The :class:`BagLayout` of a ROS 2 bag, from one pass over its messages (memory: 8 bytes
    per joint-state message). Raises what :func:`read` raises for the topics, the robot, the
    wrench overlap and a damaged bag, and gives its warnings (when ``ordered``)."""
    path = Path(path)
    check_options(options, OPTIONS, "ROS 2 bag", str(path))
    bag = _Bag(path, options)
    return _scan(bag, iter(bag), options)


def open_table(path: Path, **options: Any) -> BagLayout | WholeTable:
    """The bag opened for reading in blocks of rows (:func:`layout`); a bag whose stamps go back
    in the bag's order is read whole and sorted (:func:`read`: sorting needs every message)."""
    lay = layout(path, **options)
    if not lay.ordered:
        return whole(read(path, **options))
    return lay


@dataclass
class _Stamps:
    """What pass one keeps of a bag's messages (:func:`_stamps`).

    Attributes
    ----------
    joints : [ns] the joint-state stamps, in the bag's order ; has_dq : every one has velocities
    ordered : no stamp goes back on either topic
    w_first, w_last : [ns] the first and last wrench stamps ; w_count : distinct wrench stamps
    frame : the first wrench message's frame ; urdf : the ``/robot_description`` text, if any
    """

    joints: array[int]
    has_dq: bool
    ordered: bool
    w_first: int
    w_last: int
    w_count: int
    frame: str
    urdf: str | None


def _stamps(items: Iterator[tuple[int, int, Any]]) -> _Stamps:
    """Pass one over the messages ``items`` (from a :class:`_Bag`, or the same sorted): the
    stamps, velocity presence, the wrench's span and frame, the URDF."""
    joints: array[int] = array("q")
    has_dq, ordered = True, True
    w_first = w_last = w_count = 0
    frame, urdf_text = "", None
    for kind, stamp, msg in items:
        if kind == _JOINT:
            ordered = ordered and (not joints or stamp >= joints[-1])
            joints.append(stamp)
            has_dq = has_dq and len(msg.velocity) == len(msg.name)
        elif kind == _WRENCH:
            ordered = ordered and (not w_count or stamp >= w_last)
            if not w_count:
                w_first, frame = stamp, str(msg.header.frame_id)
            w_count += int(not w_count or stamp != w_last)  # distinct stamps
            w_last = stamp
        else:
            urdf_text = msg.data
    return _Stamps(joints, has_dq, ordered, w_first, w_last, w_count, frame, urdf_text)


def _scan(bag: _Bag, items: Iterator[tuple[int, int, Any]], options: dict[str, Any]) -> BagLayout:
    """The :class:`BagLayout` from pass one over ``items`` (from ``bag``, or the same messages
    sorted): the metadata, the columns, then (when ordered) the rows kept and the wrench merge's
    tolerance and span, with their warnings."""
    s = _stamps(items)
    path = bag.path
    if not s.joints:
        raise FormatError(f"{path}: topic {bag.jtopic} [{JOINT_STATE}] has no messages")
    foreign = "ditherlab" not in bag.custom  # a bag that ditherlab did not write
    meta = _bag_meta(bag, s.urdf, options)
    names = _joint_names(meta, path)
    columns = ["t", *(f"{p}_{j + 1}" for p in ("q", "dq", "tau") for j in range(len(names)))]
    if not s.has_dq:
        columns = [c for c in columns if not c.startswith("dq_")]
    wtopic = bag.wtopic if s.w_count else None
    lay = BagLayout(
        path, meta, columns, s.ordered, np.zeros(0), 0, bag.jtopic, wtopic, names, s.has_dq, 0.0
    )
    if not s.ordered:
        return lay  # read whole and sorted (read): its warnings then, not twice
    stamps = _kept_stamps(lay, s)
    if wtopic is None:
        return lay
    _cover(lay, s, stamps, options)
    if s.frame and foreign:
        meta["wrench_frame"] = s.frame
    return lay


def _bag_meta(bag: _Bag, urdf_text: str | None, options: dict[str, Any]) -> dict[str, Any]:
    """The recording's metadata: the ditherlab metadata the bag stores, else its
    ``/robot_description``, then the reader options; ``source`` names a bag that ditherlab did
    not write."""
    path = bag.path
    stored = (
        loads_meta(custom_meta_text(bag.custom["ditherlab"]), str(path))
        if "ditherlab" in bag.custom
        else None
    )
    if stored is None and urdf_text and options.get("robot") is None:
        robot = urdf_spec(urdf_text, options.get("tool_frame"), where=f"{path}: /robot_description")
        stored = {"robot": robot}
    meta = meta_from_options(stored, options, where=str(path))
    if "ditherlab" not in bag.custom:
        meta.setdefault("source", f"ROS 2 bag {path.name}")
    return meta


def _kept_stamps(lay: BagLayout, s: _Stamps) -> np.ndarray:
    """The joint-state stamps [ns] without the repeated ones (a warning says how many): sets
    the rows' times, their count and span, and the wrench's sample count on ``lay``."""
    stamps = np.frombuffer(s.joints, dtype=np.int64)
    keep = np.ones(len(stamps), dtype=bool)
    keep[1:] = np.diff(stamps) > 0
    if not keep.all():
        warnings.warn(
            f"{lay.path}: {int((~keep).sum())} messages on {lay.jtopic} repeat the previous "
            "time stamp and were dropped",
            DitherlabWarning,
            stacklevel=4,
        )
    t = stamps[keep] * 1e-9
    lay.t, lay.n_rows, lay.w_count = t, len(t), s.w_count
    lay.span = (int(stamps[0]), int(stamps[-1]))
    return stamps[keep]


def _cover(lay: BagLayout, s: _Stamps, stamps: np.ndarray, options: dict[str, Any]) -> None:
    """The wrench merge on ``lay``: its tolerance [s], the rows inside the wrench's span (the
    others dropped with a warning; none is a FormatError), the wrench columns. ``stamps`` [ns]:
    the rows' stamps."""
    path, t = lay.path, lay.t
    tol = options.get("wrench_tolerance")
    if tol is None:
        tol = 0.5 * float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    elif float(tol) < 0:
        raise ConfigError(f"{path}: option wrench_tolerance is {tol}, expected >= 0 s")
    lay.tol = float(tol)
    # coverage depends on the wrench's first and last samples only (merge_onto)
    ends = np.array([s.w_first, s.w_last] if s.w_count > 1 else [s.w_first]) * 1e-9
    _, covered = merge_onto(t, ends, np.zeros((len(ends), 6)), lay.tol)
    t_w = ends[[0, -1]]
    if not covered.any():
        raise FormatError(
            f"{path}: the wrench on {lay.wtopic} (t={t_w[0]:.3f}..{t_w[-1]:.3f} s) does "
            f"not overlap the joint states (t={t[0]:.3f}..{t[-1]:.3f} s)"
        )
    if not covered.all():
        bad = np.flatnonzero(~covered)
        warnings.warn(
            f"{path}: {len(bad)} joint-state samples between t={t[bad[0]]:.3f} s and "
            f"t={t[bad[-1]]:.3f} s lie outside the wrench on {lay.wtopic} and were dropped",
            DitherlabWarning,
            stacklevel=4,
        )
    lay.t, lay.n_rows = t[covered], int(covered.sum())
    kept = stamps[covered]  # one run: coverage is the wrench's span widened by tol
    lay.span = (int(kept[0]), int(kept[-1]))
    lay.columns += list(WRENCH_COLUMNS)


def frames(lay: BagLayout, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
    """The table of an ``ordered`` bag in consecutive blocks of ``rows`` rows (the last one
    shorter), read again message by message: memory holds a block, and the wrench samples
    around it (the merge's neighbours are carried across the cut)."""
    if not lay.ordered:
        raise ConfigError(f"{lay.path}: the bag's time stamps go back: read it whole")
    bag = _Bag(lay.path, {"joint_topic": lay.jtopic, "wrench_topic": lay.wtopic or ""})
    for block in _blocks(bag, lay, rows):
        yield block if columns is None else block[columns]


def read(path: Path, **options: Any) -> Recording:
    """Read a ROS 2 bag (folder, ``.mcap`` or ``.db3``) into a Recording (rules above): the
    messages in memory, sorted by stamp on each topic (stable), then the two passes of
    :func:`layout` and :func:`frames` over them."""
    path = Path(path)
    check_options(options, OPTIONS, "ROS 2 bag", str(path))
    bag = _Bag(path, options)
    items = list(bag)
    by_kind = {k: [x for x in items if x[0] == k] for k in (_JOINT, _WRENCH, _URDF)}
    srt = list(
        heapq.merge(
            sorted(by_kind[_JOINT], key=lambda x: x[1]),
            sorted(by_kind[_WRENCH], key=lambda x: x[1]),
            key=lambda x: x[1],
        )
    )
    lay = _scan(bag, iter(srt + by_kind[_URDF]), options)
    (data,) = list(_blocks(srt, lay, max(len(by_kind[_JOINT]), 1)))
    return Recording(data, lay.meta, name=str(path))


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


def _joint_row(
    msg: Any, names: list[str], i: int, topic: str, path: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, effort, velocity) of joint-state message ``i`` (0-based) in the robot's joint
    order (velocity empty when the message has none); FormatError for a missing joint or a
    field of the wrong length."""
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
    return pos[order], eff[order], vel[order] if len(vel) == len(msg.name) else vel[:0]


class _Merge:
    """Pass two's state (:func:`_blocks`): the joint states kept and not yet in a block, the
    wrench samples from the last one before them on, and the merged rows not yet handed out in
    blocks of ``rows``."""

    def __init__(self, lay: BagLayout, rows: int):
        self.lay, self.rows = lay, rows
        self.merge = lay.wtopic is not None
        self.js: list[int] = []  # [ns] stamps of the joint states waiting
        self.jrows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (q, tau, dq) of each
        self.wt: list[float] = []  # [s] wrench times
        self.wv: list[list[float]] = []  # [N, N·m] wrench samples
        self.w_seen = 0  # distinct wrench stamps read
        self.out: list[pd.DataFrame] = []  # merged rows not handed out
        self.held = 0  # how many

    def wrench(self, stamp: int, msg: Any) -> None:
        """Keep a wrench sample (``stamp`` [ns], a WrenchStamped)."""
        self.w_seen += 1
        f, m = msg.wrench.force, msg.wrench.torque
        self.wt.append(stamp * 1e-9)
        self.wv.append([f.x, f.y, f.z, m.x, m.y, m.z])

    def ready(self) -> bool:
        """A block of ``rows`` joint states can be merged: the wrench has a sample at or after
        its last row, or no more samples."""
        js, rows = self.js, self.rows
        if len(js) < rows or not self.merge:
            return len(js) >= rows
        wt = self.wt
        return bool(wt) and (wt[-1] >= js[rows - 1] * 1e-9 or self.w_seen == self.lay.w_count)

    def block(self, k: int) -> pd.DataFrame:
        """The first ``k`` joint states waiting as table rows, merged with the wrench (the rows
        outside its span dropped); the wrench samples before the block's last one go."""
        lay, n = self.lay, len(self.lay.names)
        t = np.asarray(self.js[:k], dtype=np.int64) * 1e-9
        cols: dict[str, np.ndarray] = {"t": t}
        for f, prefix in ((0, "q"), (2, "dq"), (1, "tau")):
            if prefix == "dq" and not lay.has_dq:
                continue
            arr = np.array([r[f] for r in self.jrows[:k]], dtype=float).reshape(k, n)
            for j in range(n):
                cols[f"{prefix}_{j + 1}"] = arr[:, j]
        data = pd.DataFrame(cols)
        del self.js[:k], self.jrows[:k]
        if not self.merge:
            return data
        tw = np.asarray(self.wt)
        a = max(int(np.searchsorted(tw, t[0])) - 1, 0)
        b = min(int(np.searchsorted(tw, t[-1])), len(tw) - 1)
        W, covered = merge_onto(t, tw[a : b + 1], np.asarray(self.wv[a : b + 1]), lay.tol)
        del self.wt[: max(b - 1, 0)], self.wv[: max(b - 1, 0)]
        data = data.loc[covered].reset_index(drop=True)
        for c, col in enumerate(WRENCH_COLUMNS):
            data[col] = W[covered, c]
        return data

    def hold(self, data: pd.DataFrame) -> None:
        """Hold merged rows for the blocks that :meth:`emit` hands out."""
        self.out.append(data)
        self.held += len(data)

    def emit(self, final: bool) -> Iterator[pd.DataFrame]:
        """Hand out every whole block of ``rows`` held (and, when ``final``, the rest)."""
        rows = self.rows
        while self.held >= rows or (final and self.held):
            data = pd.concat(self.out, ignore_index=True) if len(self.out) > 1 else self.out[0]
            yield data.iloc[:rows].reset_index(drop=True)
            self.out = [data.iloc[rows:].reset_index(drop=True)] if len(data) > rows else []
            self.held = max(len(data) - rows, 0)


def _blocks(
    items: Iterable[tuple[int, int, Any]], lay: BagLayout, rows: int
) -> Iterator[pd.DataFrame]:
    """Pass two: the table in blocks of ``rows`` rows from ``items`` in stamp order on each topic
    (``lay.ordered``). Joint states with a repeated stamp are dropped (the first kept); each
    block of ``rows`` joint states is merged with the wrench samples from the last one before
    it to the first one at or after its end (:func:`merge_onto` then gives the values of the
    whole merge). The rows outside the wrench's span (``lay.span``) are dropped as they come;
    a block waits for the wrench sample after its end, or for the wrench's last sample."""
    m = _Merge(lay, rows)
    i = 0
    last_j = last_w = None
    for kind, stamp, msg in items:
        if kind == _JOINT:
            row = _joint_row(msg, lay.names, i, lay.jtopic, lay.path)
            i += 1
            if last_j is not None and stamp <= last_j:
                if stamp < last_j:
                    raise FormatError(f"{lay.path}: the bag changed while it was read")
                continue
            last_j = stamp
            if not lay.span[0] <= stamp <= lay.span[1]:
                continue  # outside the wrench: dropped as it comes, never held
            m.js.append(stamp)
            m.jrows.append(row)
        elif kind == _WRENCH:
            if last_w is not None and stamp <= last_w:
                continue
            last_w = stamp
            m.wrench(stamp, msg)
        else:
            continue
        while m.ready():
            m.hold(m.block(rows))
            yield from m.emit(False)
    if m.js:
        m.hold(m.block(len(m.js)))
    yield from m.emit(True)


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


# ------------------------------------------------------------------------------ write
#: the prefix of the metadata stored in a bag's ``custom_data`` (:func:`custom_meta`)
CUSTOM_PREFIX = "base64:"


def custom_meta(meta: dict[str, Any]) -> str:
    """The metadata as a bag's ``custom_data`` value: its JSON (:func:`dumps_meta`) in base64,
    after :data:`CUSTOM_PREFIX`. metadata.yaml is written by ruamel.yaml, whose folding of a
    long double-quoted string loses or adds characters where an escape (a quote, a backslash, a
    non-ASCII character such as the ``·`` of ``N·m``) meets a space; base64 text has neither."""
    return CUSTOM_PREFIX + base64.b64encode(dumps_meta(meta).encode("utf-8")).decode("ascii")


def custom_meta_text(value: str) -> str:
    """The metadata JSON text of a bag's ``custom_data`` value: :func:`custom_meta`'s decoded,
    or the value itself (JSON stored as it is)."""
    if not value.startswith(CUSTOM_PREFIX):
        return value
    try:
        return base64.b64decode(value[len(CUSTOM_PREFIX) :], validate=True).decode("utf-8")
    except (ValueError, UnicodeDecodeError):
        return value  # loads_meta says that it is not JSON


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
    ns = np.round(rec.t * 1e9).astype(np.int64)  # [ns]
    dropped = not_stored(list(rec.data.columns))
    if dropped:
        warnings.warn(
            f"{path}: not stored: {column_list(dropped)}; a ROS 2 bag holds the joint states "
            "(q, dq, tau) and the wrench only (.parquet, .csv or .mcap keep every column)",
            DitherlabWarning,
            stacklevel=2,
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    clear_stale_bag_folders(path.parent)
    fd, tmpdir = locked_temp_dir(path.parent, f".{path.name}.")
    try:
        bag = tmpdir / path.name
        _write_bag(bag, plugins[storage], rec, robot, ns)
        # mkdtemp's parent is 0700; the bag gets the usual mode
        os.chmod(bag, 0o777 & ~current_umask())
        old = tmpdir / ".old"
        if path.exists():
            os.replace(path, old)
        os.replace(bag, path)
    except WriterError as exc:
        raise FormatError(f"{path}: cannot write the ROS 2 bag ({one_line(exc)})") from None
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(tmpdir)
        os.close(fd)
    return path


#: the temporary folder of :func:`write` for a bag ``NAME``: ``.NAME.XXXXXXXX`` (mkdtemp's eight
#: characters) holding the bag folder ``NAME`` as it is written
_TEMP_BAG = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}$")
#: what a bag folder being written holds (rosbags' storage files and their SQLite journals)
_BAG_FILES = (".mcap", ".db3", ".yaml", ".db3-journal", ".db3-wal", ".db3-shm")


def clear_stale_bag_folders(parent: Path) -> list[Path]:
    """Remove the temporary folders that :func:`write` left in ``parent`` when its process died
    before renaming the bag (``kill -9``); returns those removed. Only a folder of the pattern
    ``.NAME.XXXXXXXX`` that holds nothing but a bag folder ``NAME`` of storage files, and whose
    lock no process holds (:func:`ditherlab.core.files.locked_temp_dir`); one that holds a
    replaced bag (``.old``, a process killed between its two renames) is left for the user."""
    removed: list[Path] = []
    try:
        found = [(parent / n, m["name"]) for n in os.listdir(parent) if (m := _TEMP_BAG.match(n))]
    except OSError:
        return removed
    for d, name in found:
        try:
            fd = os.open(d, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        except OSError:
            continue  # not a folder, or gone meanwhile
        try:
            if _only_a_bag_being_written(d, name) and try_lock(fd):
                shutil.rmtree(d)
                removed.append(d)
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


def _only_a_bag_being_written(d: Path, name: str) -> bool:
    """Whether the folder ``d`` holds nothing but the folder ``name`` of a bag's files."""
    entries = os.listdir(d)
    if any(e != name for e in entries):
        return False
    inner = d / name
    if not entries:
        return True
    return inner.is_dir() and all(
        f.is_file() and f.name.endswith(_BAG_FILES) for f in inner.iterdir()
    )


def not_stored(columns: list[str]) -> list[str]:
    """The columns of a recording that a bag written by :func:`write` does not hold: all but
    ``t``, ``q_j``, ``dq_j``, ``tau_j`` and the wrench."""
    stored = re.compile(r"^(t|(q|dq|tau)_\d+)$")
    return [c for c in columns if not stored.match(c) and c not in WRENCH_COLUMNS]


def column_list(columns: list[str]) -> str:
    """Column names for a message, each numbered family as one range: ``dither, tau_ffw_1..6``."""
    fams: dict[str, list[int]] = {}
    out: list[str] = []
    for c in columns:
        m = re.match(r"^(.*)_(\d+)$", c)
        if m is None:
            out.append(c)
            continue
        if m.group(1) not in fams:
            fams[m.group(1)] = []
            out.append(m.group(1))
        fams[m.group(1)].append(int(m.group(2)))
    return ", ".join(
        f"{c}_{min(fams[c])}..{max(fams[c])}" if c in fams and len(fams[c]) > 1
        else f"{c}_{fams[c][0]}" if c in fams else c
        for c in out
    )  # fmt: skip


def _write_bag(
    bag: Path, plugin: StoragePlugin, rec: Recording, robot: RobotModel, ns: np.ndarray
) -> None:
    """The bag folder ``bag`` (layout in the module docstring): the metadata, the URDF, then each
    sample's JointState and WrenchStamped, logged at its time ``ns`` (N,) [ns] shifted so that
    the first is >= 0."""
    ts = get_typestore(TYPESTORE)
    String = ts.types[STRING]
    log = ns - min(0, int(ns[0]))
    wrench = rec.wrench
    with Writer(bag, version=9, storage_plugin=plugin) as w:
        w.set_custom_data("ditherlab", custom_meta(rec.meta))
        c_desc = w.add_connection("/robot_description", STRING, typestore=ts)
        c_js = w.add_connection("/joint_states", JOINT_STATE, typestore=ts)
        c_w = (
            w.add_connection("/wrench", WRENCH_STAMPED, typestore=ts)
            if wrench is not None
            else None
        )
        w.write(c_desc, int(log[0]), ts.serialize_cdr(String(data=robot.urdf), STRING))
        names = list(robot.joint_names)
        for i, (joints, wr) in enumerate(_sample_messages(ts, rec, names, ns, wrench)):
            w.write(c_js, int(log[i]), joints)
            if c_w is not None:
                w.write(c_w, int(log[i]), wr)


def _sample_messages(
    ts: Any, rec: Recording, names: list[str], ns: np.ndarray, wrench: np.ndarray | None
) -> Iterator[tuple[bytes, bytes | None]]:
    """Each sample's JointState (``names``, q [rad], dq [rad/s] when present, tau [N·m]) and
    WrenchStamped (``wrench`` (N, 6) [N, N·m], frame ``base``; None without it), serialized
    with the typestore ``ts``; ``ns`` (N,) [ns] the header stamps."""
    JointState = ts.types[JOINT_STATE]
    Wrench = ts.types["geometry_msgs/msg/Wrench"]
    WrenchStamped = ts.types[WRENCH_STAMPED]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    q, tau = np.ascontiguousarray(rec.q), np.ascontiguousarray(rec.tau)
    dq = np.ascontiguousarray(rec.dq) if rec.has_dq else None

    def header(stamp: int, frame: str) -> Any:
        sec, nsec = divmod(int(stamp), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    empty = np.zeros(0)
    for i in range(len(ns)):
        msg = JointState(
            header=header(ns[i], ""),
            name=names,
            position=q[i],
            velocity=dq[i] if dq is not None else empty,
            effort=tau[i],
        )
        wr = None
        if wrench is not None:
            f = wrench[i]
            m = WrenchStamped(
                header=header(ns[i], "base"),
                wrench=Wrench(
                    force=Vector3(x=f[0], y=f[1], z=f[2]),
                    torque=Vector3(x=f[3], y=f[4], z=f[5]),
                ),
            )
            wr = ts.serialize_cdr(m, WRENCH_STAMPED)
        yield ts.serialize_cdr(msg, JOINT_STATE), wr


# ------------------------------------------------------------------------------ the format
_SQLITE = b"SQLite format 3\x00"


def _check(path: Path) -> str | None:
    """None when ``path`` (a folder, or a file found by its suffix or first bytes) is a ROS 2
    bag: a folder with metadata.yaml or a storage file inside, a .db3 or SQLite 3 file, an MCAP
    file of profile ``ros2`` or with ROS 2 schemas; else what it holds."""
    if path.is_dir():
        if (
            (path / "metadata.yaml").is_file()
            or any(path.glob("*.mcap"))
            or any(path.glob("*.db3"))
        ):
            return None
        return "a folder without metadata.yaml, .mcap or .db3 inside"
    if path.suffix.lower() == ".db3":
        return None
    with open(path, "rb") as f:
        if f.read(len(_SQLITE)) == _SQLITE:
            return None
    profile, encodings = header_profile(path)
    if profile == "ros2" or encodings & {"ros2msg", "ros2idl"}:
        return None
    return profile_text(profile, encodings)


FORMAT = Format(
    name="rosbag",
    title="a ROS 2 bag",
    read=read,
    suffixes=(".db3", ".mcap"),
    magic=(_SQLITE, MAGIC),
    folder=True,
    check=_check,
    open=open_table,
    write=write,
    output_suffixes=("",),
    write_options=("storage",),
)

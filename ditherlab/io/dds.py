"""ROS 2 messages over DDS (Eclipse Cyclone DDS), without ROS 2 installed.

A ROS 2 node speaks RTPS: its topic ``/joint_states`` is the DDS topic ``rt/joint_states``, its
message ``sensor_msgs/msg/JointState`` the DDS type ``sensor_msgs::msg::dds_::JointState_``,
serialised as classic little-endian CDR (XCDR1, final structs: fields in order, each aligned to
its own size). The dataclasses below declare those types with ``cyclonedds.idl`` field for field
as the ``.msg`` files do, so that a ROS 2 node subscribes to what ditherlab publishes and the
other way round (``tests/test_dds.py`` checks the bytes against rosbags' ROS 2 serialiser).

Types: ``builtin_interfaces/msg/Time``, ``std_msgs/msg/Header``, ``sensor_msgs/msg/JointState``,
``geometry_msgs/msg/Vector3``, ``geometry_msgs/msg/Wrench``, ``geometry_msgs/msg/WrenchStamped``,
and ditherlab's own ``ditherlab_msgs/msg/DitherState`` (:data:`DITHER_STATE_MSG`), the dither of
every joint state: whether it is on, its period and its feedforward torque, stamped like the joint
state it belongs to.

Quality of service: reliable, keep last 10, volatile: the default profile of rclcpp and rclpy
(``rmw_qos_profile_default``) and of ``ros2 topic pub`` / ``echo``, so a subscriber or publisher
with default settings matches (:data:`QOS`). The DDS domain is ``ROS_DOMAIN_ID`` (0 without it),
as in ROS 2.
"""

# no "from __future__ import annotations": cyclonedds reads the field types at run time
import os
import re
from dataclasses import dataclass
from typing import Any

import cyclonedds.idl.types as types
import numpy as np
from cyclonedds.core import DDSException, Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from ditherlab.core.errors import ConfigError
from ditherlab.core.stamps import split_stamp

#: A Cyclone DDS configuration (for ``CYCLONEDDS_URI``) on the loopback interface alone, peers by
#: unicast: no packet leaves the machine (the tests, the bench and a one-machine demonstration)
LOOPBACK_URI = (
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface name='lo'/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    "<Peer address='127.0.0.1'/></Peers><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex></Discovery></Domain></CycloneDDS>"
)

__all__ = [
    "DITHER_STATE_MSG",
    "QOS",
    "DitherState",
    "Header",
    "JointState",
    "Reader",
    "Time",
    "Vector3",
    "Wrench",
    "WrenchStamped",
    "Writer",
    "dds_topic",
    "domain_id",
    "participant",
    "stamp_of",
    "wrench_stamped",
]


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """``builtin_interfaces/msg/Time``: ``sec`` [s] and ``nanosec`` [ns] since the epoch."""

    sec: types.int32
    nanosec: types.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """``std_msgs/msg/Header``: the stamp and the frame the data is in."""

    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    """``sensor_msgs/msg/JointState``: per named joint ``position`` [rad], ``velocity``
    [rad/s], ``effort`` [N·m] (each empty or as long as ``name``)."""

    header: Header
    name: types.sequence[str]
    position: types.sequence[types.float64]
    velocity: types.sequence[types.float64]
    effort: types.sequence[types.float64]


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    """``geometry_msgs/msg/Vector3``."""

    x: types.float64
    y: types.float64
    z: types.float64


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    """``geometry_msgs/msg/Wrench``: ``force`` [N], ``torque`` [N·m]."""

    force: Vector3
    torque: Vector3


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    """``geometry_msgs/msg/WrenchStamped``."""

    header: Header
    wrench: Wrench


#: the ``.msg`` definition of :class:`DitherState`, to build it as a ROS 2 package
#: ``ditherlab_msgs``
DITHER_STATE_MSG = """\
# The dither of the joint state with the same stamp.
std_msgs/Header header
bool on            # the dither feedforward is on
float64 period     # [s] its period (0: unknown)
string[] name      # joints, as in the JointState
float64[] feedforward  # [N·m] the dither feedforward per joint (may be empty)
"""


@dataclass
class DitherState(IdlStruct, typename="ditherlab_msgs::msg::dds_::DitherState_"):
    """``ditherlab_msgs/msg/DitherState`` (:data:`DITHER_STATE_MSG`)."""

    header: Header
    on: bool
    period: types.float64
    name: types.sequence[str]
    feedforward: types.sequence[types.float64]


#: reliable, keep last 10, volatile: ROS 2's default profile (module docstring)
QOS = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.History.KeepLast(10),
    Policy.Durability.Volatile,
)

_NAME = re.compile(r"^[A-Za-z_~{][A-Za-z0-9_/{}~]*$")


def dds_topic(topic: str, namespace: str = "") -> str:
    """The DDS topic of a ROS 2 topic: ``/joint_states`` in namespace ``/arm`` ->
    ``rt/arm/joint_states``. A relative topic joins the namespace; an absolute one ignores it.

    Raises ConfigError for a name ROS 2 would refuse (empty, a space, ``//``, a trailing ``/``).
    """
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    full = topic if topic.startswith("/") else f"{ns}/{topic}"
    parts = full.strip("/").split("/")
    if not topic or full.endswith("/") or "//" in full or not all(_NAME.match(p) for p in parts):
        raise ConfigError(
            f"topic {topic!r} (namespace {namespace!r}) is not a ROS 2 topic name; expected "
            "names like /joint_states of letters, digits and _ joined by /"
        )
    return "rt/" + "/".join(parts)


def domain_id(domain: int | None = None) -> int:
    """The DDS domain: ``domain`` when given, else ``ROS_DOMAIN_ID``, else 0; ConfigError
    outside 0..232 (RTPS's port formula)."""
    if domain is None:
        text = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
        try:
            domain = int(text)
        except ValueError:
            raise ConfigError(f"ROS_DOMAIN_ID is {text!r}; expected an integer 0..232") from None
    if not 0 <= int(domain) <= 232:
        raise ConfigError(f"DDS domain {domain!r}; expected an integer 0..232")
    return int(domain)


def participant(domain: int | None = None) -> DomainParticipant:
    """A DDS participant on the domain (:func:`domain_id`)."""
    try:
        return DomainParticipant(domain_id(domain))
    except DDSException as exc:
        raise ConfigError(f"DDS: no participant on domain {domain_id(domain)}: {exc}") from None


class Writer:
    """Publishes one ROS 2 message type on one topic (:data:`QOS`).

    Parameters
    ----------
    dp : the participant ; topic : the DDS topic (:func:`dds_topic`) ; kind : the message type
    """

    def __init__(self, dp: DomainParticipant, topic: str, kind: type) -> None:
        self.topic = topic
        self._writer = DataWriter(dp, Topic(dp, topic, kind, qos=QOS), qos=QOS)

    def write(self, msg: Any) -> None:
        """Send one message."""
        self._writer.write(msg)

    def matched(self) -> int:
        """How many readers are matched to this writer now."""
        return len(self._writer.get_matched_subscriptions())


class Reader:
    """Takes one ROS 2 message type from one topic (:data:`QOS`; the reader's own history
    keeps ``depth`` samples, so that a burst waits for :meth:`take`).

    Parameters
    ----------
    dp : the participant ; topic : the DDS topic ; kind : the message type
    depth : samples the reader holds before the oldest is overwritten
    """

    def __init__(self, dp: DomainParticipant, topic: str, kind: type, depth: int = 1000) -> None:
        self.topic = topic
        qos = Qos(
            Policy.Reliability.Reliable(max_blocking_time=100_000_000),
            Policy.History.KeepLast(depth),
            Policy.Durability.Volatile,
        )
        self._reader = DataReader(dp, Topic(dp, topic, kind, qos=QOS), qos=qos)

    def take(self, n: int = 256) -> list[Any]:
        """Up to ``n`` messages received since the last call, oldest first."""
        return list(self._reader.take(N=n))

    def matched(self) -> int:
        """How many writers are matched to this reader now."""
        return len(self._reader.get_matched_publications())


def stamp_of(t: float) -> Time:
    """The stamp of ``t`` [s] (whole nanoseconds, :func:`ditherlab.core.stamps.split_stamp`)."""
    sec, ns = split_stamp(t)
    return Time(int(sec), int(ns))


def wrench_stamped(t: float, frame: str, w: np.ndarray) -> WrenchStamped:
    """A WrenchStamped at ``t`` [s] in ``frame`` of ``w`` (6,) ``f_x .. m_z`` [N, N·m]."""
    f = [float(x) for x in w]
    return WrenchStamped(
        Header(stamp_of(t), frame),
        Wrench(Vector3(f[0], f[1], f[2]), Vector3(f[3], f[4], f[5])),
    )

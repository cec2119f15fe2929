"""What the commands' workflows share: how a foreign log is read (:class:`ReadOptions`), the
output guard before any work (:func:`guard`, :func:`guard_recording`), and recordings and
models given as objects or as paths (:func:`as_recordings`, :func:`as_model`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ditherlab.core.errors import ConfigError
from ditherlab.core.files import FileKind, check_output
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io import read
from ditherlab.io.mapping import mapping_path

#: ``progress(done, total)``: what long work calls as it goes (the CLI draws a bar)
Progress = Callable[[int, int], None]

#: A recording written by :func:`ditherlab.io.write`: the suffixes it dispatches on (a path
#: without a suffix is a ROS 2 bag folder, :func:`guard_recording`)
RECORDING_FILE = FileKind(
    "a recording; no suffix: a ROS 2 bag folder",
    (".parquet", ".pq", ".csv", ".mcap"),
    "recording.parquet",
)


@dataclass(frozen=True)
class ReadOptions:
    """How to read a log without ditherlab metadata (``--mapping``, ``--robot``) and which
    topics of a ROS 2 bag (``--joint-topic``, ``--wrench-topic``).

    Attributes
    ----------
    mapping : a TOML mapping file, or the name of a built-in mapping (``ur10e``), describing a
        foreign log's columns and units (:mod:`ditherlab.io.mapping`)
    robot : the robot of a file without metadata: a built-in name (``irb140``), an
        example-robot-data arm (``ur5``), or a URDF or xacro path
    joint_topic : a bag's ``sensor_msgs/msg/JointState`` topic (needed when it has several)
    wrench_topic : a bag's ``geometry_msgs/msg/WrenchStamped`` topic; ``""`` reads no wrench
    tool_frame : the robot's tool frame, where it is not the description's own
    robot_args : a xacro robot's ``NAME:=VALUE`` arguments
    """

    mapping: str | None = None
    robot: str | None = None
    joint_topic: str | None = None
    wrench_topic: str | None = None
    tool_frame: str | None = None
    robot_args: tuple[str, ...] = ()

    def kwargs(self) -> dict[str, Any]:
        """The options of :func:`ditherlab.io.read` and :func:`ditherlab.io.stream.open_source`
        (the topics only when given: other formats refuse them)."""
        given = (
            ("mapping", self.mapping),
            ("robot", self.robot),
            ("tool_frame", self.tool_frame),
            ("robot_args", list(self.robot_args)),
        )
        topics = (("joint_topic", self.joint_topic), ("wrench_topic", self.wrench_topic))
        return {k: v for k, v in given if v} | {k: v for k, v in topics if v is not None}

    def files(self) -> list[Path]:
        """The files these options read (the mapping file, a URDF or xacro file), which no
        output may overwrite."""
        robot = [Path(self.robot)] if self.robot and Path(self.robot).is_file() else []
        if self.mapping is None:
            return robot
        try:
            return [mapping_path(self.mapping), *robot]
        except ConfigError:  # the reader says what is wrong with it, in its own words
            return robot


def guard(
    out: str | Path,
    inputs: Iterable[str | Path | None],
    *,
    read: ReadOptions | None = None,
    kind: FileKind | None = None,
    folder: bool = False,
    force: bool = False,
) -> Path:
    """The output guard of a command (:func:`ditherlab.core.files.check_output`), before any
    work: ``out`` is not, inside or holding an input (or the mapping file of ``read``), can be
    written, is named as ``kind`` says, and replaces an existing file or writes into a non-empty
    folder only with ``force``. Returns ``Path(out)``."""
    extra = read.files() if read is not None else []
    return check_output(out, [*inputs, *extra], kind=kind, folder=folder, force=force)


def guard_recording(
    out: str | Path,
    inputs: Iterable[str | Path | None],
    *,
    read: ReadOptions | None = None,
    force: bool = False,
) -> Path:
    """:func:`guard` for a recording written by :func:`ditherlab.io.write`: one of
    :data:`RECORDING_FILE`'s suffixes, or no suffix for a ROS 2 bag folder, replaced as a whole
    (an existing non-empty one only with ``force``, and only when it is a bag); a CSV file
    brings its sidecar."""
    extra = read.files() if read is not None else []
    bag = Path(out).suffix == ""
    return check_output(
        out,
        [*inputs, *extra],
        kind=None if bag else RECORDING_FILE,
        folder=bag,
        replace=bag,
        force=force,
    )


def as_recording(rec: Recording | str | Path, read_options: ReadOptions | None = None) -> Recording:
    """A Recording as given, or read from its file (:func:`ditherlab.io.read`)."""
    if isinstance(rec, Recording):
        return rec
    return read(rec, **(read_options.kwargs() if read_options else {}))


def as_recordings(
    recs: Recording | str | Path | Sequence[Recording | str | Path],
    read_options: ReadOptions | None = None,
) -> list[Recording]:
    """Recordings as given, or read from their files; one recording or path is a list of one."""
    if isinstance(recs, Recording | str | Path):
        recs = [recs]
    return [as_recording(r, read_options) for r in recs]


def as_model(model: TorqueModel | str | Path) -> TorqueModel:
    """A TorqueModel as given, or loaded from its TOML file."""
    return model if isinstance(model, TorqueModel) else TorqueModel.load(model)

"""The robot model: kinematics and dynamics over pinocchio, batched over the samples of a log.

A :class:`RobotModel` is built from a URDF (a built-in robot such as ``"irb140"``, or the URDF
text a recording embeds) plus the recording's ``tool_offset`` and ``payload``. Its methods take
joint positions ``q : (N, n) [rad]`` (or one configuration ``(n,)``) and return arrays with time
as the first axis:

- ``gravity(q) -> (N, n) [N·m]``: the joint torques that hold the arm against gravity,
- ``jacobian(q) -> (N, 6, n)``: the geometric Jacobian of the tool point, linear part first, both
  parts in base-frame axes (pinocchio's ``LOCAL_WORLD_ALIGNED``),
- ``gravity_jacobian(q)``: both with one deduplication pass,
- ``mass_matrix(q) -> (N, n, n) [kg m²]``, ``tool_pose(q) -> (N, 4, 4)``,
  ``link_poses(q) -> {link: (N, 4, 4)}``, ``gravity_regressor(q) -> (N, n, 10)`` (for a payload's
  dynamic parameters), ``inverse_dynamics(q, dq, ddq) -> (N, n) [N·m]``.

Robots: :func:`builtin_robots` (``irb140``, ``panda``, ``ur10e``), a URDF file (:func:`resolve_spec` embeds
its text in the recording's metadata) or ``{"urdf": text, "tool_frame": name}``. Revolute,
prismatic and continuous joints (the latter take an angle like the others).

A robot that stands still repeats the same configuration thousands of times, so every batched
method computes each *distinct* configuration once and scatters the result back
(:func:`unique_configurations`). Exact repeats give bit-identical results to the per-sample loop;
an optional quantisation ``tol`` [rad] merges configurations that differ by less than the
encoder resolution, at a bounded error (see :meth:`RobotModel.gravity`).

Conventions (RECORDING.md): the tool point is the origin of the tool frame moved by
``tool_offset`` (tool-frame axes, [m]); the payload ``{"mass": kg, "com": [x, y, z]}`` (tool
frame, [m]) is a point mass added to the link that carries the tool frame. Gravity is
pinocchio's, 9.81 m/s² along -z of the URDF's root link (a wall or ceiling mounting goes into
the URDF as a fixed joint above the first link).

A RobotModel holds one pinocchio ``Data`` as scratch space, guarded by a lock: it may be shared
between threads (they take turns); for parallel work give each process its own (it pickles).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
import threading
import warnings
import xml.etree.ElementTree as ET
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pinocchio as pin

from ditherlab.errors import DitherlabWarning, RobotError, where_prefix

__all__ = [
    "PAPER_POSE",
    "RobotModel",
    "UniqueConfigurations",
    "builtin_robots",
    "builtin_urdf",
    "format_description",
    "resolve_spec",
    "unique_configurations",
]

#: The pose of the paper's Fig. 1 for the IRB140, ``(6,) [rad]``: q1 = 0, upper arm vertical,
#: forearm horizontal along +x, q5 = 90° so the flange points down (flange centre at
#: (0.450, 0, 0.647) m).
PAPER_POSE: np.ndarray = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
PAPER_POSE.setflags(write=False)

#: Built-in robots: name -> (URDF file in ditherlab/robots, tool frame).
_BUILTIN: dict[str, tuple[str, str]] = {
    "irb140": ("irb140.urdf", "tool0"),
    "panda": ("panda.urdf", "panda_hand_tcp"),
    "ur10e": ("ur10e.urdf", "tool0"),
}

#: Link names tried, in order, when a URDF is given without a tool frame.
_TOOL_FRAME_GUESSES = ("tool0", "flange", "ee_link", "tool", "end_effector")

#: Name of the frame ditherlab adds at the tool point (tool frame + tool_offset).
TOOL_POINT_FRAME = "ditherlab_tool_point"

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def builtin_robots() -> list[str]:
    """Names of the built-in robots, sorted (``["irb140", "panda", "ur10e"]``)."""
    return sorted(_BUILTIN)


def builtin_urdf(name: str) -> str:
    """The URDF text of the built-in robot ``name``; RobotError when there is none."""
    if name not in _BUILTIN:
        raise RobotError(_unknown_robot(name, ""))
    fname = _BUILTIN[name][0]
    return (Path(__file__).parent / "robots" / fname).read_text(encoding="utf-8")


def _unknown_robot(name: Any, where: str) -> str:
    return (
        f"{where}robot {_short(name)} is not a built-in robot (expected one of: "
        f"{', '.join(builtin_robots())}, a path to a .urdf file, or an object "
        "{'urdf': <URDF text>, 'tool_frame': <frame name>})"
    )


def resolve_spec(
    spec: str | Mapping[str, Any], tool_frame: str | None = None, where: str | None = None
) -> str | dict[str, Any]:
    """Turn a user's robot choice into a recording's ``meta["robot"]`` entry.

    Parameters
    ----------
    spec : str or dict
        A built-in name (kept as is), a path to a ``.urdf`` file (read and embedded, so the
        recording is self-describing), or ``{"urdf": text, "tool_frame": name}`` (checked).
    tool_frame : str, optional
        Tool frame for a URDF file; default: the first of ``tool0``, ``flange``, ``ee_link``,
        ``tool``, ``end_effector`` that exists, else the last link of the chain.
    where : str, optional
        File or option name for error messages.

    Returns
    -------
    str or {"urdf": text, "tool_frame": name, "name": robot name}
    """
    w = where_prefix(where)
    if isinstance(spec, Mapping):
        RobotModel.from_spec(spec, where=where)  # validates
        return dict(spec)
    if isinstance(spec, str) and spec in _BUILTIN:
        return spec
    if isinstance(spec, str | os.PathLike) and (
        str(spec).lower().endswith(".urdf") or Path(spec).is_file()
    ):
        path = Path(spec)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise RobotError(f"{w}robot URDF file '{path}' does not exist") from None
        except (OSError, UnicodeDecodeError) as e:
            raise RobotError(f"{w}robot URDF file '{path}' cannot be read ({e})") from None
        robot = RobotModel(text, tool_frame, where=str(path))
        return {"urdf": text, "tool_frame": robot.tool_frame, "name": robot.name}
    raise RobotError(_unknown_robot(spec, w))


# ---------------------------------------------------------------------- deduplication
@dataclass(frozen=True)
class UniqueConfigurations:
    """Distinct configurations of a batch and the map back to every sample.

    Attributes
    ----------
    q : (U, n) [rad]
        One configuration per group: the exact configuration when ``tol == 0``, the centre of the
        quantisation cell otherwise.
    inverse : (N,) int
        Sample ``i`` belongs to group ``inverse[i]``, so ``values[inverse]`` scatters per-group
        results back to the samples.
    tol : float
        Quantisation step [rad] (0 = exact repeats only).
    """

    q: np.ndarray
    inverse: np.ndarray
    tol: float

    @property
    def ratio(self) -> float:
        """Samples per distinct configuration (N / U, ≥ 1)."""
        return len(self.inverse) / max(len(self.q), 1)


def unique_configurations(q: np.ndarray, tol: float = 0.0) -> UniqueConfigurations:
    """Group the samples of ``q`` into distinct configurations.

    Parameters
    ----------
    q : (N, n) [rad]
        Joint positions.
    tol : float [rad]
        0 merges exact repeats only (bit-identical rows; -0.0 counts as 0.0). ``tol > 0`` merges
        configurations in the same cell of a grid of step ``tol`` on every joint and represents
        each cell by its centre, so every sample is evaluated at most ``tol / 2`` [rad] away from
        its own value per joint.

    Returns
    -------
    UniqueConfigurations
        ``q (U, n)`` in order of first appearance, ``inverse (N,)`` with ``q_out[inverse] == q``
        (exactly when ``tol == 0``).

    Notes
    -----
    1. Runs of consecutive identical rows (a robot standing still with a quiet encoder) are
       collapsed in O(N).
    2. The run representatives are grouped by a 64-bit hash of their bits (``pandas.factorize``,
       O(R)), so a configuration that recurs later (encoder flicker between two counts) is also
       computed once.
    3. The grouping is verified bit for bit; on a hash collision (never observed) it falls back to
       sorting the rows (``numpy.unique``), so the result is exact either way.
    """
    q = np.ascontiguousarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise RobotError(f"q has shape {q.shape}, expected (N, n)")
    N, n = q.shape
    if not (np.isfinite(tol) and tol >= 0):
        raise RobotError(f"quantisation tolerance is {tol!r}, expected a finite value >= 0 [rad]")
    if N == 0:
        return UniqueConfigurations(q.copy(), np.zeros(0, dtype=np.intp), float(tol))
    if tol > 0:
        key = np.floor(q / tol + 0.5) + 0.0  # cell index (exact integers for |q / tol| < 2**52)
    else:
        key = q + 0.0  # + 0.0 maps -0.0 to 0.0
    bits = key.view(np.uint64)  # (N, n): compare and hash bit patterns (NaN == NaN here)
    # 1) collapse runs of identical consecutive rows
    starts = np.empty(N, dtype=bool)
    starts[0] = True
    np.any(bits[1:] != bits[:-1], axis=1, out=starts[1:])
    run_first = np.flatnonzero(starts)
    run_id = np.cumsum(starts) - 1  # (N,) run of each sample
    reps = bits[run_first]  # (R, n)
    # 2) hash the representatives, group equal hashes in order of first appearance
    codes, _ = pd.factorize(_row_hash(reps))
    codes = codes.astype(np.intp, copy=False)
    prev_max = np.maximum.accumulate(np.concatenate(([-1], codes[:-1])))
    first = np.flatnonzero(codes > prev_max)  # codes appear in increasing order
    # 3) verify bit for bit (a hash collision would merge different rows)
    if not np.array_equal(reps[first][codes], reps):  # pragma: no cover - 2**-64 per pair
        rows = np.ascontiguousarray(reps).view(np.dtype((np.void, 8 * n))).ravel()
        _, first, codes = np.unique(rows, return_index=True, return_inverse=True)
        codes = codes.reshape(-1)
    inverse = codes[run_id]
    uq = key[run_first[first]] * tol if tol > 0 else q[run_first[first]]
    return UniqueConfigurations(np.ascontiguousarray(uq), inverse, float(tol))


_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def _row_hash(bits: np.ndarray) -> np.ndarray:
    """(R,) uint64 hash of the rows of a (R, n) uint64 array (splitmix64 finaliser per column)."""
    h = np.zeros(len(bits), dtype=np.uint64)
    for j in range(bits.shape[1]):
        x = h ^ (bits[:, j] + np.uint64(_GOLDEN * (j + 1) % 2**64))
        x ^= x >> np.uint64(30)
        x *= _MIX1
        x ^= x >> np.uint64(27)
        x *= _MIX2
        x ^= x >> np.uint64(31)
        h = x
    return h


# ---------------------------------------------------------------------- URDF parsing
@contextlib.contextmanager
def _captured_stderr_fd():
    """Capture what C++ code (urdfdom) writes to file descriptor 2, yielding a getter."""
    buf: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded interpreters): nothing to capture
        yield lambda: ""
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        try:
            os.dup2(tmp.fileno(), 2)
            yield lambda: "".join(buf)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            buf.append(tmp.read().decode("utf-8", "replace"))


def _urdfdom_reason(text: str) -> str:
    """The first 'Error: ...' line urdfdom printed, without its source location."""
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("Error:"):
            return " ".join(line[len("Error:") :].split())
    return ""


def _build_model(urdf: str, where: str) -> pin.Model:
    if not isinstance(urdf, str) or not urdf.strip():
        raise RobotError(f"{where}robot URDF is empty (expected URDF XML text)")
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as e:
        raise RobotError(f"{where}robot URDF does not parse as XML ({e})") from None
    if root.tag != "robot":
        raise RobotError(
            f"{where}robot URDF has root element <{root.tag}>, expected <robot name=...>"
        )
    got: Callable[[], str]
    try:
        with _captured_stderr_fd() as got:
            model = pin.buildModelFromXML(urdf)
    except (ValueError, RuntimeError) as e:
        reason = _urdfdom_reason(got()) or str(e).strip()
        raise RobotError(f"{where}robot URDF does not parse: {reason}") from None
    if model.njoints <= 1:
        raise RobotError(f"{where}robot URDF has no movable joints (expected at least one)")
    bad = [
        f"{model.names[j]} ({model.joints[j].shortname()})"
        for j in range(1, model.njoints)
        if not (model.joints[j].nv == 1 and model.joints[j].nq in (1, 2))
    ]
    if bad:
        raise RobotError(
            f"{where}robot URDF has joints {', '.join(bad)} with several degrees of freedom; "
            "expected revolute, continuous or prismatic joints"
        )
    return model


# ---------------------------------------------------------------------- the model
class RobotModel:
    """A serial robot over pinocchio, with the tool point and payload of a recording.

    Parameters
    ----------
    urdf : str
        URDF text.
    tool_frame : str or None
        Name of the URDF link (or frame) at the robot's flange / tool; None picks the first of
        ``tool0``, ``flange``, ``ee_link``, ``tool``, ``end_effector``, else the last link of
        the chain.
    name : str, optional
        Short name (default: the URDF's ``<robot name>``).
    tool_offset : (3,) [m], optional
        Tool point relative to the tool frame, in tool-frame axes.
    payload : {"mass": kg, "com": (3,) m}, optional
        Point mass with its centre in the tool frame, added to the link carrying the tool frame.
    where : str, optional
        File or recording name used in error messages.

    Attributes
    ----------
    name, n, joint_names, q_lower, q_upper (n,) [rad], velocity_limit (n,) [rad/s],
    effort_limit (n,) [N·m], urdf, tool_frame, tool_offset (3,) [m], payload (dict or None),
    model (pinocchio.Model with the payload and the tool-point frame added).
    """

    def __init__(
        self,
        urdf: str,
        tool_frame: str | None = None,
        *,
        name: str | None = None,
        tool_offset: Sequence[float] | np.ndarray | None = None,
        payload: Mapping[str, Any] | None = None,
        where: str | None = None,
    ) -> None:
        w = where_prefix(where)
        model = _build_model(urdf, w)
        if tool_frame is None:
            tool_frame = _guess_tool_frame(model)
        if not isinstance(tool_frame, str) or not model.existFrame(tool_frame):
            links = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
            raise RobotError(
                f"{w}tool frame {tool_frame!r} is not in the robot's URDF (expected one of its "
                f"links: {', '.join(links)})"
            )
        offset = np.zeros(3) if tool_offset is None else np.asarray(tool_offset, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise RobotError(
                f"{w}tool_offset is {tool_offset!r}, expected three finite numbers [x, y, z] in m"
            )
        tf_id = model.getFrameId(tool_frame)
        tf = model.frames[tf_id]
        parent_joint = tf.parentJoint
        if payload is not None:
            mass, com = _parse_payload(payload, w)
            if mass > 0:
                # point mass at `com` in the tool frame, expressed in the parent joint's frame
                inertia = pin.Inertia(mass, com, np.zeros((3, 3)))
                model.inertias[parent_joint] = model.inertias[parent_joint] + tf.placement.act(
                    inertia
                )
            payload = {"mass": mass, "com": com.tolist()}
        placement = tf.placement * pin.SE3(np.eye(3), offset)
        self._tool_point_id = model.addFrame(
            pin.Frame(TOOL_POINT_FRAME, parent_joint, tf_id, placement, pin.FrameType.OP_FRAME)
        )
        self._tool_frame_id = tf_id
        self._tool_joint = parent_joint
        self.model = model
        self._data = model.createData()
        self.urdf = urdf
        self.tool_frame = tool_frame
        self.tool_offset = offset
        self.payload = payload
        self.name = name or _robot_name(urdf) or "urdf"
        self.n = int(model.nv)
        # continuous joints have (cos, sin) coordinates in pinocchio; ditherlab's q is the angle
        self._q_map = [
            (int(model.idx_qs[j]), int(model.idx_vs[j]), int(model.joints[j].nq))
            for j in range(1, model.njoints)
        ]
        self._angles_are_pin_q = all(nq == 1 for _, _, nq in self._q_map)
        self.joint_names = list(model.names[1:])
        self.q_lower = np.full(self.n, -np.inf)
        self.q_upper = np.full(self.n, np.inf)
        for iq, iv, nq in self._q_map:
            if nq == 1:
                self.q_lower[iv] = model.lowerPositionLimit[iq]
                self.q_upper[iv] = model.upperPositionLimit[iq]
        self.velocity_limit = np.array(model.velocityLimit, dtype=float)
        self.effort_limit = np.array(model.effortLimit, dtype=float)
        self.link_names = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
        self._where = where
        self._lock = threading.RLock()
        self._cache: OrderedDict[tuple, dict[str, np.ndarray | None]] = OrderedDict()
        #: Byte budget of the per-configuration result cache (see :meth:`evaluate`).
        self.cache_bytes = 256 * 2**20
        self._kernels_cache = self._kernels()

    def __reduce__(self):
        """Pickle as the constructor's arguments (pinocchio objects are rebuilt)."""
        return (
            _rebuild,
            (
                self.urdf,
                self.tool_frame,
                self.name,
                self.tool_offset.tolist(),
                self.payload,
                self._where,
            ),
        )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_spec(
        cls,
        spec: str | Mapping[str, Any],
        tool_offset: Sequence[float] | np.ndarray | None = None,
        payload: Mapping[str, Any] | None = None,
        where: str | None = None,
    ) -> RobotModel:
        """Build from a recording's ``meta["robot"]`` entry.

        Parameters
        ----------
        spec : str or dict
            A built-in name (:func:`builtin_robots`), ``{"urdf": text, "tool_frame": name}``
            (optionally ``"name"``), or a path to a ``.urdf`` file (see :func:`resolve_spec`).
        tool_offset : (3,) [m], optional
            Tool point relative to the tool frame (tool-frame axes).
        payload : {"mass": kg, "com": [x, y, z] m}, optional
            Point mass in the tool frame.
        where : str, optional
            File or recording name for error messages.
        """
        w = where_prefix(where)
        if isinstance(spec, str | os.PathLike) and spec not in _BUILTIN:
            spec = resolve_spec(spec, where=where)
        if isinstance(spec, str):
            fname, tool = _BUILTIN[spec]
            return cls(
                builtin_urdf(spec),
                tool,
                name=spec,
                tool_offset=tool_offset,
                payload=payload,
                where=where,
            )
        if isinstance(spec, Mapping):
            urdf, tool = spec.get("urdf"), spec.get("tool_frame")
            if not isinstance(urdf, str) or not urdf.strip():
                raise RobotError(f"{w}robot key 'urdf' is {_short(urdf)}, expected URDF text")
            if not isinstance(tool, str) or not tool:
                raise RobotError(
                    f"{w}robot key 'tool_frame' is {tool!r}, expected the name of a URDF link"
                )
            return cls(
                urdf,
                tool,
                name=spec.get("name"),
                tool_offset=tool_offset,
                payload=payload,
                where=where,
            )
        raise RobotError(_unknown_robot(spec, w))

    @classmethod
    def from_recording_meta(
        cls,
        meta: Mapping[str, Any],
        n_expected: int | None = None,
        where: str | None = None,
    ) -> RobotModel:
        """Build from recording metadata (``robot``, ``tool_offset``, ``payload``).

        Parameters
        ----------
        meta : dict
            Recording metadata (RECORDING.md).
        n_expected : int, optional
            Number of joints in the recording; RobotError when the robot has another count.
        where : str, optional
            File or recording name for error messages.
        """
        w = where_prefix(where)
        if "robot" not in meta:
            raise RobotError(
                f"{w}metadata key 'robot' is missing (expected a built-in name such as "
                f"{builtin_robots()[0]!r} or {{'urdf': ..., 'tool_frame': ...}})"
            )
        robot = cls.from_spec(
            meta["robot"],
            tool_offset=meta.get("tool_offset"),
            payload=meta.get("payload"),
            where=where,
        )
        if n_expected is not None and int(n_expected) != robot.n:
            raise RobotError(
                f"{w}robot {robot.name!r} has {robot.n} joints but the recording has "
                f"{int(n_expected)} (expected columns q_1..q_{robot.n})"
            )
        return robot

    def with_payload(self, payload: Mapping[str, Any] | None) -> RobotModel:
        """The same robot and tool point with another payload (None = none)."""
        return RobotModel(
            self.urdf,
            self.tool_frame,
            name=self.name,
            tool_offset=self.tool_offset,
            payload=payload,
            where=self._where,
        )

    def __repr__(self) -> str:
        p = f", payload={self.payload['mass']:g} kg" if self.payload else ""
        return (
            f"RobotModel({self.name!r}, n={self.n}, tool_frame={self.tool_frame!r}, "
            f"tool_offset={self.tool_offset.tolist()}{p})"
        )

    # ------------------------------------------------------------------ summary
    def parse_pose(self, text: str | None, where: str = "--q") -> np.ndarray:
        """A configuration from text: ``"paper"`` (:data:`PAPER_POSE`, IRB140), ``"zero"``, or
        ``n`` comma-separated angles in radians.

        Returns
        -------
        (n,) [rad]
        """
        if text is None or text.strip().lower() in ("", "zero"):
            return np.zeros(self.n)
        if text.strip().lower() == "paper":
            if self.name != "irb140":
                raise RobotError(
                    f"{where} is 'paper', which is defined for robot 'irb140' only (this is "
                    f"{self.name!r}); expected {self.n} comma-separated angles in rad"
                )
            return np.array(PAPER_POSE)
        try:
            q = np.array([float(x) for x in text.split(",")])
        except ValueError:
            q = np.zeros(0)
        if q.shape != (self.n,) or not np.all(np.isfinite(q)):
            raise RobotError(
                f"{where} is {text!r}, expected {self.n} comma-separated angles in rad "
                "(or 'zero', 'paper')"
            )
        return q

    def describe(self, q: np.ndarray | None = None) -> dict[str, Any]:
        """A JSON-ready summary: joints and limits, masses, and at pose ``q`` the tool pose,
        gravity and lever arms.

        Parameters
        ----------
        q : (n,) [rad], optional
            Pose for the pose-dependent part (default: zeros).

        Returns
        -------
        dict
            ``name, n, tool_frame, tool_offset [m], payload, moving_mass [kg], joints`` (name,
            lower/upper [rad], velocity [rad/s], effort [N·m]) and ``pose``: ``q [rad]``,
            ``tool_position [m]``, ``tool_rotation`` (3×3, columns = tool axes in base axes),
            ``gravity [N·m]``, ``lever_arms [m]`` (3 × n: |∂tau_j/∂F_axis| for F along base
            x, y, z at the tool point).
        """
        q = np.zeros(self.n) if q is None else np.asarray(q, dtype=float).reshape(self.n)
        r = self.evaluate(q, ["gravity", "jacobian", "tool_pose"], dedup=False)
        T = r["tool_pose"][0]

        def finite(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "name": self.name,
            "n": self.n,
            "tool_frame": self.tool_frame,
            "tool_offset": self.tool_offset.tolist(),
            "payload": self.payload,
            "moving_mass": float(sum(self.model.inertias[j].mass for j in range(1, self.n + 1))),
            "joints": [
                {
                    "name": name,
                    "lower": finite(self.q_lower[j]),
                    "upper": finite(self.q_upper[j]),
                    "velocity": finite(self.velocity_limit[j]),
                    "effort": finite(self.effort_limit[j]),
                }
                for j, name in enumerate(self.joint_names)
            ],
            "pose": {
                "q": q.tolist(),
                "tool_position": T[:3, 3].tolist(),
                "tool_rotation": T[:3, :3].tolist(),
                "gravity": r["gravity"][0].tolist(),
                "lever_arms": np.abs(r["jacobian"][0][:3]).tolist(),
            },
        }

    # ------------------------------------------------------------------ checks
    def check_units(self, q: np.ndarray, where: str | None = None, margin: float = np.pi) -> bool:
        """Warn (DitherlabWarning) when joint angles lie far outside the limits, as if in degrees.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
            Joint positions.
        where : str, optional
            File or recording name for the message.
        margin : float [rad]
            A joint is suspicious when some sample lies more than ``margin`` outside
            ``[q_lower, q_upper]`` (NaN samples are ignored).

        Returns
        -------
        bool
            True when a warning was issued (for the joint that is furthest outside).
        """
        q2 = self._as_batch(q, where)
        if q2.shape[0] == 0 or not np.any(np.isfinite(q2)):
            return False
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
            lo, hi = np.nanmin(q2, axis=0), np.nanmax(q2, axis=0)
        excess = np.fmax(self.q_lower - lo, hi - self.q_upper)  # [rad] beyond the limits
        excess = np.where(np.isfinite(excess), excess, -np.inf)
        j = int(np.argmax(excess))
        if excess[j] <= margin:
            return False
        peak = hi[j] if hi[j] - self.q_upper[j] >= self.q_lower[j] - lo[j] else lo[j]
        in_deg = self.q_lower[j] - 0.1 <= np.radians(lo[j]) and np.radians(hi[j]) <= (
            self.q_upper[j] + 0.1
        )
        hint = " as if in degrees" if in_deg else ""
        warnings.warn(
            f"{where_prefix(where)}q_{j + 1} reaches {peak:.4g}, far outside the joint limits "
            f"[{self.q_lower[j]:.3g}, {self.q_upper[j]:.3g}] rad{hint} (expected radians)",
            DitherlabWarning,
            stacklevel=2,
        )
        return True

    def _as_batch(self, q: np.ndarray, where: str | None = None) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != self.n:
            raise RobotError(
                f"{where_prefix(where or self._where)}q has shape {q.shape}, expected (N, {self.n}) "
                f"or ({self.n},) for robot {self.name!r}"
            )
        return q

    # ------------------------------------------------------------------ batched evaluation
    def pin_configuration(self, q: np.ndarray) -> np.ndarray:
        """Joint angles ``q (N, n) [rad]`` as pinocchio configurations ``(N, model.nq)``.

        The same array for revolute and prismatic joints; a continuous joint's angle becomes
        ``(cos q, sin q)``.
        """
        q = self._as_batch(q)
        if self._angles_are_pin_q:
            return q
        out = np.empty((len(q), self.model.nq))
        for iq, iv, nq in self._q_map:
            if nq == 1:
                out[:, iq] = q[:, iv]
            else:
                out[:, iq] = np.cos(q[:, iv])
                out[:, iq + 1] = np.sin(q[:, iv])
        return out

    def _kernels(self) -> dict[str, tuple[Callable[[np.ndarray, np.ndarray], None], tuple]]:
        """Per-quantity loops over pinocchio: name -> (fill(qs (U, n), out (U, ...)), shape).

        Each ``fill`` is a tight loop with its pinocchio function and arguments bound to local
        names: the per-sample Python overhead is then about that of one pinocchio call.
        """
        m, d, n = self.model, self._data, self.n
        fid, parent = self._tool_point_id, self._tool_joint
        tool_placement = m.frames[fid].placement
        z = np.zeros(n)
        cols = slice(10 * (parent - 1), 10 * parent)
        T_params = self._tool_to_joint_params()
        link_ids = [m.getFrameId(name) for name in self.link_names]
        oMi, oMf = d.oMi, d.oMf

        def gravity(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.computeGeneralizedGravity
            for i in range(len(qs)):
                out[i] = f(m, d, qs[i])

        def jacobian(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.computeFrameJacobian
            for i in range(len(qs)):
                out[i] = f(m, d, qs[i], fid, _LWA)

        def mass(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.crba
            for i in range(len(qs)):
                out[i] = f(m, d, qs[i])
            # pinocchio fills the upper triangle only
            iu = np.tril_indices(n, -1)
            out[:, iu[0], iu[1]] = out[:, iu[1], iu[0]]

        def tool(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.forwardKinematics
            for i in range(len(qs)):
                f(m, d, qs[i])
                out[i] = (oMi[parent] * tool_placement).homogeneous

        def links(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.framesForwardKinematics
            for i in range(len(qs)):
                f(m, d, qs[i])
                for k, j in enumerate(link_ids):
                    out[i, k] = oMf[j].homogeneous

        def regressor(qs: np.ndarray, out: np.ndarray) -> None:
            f = pin.computeJointTorqueRegressor
            for i in range(len(qs)):
                out[i] = f(m, d, qs[i], z, z)[:, cols] @ T_params

        return {
            "gravity": (gravity, (n,)),
            "jacobian": (jacobian, (6, n)),
            "mass_matrix": (mass, (n, n)),
            "tool_pose": (tool, (4, 4)),
            "link_poses": (links, (len(link_ids), 4, 4)),
            "gravity_regressor": (regressor, (n, 10)),
        }

    def _compute(
        self,
        qs: np.ndarray,
        quantities: Sequence[str],
        progress: Callable[[int, int], None] | None,
    ) -> dict[str, np.ndarray]:
        """Evaluate ``quantities`` at every row of ``qs (U, n)``, one pinocchio call each."""
        kernels = self._kernels_cache
        qs = self.pin_configuration(qs)
        total = len(qs)
        outs = {k: np.empty((total, *kernels[k][1])) for k in quantities}
        chunk = max(total if progress is None else -(-total // 100), 256)
        with self._lock:  # pinocchio Data is shared scratch space
            for start in range(0, total, chunk):
                stop = min(start + chunk, total)
                for k in quantities:
                    kernels[k][0](qs[start:stop], outs[k][start:stop])
                if progress is not None:
                    progress(stop, total)
        if progress is not None and total == 0:
            progress(0, 0)
        return outs

    def evaluate(
        self,
        q: np.ndarray,
        quantities: Sequence[str],
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, np.ndarray]:
        """Several batched quantities at once, sharing one deduplication pass.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
            Joint positions.
        quantities : names
            Any of ``gravity``, ``jacobian``, ``mass_matrix``, ``tool_pose``, ``link_poses``
            (all links stacked, (N, L, 4, 4) in the order of :attr:`link_names`),
            ``gravity_regressor``.
        tol : float [rad]
            Quantisation step (see :meth:`gravity`); 0 = exact repeats only.
        dedup : bool
            False evaluates every sample with a plain loop (the reference path, not cached).
        progress : callable(done, total), optional
            Called with the number of distinct configurations evaluated so far.

        Returns
        -------
        dict name -> array with the samples on the first axis (new arrays, safe to modify).

        Notes
        -----
        When some configurations repeat, their results are kept in a small cache keyed by a
        BLAKE2 digest of ``q`` and ``tol`` (at most :attr:`cache_bytes` bytes, least recently
        used evicted), so the gravity of one recording asked for by several consumers is
        computed once (a repeated call costs a digest and a copy, ~30x faster than computing).
        """
        unknown = [k for k in quantities if k not in self._kernels_cache]
        if unknown:
            raise RobotError(
                f"unknown robot quantity {unknown[0]!r}, expected one of: "
                f"{', '.join(self._kernels_cache)}"
            )
        q = self._as_batch(q)
        if not np.isfinite(tol) or tol < 0:
            raise RobotError(
                f"quantisation tolerance is {tol!r}, expected a finite value >= 0 [rad]"
            )
        quantities = list(dict.fromkeys(quantities))
        if not dedup:
            return self._compute(q, quantities, progress)
        key = (
            hashlib.blake2b(np.ascontiguousarray(q).data, digest_size=16).digest(),
            q.shape,
            float(tol),
        )
        with self._lock:  # the cache and pinocchio Data are shared by all callers
            entry = self._cache.pop(key, None)
            if entry is None:
                u = unique_configurations(q, tol)
                # inverse None: nothing repeats (a moving robot), results are already per sample
                entry = {"q": u.q, "inverse": None if len(u.q) == len(q) else u.inverse}
            missing = [k for k in quantities if k not in entry]
            if missing:
                entry.update(self._compute(entry["q"], missing, progress))
            elif progress is not None:
                progress(len(entry["q"]), len(entry["q"]))
            inverse = entry["inverse"]
            if inverse is None and _nbytes(entry) > self.cache_bytes:
                return {k: entry[k] for k in quantities}  # too large to keep: no copy needed
            # new arrays for the caller (fancy indexing copies), so the cache cannot be altered
            result = {
                k: entry[k].copy() if inverse is None else entry[k][inverse] for k in quantities
            }
            self._remember(key, entry)
            return result

    def _remember(self, key: tuple, entry: dict[str, np.ndarray | None]) -> None:
        size = _nbytes(entry)
        if size > self.cache_bytes:
            return
        self._cache[key] = entry
        total = sum(_nbytes(e) for e in self._cache.values())
        while total > self.cache_bytes:
            _, old = self._cache.popitem(last=False)
            total -= _nbytes(old)

    def clear_cache(self) -> None:
        """Forget every cached result."""
        self._cache.clear()

    def gravity(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Gravity torques ``g(q)``: what the motors must deliver to hold the arm still.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
            Joint positions.
        tol : float [rad]
            Quantisation step for deduplication (0 = exact repeats only, bit-identical to the
            per-sample loop). With ``tol > 0`` each sample is evaluated at most ``tol / 2`` per
            joint from its own configuration, so the error is at most
            ``(tol / 2) · max_i Σ_j |∂g_i/∂q_j|``. For the IRB140 that Lipschitz constant is
            267 N·m/rad without payload and 361 N·m/rad with 6 kg at 0.1 m (worst of 20 000
            random configurations), so ``tol = 1e-5`` rad costs at most 1.3e-3 (1.8e-3) N·m;
            one count of a 20-bit encoder is 6.0e-6 rad.
        dedup : bool
            False evaluates every sample (the reference path).
        progress : callable(done, total), optional

        Returns
        -------
        (N, n) [N·m]
        """
        return self.evaluate(q, ["gravity"], tol=tol, dedup=dedup, progress=progress)["gravity"]

    def jacobian(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Geometric Jacobian of the tool point, linear part first, base-frame axes.

        ``J @ dq = (v, w)``: the tool point's linear velocity [m/s] and the tool's angular
        velocity [rad/s], both in base-frame axes (pinocchio ``LOCAL_WORLD_ALIGNED``); so
        ``J.T @ F`` is the joint torque of a wrench ``F = (f, m)`` [N, N·m] at the tool point.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
        tol, dedup, progress : see :meth:`gravity`. With ``tol > 0`` the error of a lever arm
            is at most ``(tol / 2) · Σ_j |∂J/∂q_j|`` ≈ ``tol / 2 · n · reach`` [m].

        Returns
        -------
        (N, 6, n) [m/rad for the linear rows, 1 for the angular rows]
        """
        return self.evaluate(q, ["jacobian"], tol=tol, dedup=dedup, progress=progress)["jacobian"]

    def gravity_jacobian(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`gravity` and :meth:`jacobian` with one deduplication pass.

        Returns
        -------
        gravity : (N, n) [N·m]
        jacobian : (N, 6, n)
        """
        r = self.evaluate(q, ["gravity", "jacobian"], tol=tol, dedup=dedup, progress=progress)
        return r["gravity"], r["jacobian"]

    def mass_matrix(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Joint-space mass matrix ``M(q)`` (symmetric), arm side, without motor inertia.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
        tol, dedup, progress : see :meth:`gravity`.

        Returns
        -------
        (N, n, n) [kg m²]
        """
        return self.evaluate(q, ["mass_matrix"], tol=tol, dedup=dedup, progress=progress)[
            "mass_matrix"
        ]

    def tool_pose(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Pose of the tool point in the base frame: rotation = the tool frame's axes.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
        tol, dedup, progress : see :meth:`gravity`.

        Returns
        -------
        (N, 4, 4)
            Homogeneous transforms, translation [m].
        """
        return self.evaluate(q, ["tool_pose"], tol=tol, dedup=dedup, progress=progress)["tool_pose"]

    def link_poses(
        self,
        q: np.ndarray,
        *,
        links: Sequence[str] | None = None,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, np.ndarray]:
        """Pose of every URDF link (body frame) in the base frame.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
        links : names, optional
            Subset of :attr:`link_names` (default: all).
        tol, dedup, progress : see :meth:`gravity`.

        Returns
        -------
        dict link name -> (N, 4, 4)
            Homogeneous transforms, translation [m].
        """
        names = list(self.link_names if links is None else links)
        for name in names:
            if name not in self.link_names:
                raise RobotError(
                    f"{where_prefix(self._where)}link {name!r} is not in robot {self.name!r} "
                    f"(expected one of: {', '.join(self.link_names)})"
                )
        out = self.evaluate(q, ["link_poses"], tol=tol, dedup=dedup, progress=progress)
        stacked = out["link_poses"]
        return {
            name: np.ascontiguousarray(stacked[:, self.link_names.index(name)]) for name in names
        }

    def gravity_regressor(
        self,
        q: np.ndarray,
        *,
        tol: float = 0.0,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Gravity torques per unit of the dynamic parameters of a body on the tool link.

        ``gravity_regressor(q) @ theta`` is the gravity torque of a body with dynamic parameters
        ``theta = (m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)`` (pinocchio's
        order; mass [kg], first moments [kg m], inertia about the tool-frame origin [kg m²]),
        all in the **tool frame** (not moved by ``tool_offset``), rigidly attached to the link
        that carries the tool frame. A payload ``{"mass": m, "com": c}`` has
        ``theta = (m, m c, 0, ...)``. Gravity does not depend on the inertia, so the last six
        columns are zero; they are kept so the shape matches the full joint-torque regressor.

        Built from pinocchio's ``computeJointTorqueRegressor`` at zero velocity and
        acceleration (the block of the tool link's joint), mapped from that joint's frame to
        the tool frame.

        Parameters
        ----------
        q : (N, n) or (n,) [rad]
        tol, dedup, progress : see :meth:`gravity`.

        Returns
        -------
        (N, n, 10) [N·m per unit parameter]
        """
        return self.evaluate(q, ["gravity_regressor"], tol=tol, dedup=dedup, progress=progress)[
            "gravity_regressor"
        ]

    def inverse_dynamics(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        ddq: np.ndarray,
        *,
        dedup: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Rigid-body joint torques ``M(q) ddq + C(q, dq) dq + g(q)`` (pinocchio's RNEA).

        Arm side, with the payload; without friction, motor inertia or external wrench.

        Parameters
        ----------
        q : (N, n) [rad]
        dq : (N, n) [rad/s]
        ddq : (N, n) [rad/s²]
        dedup : bool
            Evaluate each distinct ``(q, dq, ddq)`` once (a robot standing still repeats
            ``(q, 0, 0)``); False = plain per-sample loop.
        progress : callable(done, total), optional

        Returns
        -------
        (N, n) [N·m]
        """
        N, xs, inverse, qp, vs, acc = self._motion_batch(q, dq, ddq, dedup)
        n, total = self.n, len(xs)
        out = np.empty((total, n))
        m, d, f = self.model, self._data, pin.rnea
        chunk = max(total if progress is None else -(-total // 100), 256)
        with self._lock:
            for start in range(0, total, chunk):
                stop = min(start + chunk, total)
                for i in range(start, stop):
                    out[i] = f(m, d, qp[i], vs[i], acc[i])
                if progress is not None:
                    progress(stop, total)
        return out if inverse is None or len(xs) == N else out[inverse]

    def _motion_batch(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, dedup: bool
    ) -> tuple[int, np.ndarray, np.ndarray | None, np.ndarray, np.ndarray, np.ndarray]:
        """(N, distinct rows of [q dq ddq], inverse index or None, their pinocchio
        configurations, velocities, accelerations) of a batch of motion samples."""
        q = self._as_batch(q)
        dq, ddq = self._as_batch(dq), self._as_batch(ddq)
        if not (len(q) == len(dq) == len(ddq)):
            raise RobotError(
                f"{where_prefix(self._where)}q, dq and ddq have {len(q)}, {len(dq)} and {len(ddq)} "
                "samples, expected the same number"
            )
        n = self.n
        x = np.concatenate([q, dq, ddq], axis=1)
        if dedup:
            u = unique_configurations(x)
            xs, inverse = u.q, u.inverse
        else:
            xs, inverse = x, None
        qp = self.pin_configuration(xs[:, :n])
        vs, acc = np.ascontiguousarray(xs[:, n : 2 * n]), np.ascontiguousarray(xs[:, 2 * n :])
        return len(x), xs, inverse, qp, vs, acc

    def torque_regressor(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        ddq: np.ndarray,
        *,
        dedup: bool = True,
    ) -> np.ndarray:
        """Joint torques per unit of the dynamic parameters of a body on the tool link, moving.

        ``torque_regressor(q, dq, ddq) @ theta`` is the torque ``M ddq + C dq + g`` that a body
        with parameters ``theta`` (as in :meth:`gravity_regressor`, tool frame) adds; at
        ``dq = ddq = 0`` it equals :meth:`gravity_regressor`. pinocchio's
        ``computeJointTorqueRegressor`` (the tool link's block), mapped to the tool frame.

        Parameters
        ----------
        q, dq, ddq : (N, n) [rad, rad/s, rad/s²]
        dedup : evaluate each distinct ``(q, dq, ddq)`` once

        Returns
        -------
        (N, n, 10) [N·m per unit parameter]
        """
        N, xs, inverse, qp, vs, acc = self._motion_batch(q, dq, ddq, dedup)
        n = self.n
        cols = slice(10 * (self._tool_joint - 1), 10 * self._tool_joint)
        T = self._tool_to_joint_params()
        m, d, f = self.model, self._data, pin.computeJointTorqueRegressor
        out = np.empty((len(xs), n, 10))
        with self._lock:
            for i in range(len(xs)):
                out[i] = f(m, d, qp[i], vs[i], acc[i])[:, cols] @ T
        return out if inverse is None or len(xs) == N else out[inverse]

    def _tool_to_joint_params(self) -> np.ndarray:
        """(10, 10) linear map: dynamic parameters in the tool frame -> parent joint frame."""
        X = self.model.frames[self._tool_frame_id].placement
        base = np.array([1.0, 0, 0, 0, 1.0, 0, 1.0, 0, 0, 1.0])  # a valid reference body

        def act(theta: np.ndarray) -> np.ndarray:
            return X.act(pin.Inertia.FromDynamicParameters(theta)).toDynamicParameters()

        ref = act(base)
        T = np.empty((10, 10))
        for k in range(10):
            e = np.zeros(10)
            e[k] = 1.0
            T[:, k] = act(base + e) - ref
        return T


def format_description(d: Mapping[str, Any]) -> str:
    """Plain-text table of :meth:`RobotModel.describe` (angles in degrees for reading)."""

    def deg(x: float | None) -> str:
        return "-" if x is None else f"{np.degrees(x):.1f}"

    pay = d["payload"]
    lines = [
        f"robot {d['name']}: {d['n']} joints, tool frame {d['tool_frame']}, tool offset "
        f"{d['tool_offset']} m, payload "
        + (f"{pay['mass']:g} kg at {pay['com']} m" if pay else "none")
        + f", moving mass {d['moving_mass']:.1f} kg",
        f"{'joint':<22}{'lower [deg]':>12}{'upper [deg]':>12}{'vel [deg/s]':>12}"
        f"{'effort [N·m]':>13}",
    ]
    for j in d["joints"]:
        eff = "-" if j["effort"] is None else f"{j['effort']:.0f}"
        lines.append(
            f"{j['name']:<22}{deg(j['lower']):>12}{deg(j['upper']):>12}"
            f"{deg(j['velocity']):>12}{eff:>13}"
        )
    pose = d["pose"]
    qd = ", ".join(f"{np.degrees(x):.1f}" for x in pose["q"])
    px = ", ".join(_fixed(x, 3) for x in pose["tool_position"])
    z = ", ".join(_fixed(row[2], 3) for row in pose["tool_rotation"])
    lines += [
        f"at q = ({qd}) deg: tool point ({px}) m, tool z axis ({z})",
        f"{'joint':<22}{'gravity [N·m]':>14}{'lever Fx [m]':>14}{'lever Fy [m]':>14}"
        f"{'lever Fz [m]':>14}",
    ]
    lev = pose["lever_arms"]
    for k, j in enumerate(d["joints"]):
        lines.append(
            f"{j['name']:<22}{_fixed(pose['gravity'][k], 2):>14}{_fixed(lev[0][k], 3):>14}"
            f"{_fixed(lev[1][k], 3):>14}{_fixed(lev[2][k], 3):>14}"
        )
    return "\n".join(lines)


def _fixed(x: float, digits: int) -> str:
    """``x`` with ``digits`` decimals, never "-0.00"."""
    return f"{round(float(x), digits) + 0.0:.{digits}f}"


def _nbytes(entry: Mapping[str, np.ndarray | None]) -> int:
    return sum(v.nbytes for v in entry.values() if v is not None)


def _guess_tool_frame(model: pin.Model) -> str:
    for name in _TOOL_FRAME_GUESSES:
        if model.existFrame(name):
            return name
    last_joint = model.njoints - 1
    bodies = [
        f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == last_joint
    ]
    return bodies[-1] if bodies else model.frames[-1].name


def _rebuild(urdf, tool_frame, name, tool_offset, payload, where) -> RobotModel:
    return RobotModel(
        urdf, tool_frame, name=name, tool_offset=tool_offset, payload=payload, where=where
    )


def _parse_payload(payload: Mapping[str, Any], w: str) -> tuple[float, np.ndarray]:
    if not isinstance(payload, Mapping) or "mass" not in payload:
        raise RobotError(f"{w}payload is {payload!r}, expected {{'mass': kg, 'com': [x, y, z] m}}")
    try:
        mass = float(payload["mass"])
    except (TypeError, ValueError):
        mass = float("nan")
    if not np.isfinite(mass) or mass < 0:
        raise RobotError(f"{w}payload mass is {payload['mass']!r}, expected a number >= 0 [kg]")
    try:
        com = np.asarray(payload.get("com", (0.0, 0.0, 0.0)), dtype=float)
    except (TypeError, ValueError):
        com = np.full(1, np.nan)
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise RobotError(
            f"{w}payload com is {payload.get('com')!r}, expected [x, y, z] in m (tool frame)"
        )
    return mass, com


def _robot_name(urdf: str) -> str | None:
    try:
        return ET.fromstring(urdf).get("name")
    except ET.ParseError:
        return None


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 40 else r[:37] + "..."

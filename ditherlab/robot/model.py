"""The robot model: :class:`RobotModel`, kinematics and dynamics over pinocchio, batched over the
samples of a log (see :mod:`ditherlab.robot` for the conventions), and :func:`resolve_spec`.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pinocchio as pin

from ditherlab.core.errors import RobotError, where_prefix
from ditherlab.robot.batch import compiled_kernels, quantity_kernels, tool_to_joint_params
from ditherlab.robot.dedup import unique_configurations
from ditherlab.robot.describe import describe_robot
from ditherlab.robot.poses import PAPER_POSE, check_units, parse_pose
from ditherlab.robot.sources import read_description, unknown_name
from ditherlab.robot.urdf import (
    BUILTIN,
    build_model,
    builtin_robots,
    builtin_urdf,
    frame_id,
    guess_tool_frame,
    parse_payload,
    robot_name,
    short_repr,
)

__all__ = ["PAPER_POSE", "TOOL_POINT_FRAME", "RobotModel", "resolve_spec"]

#: Name of the frame ditherlab adds at the tool point (tool frame + tool_offset).
TOOL_POINT_FRAME = "ditherlab_tool_point"


def resolve_spec(
    spec: str | Mapping[str, Any],
    tool_frame: str | None = None,
    where: str | None = None,
    robot_args: Iterable[str] | Mapping[str, str] | None = None,
) -> str | dict[str, Any]:
    """Turn a user's robot choice into a recording's ``meta["robot"]`` entry.

    Parameters
    ----------
    spec : str or dict
        A built-in name (returned as is), an arm of example-robot-data by name (``ur5``,
        ``erd:panda``), a path to a ``.urdf`` file or a ``.xacro`` file (read, expanded and
        embedded, so the recording is self-describing), or ``{"urdf": text, "tool_frame":
        name}`` (checked).
    tool_frame : str, optional
        The tool frame, when it is not the description's own: a built-in's ``tool0``, an
        example-robot-data arm's flange, or for a URDF the first of ``tool0``, ``flange``,
        ``ee_link``, ``tool``, ``end_effector`` that exists, else the last link of the chain.
    where : str, optional
        File or option name for error messages.
    robot_args : ``NAME:=VALUE`` texts, optional
        A xacro file's arguments; ``package://PKG:=DIR`` says where a ROS package is
        (:func:`~ditherlab.robot.xacro_file.parse_robot_args`).

    Returns
    -------
    str or {"urdf": text, "tool_frame": name, "name": robot name[, "path": source file]}
    """
    w = where_prefix(where)
    if isinstance(spec, Mapping):
        if tool_frame is not None:
            spec = {**spec, "tool_frame": tool_frame}
        RobotModel.from_spec(spec, where=where)  # validates
        return dict(spec)
    if isinstance(spec, str) and spec in BUILTIN and not robot_args:
        if tool_frame is None or tool_frame == BUILTIN[spec][1]:
            return spec
        robot = RobotModel(builtin_urdf(spec), tool_frame, name=spec, where=where)
        return {"urdf": robot.urdf, "tool_frame": robot.tool_frame, "name": spec}
    if not isinstance(spec, str | os.PathLike):
        raise RobotError(unknown_name(spec, w))
    d = read_description(spec, robot_args, w)
    label = f"robot {d.name!r}" if d.name else d.path  # an arm by name, else its file
    robot = RobotModel(d.urdf, tool_frame or d.tool_frame, name=d.name, where=label or where)
    out = {"urdf": d.urdf, "tool_frame": robot.tool_frame, "name": robot.name}
    return out if d.path is None else {**out, "path": d.path}


def _tool_frame(model: pin.Model, tool_frame: str | None, w: str) -> str:
    """The tool frame's name: ``tool_frame`` when the URDF has it, the guess when None
    (:func:`~.urdf.guess_tool_frame`); RobotError otherwise."""
    if tool_frame is None:
        tool_frame = guess_tool_frame(model)
    if not isinstance(tool_frame, str) or not model.existFrame(tool_frame):
        links = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
        raise RobotError(
            f"{w}tool frame {tool_frame!r} is not in the robot's URDF (expected one of its "
            f"links: {', '.join(links)})"
        )
    return tool_frame


def _tool_offset(tool_offset: Sequence[float] | np.ndarray | None, w: str) -> np.ndarray:
    """The tool point's offset ``(3,)`` [m] in tool-frame axes (zeros when None)."""
    offset = np.zeros(3) if tool_offset is None else np.asarray(tool_offset, dtype=float)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise RobotError(
            f"{w}tool_offset is {tool_offset!r}, expected three finite numbers [x, y, z] in m"
        )
    return offset


def _add_payload(
    model: pin.Model, tf_id: int, payload: Mapping[str, Any], w: str
) -> dict[str, Any]:
    """Add the payload, a point mass [kg] at ``com`` [m] in the tool frame, to the inertia of the
    link that carries the tool frame ``tf_id`` (in place); returns it as ``{"mass", "com"}``."""
    mass, com = parse_payload(payload, w)
    if mass > 0:
        tf = model.frames[tf_id]
        parent_joint = tf.parentJoint
        # point mass at `com` in the tool frame, expressed in the parent joint's frame
        inertia = pin.Inertia(mass, com, np.zeros((3, 3)))
        model.inertias[parent_joint] = model.inertias[parent_joint] + tf.placement.act(inertia)
    return {"mass": mass, "com": com.tolist()}


def _add_tool_point(model: pin.Model, tf_id: int, offset: np.ndarray) -> int:
    """Add the frame :data:`TOOL_POINT_FRAME` at ``offset (3,)`` [m] from the tool frame
    ``tf_id`` (in place); returns its id."""
    tf = model.frames[tf_id]
    placement = tf.placement * pin.SE3(np.eye(3), offset)
    return model.addFrame(
        pin.Frame(TOOL_POINT_FRAME, tf.parentJoint, tf_id, placement, pin.FrameType.OP_FRAME)
    )


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
        model = build_model(urdf, w)
        tool_frame = _tool_frame(model, tool_frame, w)
        offset = _tool_offset(tool_offset, w)
        tf_id = frame_id(model, tool_frame)
        if payload is not None:
            payload = _add_payload(model, tf_id, payload, w)
        self._tool_point_id = _add_tool_point(model, tf_id, offset)
        self._tool_frame_id = tf_id
        self._tool_joint = model.frames[tf_id].parentJoint
        self.model = model
        self._data = model.createData()
        self.urdf = urdf
        self.tool_frame = tool_frame
        self.tool_offset = offset
        self.payload = payload
        self.name = name or robot_name(urdf) or "urdf"
        self.n = int(model.nv)
        self._read_joints()
        self.link_names = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
        self._where = where
        self._lock = threading.RLock()
        self._cache: OrderedDict[tuple, dict[str, np.ndarray | None]] = OrderedDict()
        #: Byte budget of the per-configuration result cache (see :meth:`evaluate`).
        self.cache_bytes = 256 * 2**20
        self._reference_cache = self.reference_kernels()
        self._kernels_cache = compiled_kernels(
            self.model, self._tool_point_id, self._reference_cache
        )

    def _read_joints(self) -> None:
        """The joints' names, position limits ``q_lower, q_upper (n,)`` [rad] (infinite for a
        continuous joint), velocity [rad/s] and effort [N·m] limits, and the map from
        ditherlab's angles to pinocchio's coordinates (a continuous joint has ``(cos, sin)``
        in pinocchio; ditherlab's ``q`` is the angle)."""
        model = self.model
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
        if isinstance(spec, str | os.PathLike) and spec not in BUILTIN:
            spec = resolve_spec(spec, where=where)
        if isinstance(spec, str):
            fname, tool = BUILTIN[spec]
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
                raise RobotError(f"{w}robot key 'urdf' is {short_repr(urdf)}, expected URDF text")
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
        raise RobotError(unknown_name(spec, w))

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
            Recording metadata (``docs/recording-format.md``).
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

    # ------------------------------------------------------------------ poses, summary, checks
    def parse_pose(self, text: str | None, where: str = "--q") -> np.ndarray:
        """A configuration ``(n,) [rad]`` from text: ``"paper"`` (:data:`PAPER_POSE`, IRB140),
        ``"zero"``, or ``n`` comma-separated angles in radians (:func:`~.poses.parse_pose`)."""
        return parse_pose(text, self.n, self.name, where)

    def describe(self, q: np.ndarray | None = None) -> dict[str, Any]:
        """A JSON-ready summary: joints and limits, masses, and at pose ``q`` (default: zeros)
        the tool pose, gravity and lever arms (:func:`~.describe.describe_robot`)."""
        return describe_robot(self, q)

    def check_units(self, q: np.ndarray, where: str | None = None, margin: float = np.pi) -> bool:
        """Warn (DitherlabWarning) when joint angles ``q (N, n) or (n,) [rad]`` lie more than
        ``margin`` [rad] outside the limits, as if in degrees; True when it warned
        (:func:`~.poses.check_units`)."""
        return check_units(self._as_batch(q, where), self.q_lower, self.q_upper, where, margin)

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

    def reference_kernels(self) -> dict[str, tuple[Callable, tuple]]:
        """Per-quantity loops over pinocchio (:func:`~ditherlab.robot.batch.quantity_kernels`,
        the reference of the compiled ones): ``name -> (fill(qs (U, nq), out (U, ...)), shape)``."""
        return quantity_kernels(
            self.model,
            self._data,
            self._tool_point_id,
            self._tool_joint,
            self.link_names,
            tool_to_joint_params(self.model, self._tool_frame_id),
        )

    def _compute(
        self,
        qs: np.ndarray,
        quantities: Sequence[str],
        progress: Callable[[int, int], None] | None,
        reference: bool = False,
    ) -> dict[str, np.ndarray]:
        """Evaluate ``quantities`` at every row of ``qs (U, n)`` (``reference``: with pinocchio's
        loops, :meth:`reference_kernels`)."""
        kernels = self._reference_cache if reference else self._kernels_cache
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
        reference: bool = False,
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
        reference : bool
            Every quantity with pinocchio's own functions (:meth:`reference_kernels`; the
            simulator's ground truth), without deduplication; by default gravity and the
            Jacobian come from the compiled kernels of :mod:`ditherlab.robot.tree` (within
            1e-12 relative of pinocchio's) when the robot's joints allow.
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
        computed once (a repeated call costs a digest and a copy, far less than computing).
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
        if not dedup or reference:
            return self._compute(q, quantities, progress, reference=reference)
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
            ``(tol / 2) · max_i Σ_j |∂g_i/∂q_j|``. For the IRB140 that Lipschitz constant is a
            few hundred N·m/rad, so ``tol = 1e-5`` rad costs about 1e-3 N·m; one count of a
            20-bit encoder is 6.0e-6 rad.
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
        all_links: bool = False,
    ) -> np.ndarray:
        """Joint torques per unit of the dynamic parameters of a body on the tool link, moving.
        ``all_links``: pinocchio's whole regressor instead, (N, n, 10 n), per unit of every
        link's parameters in its joint frame (``link_parameters`` order).

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
        T = tool_to_joint_params(self.model, self._tool_frame_id)
        m, d, f = self.model, self._data, pin.computeJointTorqueRegressor
        if all_links:
            cols, T = slice(None), np.eye(10 * (m.njoints - 1))
        out = np.empty((len(xs), n, T.shape[1]))
        with self._lock:
            for i in range(len(xs)):
                out[i] = f(m, d, qp[i], vs[i], acc[i])[:, cols] @ T
        return out if inverse is None or len(xs) == N else out[inverse]

    def link_parameters(self) -> np.ndarray:
        """(10 n,): every link's dynamic parameters (m [kg], m c [kg m], I [kg m²]) in its joint
        frame (pinocchio's order), payload in."""
        return np.concatenate(
            [self.model.inertias[i].toDynamicParameters() for i in range(1, self.model.njoints)]
        )


def _nbytes(entry: Mapping[str, np.ndarray | None]) -> int:
    return sum(v.nbytes for v in entry.values() if v is not None)


def _rebuild(urdf, tool_frame, name, tool_offset, payload, where) -> RobotModel:
    return RobotModel(
        urdf, tool_frame, name=name, tool_offset=tool_offset, payload=payload, where=where
    )

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

Conventions (``docs/recording-format.md``): the tool point is the origin of the tool frame moved by
``tool_offset`` (tool-frame axes, [m]); the payload ``{"mass": kg, "com": [x, y, z]}`` (tool
frame, [m]) is a point mass added to the link that carries the tool frame. Gravity is
pinocchio's, 9.81 m/s² along -z of the URDF's root link (a wall or ceiling mounting goes into
the URDF as a fixed joint above the first link).

A RobotModel holds one pinocchio ``Data`` as scratch space, guarded by a lock: it may be shared
between threads (they take turns); for parallel work give each process its own (it pickles).

Modules: :mod:`~ditherlab.robot.model` (:class:`RobotModel`, :func:`resolve_spec`),
:mod:`~ditherlab.robot.urdf` (built-in robots, URDF parsing; the URDF files are the package data
in ``ditherlab/robots``), :mod:`~ditherlab.robot.dedup` (:func:`unique_configurations`),
:mod:`~ditherlab.robot.batch` (the pinocchio loops), :mod:`~ditherlab.robot.describe`
(:meth:`RobotModel.describe`, :func:`format_description`).
"""

from __future__ import annotations

from ditherlab.robot.dedup import UniqueConfigurations, unique_configurations
from ditherlab.robot.describe import format_description
from ditherlab.robot.model import TOOL_POINT_FRAME as TOOL_POINT_FRAME
from ditherlab.robot.model import RobotModel, resolve_spec
from ditherlab.robot.poses import PAPER_POSE
from ditherlab.robot.urdf import builtin_robots, builtin_urdf

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

"""Robots from every source ``--robot`` takes: example-robot-data's arms by name, xacro files
with ``--robot-arg``, URDF files with ``--tool-frame``; the list; bad inputs as one line; the
vendor mappings' URDFs kept through a round trip; the meshes ``view`` draws."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest
from test_cli_io import assert_user_error
from test_vendor_mappings import RTDE_MINIMAL_RECIPE, write_franka_csv, write_rtde_csv

import ditherlab.io as dio
from ditherlab.core.errors import RobotError
from ditherlab.data.recording import SCHEMA, Recording
from ditherlab.output.rerun import rerun_log as rl
from ditherlab.robot import RobotModel, example_robots, resolve_spec
from ditherlab.robot.example_robots import EXAMPLE_ARMS, example_urdf_path
from ditherlab.robot.visuals import mesh_visuals

pytest.importorskip("xacro")
if not example_robots.installed():
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

#: a two-link planar arm in xacro: an argument, a macro and an include through $(find ...)
LINK_XACRO = """<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:macro name="link" params="name mass length">
    <link name="${name}">
      <inertial><origin xyz="${length/2} 0 0"/><mass value="${mass}"/>
        <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    </link>
  </xacro:macro>
</robot>
"""
ARM_XACRO = """<?xml version="1.0"?>
<robot name="two_link" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:arg name="length" default="0.5"/>
  <xacro:property name="L" value="$(arg length)"/>
  <xacro:include filename="$(find my_description)/urdf/link.xacro"/>
  <link name="base_link"/>
  <xacro:link name="link1" mass="2.0" length="${L}"/>
  <xacro:link name="link2" mass="1.0" length="${L}"/>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="link1"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="link1"/><child link="link2"/>
    <origin xyz="${L} 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="link2"/><child link="tool0"/>
    <origin xyz="${L} 0 0"/></joint>
</robot>
"""


@pytest.fixture
def xacro_arm(tmp_path) -> Path:
    """``my_description/urdf/arm.urdf.xacro`` in a package folder (with its package.xml)."""
    pkg = tmp_path / "my_description"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>my_description</name></package>")
    (pkg / "urdf" / "link.xacro").write_text(LINK_XACRO)
    (pkg / "urdf" / "arm.urdf.xacro").write_text(ARM_XACRO)
    return pkg / "urdf" / "arm.urdf.xacro"


# ---------------------------------------------------------------- gravity and J vs pinocchio
ARMS = ["ur5", "ur10", "kinova", "xarm7", "z1", "erd:panda", "so100", "talos_arm"]


@pytest.mark.parametrize("name", ARMS)
def test_arm_gravity_and_jacobian_equal_pinocchio_on_its_own_file(name):
    """Each arm by name: gravity and the tool Jacobian at random poses equal pinocchio's on
    the same URDF file read by pinocchio itself, at the arm's tool frame."""
    path, tool = example_urdf_path(name)
    robot = RobotModel.from_spec(resolve_spec(name))
    assert robot.tool_frame == tool and robot.name == name.removeprefix("erd:")
    ref = pin.buildModelFromUrdf(str(path))
    data = ref.createData()
    fid = ref.getFrameId(tool, pin.FrameType.BODY)
    rng = np.random.default_rng(3)
    lo, hi = np.maximum(robot.q_lower, -np.pi), np.minimum(robot.q_upper, np.pi)
    q = rng.uniform(lo, hi, (5, robot.n))
    g, J = robot.gravity(q), robot.jacobian(q)
    assert np.abs(g).max() > 0.1  # the arm has weight: a zero model would fail here
    qp = robot.pin_configuration(q)  # a continuous joint is (cos, sin) in pinocchio
    for i in range(len(q)):
        np.testing.assert_allclose(
            g[i], pin.computeGeneralizedGravity(ref, data, qp[i]), rtol=1e-9, atol=1e-9
        )
        Jr = pin.computeFrameJacobian(ref, data, qp[i], fid, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J[i], Jr, rtol=1e-9, atol=1e-9)


def test_tool_frame_where_the_tip_is_not_the_last_link():
    """--tool-frame wrist_2_link: the tool pose is that link's pose and the last joint's column
    of the Jacobian is zero (it does not move that frame)."""
    spec = resolve_spec("ur5", tool_frame="wrist_2_link")
    assert spec["tool_frame"] == "wrist_2_link"
    robot = RobotModel.from_spec(spec)
    q = np.array([0.3, -1.0, 1.2, -0.5, 0.7, 0.9])
    np.testing.assert_allclose(robot.tool_pose(q)[0], robot.link_poses(q)["wrist_2_link"][0])
    J = robot.jacobian(q)[0]
    assert np.allclose(J[:, 5], 0) and not np.allclose(J[:, 4], 0)
    with pytest.raises(RobotError, match="robot 'ur5': tool frame 'nope' is not in"):
        resolve_spec("ur5", tool_frame="nope")


def test_builtin_with_another_tool_frame_embeds_its_urdf():
    """A built-in with a tool frame of its own stays its name; another one embeds its URDF."""
    assert resolve_spec("irb140", tool_frame="tool0") == "irb140"
    spec = resolve_spec("irb140", tool_frame="link_6")
    assert spec["tool_frame"] == "link_6" and spec["name"] == "irb140"


# ---------------------------------------------------------------- xacro
def test_xacro_expands_with_find_and_arguments(xacro_arm):
    """$(find pkg) resolves in the file's own tree; --robot-arg length:= changes the arm: the
    gravity torque at the horizontal pose is g (m1 L/2 + m2 3L/2) at joint 1."""
    for length, args in ((0.5, None), (1.0, ["length:=1.0"])):
        spec = resolve_spec(str(xacro_arm), robot_args=args)
        assert spec["name"] == "two_link" and spec["tool_frame"] == "tool0"
        assert spec["path"] == str(xacro_arm.resolve()) and "xacro:" not in spec["urdf"]
        g = RobotModel.from_spec(spec).gravity(np.zeros(2))[0]
        expected = 9.81 * np.array([2.0 * length / 2 + 1.0 * 1.5 * length, 1.0 * length / 2])
        np.testing.assert_allclose(np.abs(g), expected, rtol=1e-12)


def test_xacro_package_map_and_unresolved_package(tmp_path_factory, xacro_arm):
    """A package outside the file's tree: not found is one line saying --robot-arg
    package://PKG:=DIR; with that argument it expands."""
    moved = tmp_path_factory.mktemp("elsewhere") / "arm.urdf.xacro"
    moved.write_text(ARM_XACRO)
    with pytest.raises(RobotError) as e:
        resolve_spec(str(moved), where="--robot")
    msg = str(e.value)
    assert "\n" not in msg and "does not expand" in msg
    assert "'my_description' not found" in msg and "package://my_description:=DIR" in msg
    arg = f"package://my_description:={xacro_arm.parent.parent}"
    assert resolve_spec(str(moved), robot_args=[arg])["name"] == "two_link"


def test_xacro_errors_are_one_line(xacro_arm, monkeypatch):
    """A bad argument value, a missing argument form, and xacro not installed."""
    with pytest.raises(RobotError, match=r"does not expand: .*length/2"):
        resolve_spec(str(xacro_arm), robot_args=["length:=abc"])
    with pytest.raises(RobotError, match=r"'length': expected NAME:=VALUE"):
        resolve_spec(str(xacro_arm), robot_args=["length"])
    with pytest.raises(RobotError, match=r"'ur5' is not a xacro file"):
        resolve_spec("ur5", robot_args=["a:=1"])
    monkeypatch.setitem(sys.modules, "xacro", None)  # an import of xacro now fails
    with pytest.raises(
        RobotError, match=r"needs the xacro package.*pip install 'ditherlab\[robots\]'"
    ):
        resolve_spec(str(xacro_arm))


# ---------------------------------------------------------------- the CLI
def test_cli_robot_lists_every_arm_with_its_joint_count(cli):
    """`ditherlab robot` (no spec) and `--list --json`: built-ins first, then every
    example-robot-data arm, each with its model's joint count."""
    res = cli("robot")
    assert res.code == 0, res.err
    lines = res.out.splitlines()
    assert lines[1].split()[:2] == ["irb140", "6"] and "ur5" in res.out
    data = json.loads(cli("robot", "--list", "--json").out)
    rows = {r["name"]: r for r in data["robots"]}
    assert len(rows) == 3 + len(EXAMPLE_ARMS) and rows["erd:panda"]["joints"] == 9
    assert rows["panda"]["source"] == "built-in" and rows["xarm7"]["joints"] == 7
    assert_user_error(cli("robot", "--list", "--q", "zero"), r"expected no --q with it")


def test_cli_bad_robots_are_one_line(cli, tmp_path, xacro_arm):
    """Unknown name with the close names; bad xacro; --robot-arg without a xacro robot:
    exit 2, one line, nothing written."""
    src = tmp_path / "bare.csv"
    rec = dio.read(Path(__file__).parent / "data" / "ur10e" / "ur-static.csv", mapping="ur10e")
    rec.data[["t", *[f"{c}_{j}" for c in ("q", "tau") for j in range(1, 7)]]].iloc[:50].to_csv(
        src, index=False
    )
    out = tmp_path / "out.parquet"
    assert_user_error(cli("robot", "ur55"), r"robot 'ur55' is not .*\(close names: ur5\)")
    assert_user_error(cli("convert", src, out, "--robot", "xarm"), r"close names: xarm7")
    assert_user_error(
        cli("convert", src, out, "--robot", xacro_arm, "--robot-arg", "length:=x"),
        r"arm\.urdf\.xacro' does not expand",
    )
    assert_user_error(
        cli("info", src, "--robot", "ur5", "--robot-arg", "a:=1"), r"not a xacro file"
    )
    assert not out.exists()
    assert cli("convert", src, out, "--robot", "ur5", "--tool-frame", "wrist_3_link").code == 0
    back = dio.read(out).meta["robot"]
    assert back["name"] == "ur5" and back["tool_frame"] == "wrist_3_link"


def test_cli_example_robot_data_missing_says_how_to_install(cli, monkeypatch):
    """Without example-robot-data an arm of it is one line naming the install command; the
    list says what it would add."""
    monkeypatch.setattr(example_robots, "share_root", lambda: None)
    assert_user_error(
        cli("robot", "ur5"), r"example-robot-data, which is not installed.*ditherlab\[robots\]"
    )
    res = cli("robot", "--list")
    assert res.code == 0 and "example-robot-data is not installed" in res.out


# ---------------------------------------------------------------- vendor mappings round trip
@pytest.mark.parametrize("mapping", ["ur10e", "ur_rtde", "franka"])
def test_mapping_urdf_kept_through_a_round_trip(cli, tmp_path, mapping):
    """A log converted with a built-in mapping keeps its robot (URDF text, tool frame, name)
    through Parquet, MCAP and CSV, and the robot read back has the same gravity."""
    if mapping == "ur10e":
        src = Path(__file__).parent / "data" / "ur10e" / "ur-static.csv"
    elif mapping == "ur_rtde":
        src = tmp_path / "robot_data.csv"
        write_rtde_csv(src, RTDE_MINIMAL_RECIPE, n_rows=100)
    else:
        src = tmp_path / "panda_state.csv"
        write_franka_csv(src, n_rows=100)
    first = tmp_path / "a.parquet"
    assert cli("convert", src, first, "--mapping", mapping).code == 0
    spec = dio.read(first).meta["robot"]
    urdf = Path(spec["path"]).read_text(encoding="utf-8")
    assert spec["urdf"] == urdf  # the mapping's URDF file, embedded as it is
    prev = first
    for suffix in (".mcap", ".csv", ".parquet"):
        nxt = tmp_path / f"b{suffix}"
        assert cli("convert", prev, nxt).code == 0
        back = dio.read(nxt)
        assert back.meta["robot"] == spec
        q = back.q[:3]
        np.testing.assert_array_equal(
            back.robot().gravity(q), RobotModel.from_spec(spec).gravity(q)
        )
        prev = nxt


# ---------------------------------------------------------------- meshes in view
def _tiny(spec, n: int) -> Recording:
    """20 samples at 250 Hz of a still arm ``spec`` with ``n`` joints."""
    t = np.arange(20) * 0.004
    cols = {"t": t} | {f"q_{j}": np.full(20, 0.1 * j) for j in range(1, n + 1)}
    cols |= {f"tau_{j}": np.zeros(20) for j in range(1, n + 1)}
    return Recording(pd.DataFrame(cols), {"schema": SCHEMA, "robot": spec}, name="tiny")


def test_view_draws_the_meshes_found_and_axes_without(tmp_path, xacro_arm):
    """UR5: every link with a mesh in its description has it in the .rrd (its collision STL,
    since Rerun does not draw its Collada visuals), placed as the URDF says; the xacro arm
    without meshes keeps its link axes and has none."""
    spec = resolve_spec("ur5")
    meshes = mesh_visuals(spec["urdf"], Path(spec["path"]).parent)
    assert {v.link for v in meshes} == {
        "base_link", "shoulder_link", "upper_arm_link", "forearm_link",
        "wrist_1_link", "wrist_2_link", "wrist_3_link",
    }  # fmt: skip
    assert all(v.path.suffix == ".stl" and v.path.is_file() for v in meshes)
    rl.save_view(_tiny(spec, 6), tmp_path / "ur5.rrd")
    c = rl.rrd_contents(tmp_path / "ur5.rrd")
    for v in meshes:
        assert f"robot/links/{v.link}/mesh_0/asset" in c
    plain = resolve_spec(str(xacro_arm))
    rl.save_view(_tiny(plain, 2), tmp_path / "arm.rrd")
    c = rl.rrd_contents(tmp_path / "arm.rrd")
    assert not any("mesh" in k for k in c) and "robot/links/tool0" in c

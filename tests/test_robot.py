"""Tests of ditherlab.robot: the IRB140 model, batched kinematics/dynamics, dedup, errors."""

from __future__ import annotations

import warnings

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ditherlab.core.errors import DitherlabWarning, RobotError
from ditherlab.robot import (
    PAPER_POSE,
    RobotModel,
    builtin_robots,
    builtin_urdf,
    unique_configurations,
)

G = 9.81  # [m/s²], pinocchio's default gravity

# IRB140 link lengths [m] (public kinematics)
D1, A1, A2, D4, D6 = 0.352, 0.070, 0.360, 0.380, 0.065


@pytest.fixture(scope="module")
def irb() -> RobotModel:
    return RobotModel.from_spec("irb140")


def random_q(robot: RobotModel, N: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(robot.q_lower, robot.q_upper, size=(N, robot.n))


# ---------------------------------------------------------------------- the built-in IRB140
def test_builtin_list_and_attributes(irb):
    """The IRB140 is built in with six revolute joints named joint_1..6 and the ABB limits."""
    assert builtin_robots() == ["irb140", "panda", "ur10e"]
    assert irb.n == 6 and irb.joint_names == [f"joint_{i}" for i in range(1, 7)]
    lo = np.radians([-180, -90, -230, -200, -115, -400])
    hi = np.radians([180, 110, 50, 200, 115, 400])
    np.testing.assert_allclose(irb.q_lower, lo, atol=1e-9)
    np.testing.assert_allclose(irb.q_upper, hi, atol=1e-9)
    assert irb.tool_frame == "tool0" and "estimate" in irb.urdf.lower()
    total = sum(irb.model.inertias[j].mass for j in range(1, 7))
    assert 60 < total < 98  # moving links of a ~98 kg arm (base excluded)


def test_paper_pose_tool_point_by_hand(irb):
    """In the paper pose the flange centre is at (a1 + d4, 0, d1 + a2 - d6) with tool z down."""
    T = irb.tool_pose(PAPER_POSE)[0]
    np.testing.assert_allclose(T[:3, 3], [A1 + D4, 0.0, D1 + A2 - D6], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-9)


def test_paper_pose_lever_arms_by_hand(irb):
    """The Jacobian's linear rows give the hand-computed lever arms of SIMULATOR-NOTES."""
    J = irb.jacobian(PAPER_POSE)[0]
    lever = np.abs(J[:3])  # |d tau_j / d F_axis| [m]
    expected = np.zeros((3, 6))
    expected[0, [1, 2, 4]] = [D1 + A2 - D6 - D1, D6, D6]  # Fx: J2 0.295, J3 0.065, J5 0.065
    expected[1, [0, 3]] = [A1 + D4, D6]  # Fy: J1 0.450, J4 0.065
    expected[2, [1, 2]] = [D4, D4]  # Fz: J2 0.380, J3 0.380
    np.testing.assert_allclose(lever, expected, atol=1e-9)
    np.testing.assert_allclose(expected[0, 1], 0.295, atol=1e-12)


# ---------------------------------------------------------------------- the built-in Panda
def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = x, y, z
    return T


def test_builtin_panda_matches_franka_dh_and_holds_its_weight():
    """The Panda (7 joints) follows Franka's published modified-DH table to the flange and the
    hand TCP (0.1034 m, -45° about z); its gravity torques are a few to tens of N·m."""
    panda = RobotModel.from_spec("panda")
    assert panda.n == 7 and panda.tool_frame == "panda_hand_tcp"
    assert panda.joint_names == [f"panda_joint{i}" for i in range(1, 8)]
    assert 15 < panda.describe()["moving_mass"] < 19  # links 1-7 + hand + fingers: 16.8 kg
    # Franka's documented DH (Craig's convention): a, d, alpha per joint, then the flange
    a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]
    d = [0.333, 0, 0.316, 0, 0.384, 0, 0]
    alpha = [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2]
    q = random_q(panda, 20, seed=7)
    flange = panda.link_poses(q, links=["panda_link8"])["panda_link8"]
    tool = panda.tool_pose(q)
    for k in range(len(q)):
        T = np.eye(4)
        for j in range(7):
            T = T @ _rot_x(alpha[j]) @ _trans(a[j], 0, 0) @ _rot_z(q[k, j]) @ _trans(0, 0, d[j])
        T = T @ _trans(0, 0, 0.107)
        np.testing.assert_allclose(flange[k], T, atol=1e-12)
        np.testing.assert_allclose(
            tool[k], T @ _rot_z(-np.pi / 4) @ _trans(0, 0, 0.1034), atol=1e-12
        )
    # the "ready" pose of franka_ros: hand TCP at (0.307, 0, 0.487) m pointing down; the elbow
    # (joint 4) carries ~22 N·m
    ready = np.array([0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4])
    np.testing.assert_allclose(panda.tool_pose(ready)[0][:3, 3], [0.307, 0, 0.487], atol=1e-3)
    g = panda.gravity(ready)[0]
    assert 20 < g[3] < 25 and np.abs(g).max() == g[3]
    g = np.abs(panda.gravity(q))
    assert (g <= panda.effort_limit).all() and (g.max(axis=1) > 1).all()


# ---------------------------------------------------------------------- against finite differences
def _tool_point_fd(robot: RobotModel, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(6, n) central differences of the tool point position and orientation (log map)."""
    J = np.zeros((6, robot.n))
    for k in range(robot.n):
        e = np.zeros(robot.n)
        e[k] = h
        Tp, Tm = robot.tool_pose(q + e)[0], robot.tool_pose(q - e)[0]
        J[:3, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        # angular velocity in base axes: log(R+ R-^T) / 2h
        J[3:, k] = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
    return J


def test_jacobian_matches_finite_differences(irb):
    """Every Jacobian column equals finite differences of the tool point's position/orientation."""
    robot = RobotModel.from_spec("irb140", tool_offset=[0.02, -0.03, 0.15])
    for q in random_q(robot, 5, seed=1):
        np.testing.assert_allclose(robot.jacobian(q)[0], _tool_point_fd(robot, q), atol=1e-8)


def test_gravity_matches_potential_energy_gradient():
    """g(q) equals the gradient of pinocchio's potential energy by central differences."""
    robot = RobotModel.from_spec("irb140", payload={"mass": 3.0, "com": [0.01, 0.02, 0.1]})
    m, d = robot.model, robot.model.createData()
    h = 1e-6
    for q in random_q(robot, 5, seed=2):
        fd = np.empty(robot.n)
        for k in range(robot.n):
            e = np.zeros(robot.n)
            e[k] = h
            fd[k] = (
                pin.computePotentialEnergy(m, d, q + e) - pin.computePotentialEnergy(m, d, q - e)
            ) / (2 * h)
        np.testing.assert_allclose(robot.gravity(q)[0], fd, atol=1e-6)


def test_mass_matrix_symmetric_and_matches_rnea():
    """M(q) is symmetric and M(q) e_k equals rnea(q, 0, e_k) - g(q)."""
    robot = RobotModel.from_spec("irb140")
    m, d = robot.model, robot.model.createData()
    qs = random_q(robot, 3, seed=3)
    M = robot.mass_matrix(qs)
    np.testing.assert_array_equal(M, np.swapaxes(M, 1, 2))
    for q, Mi in zip(qs, M, strict=True):
        g = pin.rnea(m, d, q, np.zeros(6), np.zeros(6))
        for k in range(6):
            a = np.zeros(6)
            a[k] = 1.0
            np.testing.assert_allclose(Mi[:, k], pin.rnea(m, d, q, np.zeros(6), a) - g, atol=1e-10)


# ---------------------------------------------------------------------- payload
def test_payload_changes_gravity_by_m_g_lever(irb):
    """A payload 0.1 m below the flange in the paper pose adds m·g·0.380 on J2 and J3 only."""
    mass = 2.5
    loaded = RobotModel.from_spec("irb140", payload={"mass": mass, "com": [0, 0, 0.1]})
    dg = loaded.gravity(PAPER_POSE)[0] - irb.gravity(PAPER_POSE)[0]
    expected = np.array([0.0, -mass * G * D4, -mass * G * D4, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(dg, expected, atol=1e-9)


def test_gravity_regressor_reproduces_payload():
    """gravity_regressor(q) @ (m, m c, 0) equals the gravity change of that payload."""
    mass, com = 1.7, np.array([0.03, -0.02, 0.12])
    plain = RobotModel.from_spec("irb140", tool_offset=[0, 0, 0.1])
    loaded = RobotModel.from_spec(
        "irb140", tool_offset=[0, 0, 0.1], payload={"mass": mass, "com": com}
    )
    qs = random_q(plain, 20, seed=4)
    theta = np.concatenate([[mass], mass * com, np.zeros(6)])
    Y = plain.gravity_regressor(qs)
    assert Y.shape == (20, 6, 10)
    np.testing.assert_allclose(Y @ theta, loaded.gravity(qs) - plain.gravity(qs), atol=1e-10)


# ---------------------------------------------------------------------- dedup
#: max over q of max_i sum_j |dg_i/dq_j| for the IRB140 without payload (20 000 random q: 266.5)
IRB140_GRAVITY_LIPSCHITZ = 270.0  # [N·m/rad]
COUNT = 2 * np.pi / 2**20  # [rad] one count of a 20-bit encoder


def _still_log(robot: RobotModel, N: int, seed: int) -> np.ndarray:
    """A mostly-still log: four poses held, each joint flickering by one count 5 % of the time."""
    rng = np.random.default_rng(seed)
    poses = random_q(robot, 4, seed)
    idx = np.repeat(np.arange(4), N // 4)
    flicker = (rng.random((len(idx), robot.n)) < 0.05) * rng.choice([-1, 1], (len(idx), robot.n))
    return poses[idx] + COUNT * flicker


def test_dedup_exact_equals_loop(irb):
    """With exact repeats, the deduplicated results are bit-identical to the per-sample loop."""
    q = _still_log(irb, 400, seed=5)
    u = unique_configurations(q)
    assert len(u.q) < 400 / 2
    np.testing.assert_array_equal(u.q[u.inverse], q)
    for method in ("gravity", "jacobian", "tool_pose", "mass_matrix", "gravity_regressor"):
        fast = getattr(irb, method)(q)
        slow = getattr(irb, method)(q, dedup=False)
        np.testing.assert_array_equal(fast, slow, err_msg=method)
    poses = irb.link_poses(q)
    slow_poses = irb.link_poses(q, dedup=False)
    for name in irb.link_names:
        np.testing.assert_array_equal(poses[name], slow_poses[name])


def test_dedup_with_tolerance_within_bound(irb):
    """With tol, each sample is evaluated within tol/2 per joint, gravity within the Lipschitz bound."""
    tol = 4 * COUNT
    q = _still_log(irb, 400, seed=6)
    u = unique_configurations(q, tol)
    assert np.max(np.abs(u.q[u.inverse] - q)) <= tol / 2 * (1 + 1e-9)
    assert len(u.q) < len(unique_configurations(q).q)
    m, d = irb.model, irb.model.createData()
    # bound: (tol / 2) * sum_j |dg/dq_j| at each sample (first order; second order is ~1e-10)
    dgdq = np.stack([pin.computeGeneralizedGravityDerivatives(m, d, qi) for qi in q])
    bound = tol / 2 * np.abs(dgdq).sum(axis=2) + 1e-9
    err = np.abs(irb.gravity(q, tol=tol) - irb.gravity(q, dedup=False))
    assert np.all(err <= bound)
    assert err.max() <= tol / 2 * IRB140_GRAVITY_LIPSCHITZ  # the documented worst case


# ---------------------------------------------------------------------- errors
def test_unknown_robot_name_lists_builtins():
    """An unknown name names the recording and lists the built-in robots."""
    with pytest.raises(RobotError) as e:
        RobotModel.from_spec("irb120", where="log.parquet")
    assert str(e.value).startswith("log.parquet: robot 'irb120' is not a built-in robot")
    assert "irb140" in str(e.value)


def test_bad_urdf_errors():
    """A URDF that is not XML, and one urdfdom rejects, give one sentence with the reason."""
    with pytest.raises(RobotError, match=r"^x.mcap: robot URDF does not parse as XML"):
        RobotModel.from_spec({"urdf": "<robot name='r'", "tool_frame": "a"}, where="x.mcap")
    bad = (
        '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="b"/></joint></robot>'
    )
    with pytest.raises(RobotError) as e:
        RobotModel.from_spec({"urdf": bad, "tool_frame": "b"}, where="x.mcap")
    assert str(e.value) == (
        "x.mcap: robot URDF does not parse: Joint [j] is of type REVOLUTE but it does not "
        "specify limits"
    )


def test_missing_tool_frame():
    """A tool frame that is not in the URDF is named together with the links that exist."""
    with pytest.raises(RobotError) as e:
        RobotModel.from_spec({"urdf": builtin_urdf("irb140"), "tool_frame": "flange"}, where="r")
    assert str(e.value).startswith("r: tool frame 'flange' is not in the robot's URDF")
    assert "tool0" in str(e.value)


def test_wrong_joint_count():
    """A recording with another joint count than the robot is rejected naming both counts."""
    with pytest.raises(RobotError) as e:
        RobotModel.from_recording_meta({"robot": "irb140"}, n_expected=5, where="d.csv")
    assert str(e.value) == (
        "d.csv: robot 'irb140' has 6 joints but the recording has 5 (expected columns q_1..q_6)"
    )
    with pytest.raises(RobotError, match=r"q has shape \(3, 5\), expected \(N, 6\)"):
        RobotModel.from_spec("irb140").gravity(np.zeros((3, 5)))


def test_check_units_warns_for_degrees(irb):
    """Angles in degrees trigger a DitherlabWarning; the same angles in radians do not."""
    q = np.tile(PAPER_POSE, (10, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert irb.check_units(q, "ok.csv") is False
    with pytest.warns(DitherlabWarning, match=r"deg.csv: q_5 reaches 90.*as if in degrees"):
        assert irb.check_units(np.degrees(q), "deg.csv") is True


# ---------------------------------------------------------------------- embedded URDF
PLANAR = """<?xml version="1.0"?>
<robot name="planar2">
  <link name="base"/>
  <link name="l1">
    <inertial><origin xyz="0.25 0 0"/><mass value="3.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial>
  </link>
  <link name="l2">
    <inertial><origin xyz="0.2 0 0"/><mass value="2.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0"/><axis xyz="0 -1 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.5 0 0"/><axis xyz="0 -1 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="tipj" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0.4 0 0"/></joint>
</robot>
"""


def test_embedded_planar_urdf_gravity_analytic():
    """A 2-link planar arm in the x-z plane has g = (m1 c1 + m2 l1) g cos q1 + m2 c2 g cos q12."""
    meta = {"robot": {"urdf": PLANAR, "tool_frame": "tip"}}
    robot = RobotModel.from_recording_meta(meta, n_expected=2, where="planar.parquet")
    assert robot.name == "planar2" and robot.n == 2
    q = np.random.default_rng(7).uniform(-3, 3, size=(50, 2))
    c1, c12 = np.cos(q[:, 0]), np.cos(q[:, 0] + q[:, 1])
    g2 = 2.0 * 0.2 * G * c12
    g1 = (3.0 * 0.25 + 2.0 * 0.5) * G * c1 + g2
    np.testing.assert_allclose(robot.gravity(q), np.stack([g1, g2], axis=1), atol=1e-10)
    # tool point: tip at (l1 c1 + l2 c12, 0, l1 s1 + l2 s12)
    s1, s12 = np.sin(q[:, 0]), np.sin(q[:, 0] + q[:, 1])
    p = robot.tool_pose(q)[:, :3, 3]
    np.testing.assert_allclose(p[:, 0], 0.5 * c1 + 0.4 * c12, atol=1e-12)
    np.testing.assert_allclose(p[:, 2], 0.5 * s1 + 0.4 * s12, atol=1e-12)


# ---------------------------------------------------------------------- more hand-checked poses
def _urdf_inertials(urdf: str) -> dict[str, tuple[float, np.ndarray]]:
    """link -> (mass [kg], centre of mass in the link frame [m]) read from the URDF text."""
    import xml.etree.ElementTree as ET

    out = {}
    for link in ET.fromstring(urdf).iter("link"):
        inertial = link.find("inertial")
        if inertial is not None:
            xyz = np.array(inertial.find("origin").get("xyz").split(), dtype=float)
            out[link.get("name")] = (float(inertial.find("mass").get("value")), xyz)
    return out


def test_paper_pose_gravity_by_hand(irb):
    """Gravity on J2 and J3 in the paper pose is -g · sum of m_k times the k-th COM's x lever."""
    inert = _urdf_inertials(irb.urdf)
    # link frames in the paper pose (by hand from the link lengths; q5 = 90° turns link_5/6 x down)
    elbow = np.array([A1, 0, D1 + A2])
    wrist = np.array([A1 + D4, 0, D1 + A2])
    down = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # R_y(90°): x -> -z, z -> x
    com = {
        "link_2": np.array([A1, 0, D1]) + inert["link_2"][1],
        "link_3": elbow + inert["link_3"][1],
        "link_4": elbow + np.array([0.18, 0, 0]) + inert["link_4"][1],
        "link_5": wrist + down @ inert["link_5"][1],
        "link_6": wrist + np.array([0, 0, -D6]) + down @ inert["link_6"][1],
    }
    moment2 = sum(inert[k][0] * (com[k][0] - A1) for k in com)  # [kg m] about the J2 axis
    moment3 = sum(inert[k][0] * (com[k][0] - A1) for k in com if k != "link_2")
    moment5 = sum(inert[k][0] * (com[k][0] - wrist[0]) for k in ("link_5", "link_6"))
    g = irb.gravity(PAPER_POSE)[0]
    np.testing.assert_allclose(g, [0, -G * moment2, -G * moment3, 0, -G * moment5, 0], atol=1e-10)
    assert abs(g[1]) > 10  # the forearm's weight is felt


def test_zero_pose_and_tool_offset_by_hand():
    """At q = 0 the flange is at (a1 + d4 + d6, 0, d1 + a2) facing +x; tool_offset moves along it."""
    robot = RobotModel.from_spec("irb140", tool_offset=[0, 0, 0.1])
    T0 = robot.tool_pose(np.zeros(6))[0]
    np.testing.assert_allclose(T0[:3, 3], [A1 + D4 + D6 + 0.1, 0, D1 + A2], atol=1e-12)
    np.testing.assert_allclose(T0[:3, 2], [1, 0, 0], atol=1e-9)
    # paper pose: the tool point is 0.1 m below the flange, so Fx acts on J2 with 0.295 - 0.1
    J = robot.jacobian(PAPER_POSE)[0]
    np.testing.assert_allclose(J[0, 1], D1 + A2 - D6 - 0.1 - D1, atol=1e-12)
    np.testing.assert_allclose(robot.tool_pose(PAPER_POSE)[0][:3, 3], [0.45, 0, 0.547], atol=1e-12)


# ---------------------------------------------------------------------- batching and caching
def test_single_configuration_and_empty_batch(irb):
    """A (n,) configuration gives a batch of one; an empty (0, n) batch gives empty results."""
    assert irb.gravity(PAPER_POSE).shape == (1, 6)
    assert irb.jacobian(np.zeros((0, 6))).shape == (0, 6, 6)
    assert irb.link_poses(np.zeros((0, 6)))["tool0"].shape == (0, 4, 4)


def test_gravity_jacobian_and_cache_return_new_arrays(irb):
    """gravity_jacobian equals the separate calls; mutating a result never alters a later one."""
    q = _still_log(irb, 200, seed=8)
    irb.clear_cache()
    g, J = irb.gravity_jacobian(q)
    g_ref, J_ref = irb.gravity(q, dedup=False), irb.jacobian(q, dedup=False)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(J, J_ref)
    g[:] = 0.0
    J[:] = 0.0
    g2, J2 = irb.gravity_jacobian(q)  # served from the cache
    np.testing.assert_array_equal(g2, g_ref)
    np.testing.assert_array_equal(J2, J_ref)
    # a different batch with the same shape is not confused with the cached one
    q3 = q.copy()
    q3[0, 0] += 0.1
    np.testing.assert_array_equal(irb.gravity(q3), irb.gravity(q3, dedup=False))


def test_cache_respects_byte_budget():
    """The cache never holds more than cache_bytes."""
    robot = RobotModel.from_spec("irb140")
    robot.cache_bytes = 200_000
    for seed in range(6):
        robot.gravity_jacobian(_still_log(robot, 400, seed=seed))
        held = sum(
            sum(v.nbytes for v in e.values() if v is not None) for e in robot._cache.values()
        )
        assert held <= robot.cache_bytes


def test_progress_reports_done_and_total(irb):
    """progress(done, total) is called with increasing counts ending at (U, U)."""
    calls = []
    q = random_q(irb, 1000, seed=9)
    irb.gravity(q, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (1000, 1000)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:], strict=False))


def test_hash_collision_falls_back_to_exact_grouping(monkeypatch):
    """If every row hashed alike, the grouping would still be exact (verified, then sorted)."""
    import ditherlab.robot.dedup as dedup_mod

    monkeypatch.setattr(dedup_mod, "_row_hash", lambda bits: np.zeros(len(bits), np.uint64))
    q = np.array([[0.0, 1.0], [0.0, 2.0], [0.0, 1.0], [-0.0, 2.0], [3.0, 3.0]])
    u = dedup_mod.unique_configurations(q)
    assert len(u.q) == 3
    np.testing.assert_array_equal(u.q[u.inverse], q)


def test_unique_configurations_negative_zero_and_order():
    """-0.0 and 0.0 are one configuration; groups come in order of first appearance."""
    q = np.array([[0.5, -0.0], [0.5, 0.0], [0.1, 0.2], [0.5, 0.0], [0.1, 0.2]])
    u = unique_configurations(q)
    np.testing.assert_array_equal(u.inverse, [0, 0, 1, 0, 1])
    assert u.ratio == 2.5


def test_pickle_round_trip(irb):
    """A RobotModel pickles (for process pools) and gives identical results after unpickling."""
    import pickle

    robot = RobotModel.from_spec(
        "irb140", tool_offset=[0, 0, 0.1], payload={"mass": 1.0, "com": [0, 0, 0.05]}
    )
    back = pickle.loads(pickle.dumps(robot))
    q = random_q(robot, 10, seed=10)
    np.testing.assert_array_equal(back.gravity(q), robot.gravity(q))
    np.testing.assert_array_equal(back.jacobian(q), robot.jacobian(q))


# ---------------------------------------------------------------------- inverse dynamics
def test_inverse_dynamics_is_mass_matrix_plus_gravity_at_rest():
    """At dq = 0, inverse_dynamics(q, 0, ddq) = M(q) ddq + g(q); dedup equals the plain loop."""
    robot = RobotModel.from_spec("irb140", payload={"mass": 2.0, "com": [0, 0, 0.1]})
    rng = np.random.default_rng(11)
    q = np.repeat(random_q(robot, 5, seed=11), 20, axis=0)
    ddq = np.repeat(rng.normal(size=(5, 6)), 20, axis=0)
    tau = robot.inverse_dynamics(q, np.zeros_like(q), ddq)
    expected = np.einsum("nij,nj->ni", robot.mass_matrix(q), ddq) + robot.gravity(q)
    np.testing.assert_allclose(tau, expected, atol=1e-10)
    dq = rng.normal(size=q.shape)
    np.testing.assert_array_equal(
        robot.inverse_dynamics(q, dq, ddq), robot.inverse_dynamics(q, dq, ddq, dedup=False)
    )


# ---------------------------------------------------------------------- UR10e against real logs
def _ur10e_log(shared_data, name: str) -> np.ndarray:
    """(N, 31): t, q1..6, qd1..6, i_act1..6, i_des1..6, tau_des1..6 (tests/data/README.md)."""
    return np.loadtxt(shared_data / "ur10e" / name, delimiter=",")


def test_ur10e_gravity_matches_controller_on_static_log(shared_data):
    """On the real UR10e static log, our gravity equals the controller's desired torque (< 0.2 N·m)."""
    log = _ur10e_log(shared_data, "ur-static.csv")
    robot = RobotModel.from_recording_meta({"robot": "ur10e"}, n_expected=6, where="ur-static")
    g = robot.gravity(log[:, 1:7])
    tau_des = log[:, 25:31]
    err = np.median(np.abs(g - tau_des), axis=0)  # [N·m]
    assert np.all(err < 0.2), err
    assert np.median(np.abs(tau_des[:, 1])) > 20  # the shoulder really carries the arm


def test_ur10e_dynamics_explain_moving_log_better_than_gravity(shared_data):
    """On the real UR10e free-motion log, RNEA cuts the shoulder residual to a third of gravity's."""
    log = _ur10e_log(shared_data, "no_torque.csv")
    robot = RobotModel.from_spec("ur10e")
    t, q, dq, tau_des = log[:, 0], log[:, 1:7], log[:, 7:13], log[:, 25:31]
    ddq = np.gradient(dq, t, axis=0)
    res_g = np.median(np.abs(tau_des - robot.gravity(q)), axis=0)
    res_id = np.median(np.abs(tau_des - robot.inverse_dynamics(q, dq, ddq)), axis=0)
    assert res_id[1] < res_g[1] / 3, (res_g, res_id)


# ---------------------------------------------------------------------- URDF files
def test_urdf_path_is_embedded_with_guessed_tool_frame(tmp_path):
    """A .urdf path becomes {'urdf': text, 'tool_frame': ...}; without tool0 the last link is used."""
    from ditherlab.robot import resolve_spec

    path = tmp_path / "planar.urdf"
    path.write_text(PLANAR)
    spec = resolve_spec(str(path))
    assert spec == {"urdf": PLANAR, "tool_frame": "tip", "name": "planar2", "path": str(path)}
    robot = RobotModel.from_spec(str(path))
    assert robot.tool_frame == "tip" and robot.n == 2
    assert resolve_spec("irb140") == "irb140"
    with pytest.raises(RobotError) as e:
        resolve_spec(str(tmp_path / "missing.urdf"), where="--robot")
    assert str(e.value) == f"--robot: robot URDF file '{tmp_path / 'missing.urdf'}' does not exist"


def test_ur10e_tool_position_matches_published_dh():
    """The UR10e tool0 position equals Universal Robots' published DH chain at random q."""
    d = [0.1807, 0, 0, 0.17415, 0.11985, 0.11655]
    a = [0, -0.6127, -0.57155, 0, 0, 0]
    alpha = [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0]

    def dh(qs: np.ndarray) -> np.ndarray:
        T = np.diag([-1.0, -1.0, 1.0, 1.0])  # base_link -> UR 'base' (pi about z)
        for th, di, ai, al in zip(qs, d, a, alpha, strict=True):
            ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
            T = T @ np.array(
                [
                    [ct, -st * ca, st * sa, ai * ct],
                    [st, ct * ca, -ct * sa, ai * st],
                    [0, sa, ca, di],
                    [0, 0, 0, 1],
                ]
            )
        return T[:3, 3]

    robot = RobotModel.from_spec("ur10e")
    qs = np.random.default_rng(12).uniform(-np.pi, np.pi, size=(20, 6))
    p = robot.tool_pose(qs)[:, :3, 3]
    np.testing.assert_allclose(p, np.stack([dh(qi) for qi in qs]), atol=1e-9)


def test_continuous_joint_takes_an_angle():
    """A continuous joint's q is an angle: same gravity and tool point as the revolute version."""
    cont = PLANAR.replace('name="j2" type="revolute"', 'name="j2" type="continuous"')
    robot = RobotModel.from_spec({"urdf": cont, "tool_frame": "tip"})
    ref = RobotModel.from_spec({"urdf": PLANAR, "tool_frame": "tip"})
    assert robot.model.nq == 3 and robot.n == 2
    assert robot.q_upper[1] == np.inf and robot.q_upper[0] == 3.0
    q = np.random.default_rng(13).uniform(-3, 3, size=(30, 2))
    np.testing.assert_allclose(robot.gravity(q), ref.gravity(q), atol=1e-12)
    np.testing.assert_allclose(robot.jacobian(q), ref.jacobian(q), atol=1e-12)
    np.testing.assert_allclose(robot.tool_pose(q), ref.tool_pose(q), atol=1e-12)


def test_multi_dof_joint_is_rejected():
    """A floating joint in the URDF is named in the error with what was expected."""
    floating = PLANAR.replace('name="j1" type="revolute"', 'name="j1" type="floating"')
    with pytest.raises(RobotError) as e:
        RobotModel.from_spec({"urdf": floating, "tool_frame": "tip"}, where="f.urdf")
    assert str(e.value) == (
        "f.urdf: robot URDF has joints j1 (JointModelFreeFlyer) with several degrees of "
        "freedom; expected revolute, continuous or prismatic joints"
    )


def test_prismatic_joint_carries_the_whole_weight():
    """A vertical prismatic first joint holds (m1 + m2) g, whatever the second joint's angle."""
    lift = PLANAR.replace(
        '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>\n'
        '    <origin xyz="0 0 0"/><axis xyz="0 -1 0"/>',
        '<joint name="j1" type="prismatic"><parent link="base"/><child link="l1"/>\n'
        '    <origin xyz="0 0 0"/><axis xyz="0 0 1"/>',
    )
    assert 'type="prismatic"' in lift
    robot = RobotModel.from_spec({"urdf": lift, "tool_frame": "tip"})
    q = np.random.default_rng(14).uniform(-1, 1, size=(10, 2))
    g = robot.gravity(q)
    np.testing.assert_allclose(g[:, 0], (3.0 + 2.0) * G, atol=1e-10)
    np.testing.assert_allclose(g[:, 1], 2.0 * 0.2 * G * np.cos(q[:, 1]), atol=1e-10)


# ---------------------------------------------------------------------- properties and integration
@settings(max_examples=60, deadline=None)
@given(
    pool=st.lists(
        st.lists(st.floats(-4, 4, allow_nan=False, width=64), min_size=3, max_size=3),
        min_size=1,
        max_size=5,
    ),
    picks=st.lists(st.integers(0, 4), min_size=0, max_size=60),
    tol=st.sampled_from([0.0, 1e-3, 0.5]),
)
def test_unique_configurations_property(pool, picks, tol):
    """Any batch: groups are distinct cells in first-appearance order and cover every sample."""
    pool = np.array(pool)
    q = pool[[p % len(pool) for p in picks]] if picks else np.zeros((0, 3))
    u = unique_configurations(q, tol)
    assert u.inverse.shape == (len(q),)
    if len(q) == 0:
        return
    if tol == 0:
        np.testing.assert_array_equal(u.q[u.inverse], q)
        assert len({row.tobytes() for row in (u.q + 0.0)}) == len(u.q)
    else:
        assert np.all(np.abs(u.q[u.inverse] - q) <= tol / 2 * (1 + 1e-12))
    first = [int(np.flatnonzero(u.inverse == k)[0]) for k in range(len(u.q))]
    assert first == sorted(first)


def test_recording_robot_carries_tool_offset_and_payload():
    """Recording.robot() builds the embedded URDF with the metadata's tool offset and payload."""
    from ditherlab.data.recording import Recording, RecordingArrays

    N = 5
    q = np.tile([0.3, -0.4], (N, 1))
    meta = {
        "robot": {"urdf": PLANAR, "tool_frame": "tip"},
        "tool_offset": [0.1, 0.0, 0.0],
        "payload": {"mass": 1.5, "com": [0.1, 0.0, 0.0]},
    }
    rec = Recording.from_arrays(
        RecordingArrays(np.arange(N) / 250.0, q, np.zeros((N, 2))), meta, name="p.parquet"
    )
    robot = rec.robot()
    assert robot.name == "planar2" and robot.payload == {"mass": 1.5, "com": [0.1, 0.0, 0.0]}
    np.testing.assert_array_equal(robot.tool_offset, [0.1, 0, 0])
    # the payload sits at the tool point, 0.5 m along the second link: extra m g 0.5 cos(q12)
    c12 = np.cos(q[:, 0] + q[:, 1])
    plain = RobotModel.from_spec({"urdf": PLANAR, "tool_frame": "tip"})
    dg = robot.gravity(q) - plain.gravity(q)
    np.testing.assert_allclose(dg[:, 1], 1.5 * G * 0.5 * c12, atol=1e-10)
    p = robot.tool_pose(q)[:, :3, 3]
    np.testing.assert_allclose(p[:, 0], 0.5 * np.cos(q[:, 0]) + 0.5 * c12, atol=1e-12)


def test_batch_larger_than_cache_is_returned_uncached():
    """A moving batch larger than the cache budget is computed, returned and not cached."""
    robot = RobotModel.from_spec("irb140")
    robot.cache_bytes = 10_000
    q = random_q(robot, 300, seed=15)
    g, J = robot.gravity_jacobian(q)
    assert len(robot._cache) == 0
    np.testing.assert_array_equal(J, robot.jacobian(q, dedup=False))
    np.testing.assert_array_equal(g, robot.gravity(q, dedup=False))


# ---------------------------------------------------------------------- the `ditherlab robot` command
def test_cli_robot_paper_pose_table(cli):
    """`ditherlab robot irb140 --q paper` prints the paper pose's tool point and lever arms."""
    r = cli("robot", "irb140", "--q", "paper")
    assert r.code == 0, r.err
    assert "tool point (0.450, 0.000, 0.647) m" in r.out
    row = next(
        line for line in r.out.splitlines() if line.startswith("joint_2") and "0.295" in line
    )
    assert row.split()[2:] == ["0.295", "0.000", "0.380"]


def test_cli_robot_json_and_urdf_file(cli, tmp_path):
    """--json gives the summary of a URDF file, with its guessed tool frame and lever arms."""
    import json

    path = tmp_path / "planar.urdf"
    path.write_text(PLANAR)
    r = cli("robot", str(path), "--q", "0,0", "--json")
    assert r.code == 0, r.err
    d = json.loads(r.out)
    assert d["name"] == "planar2" and d["tool_frame"] == "tip"
    np.testing.assert_allclose(d["pose"]["tool_position"], [0.9, 0, 0], atol=1e-12)
    np.testing.assert_allclose(d["pose"]["lever_arms"][2], [0.9, 0.4], atol=1e-12)


def test_cli_robot_errors(cli):
    """An unknown robot and a pose of the wrong length give one line on stderr and exit 2."""
    r = cli("robot", "irb14")
    assert r.code == 2 and r.out == ""
    assert r.err.startswith(
        "error: robot 'irb14' is not a built-in robot or an example-robot-data arm "
        "(close names: irb140); expected one of: "
    )
    r = cli("robot", "ur10e", "--q", "1,2")
    assert r.code == 2
    assert (
        r.err
        == "error: --q is '1,2', expected 6 comma-separated angles in rad (or 'zero', 'paper')\n"
    )
    r = cli("robot", "ur10e", "--q", "paper")
    assert r.code == 2 and "defined for robot 'irb140' only" in r.err


def test_threads_sharing_a_model_get_correct_results():
    """Four threads using one RobotModel at once each get their own batch's exact results."""
    from concurrent.futures import ThreadPoolExecutor

    robot = RobotModel.from_spec("irb140")
    batches = [_still_log(robot, 200, seed=20 + k) for k in range(4)]
    expected = [robot.jacobian(b, dedup=False) for b in batches]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda b: robot.jacobian(b), batches))
    for e, g in zip(expected, got, strict=True):
        np.testing.assert_array_equal(g, e)


def test_torque_regressor_is_the_payload_inverse_dynamics():
    """``torque_regressor(q, dq, ddq) @ theta`` equals the RNEA torque difference of the robot
    with and without a point mass (theta with the point mass's inertia about the tool origin),
    to 1e-10 N·m, and equals the gravity regressor at rest."""
    r = RobotModel.from_spec("irb140")
    rng = np.random.default_rng(0)
    q, dq, ddq = rng.uniform(-1, 1, (40, 6)), rng.normal(size=(40, 6)), rng.normal(size=(40, 6))
    m, c = 2.5, np.array([0.01, -0.02, 0.06])
    plant = r.with_payload({"mass": m, "com": list(c)})
    inertia = m * (c @ c * np.eye(3) - np.outer(c, c))
    theta = np.r_[m, m * c, inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2],
                  inertia[1, 2], inertia[2, 2]]  # fmt: skip
    Y = r.torque_regressor(q, dq, ddq)
    want = plant.inverse_dynamics(q, dq, ddq) - r.inverse_dynamics(q, dq, ddq)
    np.testing.assert_allclose(Y @ theta, want, atol=1e-10)
    np.testing.assert_allclose(r.torque_regressor(q, 0 * dq, 0 * ddq), r.gravity_regressor(q))


# ---------------------------------------------------------------------- compiled gravity, Jacobian
#: a tree (two branches off link a), a prismatic joint on a tilted axis, unaligned revolute axes,
#: a rotated joint origin, and the tool on the branch that does not hold the heavier links
TREE = """<?xml version="1.0"?>
<robot name="tree">
  <link name="base"/>
  <link name="a"><inertial><origin xyz="0.1 0.0 0.2"/><mass value="4.0"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="b"><inertial><origin xyz="0.0 0.3 0.0"/><mass value="2.5"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="c"><inertial><origin xyz="0.2 0.1 -0.1"/><mass value="1.5"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="d"><inertial><origin xyz="0.05 0.0 0.1"/><mass value="3.0"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0 0 0.3" rpy="0.1 -0.2 0.3"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/>
    <origin xyz="0.2 0 0.1"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-1" upper="1" effort="100" velocity="2"/></joint>
  <joint name="j3" type="revolute"><parent link="b"/><child link="c"/>
    <origin xyz="0 0.4 0" rpy="0.5 0 -0.4"/><axis xyz="0.3 0.5 0.81"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="j4" type="revolute"><parent link="a"/><child link="d"/>
    <origin xyz="-0.2 0.1 0.0"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="tipj" type="fixed"><parent link="c"/><child link="tip"/>
    <origin xyz="0.3 0.0 0.05" rpy="0 0.3 0"/></joint>
</robot>
"""


@pytest.mark.parametrize(
    "spec, payload",
    [
        ("irb140", None),
        ("irb140", {"mass": 2.5, "com": [0.01, 0.02, 0.1]}),
        ("ur10e", None),
        ("panda", None),
        ({"urdf": TREE, "tool_frame": "tip"}, {"mass": 0.7, "com": [0.0, 0.1, 0.0]}),
    ],
    ids=["irb140", "irb140-payload", "ur10e", "panda", "tree"],
)
def test_compiled_gravity_and_jacobian_equal_pinocchio(spec, payload):
    """The compiled gravity torque and tool-point Jacobian (ditherlab.robot.tree) against
    pinocchio's computeGeneralizedGravity and computeFrameJacobian on the same model, payload
    and tool point: 1e-12 relative, at poses over the whole circle and beyond."""
    from ditherlab.robot.tree import tree_of

    robot = RobotModel.from_spec(spec, payload=payload, tool_offset=[0.01, -0.02, 0.15])
    assert tree_of(robot.model, robot._tool_point_id) is not None  # the compiled path is taken
    q = np.random.default_rng(31).uniform(-7, 7, size=(500, robot.n))
    ref = robot.reference_kernels()
    g, J = np.empty((500, robot.n)), np.empty((500, 6, robot.n))
    ref["gravity"][0](q, g)
    ref["jacobian"][0](q, J)
    out = robot.evaluate(q, ["gravity", "jacobian"], dedup=False)
    scale = np.abs(g).max()
    assert scale > 1.0
    assert np.abs(out["gravity"] - g).max() <= 1e-12 * scale
    assert np.abs(out["jacobian"] - J).max() <= 1e-12 * max(np.abs(J).max(), 1.0)
    # a joint that does not carry the tool has a zero column (j4 of the tree)
    if isinstance(spec, dict):
        assert np.all(J[:, :, 3] == 0) and np.all(out["jacobian"][:, :, 3] == 0)


def test_continuous_joint_keeps_pinocchio():
    """A continuous joint (two coordinates in pinocchio) is not compiled: pinocchio's loops
    serve, with the same numbers as the revolute version compiled."""
    from ditherlab.robot.tree import tree_of

    cont = RobotModel.from_spec(
        {
            "urdf": PLANAR.replace('"j2" type="revolute"', '"j2" type="continuous"'),
            "tool_frame": "tip",
        }
    )
    rev = RobotModel.from_spec({"urdf": PLANAR, "tool_frame": "tip"})
    assert tree_of(cont.model, cont._tool_point_id) is None
    assert tree_of(rev.model, rev._tool_point_id) is not None
    q = np.random.default_rng(32).uniform(-3, 3, size=(40, 2))
    np.testing.assert_allclose(cont.gravity(q), rev.gravity(q), atol=1e-12)
    np.testing.assert_allclose(cont.jacobian(q), rev.jacobian(q), atol=1e-12)

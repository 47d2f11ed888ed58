"""The simulated arms: kinematics against the makers' published tables, verified IK, motion, tools."""

from __future__ import annotations

import time

import numpy as np
import pybullet as p
import pybullet_data
import pytest

from robots.geometry import make_pose, rotation_error_deg, translation_error
from robots.interfaces import SafetyError, UnreachableError
from robots.safety import Safety
from sim_backends.arms import ARM_NAMES, SimArm
from sim_backends.tools import SimGripper, SimPointer, SimRobot, SimSuctionCup

PI = np.pi

# ---------------------------------------------------------------- independent kinematics
# Written from the published tables, not from the URDFs, so a wrong URDF shows up here.


def dh_standard(a, alpha, d, theta):
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0, sa, ca, d], [0, 0, 0, 1.0]])


def dh_modified(a, alpha, d, theta):  # Craig: Rx(alpha) Tx(a) Rz(theta) Tz(d)
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -d * sa],
                     [st * sa, ct * sa, ca, d * ca], [0, 0, 0, 1.0]])


PUBLISHED_DH = {  # standard DH: a (m), alpha (rad), d (m), theta offset (rad)
    "ur5e": [(0, PI / 2, 0.1625, 0), (-0.425, 0, 0, 0), (-0.3922, 0, 0, 0),
             (0, PI / 2, 0.1333, 0), (0, -PI / 2, 0.0997, 0), (0, 0, 0.0996, 0)],
    "ur10e": [(0, PI / 2, 0.1807, 0), (-0.6127, 0, 0, 0), (-0.57155, 0, 0, 0),
              (0, PI / 2, 0.17415, 0), (0, -PI / 2, 0.11985, 0), (0, 0, 0.11655, 0)],
    "aubo_i5": [(0, PI / 2, 0.0985, 0), (0.408, PI, 0, PI / 2), (0.376, PI, 0, 0),
                (0, -PI / 2, 0.1215, -PI / 2), (0, PI / 2, 0.1025, 0), (0, 0, 0.094, 0)],
}
# Franka's published (Craig) parameters: a, d, alpha per joint, then the flange d = 0.107.
PANDA_MDH = [(0, 0.333, 0), (0, 0, -PI / 2), (0, 0.316, PI / 2), (0.0825, 0, PI / 2),
             (-0.0825, 0.384, -PI / 2), (0, 0, PI / 2), (0.088, 0, PI / 2)]
COBOTTA_CHAIN = [((0, 0, 0), "z"), ((0, 0, 0.180), "y"), ((0, 0, 0.165), "y"),
                 ((-0.012, 0.020, 0.088), "z"), ((0, -0.020, 0.0895), "y"), ((0, -0.0445, 0.042), "z")]


def published_fk(name: str, q) -> np.ndarray:
    T = np.eye(4)
    if name in PUBLISHED_DH:
        for (a, alpha, d, off), qi in zip(PUBLISHED_DH[name], q):
            T = T @ dh_standard(a, alpha, d, qi + off)
    elif name == "panda":
        for (a, d, alpha), qi in zip(PANDA_MDH, q):
            T = T @ dh_modified(a, alpha, d, qi)
        T = T @ dh_modified(0, 0, 0.107, 0)
    else:
        for (xyz, axis), qi in zip(COBOTTA_CHAIN, q):
            c, s = np.cos(qi), np.sin(qi)
            R = {"z": [[c, -s, 0], [s, c, 0], [0, 0, 1]], "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]]}[axis]
            T = T @ make_pose(np.array(R), xyz)
    return T


# ---------------------------------------------------------------- fixtures


@pytest.fixture
def world():
    client = p.connect(p.DIRECT)
    p.setGravity(0, 0, -9.81, physicsClientId=client)
    p.loadURDF(pybullet_data.getDataPath() + "/plane.urdf", physicsClientId=client)
    yield client
    p.disconnect(physicsClientId=client)


def make_box(client, xy, size=0.03, mass=0.05):
    h = size / 2
    shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[h] * 3, physicsClientId=client)
    box = p.createMultiBody(mass, shape, -1, [xy[0], xy[1], h], physicsClientId=client)
    for _ in range(30):
        p.stepSimulation(physicsClientId=client)
    return box


def box_position(client, box):
    return np.array(p.getBasePositionAndOrientation(box, physicsClientId=client)[0])


TOOL_DOWN = np.diag([1.0, -1.0, -1.0])  # tool z pointing at the floor

# ---------------------------------------------------------------- kinematics


@pytest.mark.parametrize("name", ARM_NAMES)
def test_flange_matches_published_kinematics(world, name):
    arm = SimArm(world, name)
    rng = np.random.default_rng(3)
    lim = arm.joint_limits()
    for q in [np.zeros(arm.n_joints), *rng.uniform(lim[:, 0], lim[:, 1], (8, arm.n_joints))]:
        arm.set_joint_positions(q)
        expected = published_fk(name, q)
        for got in (arm.flange_pose(), arm.true_flange_pose()):
            assert np.abs(got[:3, 3] - expected[:3, 3]).max() < 1e-6
            assert np.abs(got[:3, :3] - expected[:3, :3]).max() < 1e-6
    arm.close()


def test_world_placement_and_encoder_offsets(world):
    world_T_base = make_pose(np.diag([-1.0, -1.0, 1.0]), [0.4, -0.2, 0.75])
    offsets = np.radians([0.3, -0.2, 0.1, 0.0, 0.25, -0.1])
    arm = SimArm(world, "ur5e", world_T_base=world_T_base, encoder_offsets=offsets)
    q = arm.joint_positions()
    assert np.allclose(q - arm.true_joint_positions(), offsets)
    # Reported: the model's FK of the reported joints. Truth: the body in the world.
    assert translation_error(arm.flange_pose(), published_fk("ur5e", q)) < 1e-6
    assert translation_error(arm.world_T_flange(),
                             world_T_base @ published_fk("ur5e", q - offsets)) < 1e-6
    assert translation_error(arm.flange_pose(), arm.true_flange_pose()) > 1e-3  # offsets show
    arm.close()


# ---------------------------------------------------------------- IK


@pytest.mark.parametrize("name", ARM_NAMES)
def test_reaches_50_seeded_poses(world, name):
    arm = SimArm(world, name, rng=np.random.default_rng(0))
    rng = np.random.default_rng(2024)
    lim = arm.joint_limits()
    times, worst = [], (0.0, 0.0)
    for q_true in rng.uniform(lim[:, 0], lim[:, 1], (50, arm.n_joints)):
        target = published_fk(name, q_true)  # reachable by construction
        t0 = time.perf_counter()
        q = arm.solve_ik(target)
        times.append(time.perf_counter() - t0)
        assert np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
        arm.set_joint_positions(q)
        for reached in (arm.flange_pose(), arm.true_flange_pose()):  # no offsets: both equal
            worst = (max(worst[0], translation_error(reached, target)),
                     max(worst[1], rotation_error_deg(reached, target)))
    assert worst[0] < 0.5e-3 and worst[1] < 0.1
    print(f"\n{name}: IK median {1e3 * np.median(times):.1f} ms, max {1e3 * max(times):.0f} ms, "
          f"worst miss {worst[0] * 1e3:.5f} mm / {worst[1]:.5f} deg")
    arm.close()


@pytest.mark.parametrize("name", ARM_NAMES)
def test_target_out_of_reach_raises(world, name):
    arm = SimArm(world, name)
    with pytest.raises(UnreachableError, match="closer to the base"):
        arm.solve_ik(make_pose(TOOL_DOWN, [1.5, 0.0, 0.5]))
    arm.close()


def test_pose_just_out_of_reach_raises_with_the_miss(world):
    arm = SimArm(world, "ur5e")
    # 1.05 m from the shoulder: inside the quick bound (sum of link lengths, 1.15 m) so the
    # solver really tries, but beyond the UR5e's true reach (about 0.95 m).
    target = make_pose(TOOL_DOWN, [1.05, 0.0, 0.1625])
    with pytest.raises(UnreachableError, match=r"missed by \d+\.\d+ mm and \d+\.\d+ deg"):
        arm.solve_ik(target, max_restarts=4)
    arm.close()


def test_ik_is_deterministic(world):
    a, b = SimArm(world, "panda", rng=7), SimArm(world, "panda", rng=7)
    target = published_fk("panda", np.array([0.3, 0.2, -0.4, -2.0, 0.5, 2.2, 0.1]))
    assert np.array_equal(a.solve_ik(target), b.solve_ik(target))
    a.close(), b.close()


# ---------------------------------------------------------------- motion


def test_move_linear_follows_a_straight_line(world):
    arm = SimArm(world, "ur5e")
    start = arm.flange_pose()
    target = start.copy()
    target[:3, 3] += [0.15, -0.1, -0.05]
    trail = []
    arm.on_step.append(lambda: trail.append(arm.flange_pose()[:3, 3]))
    t0 = time.perf_counter()
    arm.move_linear(target, speed=0.1)
    elapsed = time.perf_counter() - t0
    direction = (target[:3, 3] - start[:3, 3]) / np.linalg.norm(target[:3, 3] - start[:3, 3])
    off_line = [np.linalg.norm((x - start[:3, 3]) - ((x - start[:3, 3]) @ direction) * direction)
                for x in trail]
    assert len(trail) >= 10 and max(off_line) < 1e-4
    assert translation_error(arm.flange_pose(), target) < 1e-4
    assert rotation_error_deg(arm.flange_pose(), target) < 0.05
    print(f"\nur5e: move_linear 0.187 m in {1e3 * elapsed:.0f} ms wall, {len(trail)} waypoints")
    arm.close()


def test_failed_linear_move_does_not_move(world):
    arm = SimArm(world, "panda")
    q0 = arm.joint_positions()
    target = arm.flange_pose()
    target[:3, 3] = [1.4, 0.0, 0.4]
    with pytest.raises(UnreachableError):
        arm.move_linear(target, 0.1)
    assert np.array_equal(arm.joint_positions(), q0)
    arm.close()


def test_move_joints_ends_exactly_and_checks_limits(world):
    arm = SimArm(world, "aubo_i5")
    q = arm.joint_positions() + np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.5])
    arm.move_joints(q, speed=0.5)
    assert np.allclose(arm.joint_positions(), q, atol=1e-12)
    bad = q.copy()
    bad[2] = 3.2
    with pytest.raises(ValueError, match="joint 2"):
        arm.move_joints(bad)
    assert np.allclose(arm.joint_positions(), q, atol=1e-12)
    arm.close()


# ---------------------------------------------------------------- tools


def _flange_for_tcp(tool, position):
    return make_pose(TOOL_DOWN, position) @ np.linalg.inv(tool.flange_T_tcp)


@pytest.mark.parametrize("name", ["ur5e", "panda"])
def test_suction_picks_and_moves_a_box(world, name):
    arm = SimArm(world, name)
    cup = SimSuctionCup(world, arm)
    box = make_box(world, (0.35, 0.1))
    start = box_position(world, box)
    top = start + [0, 0, 0.015]
    arm.move_joints(arm.solve_ik(_flange_for_tcp(cup, top + [0, 0, 0.1])), 1.0)
    assert cup.grasp() is False and not cup.is_holding  # nothing under the cup
    arm.move_linear(_flange_for_tcp(cup, top), 0.1)
    assert cup.grasp() is True and cup.held_body == box
    arm.move_linear(_flange_for_tcp(cup, top + [-0.1, 0.05, 0.12]), 0.1)
    assert np.allclose(box_position(world, box) - start, [-0.1, 0.05, 0.12], atol=1e-3)
    for _ in range(60):  # held through physics steps too
        p.stepSimulation(physicsClientId=world)
    assert np.allclose(box_position(world, box) - start, [-0.1, 0.05, 0.12], atol=2e-3)
    cup.release()
    for _ in range(240):
        p.stepSimulation(physicsClientId=world)
    assert not cup.is_holding
    assert abs(box_position(world, box)[2] - 0.015) < 2e-3  # fell back onto the floor
    arm.close()


@pytest.mark.parametrize("name, xy", [("panda", (0.45, -0.05)), ("cobotta", (0.18, 0.05))])
def test_gripper_picks_a_box(world, name, xy):
    arm = SimArm(world, name)
    gripper = SimGripper(world, arm)
    box = make_box(world, xy, size=0.03)
    centre = box_position(world, box)
    arm.move_joints(arm.solve_ik(_flange_for_tcp(gripper, centre + [0, 0, 0.08])), 1.0)
    assert gripper.grasp() is False and gripper.opening() == 0.0
    gripper.release()
    arm.move_linear(_flange_for_tcp(gripper, centre), 0.1)
    assert gripper.grasp() is True
    assert abs(gripper.opening() - 0.03) < 1e-3  # closed on the 30 mm box
    arm.move_linear(_flange_for_tcp(gripper, centre + [0.03, 0.05, 0.1]), 0.1)
    assert np.allclose(box_position(world, box) - centre, [0.03, 0.05, 0.1], atol=1e-3)
    arm.close()


def test_pointer_tip_and_robot_wrapper(world):
    arm = SimArm(world, "ur10e")
    robot = SimRobot(arm, SimPointer(world, arm), safety=Safety(max_step=0.2))
    assert np.allclose(robot.tool.flange_T_tcp[:3, 3], [0, 0, 0.150])
    with pytest.raises(RuntimeError, match="cannot grasp"):
        robot.tool.grasp()
    start = robot.flange_pose()
    target = start.copy()
    target[:3, 3] += [0.05, 0.05, -0.05]
    robot.move_to(target, speed=0.1)
    assert translation_error(robot.flange_pose(), target) < 1e-4
    assert np.allclose(robot.tcp_pose(), robot.flange_pose() @ robot.tool.flange_T_tcp)
    q = robot.joint_positions()
    far = target.copy()
    far[:3, 3] += [0.3, 0, 0]  # longer than Safety.max_step: refused before moving
    with pytest.raises(SafetyError):
        robot.move_to(far)
    assert np.array_equal(robot.joint_positions(), q)
    robot.move_joints(q + 0.1, speed=0.5)
    assert np.allclose(robot.joint_positions(), q + 0.1)
    robot.close()

"""Endpoint open-loop vs endpoint closed-loop with a fixed camera (solutions.endpoint), in PyBullet.

Every run: Panda, eye-to-hand camera at 640x480, ChArUco board on the table, chessboard on the
flange; the tool point (flange chessboard centre) goes to 0.2 m above the board centre.
"""

import numpy as np
import pybullet as p
import pytest
from scipy.spatial.transform import Rotation

from robots import perception as P
from robots.geometry import invert, make_pose, pose_from_rotvec, transform_points
from sim_backends.world import create_workcell
from solutions import endpoint as EP

# ECL's final error (truth), measured with benchmarks/servo_endpoint.py: median 0.5 mm, worst
# 1.58 mm over 80 runs (seeds 0-19 x calibration errors from 0 to (10 mm, 5 deg)); the seeds
# used here end at 0.17-0.77 mm. 2 mm sits above that worst case (the floor is the bias of
# two PnP poses, plus the 0.5 mm stopping tolerance), yet well under the smallest miss of EOL
# on these seeds with (5 mm, 2 deg): 7.9 mm (seed 0; 22-23 mm on seeds 1 and 2).
# The comparison and the bound run here on one seed each (0 and 3): every run is a PyBullet
# servo of about 3 s of CPU. The same claims on seeds 1-2 and 4 (and the table over 20 seeds)
# are checked by benchmarks/servo_endpoint.py, which exits 1 when one breaks.
ECL_BOUND_M = 2.0e-3


def _cell(seed):
    return create_workcell(arm="panda", mount="eye_to_hand", scene="calibration",
                           target="charuco", seed=seed)


def _tool_error(cell, task) -> float:
    """Distance (m, truth) between the tool point and the goal."""
    truth = cell.truth
    tool = transform_points(truth.base_T_flange(), [task.flange_p_tool])[0]
    goal = transform_points(truth.base_T_board, [task.goal_in_target])[0]
    return float(np.linalg.norm(tool - goal))


def _goal_shift(cell, task, base_T_cam_cal) -> float:
    """How far (m) a calibration moves the true goal when mapped through it: EOL's error."""
    truth = cell.truth
    goal = transform_points(truth.base_T_board, [task.goal_in_target])[0]
    cam_p_goal = transform_points(invert(truth.base_T_cam), [goal])[0]
    return float(np.linalg.norm(transform_points(base_T_cam_cal, [cam_p_goal])[0] - goal))


def _run(mode, seed, mm, deg):
    with _cell(seed) as cell:
        task = EP.sim_task(cell)
        cal = EP.perturbed_calibration(cell.truth.base_T_cam, mm, deg,
                                       np.random.default_rng(1000 + seed))
        result = (EP.reach_eol if mode == "eol" else EP.reach_ecl)(cell, cal, task)
        assert result.converged
        return _tool_error(cell, task), _goal_shift(cell, task, cal), result


@pytest.mark.slow
def test_ecl_beats_eol_under_a_5mm_2deg_calibration_error():
    eol_error, shift, _ = _run("eol", 0, 5.0, 2.0)
    ecl_error, _, ecl = _run("ecl", 0, 5.0, 2.0)
    # EOL lands where the wrong calibration puts the goal (up to detection noise)...
    assert abs(eol_error - shift) < 2e-3, (eol_error, shift)
    assert eol_error > 5e-3
    # ...ECL where the camera sees the goal, whatever the calibration.
    assert ecl_error <= ECL_BOUND_M, ecl_error
    assert eol_error > 5 * ecl_error, (eol_error, ecl_error)
    assert ecl.iterations <= 40


@pytest.mark.slow
def test_ecl_error_stays_bounded_with_a_10mm_5deg_calibration_error():
    error, shift, _ = _run("ecl", 3, 10.0, 5.0)
    assert shift > 0.02  # the calibration really is far off at the goal
    assert error <= ECL_BOUND_M, error


@pytest.mark.slow
def test_ecl_ignores_the_calibration_translation_and_diverges_with_a_flipped_rotation():
    with _cell(5) as cell:
        task = EP.sim_task(cell)
        right = EP.reach_ecl(cell, cell.truth.base_T_cam, task)
        end_right = cell.robot.flange_pose()
        assert _tool_error(cell, task) <= ECL_BOUND_M
    with _cell(5) as cell:  # the same world again (deterministic for a seed)
        task = EP.sim_task(cell)
        # A calibration 10 cm off in translation only: the very same motion, to the bit.
        shifted = cell.truth.base_T_cam @ make_pose(t=[0.1, 0.0, 0.0])
        moved = EP.reach_ecl(cell, shifted, task)
        np.testing.assert_allclose(cell.robot.flange_pose(), end_right, rtol=0, atol=1e-9)
        assert moved.iterations == right.iterations
        # From the goal, a calibration turned half round about the camera y axis pushes the
        # error the wrong way along x and z: it must grow and be caught.
        flipped = cell.truth.base_T_cam @ pose_from_rotvec([0.0, np.pi, 0.0])
        with pytest.raises((P.ServoDivergedError, P.TargetOutOfViewError)):
            EP.reach_ecl(cell, flipped, task, tolerance_m=1e-5)


def _plate(cell, half_extents, base_T_plate) -> int:
    """A grey plate (PyBullet visual only) at ``base_T_plate``: something in the way."""
    c = cell.client
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=list(half_extents),
                              rgbaColor=[0.5, 0.5, 0.5, 1.0], physicsClientId=c)
    world_T = invert(cell.truth.base_T_pybullet) @ base_T_plate
    return p.createMultiBody(0, -1, vis, world_T[:3, 3].tolist(),
                             Rotation.from_matrix(world_T[:3, :3]).as_quat().tolist(),
                             physicsClientId=c)


@pytest.mark.slow
@pytest.mark.parametrize("what", ["target", "tool marker"])
def test_a_marker_hidden_mid_servo_raises_and_stops_the_robot(what):
    with _cell(0) as cell:
        task = EP.sim_task(cell)
        truth, robot = cell.truth, cell.robot
        poses, stops = [], []
        real_stop = robot.stop

        def spy_stop():
            stops.append(cell.arm.motion_time)
            real_stop()

        robot.stop = spy_stop

        def hide_after_a_second():
            if cell.arm.motion_time < 1.0:
                return
            cell.arm.on_step.remove(hide_after_a_second)
            if what == "target":  # a sheet laid over the board on the table
                goal = transform_points(truth.base_T_board, [task.goal_in_target])[0]
                _plate(cell, [0.25, 0.25, 0.001], make_pose(t=[goal[0], goal[1], 0.015]))
            else:  # a card held 3 cm in front of the flange chessboard, moving with it
                flange_T_card = make_pose(t=task.flange_p_tool + [0.0, 0.0, 0.03])
                card = _plate(cell, [0.1, 0.09, 0.001], truth.base_T_flange() @ flange_T_card)
                cell.arm.attach(card, flange_T_card)

        cell.arm.on_step.append(lambda: poses.append(robot.flange_pose()))  # every waypoint
        cell.arm.on_step.append(hide_after_a_second)
        with pytest.raises(P.TargetLostError, match=what):
            EP.reach_ecl(cell, truth.base_T_cam, task)
        assert stops and stops[-1] >= 1.0, "the robot was not stopped after the loss"
        assert cell.arm.motion_time >= 1.0  # it was hidden mid-servo, not before the start
        # Nothing moved after the last waypoint of the move during which it was hidden.
        np.testing.assert_allclose(robot.flange_pose(), poses[-1], atol=1e-12)


def test_bad_inputs_raise_clear_errors():
    with _cell(0) as cell:
        task = EP.sim_task(cell)
        with pytest.raises(ValueError, match="gain"):
            EP.reach_ecl(cell, cell.truth.base_T_cam, task, gain=10.0, dt=0.2)
        eol_only = EP.EndpointTask(task.detect_target, task.goal_in_target, task.flange_p_tool)
        with pytest.raises(ValueError, match="detect_tool"):
            EP.reach_ecl(cell, cell.truth.base_T_cam, eol_only)
        with pytest.raises(ValueError, match="3-vector"):
            EP.EndpointTask(task.detect_target, [0.0, 0.1], task.flange_p_tool)
        with pytest.raises(ValueError, match="base_T_cam"):
            EP.reach_eol(cell, np.eye(3), task)
    with create_workcell(arm="panda", mount="eye_in_hand", seed=0) as cell:
        with pytest.raises(ValueError, match="eye_to_hand"):
            EP.sim_task(cell)

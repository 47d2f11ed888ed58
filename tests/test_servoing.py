"""Visual servoing: interaction matrix, PBVS/IBVS/decoupled laws, error handling, the sim."""

import numpy as np
import pytest

from robots import perception as P
from robots.geometry import (
    compose,
    invert,
    make_pose,
    pose_from_rotvec,
    rotation_error_deg,
    transform_points,
    translation_error,
)
from sim_backends.world import create_workcell, default_intrinsics
from solutions import servoing as S

INTR = default_intrinsics(320, 240)
SQUARE = np.array([[-.04, -.04, 0], [.04, -.04, 0], [.04, .04, 0], [-.04, .04, 0]])
GOAL = make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5])  # camera 0.5 m above, looking down


# --------------------------------------------------------------------------- pure math


def test_interaction_matrix_matches_finite_differences():
    rng = np.random.default_rng(0)
    pts_world = rng.uniform([-0.1, -0.1, -0.05], [0.1, 0.1, 0.05], (6, 3))
    T = compose(GOAL, pose_from_rotvec(rng.normal(0, 0.2, 3), rng.normal(0, 0.03, 3)))
    cam = transform_points(invert(T), pts_world)
    L = S.interaction_matrix(S.normalised_projection(cam), cam[:, 2])
    h = 1e-6
    for k in range(6):
        twist = np.zeros(6)
        twist[k] = 1.0
        moved = S.integrate_twist(T, twist, h)
        back = S.integrate_twist(T, twist, -h)
        ds = (S.normalised_projection(transform_points(invert(moved), pts_world))
              - S.normalised_projection(transform_points(invert(back), pts_world))) / (2 * h)
        np.testing.assert_allclose(L[:, k], ds.ravel(), atol=1e-6)


def test_twist_transform_moves_the_camera_with_the_flange():
    rng = np.random.default_rng(1)
    flange_T_cam = pose_from_rotvec(rng.normal(0, 0.5, 3), [0.075, 0.0, 0.03])
    base_T_flange = pose_from_rotvec(rng.normal(0, 0.5, 3), [0.4, 0.1, 0.5])
    v_cam = rng.normal(0, 0.2, 6)
    v_flange = S.cam_twist_to_flange(v_cam, flange_T_cam)
    moved = S.integrate_twist(base_T_flange, v_flange, 0.3) @ flange_T_cam
    expected = S.integrate_twist(base_T_flange @ flange_T_cam, v_cam, 0.3)
    np.testing.assert_allclose(moved, expected, atol=1e-12)


@pytest.mark.parametrize("method", ["ibvs", "pbvs"])
def test_servo_converges_from_seeded_offsets_in_pure_kinematics(method):
    rng = np.random.default_rng(2)
    for _ in range(10):
        start = S.offset_start(GOAL, [0, 0, 0], 0.10, 20.0, rng)
        result = S.simulate_servo(method, start, GOAL, SQUARE, INTR)
        assert result.converged and result.iterations <= 50
        assert result.position_error_m <= 1e-3 and result.rotation_error_deg < 0.2


def test_ibvs_copes_with_a_wrong_depth_estimate():
    start = S.offset_start(GOAL, [0, 0, 0], 0.10, 20.0, np.random.default_rng(3))
    result = S.simulate_servo("ibvs", start, GOAL, SQUARE, INTR, depth_error=0.3)
    assert result.position_error_m <= 1e-3


def test_decoupled_law_centres_a_blob():
    # Camera looking straight down at a disc; features: centroid, area, no angle.
    disc = np.array([[0.02 * np.cos(a), 0.02 * np.sin(a), 0] for a in np.linspace(0, 6.28, 40)])
    goal = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.3])
    T = compose(make_pose(t=[0.05, -0.03, 0.08]), goal)

    def features(T):
        xy = S.normalised_projection(transform_points(invert(T), disc))
        area = 0.5 * abs(np.sum(xy[:, 0] * np.roll(xy[:, 1], 1) - np.roll(xy[:, 0], 1) * xy[:, 1]))
        return np.array([*xy.mean(axis=0), area, np.nan])

    desired = features(goal)
    for _ in range(40):
        depth = transform_points(invert(T), [[0, 0, 0]])[0, 2]
        T = S.integrate_twist(T, S.decoupled_velocity(features(T), desired, depth, 2.0), 0.2)
    assert translation_error(T, goal) < 1e-4


def test_pbvs_error_is_zero_at_the_goal_and_saturation_keeps_direction():
    target = make_pose(t=[0.01, 0.02, 0.4])
    assert np.allclose(S.pbvs_error(target, target), 0)
    v = S.saturate([1.0, 0, 0, 0, 0, 2.0], 0.1, 1.0)
    np.testing.assert_allclose(v, [0.1, 0, 0, 0, 0, 0.2])


def test_monitor_flags_divergence_timeout_and_nan():
    m = S.ConvergenceMonitor(tolerance=1e-3, max_iterations=100)
    with pytest.raises(P.ServoDivergedError):
        for e in [0.1, 0.08, 0.2, 0.5]:
            m.update(e)
    with pytest.raises(P.ServoTimeoutError):
        m = S.ConvergenceMonitor(tolerance=1e-3, max_iterations=3)
        for _ in range(3):
            m.update(0.1)
    with pytest.raises(P.ServoDivergedError):
        S.ConvergenceMonitor(1e-3).update(float("nan"))


def test_wrong_sign_gain_diverges_and_target_leaving_the_image_raises():
    start = S.offset_start(GOAL, [0, 0, 0], 0.05, 5.0, np.random.default_rng(4))
    with pytest.raises((P.ServoDivergedError, P.TargetOutOfViewError)):
        S.simulate_servo("ibvs", start, GOAL, SQUARE, INTR, gain=-2.0)
    far = compose(make_pose(t=[0.3, 0, 0]), GOAL)  # the square is off to the side
    with pytest.raises(P.TargetOutOfViewError):
        S.simulate_servo("ibvs", far, GOAL, SQUARE, INTR)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="depth"):
        S.interaction_matrix([[0, 0]], [0.0])
    with pytest.raises(ValueError, match="at least 3"):
        S.ibvs_velocity([[0, 0], [1, 1]], [[0, 0], [1, 1]], [1, 1])
    with pytest.raises(ValueError, match="method"):
        S.simulate_servo("magic", GOAL, GOAL, SQUARE)


# --------------------------------------------------------------------------- PyBullet


def _charuco_cell(seed):
    cell = create_workcell(arm="panda", target="charuco", seed=seed, width=320, height=240)
    truth, board = cell.truth, cell.truth.board
    centre = board.centre
    camd_T_board = compose(make_pose(t=[0, 0, 0.45]), make_pose(t=-centre))
    base_T_camd = compose(truth.base_T_board, invert(camd_T_board))
    centre_base = transform_points(truth.base_T_board, [centre])[0]

    def detect(frame):
        return P.detect_charuco(frame, cell.camera.intrinsics, board.board)

    return cell, camd_T_board, base_T_camd, centre_base, detect


@pytest.mark.parametrize("method", ["ibvs", "pbvs"])
def test_servo_converges_in_pybullet(method):
    """10 cm / 20 deg seeded offsets, eye-in-hand, ChArUco board at 320x240, nominal mount."""
    for seed in (0, 1):
        cell, camd_T_board, base_T_camd, centre, detect = _charuco_cell(seed)
        with cell:
            truth, intr = cell.truth, cell.camera.intrinsics
            start = S.offset_start(base_T_camd, centre, 0.10, 20.0, np.random.default_rng(seed))
            S.move_in_steps(cell.robot, start @ invert(truth.flange_T_cam))
            make = S.ibvs_step if method == "ibvs" else S.pbvs_step
            step = make(detect, camd_T_board, intr, margin_px=None)
            result = S.run_servo(cell.robot, cell.camera, truth.nominal_flange_T_cam, step,
                                 tolerance=5e-4 if method == "ibvs" else 2e-3)
            assert result.converged and result.iterations <= 50
            # Measured at 320x240: 0.4-1.9 mm (corner noise floor ~0.1 px).
            assert translation_error(truth.base_T_cam_now(), base_T_camd) < 2.5e-3
            assert rotation_error_deg(truth.base_T_cam_now(), base_T_camd) < 0.4


def test_lost_target_and_out_of_view_stop_the_robot():
    cell, camd_T_board, base_T_camd, _centre, detect = _charuco_cell(0)
    with cell:
        truth, intr = cell.truth, cell.camera.intrinsics
        # Looking 0.6 m to the side of the board: nothing to see.
        away = compose(make_pose(t=[0.0, 0.45, 0.0]), base_T_camd)
        S.move_in_steps(cell.robot, away @ invert(truth.flange_T_cam))
        before = cell.robot.flange_pose()
        with pytest.raises(P.TargetLostError):
            S.run_servo(cell.robot, cell.camera, truth.flange_T_cam,
                        S.ibvs_step(detect, camd_T_board, intr), tolerance=5e-4)
        np.testing.assert_allclose(cell.robot.flange_pose(), before, atol=1e-12)
        # Board partly out of the image: the default margin check refuses to servo on.
        half_out = compose(make_pose(t=[0.0, 0.17, 0.0]), base_T_camd)
        S.move_in_steps(cell.robot, half_out @ invert(truth.flange_T_cam))
        before = cell.robot.flange_pose()
        with pytest.raises((P.TargetOutOfViewError, P.TargetLostError)):
            S.run_servo(cell.robot, cell.camera, truth.flange_T_cam,
                        S.pbvs_step(detect, camd_T_board, intr, margin_px=None,
                                    required_points=truth.board.object_points),
                        tolerance=2e-3)
        np.testing.assert_allclose(cell.robot.flange_pose(), before, atol=1e-12)


def test_wrong_sign_servo_diverges_on_the_robot():
    cell, camd_T_board, base_T_camd, centre, detect = _charuco_cell(1)
    with cell:
        truth, intr = cell.truth, cell.camera.intrinsics
        start = S.offset_start(base_T_camd, centre, 0.03, 3.0, np.random.default_rng(1))
        S.move_in_steps(cell.robot, start @ invert(truth.flange_T_cam))
        with pytest.raises((P.ServoDivergedError, P.TargetOutOfViewError, P.TargetLostError)):
            S.run_servo(cell.robot, cell.camera, truth.flange_T_cam,
                        S.pbvs_step(detect, camd_T_board, intr, margin_px=None),
                        tolerance=2e-3, gain=-2.0)


def test_pick_and_place_moves_e2_to_e4():
    with create_workcell(arm="panda", scene="chess", seed=0, width=320, height=240) as cell:
        result = S.pick_and_place(cell, "e2", "e4")
        stages = [e.stage for e in result.log]
        assert stages == ["search", "approach", "coarse", "precise", "grasp", "lift", "place",
                          "done"]
        pieces = cell.truth.pieces
        assert "e2" not in pieces and pieces["e4"].kind == "pawn"
        assert pieces["e4"].colour == "white"

"""The integrated sim workcell: connect("sim"), ground truth, knobs, and end-to-end hand-eye."""

import cv2
import numpy as np
import pytest

from robots import connect
from robots.capture import chessboard_detector
from robots.geometry import (
    compose,
    invert,
    make_pose,
    pose_from_rotvec,
    pose_from_rpy,
    rotation_angle_deg,
    rotation_error_deg,
    translation_error,
)
from robots.interfaces import Frame, RobotDisconnectedError, SafetyError, UnreachableError, Workcell
from sim_backends.scene import PIECE_HEIGHT
from sim_backends.world import SimWorkcell, create_workcell


def detect_board_pose(frame, target, intrinsics):
    """cam_T_target from a chessboard image through the project's detector, or None."""
    cols, rows = target.pattern_size
    square = target.object_points[1, 0] - target.object_points[0, 0]
    detection = chessboard_detector(cols, rows, square)(frame, intrinsics)
    return None if detection is None else detection.cam_T_target


def _hand_eye(mount):
    try:
        from solutions import handeye

        return (handeye.calibrate_eye_in_hand if mount == "eye_in_hand"
                else handeye.calibrate_eye_to_hand)
    except ImportError:  # the project's solvers are optional here; OpenCV is the fallback
        def opencv(F, C):
            F = np.asarray(F) if mount == "eye_in_hand" else invert(np.asarray(F))
            R, t = cv2.calibrateHandEye(F[:, :3, :3], F[:, :3, 3], C[:, :3, :3], C[:, :3, 3],
                                        method=cv2.CALIB_HAND_EYE_PARK)
            return make_pose(R, t.ravel())
        return opencv


# --------------------------------------------------------------------------- basics


def test_connect_sim_gives_a_workcell_with_truth():
    with connect("sim", engine="pybullet", arm="panda", mount="eye_in_hand", seed=0,
                 width=320, height=240) as cell:   # SimWorkcell is the PyBullet engine's
        assert isinstance(cell, SimWorkcell) and isinstance(cell, Workcell)
        assert cell.kind == "sim" and cell.cameras == {"cam": cell.camera}
        frame = cell.camera.capture()
        assert isinstance(frame, Frame) and frame.rgb.shape == (240, 320, 3)
        assert frame.depth.shape == (240, 320)
        truth = cell.truth
        assert truth.mount == "eye_in_hand" and truth.base_T_cam is None
        assert truth.flange_T_cam.shape == (4, 4) and truth.base_T_board.shape == (4, 4)
        # The world frame of the calibration scene is the board's origin corner.
        np.testing.assert_allclose(truth.base_T_world, truth.base_T_board)
        # No knobs turned: the robot reports the true flange pose.
        np.testing.assert_allclose(cell.robot.flange_pose(), truth.base_T_flange(), atol=1e-9)
        assert truth.pieces == {}
    with pytest.raises(RobotDisconnectedError):
        cell.camera.capture()


def test_start_pose_sees_the_board_where_truth_says():
    with create_workcell(arm="panda", mount="eye_in_hand", seed=3) as cell:
        truth = cell.truth
        est = detect_board_pose(cell.camera.capture(), truth.board, cell.camera.intrinsics)
        assert est is not None, "the camera must see the board from the start pose"
        expected = compose(invert(truth.base_T_cam_now()), truth.base_T_board)
        assert translation_error(est, expected) < 1e-3
        assert rotation_error_deg(est, expected) < 0.2


def test_eye_to_hand_sees_the_flange_target_where_truth_says():
    with create_workcell(arm="panda", mount="eye_to_hand", seed=0) as cell:
        truth = cell.truth
        assert truth.flange_T_cam is None and truth.base_T_cam is not None
        frame = cell.camera.capture()
        est = detect_board_pose(frame, truth.flange_target, cell.camera.intrinsics)
        assert est is not None, "the fixed camera must see the flange target at the start"
        expected = compose(invert(truth.base_T_cam), truth.base_T_flange(), truth.flange_T_marker)
        assert translation_error(est, expected) < 1e-3
        assert rotation_error_deg(est, expected) < 0.2


@pytest.mark.parametrize("kind", ["charuco", "circles", "aruco"])
def test_other_table_targets_are_seen_where_truth_says(kind):
    with create_workcell(target=kind, seed=1) as cell:
        truth, intr = cell.truth, cell.camera.intrinsics
        target = truth.board
        assert target.kind == kind
        gray = cv2.cvtColor(cell.camera.capture().rgb, cv2.COLOR_RGB2GRAY)
        expected = compose(invert(truth.base_T_cam_now()), truth.base_T_board)
        if kind == "charuco":
            corners, ids, _, _ = cv2.aruco.CharucoDetector(target.board).detectBoard(gray)
            assert ids is not None and len(ids) >= 20
            obj, img = target.object_points[ids.ravel()], corners.reshape(-1, 2)
        elif kind == "circles":
            ok, centres = cv2.findCirclesGrid(gray, target.pattern_size,
                                              flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
            assert ok
            obj, img = target.object_points, centres.reshape(-1, 2)
        else:
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            dictionary = cv2.aruco.getPredefinedDictionary(target.dictionary)
            corners, ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(gray)
            assert ids is not None and ids.ravel().tolist() == [0]
            rv = cv2.Rodrigues(expected[:3, :3])[0]
            pred = cv2.projectPoints(target.object_points, rv, expected[:3, 3], intr.K, None)[0]
            # A lone square's corners come out ~0.1 px inside (an L-corner, not an X-corner),
            # so only the corner positions are checked, not a 1 mm pose.
            assert np.abs(corners[0].reshape(-1, 2) - pred.reshape(-1, 2)).max() < 0.5
            return
        _, rvec, tvec = cv2.solvePnP(obj, img, intr.K, None, flags=cv2.SOLVEPNP_ITERATIVE)
        est = pose_from_rotvec(rvec.ravel(), tvec.ravel())
        assert translation_error(est, expected) < 1e-3
        assert rotation_error_deg(est, expected) < 0.2


def test_seed_makes_the_world_repeatable():
    def board_and_image(seed):
        with create_workcell(seed=seed, width=160, height=120, pixel_noise=2.0) as cell:
            return cell.truth.base_T_board, cell.camera.capture().rgb

    (b1, i1), (b2, i2), (b3, _) = board_and_image(5), board_and_image(5), board_and_image(6)
    np.testing.assert_array_equal(b1, b2)
    np.testing.assert_array_equal(i1, i2)
    assert translation_error(b1, b3) > 1e-3


def test_mount_error_and_encoder_noise_knobs():
    with create_workcell(seed=2, mount_error=(3.0, 0.5), encoder_noise_deg=0.05,
                         width=160, height=120) as cell:
        t = cell.truth
        delta = compose(invert(t.nominal_flange_T_cam), t.flange_T_cam)
        assert np.linalg.norm(delta[:3, 3]) == pytest.approx(3e-3, abs=1e-9)
        assert rotation_angle_deg(delta) == pytest.approx(0.5, abs=1e-6)
        assert t.encoder_offsets is not None and len(t.encoder_offsets) == 7
        # The controller's report is off by the encoder error, the truth is not.
        assert translation_error(cell.robot.flange_pose(), t.base_T_flange()) > 1e-5
    with create_workcell(seed=2, mount="eye_to_hand", mount_error=(2.0, 0.0),
                         width=160, height=120) as cell:
        t = cell.truth
        assert translation_error(t.base_T_cam, t.nominal_base_T_cam) == pytest.approx(2e-3)


def test_stereo_pair_has_the_baseline():
    with create_workcell(seed=0, stereo_baseline=0.05) as cell:
        assert set(cell.cameras) == {"cam", "right"} and cell.camera is cell.cameras["cam"]
        poses = [detect_board_pose(cell.cameras[n].capture(), cell.truth.board,
                                   cell.camera.intrinsics) for n in ("cam", "right")]
        assert all(P is not None for P in poses)
        left_T_right = compose(poses[0], invert(poses[1]))
        np.testing.assert_allclose(left_T_right[:3, 3], [0.05, 0, 0], atol=1e-3)
        np.testing.assert_allclose(cell.truth.cam_T_right[:3, 3], [0.05, 0, 0])


def test_distortion_and_noise_reach_the_camera():
    dist = [-0.1, 0.02, 0.0, 0.0, 0.0]
    with create_workcell(seed=0, width=320, height=240, distortion=dist, pixel_noise=3.0,
                         depth_noise=0.001, lighting="dim") as cell:
        np.testing.assert_allclose(cell.camera.intrinsics.dist, dist)
        assert cell.camera.pixel_noise == 3.0 and cell.camera.depth_noise == 0.001
        cell.camera.capture()


@pytest.mark.parametrize("kwargs, match", [
    ({"arm": "kuka"}, "arm"),
    ({"mount": "on_the_ceiling"}, "mount"),
    ({"scene": "kitchen"}, "scene"),
    ({"tool": "hammer"}, "tool"),
    ({"mount_error": (1.0,)}, "mount_error"),
    ({"stereo_baseline": -0.1}, "stereo_baseline"),
    ({"lighting": "disco"}, "lighting"),
    ({"target": "dartboard"}, "target"),
])
def test_bad_options_raise_value_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        create_workcell(**kwargs)


# --------------------------------------------------------------------------- chess


@pytest.mark.parametrize("tool, engine, arm", [
    ("suction", "mujoco", "panda"), ("gripper", "mujoco", "panda"),  # the Franka Hand
    ("gripper", "pybullet", "panda"), ("gripper", "mujoco", "ur5e")])  # the generic gripper
def test_chess_scene_truth_follows_a_pick_and_place(tool, engine, arm):
    with connect("sim", engine=engine, arm=arm, scene="chess", tool=tool, seed=0, width=160,
                 height=120) as cell:
        pieces = cell.truth.pieces
        assert len(pieces) == 32 and pieces["e1"].kind == "king"
        assert pieces["a1"].colour == "white" and pieces["h8"].colour == "black"
        robot = cell.robot
        base_T_e2 = pieces["e2"].base_T_piece
        dest = compose(cell.truth.base_T_world, make_pose(t=[4.5 * 0.05, 3.5 * 0.05, 0]))  # e4
        # The cup tip just above the pawn's top; the fingertips around its middle.
        height = PIECE_HEIGHT["pawn"] + 0.002 if tool == "suction" else PIECE_HEIGHT["pawn"] / 2
        down = make_pose(np.diag([1.0, -1.0, -1.0]))  # tool pointing down

        def tcp_at(base_T_point, dz):
            return compose(make_pose(t=base_T_point[:3, 3] + [0, 0, dz]), down)

        above_e2 = tcp_at(base_T_e2, height + 0.05)
        # In joint space: from the UR5e's home a straight line would pass its wrist singularity.
        q0 = robot.joint_positions()
        q1 = robot.solve_ik(above_e2 @ invert(robot.tool.flange_T_tcp))
        for step in (0.25, 0.5, 0.75, 1.0):  # Safety's largest joint step is 90 deg
            robot.move_joints(q0 + step * (q1 - q0), speed=0.5)
        robot.move_tcp_to(tcp_at(base_T_e2, height), speed=0.05)
        assert robot.tool.grasp()
        robot.move_tcp_to(tcp_at(base_T_e2, height + 0.08), speed=0.1)
        assert "e2" not in cell.truth.pieces
        robot.move_tcp_to(tcp_at(dest, height + 0.08), speed=0.2)
        robot.move_tcp_to(tcp_at(dest, height + 0.001), speed=0.05)
        robot.tool.release()
        robot.move_tcp_to(tcp_at(dest, height + 0.05), speed=0.1)
        after = cell.truth.pieces
        assert after["e4"].kind == "pawn" and after["e4"].colour == "white"
        assert translation_error(after["e4"].base_T_piece, dest) < 5e-3


def test_a_suction_cup_on_the_bare_board_holds_nothing():
    """The board is fixed to the table: a cup pressed on an empty square must not lift it
    (it once did, and every piece went up with it)."""
    with create_workcell(scene="chess", tool="suction", seed=0, width=160, height=120) as cell:
        before = cell.truth.pieces
        e4 = compose(cell.truth.base_T_world, make_pose(t=[4.5 * 0.05, 3.5 * 0.05, 0]))
        down = make_pose(np.diag([1.0, -1.0, -1.0]))
        touching = compose(make_pose(t=e4[:3, 3] + [0, 0, 0.001]), down)
        cell.robot.move_tcp_to(compose(make_pose(t=[0, 0, 0.05]), touching), speed=0.2)
        cell.robot.move_tcp_to(touching, speed=0.05)
        assert not cell.robot.tool.grasp() and not cell.robot.tool.is_holding
        cell.robot.move_tcp_to(compose(make_pose(t=[0, 0, 0.08]), touching), speed=0.1)
        after = cell.truth.pieces
        assert set(after) == set(before)
        assert max(translation_error(after[sq].base_T_piece, before[sq].base_T_piece)
                   for sq in before) < 1e-3


def test_chess_random_position_is_seeded():
    def position(seed):
        with create_workcell(scene="chess", chess_position="random", seed=seed,
                             width=80, height=60) as cell:
            return {sq: (t.kind, t.colour) for sq, t in cell.truth.pieces.items()}

    assert position(4) == position(4) and len(position(4)) == 12
    assert position(4) != position(5)


# --------------------------------------------------------------------------- end to end


def _eye_in_hand_goals(cell, rng, n):
    """Camera poses looking at the board centre from 0.45-0.55 m, tilted 8-25 degrees."""
    truth = cell.truth
    board = truth.board
    w, h = board.size
    centre = compose(truth.base_T_board, invert(board.print_T_target),
                     make_pose(t=[w / 2, h / 2, 0]))[:3, 3]
    board_x = truth.base_T_board[:3, 0]
    for _ in range(n):
        tilt, azimuth = np.deg2rad(rng.uniform(8, 25)), rng.uniform(0, 2 * np.pi)
        d = rng.uniform(0.45, 0.55)
        direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                              np.cos(tilt)])
        eye = centre + d * direction
        z = (centre - eye) / np.linalg.norm(centre - eye)
        x = board_x - (board_x @ z) * z
        x /= np.linalg.norm(x)
        base_T_cam = make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)
        base_T_cam = compose(base_T_cam, pose_from_rpy(0, 0, np.deg2rad(rng.uniform(-15, 15))))
        yield compose(base_T_cam, invert(truth.flange_T_cam))


def _eye_to_hand_goals(cell, rng, n):
    """Flange-target poses 0.45-0.6 m in front of the fixed camera, facing it within 25 deg."""
    truth = cell.truth
    base_T_cam = truth.base_T_cam
    target = truth.flange_target
    w, h = target.size
    centre_in_target = (invert(target.print_T_target) @ [w / 2, h / 2, 0, 1])[:3]
    for _ in range(n):
        d = rng.uniform(0.45, 0.6)
        lateral = rng.uniform(-0.06, 0.06, 2)
        cam_T_centre = compose(make_pose(t=[lateral[0], lateral[1], d]),
                               pose_from_rotvec(np.deg2rad(rng.uniform(-25, 25, 3))))
        cam_T_target = compose(cam_T_centre, make_pose(t=-centre_in_target))
        yield compose(base_T_cam, cam_T_target, invert(truth.flange_T_marker))


@pytest.mark.slow
@pytest.mark.parametrize("mount, knobs", [
    ("eye_in_hand", {}),
    ("eye_to_hand", {}),
    # A camera mounted 5 mm / 2 deg off its design pose, and pixel noise: calibration must
    # find the TRUE mount (which truth holds), not the nominal one a naive user assumes.
    ("eye_in_hand", {"mount_error": (5.0, 2.0), "pixel_noise": 2.0}),
], ids=["eye_in_hand", "eye_to_hand", "eye_in_hand-mount_error-pixel_noise"])
def test_end_to_end_hand_eye_calibration(mount, knobs):
    """15 poses, chessboard detection, solvePnP, hand-eye: truth within 1 mm / 0.1 deg."""
    goals = _eye_in_hand_goals if mount == "eye_in_hand" else _eye_to_hand_goals
    with create_workcell(arm="panda", mount=mount, seed=11, **knobs) as cell:
        target = cell.truth.board if mount == "eye_in_hand" else cell.truth.flange_target
        rng = np.random.default_rng(11)
        F, C = [], []
        for base_T_flange in goals(cell, rng, 40):
            try:
                cell.robot.move_to(base_T_flange, speed=0.25)
            except (UnreachableError, SafetyError):
                continue  # a pose this arm cannot reach from here; draw another
            cam_T_target = detect_board_pose(cell.camera.capture(), target,
                                             cell.camera.intrinsics)
            if cam_T_target is None:
                continue
            F.append(cell.robot.flange_pose())
            C.append(cam_T_target)
            if len(F) == 15:
                break
        assert len(F) == 15, f"only {len(F)} usable poses"
        X = _hand_eye(mount)(np.array(F), np.array(C))
        truth = cell.truth.flange_T_cam if mount == "eye_in_hand" else cell.truth.base_T_cam
        assert translation_error(X, truth) < 1e-3
        assert rotation_error_deg(X, truth) < 0.1
        if knobs:
            assert translation_error(X, cell.truth.nominal_flange_T_cam) > 4e-3

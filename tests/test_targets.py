"""robots.targets and robots.half_turn: marker, ChArUco and circle-grid detectors on real OpenCV renderings, and the
chessboard's half-turn chosen from the robot's motion (synthetic truth and the real Franka)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from autograder.datasets import load_visp_franka
from autograder.synthetic import NoiseModel, make_hand_eye
from robots import geometry as geo
from robots.half_turn import choose_consistent_poses, half_turn, resolve_half_turns
from robots.interfaces import Frame, Intrinsics
from robots.targets import (
    aruco_detector,
    charuco_detector,
    chessboard_with_reasons,
    circle_grid_detector,
)

PX_PER_M = 4000.0  # the flat rendering's scale: a camera 1 m away with this focal length


def _flat_view(image: np.ndarray, margin: int = 60):
    """A fronto-parallel photo of a rendered target: the target plane 1 m in front of a camera
    whose focal length is PX_PER_M, so a board point (x, y) in metres lands at
    PX_PER_M * (x, y) + margin pixels. Returns (frame, intrinsics)."""
    gray = cv2.copyMakeBorder(image, margin, margin, margin, margin, cv2.BORDER_CONSTANT,
                              value=255)
    h, w = gray.shape
    intrinsics = Intrinsics(PX_PER_M, PX_PER_M, margin, margin, w, h)
    return Frame(np.dstack([gray] * 3), None, 0.0), intrinsics


def _check_pose(detection, intrinsics):
    assert detection.ok, detection.reason
    assert len(detection.corners_px) >= 4
    T = detection.cam_T_target
    # Where the detector's points land through its pose: on the detected pixels.
    proj, _ = cv2.projectPoints(detection.object_points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3],
                                intrinsics.K, intrinsics.dist)
    assert np.abs(proj.reshape(-1, 2) - detection.corners_px).max() < 1.0
    assert T[2, 3] == pytest.approx(1.0, abs=0.02)  # the board is 1 m away
    assert abs(T[2, 2]) == pytest.approx(1.0, abs=1e-3)  # and faces the camera


def test_a_single_apriltag_gives_its_four_corners_and_pose():
    tag = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), 3, 400)
    frame, intrinsics = _flat_view(np.pad(tag, 50, constant_values=255))
    detection = aruco_detector("DICT_APRILTAG_36h11", 400 / PX_PER_M, ids=(3,))(frame, intrinsics)
    _check_pose(detection, intrinsics)
    assert len(detection.corners_px) == 4
    # Tag centre at image (margin + 50 + 200) px = 0.0625 m right and down of the optical axis.
    assert detection.cam_T_target[:2, 3] == pytest.approx([0.0625, 0.0625], abs=1e-3)


def test_a_marker_that_is_not_there_is_refused_with_the_rule():
    tag = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), 3, 400)
    frame, intrinsics = _flat_view(np.pad(tag, 50, constant_values=255))
    detection = aruco_detector("DICT_APRILTAG_36h11", 0.1, ids=(7,))(frame, intrinsics)
    assert not detection.ok
    assert "found no marker" in detection.reason and "exactly 1 is needed" in detection.reason
    blank, _ = _flat_view(np.full((300, 300), 255, np.uint8))
    charuco = charuco_detector(5, 4, 0.04, 0.03)(blank, intrinsics)
    assert not charuco.ok and "found 0 markers" in charuco.reason and "at least 4" in charuco.reason
    grid = circle_grid_detector(4, 3, 0.02)(blank, intrinsics)
    assert not grid.ok and "all 12 circles are needed" in grid.reason
    board = chessboard_with_reasons(9, 6, 0.0236)(blank, intrinsics)
    assert not board.ok and "all 54 inner corners are needed" in board.reason


def test_a_grid_of_markers():
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    board = cv2.aruco.GridBoard((3, 2), 0.04, 0.01, dictionary)
    image = board.generateImage((int(0.14 * PX_PER_M), int(0.09 * PX_PER_M)), marginSize=0)
    frame, intrinsics = _flat_view(image)
    detection = aruco_detector("DICT_4X4_50", 0.04, grid=(3, 2), separation_m=0.01)(
        frame, intrinsics)
    _check_pose(detection, intrinsics)
    assert len(detection.corners_px) == 24


def test_a_charuco_board():
    board = cv2.aruco.CharucoBoard((6, 4), 0.03, 0.022,
                                   cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    image = board.generateImage((int(0.18 * PX_PER_M), int(0.12 * PX_PER_M)), marginSize=0)
    frame, intrinsics = _flat_view(image)
    detection = charuco_detector(6, 4, 0.03, 0.022)(frame, intrinsics)
    _check_pose(detection, intrinsics)
    assert len(detection.corners_px) == 15  # (6 - 1) x (4 - 1) inner corners


@pytest.mark.parametrize("asymmetric", [False, True])
def test_a_circle_grid(asymmetric):
    cols, rows, spacing = 4, 5, 0.03
    image = np.full((int(0.2 * PX_PER_M), int(0.2 * PX_PER_M)), 255, np.uint8)
    for i in range(rows):
        for j in range(cols):
            x = (2 * j + i % 2) * spacing / 2 if asymmetric else j * spacing
            y = i * spacing / 2 if asymmetric else i * spacing
            cv2.circle(image, (int(round((x + 0.02) * PX_PER_M)), int(round((y + 0.02) * PX_PER_M))),
                       int(0.005 * PX_PER_M), 0, -1, lineType=cv2.LINE_AA)
    frame, intrinsics = _flat_view(image)
    detection = circle_grid_detector(cols, rows, spacing, asymmetric)(frame, intrinsics)
    _check_pose(detection, intrinsics)


def test_sizes_in_millimetres_and_unknown_dictionaries_are_refused_by_name():
    with pytest.raises(ValueError, match="marker_m .* metres"):
        aruco_detector("DICT_APRILTAG_36h11", 48)
    with pytest.raises(ValueError, match="dictionary must be"):
        aruco_detector("APRILTAG_36h11", 0.048)
    with pytest.raises(ValueError, match="marker_m .* smaller than square_m"):
        charuco_detector(5, 4, 0.03, 0.04)


def test_the_half_turn_maps_a_grid_onto_itself_in_reverse():
    grid = np.zeros((54, 3))
    grid[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.02
    F = half_turn(grid)
    assert np.allclose(geo.transform_points(F, grid), grid[::-1])
    with pytest.raises(ValueError, match="half-turn"):
        half_turn(grid[:-1])


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_views_read_half_a_turn_round_are_found_from_the_motion(mount):
    """Known truth: corners of views 2 and 5 listed from the wrong end, as a detector that
    orders them by an image axis does for a camera rolled past 90 degrees."""
    p = make_hand_eye(4, mount, n_poses=8, noise=NoiseModel(pixel_px=0.3, robot_rot_deg=0.05,
                                                              robot_trans_mm=0.2))
    K = p.camera.K
    intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], p.camera.width, p.camera.height)
    read = [view[::-1] if k in (2, 5) else view for k, view in enumerate(p.pixels)]
    corners, poses, choice = resolve_half_turns(p.base_T_flange, read, p.board.object_points(),
                                                intrinsics)
    assert choice.changed == (2, 5) and choice.unclear == ()
    assert np.allclose(np.array(corners), p.pixels)
    assert geo.rotation_error_deg(poses, p.true_cam_T_target).max() < 1.0
    assert choice.mismatch_deg.max() < 1.0 < 20.0 < choice.alternative_deg.min()
    assert "views [2, 5] were read half a turn round" in choice.summary()


def test_a_capture_read_right_is_left_as_it_is():
    p = make_hand_eye(5, "eye_in_hand", n_poses=6, noise=NoiseModel(pixel_px=0.3))
    K = p.camera.K
    intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], p.camera.width, p.camera.height)
    corners, _, choice = resolve_half_turns(p.base_T_flange, list(p.pixels),
                                            p.board.object_points(), intrinsics)
    assert choice.changed == () and np.allclose(np.array(corners), p.pixels)
    assert choice.summary().startswith("every view kept")


def test_pure_rolls_about_the_optical_axis_leave_the_choice_unclear():
    """A view turned only about the camera's axis relative to the others gives the same
    relative angle both ways for some pairs; the evidence then cannot decide, and says so."""
    F = np.array([geo.pose_from_rotvec([0, 0, a], [0.3, 0, 0.5]) for a in (0.0, np.pi / 2, np.pi)])
    C = np.array([geo.pose_from_rotvec([0, 0, -a], [0, 0, 0.5]) for a in (0.0, np.pi / 2, np.pi)])
    turn = geo.make_pose(np.diag([-1.0, -1.0, 1.0]))
    choice = choose_consistent_poses(F, np.stack([C, C @ turn], axis=1))
    assert choice.unclear  # a half-turn about z is itself a roll: the motion cannot tell
    with pytest.raises(ValueError, match="at least 3 views"):
        choose_consistent_poses(F[:2], np.stack([C[:2], C[:2]], axis=1))


def test_the_chessboard_with_reasons_finds_what_the_plain_detector_finds():
    capture = load_visp_franka("eye_in_hand")
    folder = Path(__file__).resolve().parents[1] / "autograder" / "data" / "visp_franka"
    bgr = cv2.imread(str(folder / "eye_in_hand" / "franka_image-1.png"))
    intrinsics = Intrinsics(*capture.K[[0, 1, 0, 1], [0, 1, 2, 2]], *capture.image_size_wh)
    found = chessboard_with_reasons(9, 6, 0.0236)(Frame(bgr[:, :, ::-1], None, 0.0), intrinsics)
    assert found.ok and np.allclose(found.corners_px, capture.pixels[0])


def test_the_real_franka_capture_has_its_rolled_view_turned_back():
    """ViSP's eye-in-hand Franka capture: view 8 (index 7) has the camera rolled about half a
    turn; its corners are read in the order that agrees with the robot's motion."""
    capture = load_visp_franka("eye_in_hand")
    assert capture.notes and capture.notes[0].startswith("views [7] were read half a turn")
    corners, poses, choice = resolve_half_turns(
        capture.base_T_flange, list(capture.pixels), capture.board_points_m,
        Intrinsics(*capture.K[[0, 1, 0, 1], [0, 1, 2, 2]], *capture.image_size_wh))
    assert choice.changed == ()  # already resolved when loaded
    assert choice.mismatch_deg.max() < 0.5 and choice.alternative_deg.min() > 20.0
    tag = load_visp_franka("eye_to_hand")
    assert tag.pixels.shape == (8, 4, 2) and tag.notes == ()


def test_a_capture_run_records_why_a_view_was_refused(tmp_path):
    """capture_pose_pairs keeps the detector's reason (with the rule) for each skipped view."""
    from contract import make_gantry_cell

    from robots.capture import capture_pose_pairs

    with make_gantry_cell() as cell:
        pose = cell.robot.flange_pose()
        capture = capture_pose_pairs(cell.robot, cell.camera, [pose],
                                     aruco_detector("DICT_APRILTAG_36h11", 0.048, ids=(5,)),
                                     progress=False, settle_s=0.0)
    assert len(capture) == 0 and list(capture.failed_indices) == [0]
    assert "found no marker; exactly 1 is needed" in capture.failed_reasons[0]


def test_a_square_grid_is_refused_since_a_quarter_turn_is_not_resolved():
    grid = np.zeros((36, 3))
    grid[:, :2] = np.mgrid[0:6, 0:6].T.reshape(-1, 2) * 0.02
    F = np.array([geo.pose_from_rotvec([0.1 * k, 0, 0], [0, 0, 0]) for k in range(3)])
    intrinsics = Intrinsics(600, 600, 320, 240, 640, 480)
    cam = geo.pose_from_rotvec([0, 0, 0], [-0.05, -0.05, 0.5])
    pixels, _ = cv2.projectPoints(grid, np.zeros(3), cam[:3, 3], intrinsics.K, intrinsics.dist)
    with pytest.raises(ValueError, match="quarter turn"):
        resolve_half_turns(F, [pixels.reshape(-1, 2)] * 3, grid, intrinsics)


def test_a_capture_object_gets_its_turned_view_reordered_and_its_pose_re_solved():
    from robots.capture import Capture
    from robots.half_turn import resolve_capture_half_turns

    p = make_hand_eye(6, "eye_in_hand", n_poses=5, noise=NoiseModel(pixel_px=0.2))
    K = p.camera.K
    intrinsics = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], p.camera.width, p.camera.height)
    grid = p.board.object_points()
    read = [view[::-1] if k == 1 else view for k, view in enumerate(p.pixels)]
    capture = Capture(base_T_flange=p.base_T_flange, cam_T_target=np.full((5, 4, 4), np.nan),
                      corners_px=read, object_points=[grid] * 5, intrinsics=intrinsics,
                      commanded_base_T_flange=p.base_T_flange, pose_indices=np.arange(5),
                      timestamps=np.zeros(5), images=[])
    fixed, choice = resolve_capture_half_turns(capture)
    assert choice.changed == (1,)
    assert np.allclose(np.array(fixed.corners_px), p.pixels)
    assert geo.rotation_error_deg(fixed.cam_T_target, p.true_cam_T_target).max() < 1.0
    assert np.isnan(capture.cam_T_target).all()  # the original is left as it was

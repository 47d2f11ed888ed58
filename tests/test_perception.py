"""Perception helpers (robots.perception) and reference perception (solutions.perception)."""

import cv2
import numpy as np
import pytest

from robots import perception as P
from robots.calibration_io import CalibrationResult
from robots.geometry import (
    compose,
    invert,
    make_pose,
    pose_from_rotvec,
    rotation_error_deg,
    transform_points,
    translation_error,
)
from robots.interfaces import Frame, Intrinsics
from sim_backends.world import create_workcell
from solutions import perception as SP

DIST = Intrinsics(500.0, 500.0, 319.5, 239.5, 640, 480, [-0.2, 0.05, 0.001, -0.001, 0.0])


# --------------------------------------------------------------------------- pixels <-> metres


def test_project_and_deproject_round_trip_with_distortion():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.2, 0.2, (50, 2)), rng.uniform(0.3, 1.5, 50)])
    uv = P.project(pts, DIST)
    np.testing.assert_allclose(P.deproject(uv, pts[:, 2], DIST), pts, atol=1e-6)
    # Distortion really is applied: the pinhole pixel differs near the border.
    pinhole = pts[:, :2] / pts[:, 2:] * 500 + [319.5, 239.5]
    assert np.abs(uv - pinhole).max() > 1.0


def test_pixel_helpers_refuse_bad_input():
    with pytest.raises(ValueError, match="behind the camera"):
        P.project([0, 0, -1.0], DIST)
    with pytest.raises(ValueError, match="depth"):
        P.deproject([[10, 10]], [np.nan], DIST)
    with pytest.raises(ValueError, match="shape"):
        P.deproject(np.zeros((3, 3)), 1.0, DIST)
    with pytest.raises(ValueError, match="a1"):
        P.square_index("i9")


def test_point_cloud_and_depth_at_agree_with_deproject():
    depth = np.full((480, 640), 0.8, np.float32)
    depth[:5, :5] = np.nan
    cloud = P.point_cloud(depth, DIST)
    np.testing.assert_allclose(cloud[100, 200], P.deproject([[200, 100]], 0.8, DIST)[0], atol=1e-6)
    frame = Frame(np.zeros((480, 640, 3), np.uint8), depth, 0.0)
    assert P.depth_at(frame, [[4, 4]])[0] == pytest.approx(0.8)  # the box reaches valid pixels
    assert np.isnan(P.depth_at(frame, [[0, 0]], window=1)[0])


def test_to_base_through_saved_calibrations():
    flange_T_cam = pose_from_rotvec([0.1, -0.2, 0.3], [0.05, 0.0, 0.03])
    base_T_flange = pose_from_rotvec([3.0, 0.1, 0.0], [0.4, 0.1, 0.5])
    cal = CalibrationResult(flange_T_cam, "flange", "cam", "test", 10, {}, "2024-01-01")
    p = np.array([[0.01, 0.02, 0.5]])
    np.testing.assert_allclose(P.to_base(p, cal, base_T_flange),
                               transform_points(base_T_flange @ flange_T_cam, p))
    with pytest.raises(ValueError, match="base_T_flange"):
        P.to_base(p, cal)
    fixed = CalibrationResult(flange_T_cam, "base", "cam", "test", 10, {}, "2024-01-01")
    np.testing.assert_allclose(P.to_base(p, fixed), transform_points(flange_T_cam, p))


def test_square_names_round_trip():
    for name in ("a1", "e4", "h8", "c7"):
        centre = P.square_centre(name, 0.05)
        assert P.square_at(centre, 0.05) == [name]
    assert P.square_at([[-0.01, 0.1, 0.0]], 0.05) == [None]


# --------------------------------------------------------------------------- target detectors


@pytest.mark.parametrize("kind", ["chessboard", "charuco", "aruco", "circles"])
def test_target_detectors_match_the_sim_truth(kind):
    with create_workcell(target=kind, seed=1) as cell:
        truth, intr = cell.truth, cell.camera.intrinsics
        frame = cell.camera.capture()
        board = truth.board
        if kind == "chessboard":
            cols, rows = board.pattern_size
            det = P.detect_chessboard(frame, intr, cols, rows, board.params["square"])
        elif kind == "charuco":
            det = P.detect_charuco(frame, intr, board.board)
        elif kind == "aruco":
            det = P.detect_aruco(frame, intr, board.params["size"], board.dictionary)[0]
        else:
            det = P.detect_circle_grid(frame, intr, board.pattern_size, board.params["spacing"])
        assert det is not None
        expected = compose(invert(truth.base_T_cam_now()), truth.base_T_board)
        if kind == "chessboard" and det.cam_T_target[:3, 0] @ expected[:3, 0] < 0:
            expected = compose(expected, make_pose(np.diag([-1.0, -1.0, 1.0]),  # half turn
                                                   board.object_points.max(axis=0)))
        reproj = P.project(transform_points(det.cam_T_target, det.object_points), intr)
        assert np.abs(reproj - det.corners_px).max() < 1.0
        assert translation_error(det.cam_T_target, expected) < 3e-3
        assert rotation_error_deg(det.cam_T_target, expected) < 1.0


# --------------------------------------------------------------------------- chess board and pieces


def _overview(cell, square=0.05, height=0.63):
    truth = cell.truth
    centre = transform_points(truth.base_T_world, [[4 * square, 4 * square, 0]])[0]
    base_T_cam = make_pose(np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]]),
                           centre + [0, 0, height])
    cell.robot.move_to(base_T_cam @ invert(truth.flange_T_cam), speed=0.25)
    return cell.camera.capture()


@pytest.mark.parametrize("seed, position, lighting", [
    (0, "start", "default"), (0, "random", "side"), (1, "start", "dim"),
    (2, "start", "overhead"), (2, "random", "dim"), (3, "start", "side"),
])
def test_board_and_every_piece_found_on_seeded_boards(seed, position, lighting):
    with create_workcell(scene="chess", seed=seed, chess_position=position, lighting=lighting,
                         width=320, height=240) as cell:
        truth, intr = cell.truth, cell.camera.intrinsics
        frame = _overview(cell)
        board = P.detect_chess_board(frame, intr, 0.05,
                                     white_side_cam=invert(truth.base_T_cam_now())[:3, 3])
        assert board is not None
        expected = compose(invert(truth.base_T_cam_now()), truth.base_T_world)
        assert translation_error(board.cam_T_chess, expected) < 3e-3
        assert rotation_error_deg(board.cam_T_chess, expected) < 1.0
        pieces = SP.detect_pieces(frame, intr, board.cam_T_chess, 0.05)
        found = {p.square: p.colour for p in pieces}
        assert found == {sq: t.colour for sq, t in truth.pieces.items()}


def test_touching_pieces_are_split():
    crowd = {"d4": ("queen", "white"), "e4": ("king", "black"), "d5": ("king", "white"),
             "e5": ("queen", "black"), "a1": ("king", "white"), "h8": ("king", "black")}
    with create_workcell(scene="chess", seed=0, chess_position=crowd, width=320,
                         height=240) as cell:
        frame = _overview(cell)
        board = P.detect_chess_board(frame, cell.camera.intrinsics, 0.05,
                                     white_side_cam=invert(cell.truth.base_T_cam_now())[:3, 3])
        pieces = SP.detect_pieces(frame, cell.camera.intrinsics, board.cam_T_chess, 0.05)
        assert {p.square: (p.kind, p.colour) for p in pieces} == crowd


def test_chess_board_not_found_gives_none():
    blank = Frame(np.full((240, 320, 3), 128, np.uint8), None, 0.0)
    assert P.detect_chess_board(blank, DIST.scaled(320, 240), 0.05) is None


# --------------------------------------------------------------------------- rectangle, flange


def test_rectangle_pose_is_exact_without_noise_and_stable_with_it():
    intr = DIST
    cam_T_rect = compose(make_pose(t=[0.03, -0.02, 0.6]), pose_from_rotvec([0.4, -0.3, 0.2]))
    w, h = 0.12, 0.08
    corners = P.project(transform_points(cam_T_rect, [[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0],
                                                      [w / 2, h / 2, 0], [-w / 2, h / 2, 0]]), intr)
    est = SP.rectangle_pose(corners, w, h, intr)
    assert translation_error(est, cam_T_rect) < 1e-9 and rotation_error_deg(est, cam_T_rect) < 1e-6
    stats = SP.rectangle_pose_stability(cam_T_rect, w, h, intr, noise_px=0.5, trials=100)
    rect, pnp = stats["rectangle"], stats["pnp_iterative"]
    assert rect["failures"] == 0 and pnp["failures"] == 0
    # Measured (200 trials): rectangle 10.9 mm / 5.1 deg (12.5 / 5.8 before rectangle_pose
    # refined the closed form's rare answers that miss their corners by over 6 x the noise),
    # solvePnP 3.9 mm / 1.4 deg rms. The closed-form shape constraint is fast and needs no
    # start but is several times noisier than the (maximum-likelihood) PnP refinement, which
    # is what this comparison teaches.
    assert rect["translation_mm"] < 6 * pnp["translation_mm"]
    assert rect["rotation_deg"] < 6 * pnp["rotation_deg"]
    assert pnp["translation_mm"] < rect["translation_mm"]
    with pytest.raises(ValueError, match="4 corners"):
        SP.rectangle_pose(corners[:3], w, h, intr)


def _disc_depth(intr, cam_T_disc, radius, background_z, rng, noise=0.0003):
    """Depth image of a disc (the flange face) in front of a plane, by ray casting."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    xy = cv2.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2).astype(float), intr.K,
                             intr.dist).reshape(intr.height, intr.width, 2)
    rays = np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=2)
    n, c = cam_T_disc[:3, 2], cam_T_disc[:3, 3]
    s = (c @ n) / (rays @ n)
    hit = rays * s[..., None]
    inside = np.linalg.norm(hit - c, axis=2) < radius
    depth = np.where(inside, hit[..., 2], background_z)
    return (depth + rng.normal(0, noise, depth.shape)).astype(np.float32)


def test_flange_centre_from_depth_without_a_marker():
    intr = DIST.scaled(320, 240)
    rng = np.random.default_rng(0)
    cam_T_disc = compose(make_pose(t=[0.02, -0.01, 0.35]), pose_from_rotvec([0.3, 0.2, 0.0]))
    depth = _disc_depth(intr, cam_T_disc, 0.0315, 0.6, rng)
    for radius in (None, 0.0315):
        fit = SP.fit_flange(depth, intr, radius_m=radius)
        assert np.linalg.norm(fit.centre - cam_T_disc[:3, 3]) < 1.5e-3
        assert abs(fit.radius - 0.0315) < 1.5e-3
        assert abs(abs(fit.normal @ cam_T_disc[:3, 2]) - 1) < 1e-3

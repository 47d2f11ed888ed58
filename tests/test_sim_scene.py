"""Scene objects: targets OpenCV detects at true scale and pose, the chess set and its truth."""

import cv2
import numpy as np
import pybullet as p
import pytest

from robots.geometry import (
    compose,
    make_pose,
    pose_from_rotvec,
    pose_from_rpy,
    rotation_error_deg,
    translation_error,
)
from robots.interfaces import Intrinsics
from sim_backends import scene, textures
from sim_backends.camera import SimCamera

INTR = Intrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
SUBPIX = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)


@pytest.fixture
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _view(client, target, cam_T_target):
    """Render a target placed at cam_T_target in front of a camera at the world origin."""
    body = scene.add_target(client, target, cam_T_target)
    rgb, _, _ = SimCamera(client, INTR, world_T_cam=np.eye(4)).render()
    p.removeBody(body, physicsClientId=client)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def _pnp(object_points, image_points, flags=cv2.SOLVEPNP_ITERATIVE):
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, INTR.K, None, flags=flags)
    assert ok
    return pose_from_rotvec(rvec.ravel(), tvec.ravel())


def _project(cam_T_target, pts):
    rv = cv2.Rodrigues(cam_T_target[:3, :3])[0]
    return cv2.projectPoints(pts, rv, cam_T_target[:3, 3], INTR.K, None)[0].reshape(-1, 2)


def _poses_at_half_a_metre(seed, n, centre_xy):
    """Seeded target poses about 0.5 m in front of the camera, tilted up to ~20 degrees."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        rpy = rng.uniform(-0.35, 0.35, 3)
        xy = np.asarray(centre_xy) + rng.uniform(-0.02, 0.02, 2)
        yield pose_from_rpy(*rpy, t=[xy[0], xy[1], rng.uniform(0.47, 0.53)])


def test_chessboard_found_and_pnp_matches_truth(client):
    target = textures.chessboard()  # 9x7 squares of 39 mm
    assert target.pattern_size == (8, 6)
    assert target.object_points[1, 0] == pytest.approx(0.039)
    for cam_T_target in _poses_at_half_a_metre(0, 4, (-0.136, -0.097)):
        gray = _view(client, target, cam_T_target)
        ok, corners = cv2.findChessboardCorners(gray, target.pattern_size)
        assert ok
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), SUBPIX).reshape(-1, 2)
        pred = _project(cam_T_target, target.object_points)
        # The 9x7 board is 180-degree symmetric, so OpenCV may list corners from either end.
        if np.linalg.norm(corners[0] - pred[0]) > np.linalg.norm(corners[-1] - pred[0]):
            corners = corners[::-1]
        assert np.linalg.norm(corners - pred, axis=1).mean() < 0.15
        est = _pnp(target.object_points, corners)
        assert translation_error(est, cam_T_target) < 1e-3
        assert rotation_error_deg(est, cam_T_target) < 0.2


@pytest.mark.parametrize("squares", [(8, 7), (9, 6)])
def test_chessboard_texture_is_not_mirrored(client, squares):
    """The default 9x7 board looks the same mirrored or turned, so its corners cannot reveal a
    flipped texture; boards with an even side can. The square before the first inner corner
    (top-left) is black; an 8x7 board's top-right square is white (catches an x mirror and a
    180-degree turn), a 9x6 board's bottom-left square is white (catches a y mirror)."""
    nx, ny = squares
    target = textures.chessboard(squares=squares)
    cam_T_target = pose_from_rpy(0.2, -0.1, 0.3, t=[-0.12, -0.1, 0.5])
    gray = _view(client, target, cam_T_target)
    s = 0.039
    # Centres of the four corner squares: TL, TR, BL, BR, in the target frame.
    xs, ys = (-s / 2, (nx - 1.5) * s), (-s / 2, (ny - 1.5) * s)
    centres = np.array([[x, y, 0.0] for y in ys for x in xs])
    uv = np.rint(_project(cam_T_target, centres)).astype(int)
    dark = gray[uv[:, 1], uv[:, 0]] < 60
    expected = [((0 + 0) % 2 == 0), ((nx - 1) % 2 == 0), ((ny - 1) % 2 == 0),
                ((nx - 1 + ny - 1) % 2 == 0)]
    assert dark.tolist() == expected


def test_charuco_detected_and_pnp_matches_truth(client):
    target = textures.charuco()
    detector = cv2.aruco.CharucoDetector(target.board)
    for cam_T_target in _poses_at_half_a_metre(1, 3, (-0.14, -0.1)):
        gray = _view(client, target, cam_T_target)
        corners, ids, _, _marker_ids = detector.detectBoard(gray)
        assert ids is not None and len(ids) >= 20, "ChArUco corners not detected"
        ids = ids.ravel()
        pred = _project(cam_T_target, target.object_points[ids])
        # ChArUco ids are unique: a mirrored or turned texture would fail right here.
        assert np.linalg.norm(corners.reshape(-1, 2) - pred, axis=1).max() < 0.5
        est = _pnp(target.object_points[ids], corners.reshape(-1, 2))
        assert translation_error(est, cam_T_target) < 1e-3
        assert rotation_error_deg(est, cam_T_target) < 0.2


def test_aruco_marker_id_and_corners(client):
    target = textures.aruco_marker(marker_id=7, size=0.08)
    # The marker frame's z points out of the board, towards the camera.
    cam_T_target = pose_from_rpy(np.pi + 0.2, 0.25, 0.4, t=[0.02, -0.01, 0.45])
    gray = _view(client, target, cam_T_target)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(target.dictionary),
                                       params)
    corners, ids, _ = detector.detectMarkers(gray)
    assert ids is not None and ids.ravel().tolist() == [7]
    pred = _project(cam_T_target, target.object_points)
    assert np.linalg.norm(corners[0].reshape(-1, 2) - pred, axis=1).max() < 0.5
    est = _pnp(target.object_points, corners[0].reshape(-1, 2), cv2.SOLVEPNP_IPPE_SQUARE)
    assert translation_error(est, cam_T_target) < 2e-3


def test_circle_grid_found_at_true_positions(client):
    target = textures.circle_grid()
    cam_T_target = pose_from_rpy(0.15, -0.2, 0.05, t=[-0.1, -0.1, 0.5])
    gray = _view(client, target, cam_T_target)
    ok, centres = cv2.findCirclesGrid(gray, target.pattern_size,
                                      flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
    assert ok
    pred = _project(cam_T_target, target.object_points)
    assert np.linalg.norm(centres.reshape(-1, 2) - pred, axis=1).max() < 0.5
    est = _pnp(target.object_points, centres.reshape(-1, 2))
    assert translation_error(est, cam_T_target) < 1e-3
    assert rotation_error_deg(est, cam_T_target) < 0.2


def test_target_arguments_are_checked():
    with pytest.raises(ValueError, match="marker"):
        textures.charuco(square=0.03, marker=0.04)
    with pytest.raises(ValueError, match="squares"):
        textures.chessboard(squares=(1, 7))
    with pytest.raises(ValueError, match="marker_id"):
        textures.aruco_marker(marker_id=1000)
    with pytest.raises(ValueError, match="overlap"):
        textures.circle_grid(spacing=0.01, diameter=0.02)


# --------------------------------------------------------------------------- chess


def test_square_names_round_trip():
    assert scene.square_index("a1") == (0, 0)
    assert scene.square_index("h8") == (7, 7)
    assert scene.square_name(4, 3) == "e4"
    with pytest.raises(ValueError, match="a1"):
        scene.square_index("i9")


def test_chess_set_truth_follows_the_pieces(client):
    p.setGravity(0, 0, -9.81, physicsClientId=client)
    scene.add_table(client)
    world_T_chess = pose_from_rpy(0, 0, 0.1, t=[0.3, -0.2, 0.0])
    chess = scene.ChessSet(client, world_T_chess)
    for _ in range(240):  # one simulated second: nothing may topple or slide
        p.stepSimulation(physicsClientId=client)
    pieces = chess.pieces()
    assert len(pieces) == 32
    assert set(pieces) == set(scene.START_POSITION)
    for sq, (kind, colour) in scene.START_POSITION.items():
        k, c, world_T_piece = pieces[sq]
        assert (k, c) == (kind, colour)
        expected = chess.world_T_square(sq)
        assert translation_error(world_T_piece, expected) < 1e-3
        assert world_T_piece[2, 2] > 0.9999, f"piece on {sq} tilted"
    # Move the e2 pawn to e4 by hand: the truth now says e4.
    body = pieces["e2"].body_id
    scene.set_pose_of_body(client, body, chess.world_T_square("e4"))
    after = chess.pieces()
    assert "e2" not in after and after["e4"].kind == "pawn" and after["e4"].colour == "white"
    lifted = compose(chess.world_T_square("e4"), make_pose(t=[0, 0, 0.1]))
    scene.set_pose_of_body(client, body, lifted)
    assert f"lifted:{body}" in chess.pieces()
    # In the robot base frame when base_T_world is given.
    base_T_world = make_pose(t=[-0.1, 0.0, 0.0])
    assert np.allclose(chess.pieces(base_T_world)["a1"].base_T_piece,
                       base_T_world @ pieces["a1"].base_T_piece)


def test_chess_board_square_a1_is_dark_and_pieces_have_distinct_shapes(client):
    world_T_chess = make_pose(t=[-0.2, -0.2, 0.0])
    chess = scene.ChessSet(client, world_T_chess, position={"h8": ("king", "black")})
    # A camera 0.8 m above the board looking straight down, image top towards +y (rank 8).
    world_T_cam = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.8])
    cam = SimCamera(client, INTR, world_T_cam=world_T_cam)
    rgb, _, _ = cam.render()
    uv = np.rint(cam.project([chess.world_T_square(s)[:3, 3] for s in ("a1", "b1")])).astype(int)
    a1, b1 = (rgb[v, u].astype(int).sum() for u, v in uv)
    assert a1 < b1 - 100, "a1 must be a dark square"
    heights = scene.PIECE_HEIGHT
    assert len(set(np.round(list(heights.values()), 4))) == len(heights)


def test_random_position_is_seeded_and_sane():
    a = scene.random_position(np.random.default_rng(3), 16)
    b = scene.random_position(np.random.default_rng(3), 16)
    assert a == b and len(a) == 16
    assert sorted(v for v in a.values() if v[0] == "king") == [("king", "black"), ("king", "white")]
    assert not any(kind == "pawn" and sq[1] in "18" for sq, (kind, _) in a.items())

"""`cobotlab data import`: captures made elsewhere (a pose text file and corners or images)
become capture folders that `cobotlab calibrate` solves, printing the held-out error."""

from __future__ import annotations

from importlib import resources

import cv2
import numpy as np
import pytest

from autograder.datasets import load_rwhe_kuka
from autograder.synthetic import Board, make_hand_eye
from cobotlab import cli
from robots import geometry as geo
from robots.capture import import_pose_text_capture, load_capture, read_pose_text, save_capture


def _kuka_file(sequence, name):
    return resources.files("autograder").joinpath("data", "rwhe_kuka", sequence, name)


def test_a_pose_text_file_reads_as_row_major_base_T_flange(tmp_path):
    with resources.as_file(_kuka_file("kuka_1", "RobotPosesVec.txt")) as path:
        poses = read_pose_text(path)
    assert np.array_equal(poses, load_rwhe_kuka("kuka_1").base_T_flange)
    commas = tmp_path / "poses.csv"
    commas.write_text("# x y z\n" + "\n".join(", ".join(f"{v:.12g}" for v in T.ravel())
                                              for T in poses[:3]) + "\n")
    assert np.allclose(read_pose_text(commas), poses[:3])


@pytest.mark.parametrize("text, message", [
    ("1 2 3 4 5 6 7\n", "7 numbers, expected 16"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0.5 0.2 0.1 1\n", "column-major"),
    ("1 0 0 a\n", "not a list of numbers"),
    ("# only a comment\n", "holds no poses"),
])
def test_a_bad_pose_file_is_refused_with_the_line_and_the_fix(tmp_path, text, message):
    path = tmp_path / "poses.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_pose_text(path)


def test_corners_import_calibrates_the_camera_and_round_trips(tmp_path):
    with resources.as_file(_kuka_file("kuka_3", "RobotPosesVec.txt")) as poses, \
            resources.as_file(_kuka_file("kuka_3", "corners.npz")) as corners:
        capture = import_pose_text_capture(poses, corners_file=corners, robot_name="KUKA")
    assert len(capture) == 29 and capture.images == []
    # The data README's calibrateCamera result on all views.
    i = capture.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy) == pytest.approx((2065.9, 2065.8, 961.7, 611.3), abs=0.2)
    folder = save_capture(capture, tmp_path / "cap")
    back = load_capture(folder)
    assert np.array_equal(back.base_T_flange, capture.base_T_flange)
    assert np.array_equal(back.corners_px[5], capture.corners_px[5])
    assert back.images == []


def test_cobotlab_data_import_then_calibrate_prints_the_held_out_error(tmp_path, capsys):
    with resources.as_file(_kuka_file("kuka_3", "RobotPosesVec.txt")) as poses, \
            resources.as_file(_kuka_file("kuka_3", "corners.npz")) as corners:
        assert cli.main(["data", "import", str(poses), str(tmp_path / "cap"),
                         "--corners", str(corners)]) == 0
    assert "imported 29 views" in capsys.readouterr().out
    assert cli.main(["calibrate", str(tmp_path / "cap"), "--method", "park"]) == 0
    out = capsys.readouterr().out
    line = next(text for text in out.splitlines() if text.startswith("held-out error"))
    median = float(line.split("median ")[1].split(" px")[0])
    # benchmarks/handeye_real.py: about 2 px for PARK on kuka_3 (robot pose error at 1.5-2 m).
    assert 1.0 < median < 3.5


def _render(camera, board: Board, cam_T_target, margin_squares=1):
    """A grey image of a chessboard (board.cols x board.rows inner corners) seen at cam_T_target."""
    px_per_square = 40
    cols, rows = board.cols + 1 + 2 * margin_squares, board.rows + 1 + 2 * margin_squares
    texture = np.full((rows * px_per_square, cols * px_per_square), 255, np.uint8)
    for r in range(margin_squares, rows - margin_squares):
        for c in range(margin_squares, cols - margin_squares):
            if (r + c) % 2 == 0:
                texture[r * px_per_square:(r + 1) * px_per_square,
                        c * px_per_square:(c + 1) * px_per_square] = 0
    # Texture pixel (u, v) -> board point: the first inner corner is at texture corner
    # (margin + 1) squares in, each texture pixel square_m / px_per_square metres.
    scale = board.square_m / px_per_square
    offset = (margin_squares + 1) * board.square_m
    T = np.array([[scale, 0, -offset], [0, scale, -offset], [0, 0, 1.0]])
    H = camera.K @ cam_T_target[:3, [0, 1, 3]] @ T
    grey = cv2.warpPerspective(texture, H, (camera.width, camera.height), borderValue=128)
    return np.repeat(grey[:, :, None], 3, axis=2)


def test_images_import_detects_the_board_and_matches_the_truth(tmp_path, capsys):
    # Seed 1: no view rolls the half-turn-symmetric board past 90 deg, where the chessboard
    # detector's left-to-right rule would number its corners from the other end.
    p = make_hand_eye(1, "eye_in_hand", n_poses=8)
    images = tmp_path / "images"
    images.mkdir()
    for k, T in enumerate(p.true_cam_T_target):
        cv2.imwrite(str(images / f"im_{k:02d}.png"), _render(p.camera, p.board, T))
    poses = tmp_path / "poses.txt"
    poses.write_text("\n".join(" ".join(f"{v:.15g}" for v in T.ravel()) for T in p.base_T_flange))
    board = f"{p.board.cols}x{p.board.rows}:{p.board.square_m * 1000:g}"
    assert cli.main(["data", "import", str(poses), str(tmp_path / "cap"), "--images", str(images),
                     "--board", board]) == 0
    capture = load_capture(tmp_path / "cap")
    assert len(capture) == 8 and len(capture.images) == 8
    assert capture.intrinsics.fx == pytest.approx(p.camera.K[0, 0], rel=0.02)
    assert cli.main(["calibrate", str(tmp_path / "cap")]) == 0
    out = capsys.readouterr().out
    assert "held-out error" in out
    from robots.calibration_io import load_calibration

    X = load_calibration(tmp_path / "cap" / "flange_T_cam.yaml").pose
    assert geo.translation_error(X, p.X_true) < 0.005


def test_images_import_needs_the_board_size(tmp_path, capsys):
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n")
    assert cli.main(["data", "import", str(poses), str(tmp_path / "cap"),
                     "--images", str(tmp_path)]) == 2
    assert "--board COLSxROWS:SQUARE_MM" in capsys.readouterr().err


def test_calibrate_method_corners_fits_the_corners_and_prints_the_chosen_model(tmp_path, capsys):
    """`--method corners` runs the corner-based default on an imported real capture (one
    board for all views, though a view may see only part of it) and predicts held-out views
    better than PARK at the tail, as benchmarks/handeye_real.py measures on kuka_3 (p95 3.3
    against 3.8 px, paired interval below 1)."""
    with resources.as_file(_kuka_file("kuka_3", "RobotPosesVec.txt")) as poses, \
            resources.as_file(_kuka_file("kuka_3", "corners.npz")) as corners:
        capture = import_pose_text_capture(poses, corners_file=corners, robot_name="KUKA")
    # A board partly out of view: this view sees a different subset of the corners.
    capture.corners_px[5] = capture.corners_px[5][10:]
    capture.object_points[5] = capture.object_points[5][10:]
    folder = save_capture(capture, tmp_path / "cap")

    def held_out_p95(out):
        line = next(text for text in out.splitlines() if text.startswith("held-out error"))
        return float(line.split("p95 ")[1].split(" px")[0])

    assert cli.main(["calibrate", str(folder), "--method", "park"]) == 0
    park = held_out_p95(capsys.readouterr().out)
    assert cli.main(["calibrate", str(folder), "--method", "corners"]) == 0
    out = capsys.readouterr().out
    assert "corner fit: " in out and "chosen by held-out views" in out
    assert "a calibration without it, the chosen model kept" in out
    assert held_out_p95(out) < 0.95 * park
    from robots.calibration_io import load_calibration

    saved = load_calibration(folder / "flange_T_cam.yaml")
    assert saved.method == "corners"


def test_calibrate_method_corners_refuses_views_without_enough_corners(tmp_path, capsys):
    with resources.as_file(_kuka_file("kuka_3", "RobotPosesVec.txt")) as poses, \
            resources.as_file(_kuka_file("kuka_3", "corners.npz")) as corners:
        capture = import_pose_text_capture(poses, corners_file=corners)
    capture.corners_px[3] = capture.corners_px[3][:3]
    capture.object_points[3] = capture.object_points[3][:3]
    folder = save_capture(capture, tmp_path / "cap")
    assert cli.main(["calibrate", str(folder), "--method", "corners"]) == 2
    assert "at least 4 detected corners in every view" in capsys.readouterr().err

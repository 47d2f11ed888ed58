"""capture_pose_pairs and capture folders: on the stand-in gantry, then in the PyBullet sim."""

import importlib.util

import cv2
import numpy as np
import pytest
from contract import make_gantry_cell

from robots import Detection, SafetyError, capture_pose_pairs, load_capture
from robots.capture import Capture, chessboard_detector, save_capture
from robots.geometry import (
    compose,
    invert,
    make_pose,
    pose_from_rotvec,
    rotation_error_deg,
    translation_error,
)

detect_board = chessboard_detector(8, 5, 0.02)


def gantry_poses(cell):
    """Seven views aimed at the board centre from 0.35-0.45 m with 17-40 degree tilts, then one
    looking away and one beyond the gantry's travel (inserted at indices 3 and 4)."""
    camera = cell.camera
    base_T_centre = camera.base_T_board @ make_pose(t=[0.07, 0.04, 0.0])
    views = [
        ([0, 0, 0], 0.40),
        ([0.4, 0, 0], 0.42),
        ([-0.35, 0.2, 0.1], 0.38),
        ([0, 0.4, 0.6], 0.45),
        ([0.25, -0.35, -0.5], 0.40),
        ([0.3, 0.3, 0.7], 0.35),
        ([-0.3, -0.3, -0.3], 0.40),
    ]
    poses = [
        base_T_centre @ invert(pose_from_rotvec(r, [0, 0, d])) @ invert(camera.flange_T_cam)
        for r, d in views
    ]
    away = poses[0].copy()
    away[:3, 3] += [0.3, 0.25, 0.0]  # the board leaves the image
    out_of_travel = poses[0].copy()
    out_of_travel[0, 3] = 0.62  # inside the safety box, beyond the 0.6 m gantry
    return poses[:3] + [away, out_of_travel] + poses[3:]


def assert_captures_identical(a: Capture, b: Capture):
    for name in (
        "base_T_flange",
        "cam_T_target",
        "commanded_base_T_flange",
        "pose_indices",
        "timestamps",
        "failed_indices",
    ):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=True), name
    for name in ("corners_px", "object_points", "images"):
        xs, ys = getattr(a, name), getattr(b, name)
        assert len(xs) == len(ys), name
        for x, y in zip(xs, ys):
            assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert len(a.failed_images) == len(b.failed_images)
    for x, y in zip(a.failed_images, b.failed_images):
        assert (x is None and y is None) or np.array_equal(x, y)
    assert (a.depths is None) == (b.depths is None)
    if a.depths is not None:
        assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a.depths, b.depths))
    assert a.intrinsics == b.intrinsics
    assert (a.failed_reasons, a.robot_name, a.camera_name, a.created) == (
        b.failed_reasons,
        b.robot_name,
        b.camera_name,
        b.created,
    )


# --------------------------------------------------------------------------- stand-in gantry


def test_capture_records_read_back_poses_detections_and_failures(tmp_path):
    # A 0.1 mm / 0.1 mrad encoder resolution: the arm never reports exactly the commanded pose.
    with make_gantry_cell(resolution=1e-4) as cell:
        robot, camera = cell.robot, cell.camera
        poses = gantry_poses(cell)
        cap = capture_pose_pairs(
            robot, camera, poses, detect_board, folder=tmp_path / "cap", progress=False
        )
        # Ground truth, computed independently of the capture code from the stand-in's scene.
        quantised = [np.round(robot._ik(poses[k]) / 1e-4) * 1e-4 for k in (0, 1, 2, 5, 6, 7, 8)]
        true_cam_T_board = [
            invert(compose(robot._fk(q), camera.flange_T_cam)) @ camera.base_T_board
            for q in quantised
        ]

    assert len(cap) == 7 and list(cap.pose_indices) == [0, 1, 2, 5, 6, 7, 8]
    assert list(cap.failed_indices) == [3, 4]
    assert cap.failed_reasons[0] == "target not detected"
    assert cap.failed_reasons[1].startswith("unreachable: gantry joint 0")
    assert cap.failed_images[0].shape == (480, 640, 3) and cap.failed_images[1] is None
    commanded = cap.commanded_base_T_flange[cap.pose_indices]
    assert np.array_equal(cap.commanded_base_T_flange, np.array(poses))
    # Read back, not commanded: they differ by the encoder quantisation and no more.
    assert not np.array_equal(cap.base_T_flange, commanded)
    assert translation_error(cap.base_T_flange, commanded).max() < 1e-4
    K = camera.intrinsics.K
    for i in range(len(cap)):
        # Detected corners sit where the true view projects them (a mispaired view is pixels off).
        T = true_cam_T_board[i]
        projected, _ = cv2.projectPoints(
            cap.object_points[i], cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, None
        )
        assert np.abs(projected.reshape(-1, 2) - cap.corners_px[i]).mean() < 0.1
        assert translation_error(cap.cam_T_target[i], T) < 1e-3
        assert cap.corners_px[i].shape == (40, 2) and cap.object_points[i].shape == (40, 3)
    assert cap.robot_name == "gantry" and cap.camera_name == "board_cam"

    reloaded = load_capture(tmp_path / "cap")
    assert_captures_identical(cap, reloaded)
    assert sorted(p.name for p in (tmp_path / "cap" / "images").iterdir()) == [
        "failed_003.png",
        "view_000.png",
        "view_001.png",
        "view_002.png",
        "view_005.png",
        "view_006.png",
        "view_007.png",
        "view_008.png",
    ]


def test_the_capture_is_real_hand_eye_data(tmp_path):
    """OpenCV's hand-eye solver recovers the stand-in's flange_T_cam from the capture."""
    with make_gantry_cell() as cell:
        cap = capture_pose_pairs(
            cell.robot, cell.camera, gantry_poses(cell), detect_board, progress=False
        )
        truth = cell.camera.flange_T_cam
    base_T_flange, cam_T_target = cap.pose_pairs()
    R, t = cv2.calibrateHandEye(
        base_T_flange[:, :3, :3],
        base_T_flange[:, :3, 3],
        cam_T_target[:, :3, :3],
        cam_T_target[:, :3, 3],
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    estimate = np.eye(4)
    estimate[:3, :3], estimate[:3, 3] = R, t.ravel()
    assert translation_error(estimate, truth) < 1e-3
    assert rotation_error_deg(estimate, truth) < 0.1


def test_save_and_load_preserve_odd_values_exactly(tmp_path):
    """Ragged corner counts, a view without a pose, depth and awkward floats survive a reload."""
    rng = np.random.default_rng(3)
    from robots import Intrinsics

    intr = Intrinsics(612.123456789, 611.5, 320.25, 239.75, 64, 48, [0.1, -0.2, 1e-4, -1e-4, 0.05])
    cam_T = np.stack([pose_from_rotvec(rng.normal(size=3), rng.normal(size=3)) for _ in range(3)])
    cam_T[1] = np.nan  # the detector gave corners but no pose
    cap = Capture(
        base_T_flange=np.stack(
            [pose_from_rotvec(rng.normal(size=3), rng.normal(size=3) / 3) for _ in range(3)]
        ),
        cam_T_target=cam_T,
        corners_px=[rng.normal(size=(n, 2)) * 100 for n in (5, 1, 12)],
        object_points=[rng.normal(size=(n, 3)) for n in (5, 1, 12)],
        intrinsics=intr,
        commanded_base_T_flange=np.stack([np.eye(4)] * 4),
        pose_indices=np.array([0, 2, 3]),
        timestamps=np.array([0.1, 1 / 3, 1e-9]),
        images=[rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8) for _ in range(3)],
        failed_indices=np.array([1]),
        failed_reasons=["target not detected: glare, 'quotes' and: colons"],
        failed_images=[rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)],
        depths=[rng.random((48, 64)).astype(np.float32) for _ in range(3)],
        robot_name="ur5e",
        camera_name="d435",
        created="2024-05-01T10:00:00+00:00",
    )
    save_capture(cap, tmp_path)
    back = load_capture(tmp_path)
    assert_captures_identical(cap, back)
    pairs = back.pose_pairs()
    assert len(pairs[0]) == 2 and np.array_equal(pairs[1], cam_T[[0, 2]])
    with pytest.raises(FileExistsError, match="overwrite=True"):
        save_capture(cap, tmp_path)
    save_capture(cap, tmp_path, overwrite=True)
    assert_captures_identical(cap, load_capture(tmp_path))


def test_progress_bar_and_argument_checks(tmp_path, capsys):
    with make_gantry_cell() as cell:
        start = cell.robot.flange_pose()
        capture_pose_pairs(cell.robot, cell.camera, [start], detect_board, progress=True)
        assert "capture" in capsys.readouterr().err
        with pytest.raises(ValueError, match=r"poses\[0\]"):
            capture_pose_pairs(cell.robot, cell.camera, [np.full((4, 4), np.nan)], detect_board)
        with pytest.raises(ValueError, match="at least 1"):
            capture_pose_pairs(cell.robot, cell.camera, [], detect_board)
        with pytest.raises(ValueError, match="detector must be a callable"):
            capture_pose_pairs(cell.robot, cell.camera, [start], "chessboard")
        with pytest.raises(ValueError, match="without depth"):
            capture_pose_pairs(
                cell.robot, cell.camera, [start], detect_board, keep_depth=True, progress=False
            )
        far = start.copy()
        far[0, 3] += 0.55
        with pytest.raises(SafetyError, match="max_step"):  # a bad pose list is not skipped
            capture_pose_pairs(cell.robot, cell.camera, [start, far], detect_board, progress=False)
        capture_pose_pairs(
            cell.robot, cell.camera, [start], detect_board, folder=tmp_path, progress=False
        )
        with pytest.raises(FileExistsError):
            capture_pose_pairs(
                cell.robot, cell.camera, [start], detect_board, folder=tmp_path, progress=False
            )
    with pytest.raises(FileNotFoundError, match="poses.npz"):
        load_capture(tmp_path / "nothing")


def test_detection_validation():
    with pytest.raises(ValueError, match="correspond"):
        Detection(None, np.zeros((4, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        Detection(None, np.full((1, 2), np.nan), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="cam_T_target"):
        Detection(np.zeros((4, 4)), np.zeros((1, 2)), np.zeros((1, 3)))


# --------------------------------------------------------------------------- PyBullet sim

needs_sim = pytest.mark.skipif(
    any(importlib.util.find_spec(m) is None for m in ("sim_backends.world", "sim_backends.tools")),
    reason="the sim backend (sim_backends/world.py and tools.py) is not installed",
)


@needs_sim
@pytest.mark.slow
def test_capture_in_the_sim_round_trips_and_matches_truth(tmp_path):
    from robots import connect

    with connect("sim", arm="panda", mount="eye_in_hand", seed=0, encoder_noise_deg=0.05) as cell:
        robot, camera, truth = cell.robot, cell.camera, cell.truth
        start = robot.flange_pose()
        offsets = [
            ([0, 0, 0], [0, 0, 0]),
            ([0.15, 0, 0], [0, 0.03, 0]),
            ([0, -0.15, 0.1], [0.03, 0, 0]),
            ([-0.1, 0.1, -0.2], [0, -0.03, 0.02]),
        ]
        poses = [start @ pose_from_rotvec(r, t) for r, t in offsets]
        detector = chessboard_detector(*truth.board.pattern_size, truth.board.params["square"])
        true_cam_T_board, reported = [], []

        def detect_and_record(frame, intrinsics):
            true_cam_T_board.append(invert(truth.base_T_cam_now()) @ truth.base_T_board)
            reported.append(robot.flange_pose())
            return detector(frame, intrinsics)

        cap = capture_pose_pairs(
            robot,
            camera,
            poses,
            detect_and_record,
            folder=tmp_path,
            progress=False,
            keep_depth=True,
        )
    assert len(cap) == 4, cap.failed_reasons
    # The encoders are off by ~0.05 deg: the capture holds what the robot reported.
    assert np.array_equal(cap.base_T_flange, np.array(reported))
    assert translation_error(cap.base_T_flange, cap.commanded_base_T_flange).max() < 5e-4
    for i in range(4):
        assert translation_error(cap.cam_T_target[i], true_cam_T_board[i]) < 1e-3
        assert rotation_error_deg(cap.cam_T_target[i], true_cam_T_board[i]) < 0.2
    assert_captures_identical(cap, load_capture(tmp_path))


def test_a_malformed_target_record_is_refused_by_name(tmp_path):
    from robots.capture import TargetRecord

    record = TargetRecord("chessboard", {"inner_cols": 9, "inner_rows": 6, "square_m": 0.02},
                          True)
    assert TargetRecord.from_dict(record.to_dict()) == record
    for bad in ("chessboard", {"kind": 3}, {"kind": "chessboard", "half_turn_ambiguous": "yes"},
                {"kind": "chessboard", "geometry": [9, 6]}):
        with pytest.raises(ValueError, match="meta.yaml's target must be a mapping with kind"):
            TargetRecord.from_dict(bad, "cap/meta.yaml's target")

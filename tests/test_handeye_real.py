"""Real KUKA captures shipped with the package, the corner-based default and its noise-model
choice, and the import structure of the solvers."""

from __future__ import annotations

import ast
from pathlib import Path

import cv2
import numpy as np
import pytest

from autograder.datasets import RWHE_KUKA_SEQUENCES, load_rwhe_kuka
from autograder.synthetic import make_real_like_hand_eye
from robots import geometry as geo
from solutions import mle
from solutions.opencv_baseline import opencv_hand_eye

# Intrinsics from the data's README (cv2.calibrateCamera on all views of each sequence).
README_INTRINSICS = {
    "kuka_2": ((1056.3, 1056.4, 958.8, 586.9), (-0.131, 0.099, 0.0001, 0.0003, -0.049)),
}


@pytest.mark.parametrize("sequence, views, corners, square_m", [
    ("kuka_1", 30, 476, 0.020), ("kuka_2", 28, 408, 0.015), ("kuka_3", 29, 88, 0.060)])
def test_each_sequence_loads_as_its_readme_describes(sequence, views, corners, square_m):
    cap = load_rwhe_kuka(sequence)
    assert cap.base_T_flange.shape == (views, 4, 4)
    assert cap.pixels.shape == (views, corners, 2)
    assert cap.board_points_m.shape == (corners, 3)
    assert len(cap.image_names) == views and cap.mount == "eye_in_hand"
    geo.as_poses(cap.base_T_flange)  # proper rotations, finite
    assert np.all(np.isfinite(cap.pixels))
    assert np.all(cap.board_points_m[:, 2] == 0)
    spacing = np.linalg.norm(np.diff(cap.board_points_m[:2], axis=0))
    assert spacing == pytest.approx(square_m, rel=1e-6)  # ChArUco corners come as float32


def test_unknown_sequence_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="kuka_1"):
        load_rwhe_kuka("kuka_4")
    assert RWHE_KUKA_SEQUENCES == ("kuka_1", "kuka_2", "kuka_3")


def _pnp(cap, K, dist):
    poses = []
    for px in cap.pixels:
        ok, rvec, tvec = cv2.solvePnP(cap.board_points_m, px, K, dist)
        assert ok
        poses.append(geo.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel()))
    return np.array(poses)


def test_the_poses_are_base_T_flange_of_an_eye_in_hand_camera():
    """The README's check: with the poses as given, base_T_flange @ X @ cam_T_target is nearly
    constant (the board stands still); with them inverted it is not."""
    cap = load_rwhe_kuka("kuka_2")
    (fx, fy, cx, cy), dist = README_INTRINSICS["kuka_2"]
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    C = _pnp(cap, K, np.array(dist))

    def spread_mm(A):
        try:
            X = opencv_hand_eye(A, C, "eye_in_hand", "PARK")
        except ValueError as exc:   # OpenCV answered a reflection: no X fits these poses
            assert "not a rotation" in str(exc), exc
            return float("inf")
        t = (A @ X @ C)[:, :3, 3]
        return 1000 * float(np.median(np.linalg.norm(t - t.mean(axis=0), axis=1)))

    assert spread_mm(cap.base_T_flange) < 2.0
    assert spread_mm(geo.invert(cap.base_T_flange)) > 100.0


def _result(X, Y, scale=1.0):
    return mle.HandEyeRefinement(X=X, Y=Y, mount="eye_in_hand", rotation_sigma_rad=0.0,
                                 translation_sigma_m=0.0, weights=np.ones(1), outlier_indices=(),
                                 cost=0.0, n_iterations=0, converged=True, board_scale=scale)


def test_predicted_corners_go_through_the_robot_poses_and_the_board_scale():
    p = make_real_like_hand_eye(0, n_poses=6, robot_rot_deg=0, robot_trans_mm=0, robot_gain=0,
                                board_scale=0.95, pixel_px=0.0)
    board = p.board.object_points()
    predicted = mle.predicted_corners(_result(p.X_true, p.Y_true, 0.95), board, p.camera.K,
                                      p.camera.dist, p.base_T_flange)
    assert np.abs(predicted - p.pixels).max() < 1e-6
    unscaled = mle.predicted_corners(_result(p.X_true, p.Y_true), board, p.camera.K,
                                     p.camera.dist, p.base_T_flange)
    assert mle.view_rms_px(unscaled, p.pixels).min() > 1.0


def test_the_noise_model_is_chosen_by_held_out_views_and_finds_a_misprinted_board():
    """Board printed 5 % small, robot nearly exact: the held-out views pick the fit with the
    board's scale free, which recovers the scale and X far better than the fit that trusts
    the stated size."""
    p = make_real_like_hand_eye(3, n_poses=12, robot_rot_deg=0.002, robot_trans_mm=0.02,
                                robot_gain=0.0, board_scale=0.95, pixel_px=0.1)
    board = p.board.object_points()
    result, choices = mle.calibrate_from_corners(board, p.pixels, p.camera.K, p.camera.dist,
                                                 p.base_T_flange, cam_T_target=p.cam_T_target)
    assert len(choices) == 6 + len(mle.POSE_CANDIDATES)
    assert [c.held_out_px for c in choices] == sorted(c.held_out_px for c in choices)
    assert choices[0].method == "reprojection" and choices[0].fit_board_scale
    assert result.board_scale == pytest.approx(0.95, abs=0.002)
    start = mle.refine_hand_eye(p.base_T_flange, p.cam_T_target)
    fixed = mle.refine_reprojection(board, p.pixels, p.camera.K, p.camera.dist, p.base_T_flange,
                                    X0=start.X, Y0=start.Y, robot_sigma=(0.0, 0.0))
    chosen_mm = 1000 * geo.translation_error(result.X, p.X_true)
    assert chosen_mm < 0.25 * 1000 * geo.translation_error(fixed.X, p.X_true)
    assert chosen_mm < 2.0


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("method", ["pose_mle", "shah", "li"])
def test_pose_based_candidates_predict_exact_corners_for_both_mounts(mount, method):
    """A pose-based candidate's X and Y must mean what predicted_corners reads for the mount
    (eye-to-hand swaps the closed forms' X and Y): on exact data its prediction is exact."""
    from autograder.synthetic import NoiseModel, make_hand_eye
    p = make_hand_eye(4, mount, n_poses=8, noise=NoiseModel(pixel_px=1e-9))
    board = p.board.object_points()
    result, choices = mle.calibrate_from_corners(board, p.pixels, p.camera.K, p.camera.dist,
                                                 p.base_T_flange, mount, p.cam_T_target,
                                                 robot_weights=(), pose_candidates=(method,))
    assert [c.method for c in choices] == [method]
    assert choices[0].held_out_px < 1e-3
    assert geo.rotation_error_deg(result.X, p.X_true) < 1e-4
    predicted = mle.predicted_corners(result, board, p.camera.K, p.camera.dist, p.base_T_flange)
    assert mle.view_rms_px(predicted, p.pixels).max() < 1e-3
    assert result.reprojection_rms_px < 1e-3


def test_the_data_picks_a_pose_based_fit_when_the_pixels_are_biased_per_view():
    """Each view's corners shifted as a whole by several pixels (a per-view systematic error
    the corner fit cannot tell from the geometry) while the solvePnP poses are exact: a fit to
    the poses predicts held-out views better, and the cross-validation must find that."""
    p = make_real_like_hand_eye(5, n_poses=15, robot_rot_deg=0.0, robot_trans_mm=0.0,
                                robot_gain=0.0, board_scale=1.0, pixel_px=0.05)
    rng = np.random.default_rng(0)
    biased = p.pixels + rng.normal(0.0, 3.0, size=(len(p.pixels), 1, 2))
    board = p.board.object_points()
    result, choices = mle.calibrate_from_corners(board, biased, p.camera.K, p.camera.dist,
                                                 p.base_T_flange, cam_T_target=p.cam_T_target)
    assert choices[0].method in mle.POSE_CANDIDATES
    corner_only = min(c.held_out_px for c in choices if c.method == "reprojection")
    assert choices[0].held_out_px < corner_only
    assert geo.rotation_error_deg(result.X, p.X_true) < 0.05


def test_the_data_picks_refined_intrinsics_when_the_given_ones_are_off():
    """Intrinsics 1.5 % off in focal length and 5 px off in the principal point (what a
    calibration on few or poorly spread views gives): with ``fit_intrinsics=(False, True)``
    the held-out views choose a fit that refines them, it recovers K, and its held-out
    prediction (with the K it carries) beats every fit that kept the given K."""
    p = make_real_like_hand_eye(6, n_poses=12, robot_rot_deg=0.002, robot_trans_mm=0.02,
                                robot_gain=0.0, board_scale=1.0, pixel_px=0.1)
    board = p.board.object_points()
    K_off = np.asarray(p.camera.K, float).copy()
    K_off[0, 0] *= 1.015
    K_off[1, 1] *= 1.015
    K_off[0, 2] += 5.0
    result, choices = mle.calibrate_from_corners(board, p.pixels, K_off, p.camera.dist,
                                                 p.base_T_flange, cam_T_target=p.cam_T_target,
                                                 fit_intrinsics=(False, True))
    assert len(choices) == 12 + len(mle.POSE_CANDIDATES)
    assert choices[0].fit_intrinsics and "intrinsics refined" in choices[0].label
    kept = min(c.held_out_px for c in choices if not c.fit_intrinsics)
    assert choices[0].held_out_px < 0.5 * kept
    assert result.camera_matrix is not None
    np.testing.assert_allclose(result.camera_matrix, p.camera.K, atol=1.0)
    with pytest.raises(ValueError, match="fit_intrinsics"):
        mle.calibrate_from_corners(board, p.pixels, K_off, p.camera.dist, p.base_T_flange,
                                   cam_T_target=p.cam_T_target, fit_intrinsics=())


def test_calibrate_from_corners_refuses_bad_settings():
    p = make_real_like_hand_eye(1, n_poses=5, pixel_px=0.1)
    args = (p.board.object_points(), p.pixels, p.camera.K, p.camera.dist, p.base_T_flange)
    with pytest.raises(ValueError, match="folds"):
        mle.calibrate_from_corners(*args, folds=1)
    with pytest.raises(ValueError, match="robot_weights"):
        mle.calibrate_from_corners(*args, robot_weights=(-1.0,))
    with pytest.raises(ValueError, match="pose candidates"):
        mle.calibrate_from_corners(*args, pose_candidates=("tsai",))
    with pytest.raises(ValueError, match="no candidates"):
        mle.calibrate_from_corners(*args, robot_weights=(), pose_candidates=())


def _solutions_imports() -> dict[str, set[str]]:
    """module -> the solutions modules it imports anywhere (module level or inside functions)."""
    root = Path(__file__).resolve().parents[1] / "solutions"
    graph = {}
    for path in root.glob("*.py"):
        name = f"solutions.{path.stem}"
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found |= {a.name for a in node.names if a.name.startswith("solutions.")}
            elif isinstance(node, ast.ImportFrom) and node.module:
                if node.module == "solutions":
                    found |= {f"solutions.{a.name}" for a in node.names}
                elif node.module.startswith("solutions."):
                    found.add(node.module)
        graph[name] = found - {name}
    return graph


def test_no_two_solver_modules_import_each_other_even_inside_a_function():
    graph = _solutions_imports()
    assert "solutions.ax_yb_closed_forms" in graph["solutions.mle"]
    cycles = []

    def visit(node, path):
        for nxt in graph.get(node, ()):
            if nxt in path:
                cycles.append(path[path.index(nxt):] + [nxt])
            elif len(path) < len(graph):
                visit(nxt, path + [nxt])

    for start in graph:
        visit(start, [start])
    assert not cycles, f"import cycles: {cycles[:3]}"

"""The synthetic problem generators: exact relations at zero noise, seeding, noise levels."""

import numpy as np
import pytest

from autograder import synthetic as syn
from robots import geometry as geo


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_hand_eye_relation_is_exact_without_noise(mount):
    p = syn.make_hand_eye(0, mount, n_poses=8)
    for A, C in zip(p.base_T_flange, p.cam_T_target):
        if mount == "eye_in_hand":
            np.testing.assert_allclose(A @ p.X_true @ C, p.Y_true, atol=1e-12)
        else:
            np.testing.assert_allclose(A @ p.Y_true, p.X_true @ C, atol=1e-12)
    A, B, X, Y = p.as_ax_yb()
    np.testing.assert_allclose(A @ X, Y @ B, atol=1e-12)


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_opencv_scenario_relation_is_exact_without_noise(mount):
    p = syn.make_opencv_scenario(0, mount, noise=False)
    A, B, X, Y = p.as_ax_yb()
    np.testing.assert_allclose(A @ X, Y @ B, atol=1e-12)


def test_views_keep_the_board_in_the_image_and_motions_in_range():
    p = syn.make_hand_eye(3, n_poses=12, motion_deg=(15, 45))
    assert np.all((p.pixels[..., 0] > 0) & (p.pixels[..., 0] < p.camera.width))
    assert np.all((p.pixels[..., 1] > 0) & (p.pixels[..., 1] < p.camera.height))
    angles = geo.rotation_error_deg(p.cam_T_target[:-1], p.cam_T_target[1:])
    assert np.all((angles >= 15) & (angles <= 45))
    # A camera looking down at a face-up board sits above it.
    base_T_cam = p.base_T_flange @ p.X_true
    assert np.all(base_T_cam[:, 2, 3] > p.Y_true[2, 3])


def test_same_seed_same_problem_and_different_seed_different_problem():
    a = syn.make_hand_eye(5, noise=syn.NoiseModel(robot_rot_deg=0.1, pixel_px=0.5))
    b = syn.make_hand_eye(5, noise=syn.NoiseModel(robot_rot_deg=0.1, pixel_px=0.5))
    c = syn.make_hand_eye(6, noise=syn.NoiseModel(robot_rot_deg=0.1, pixel_px=0.5))
    np.testing.assert_array_equal(a.base_T_flange, b.base_T_flange)
    np.testing.assert_array_equal(a.pixels, b.pixels)
    assert not np.allclose(a.X_true, c.X_true)


def test_pose_noise_has_the_requested_spread():
    p = syn.make_hand_eye(1, n_poses=200, motion_deg=(0, 180),
                          noise=syn.NoiseModel(robot_rot_deg=0.5, robot_trans_mm=2.0))
    dt = (p.base_T_flange[:, :3, 3] - p.true_base_T_flange[:, :3, 3]) * 1000
    assert np.std(dt) == pytest.approx(2.0, rel=0.15)
    # The angle of a rotation vector with N(0, s) components has RMS s * sqrt(3).
    angles = geo.rotation_error_deg(p.base_T_flange, p.true_base_T_flange)
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(0.5 * np.sqrt(3), rel=0.15)


def test_outliers_are_gross_and_named():
    p = syn.make_hand_eye(2, n_poses=10, noise=syn.NoiseModel(n_outliers=1))
    (bad,) = p.outlier_indices
    errors = geo.rotation_error_deg(p.cam_T_target, p.true_cam_T_target)
    assert errors[bad] == pytest.approx(5.0, abs=1e-6)
    assert np.delete(errors, bad).max() < 1e-9


def test_pixel_noise_goes_through_solvepnp():
    p = syn.make_hand_eye(4, n_poses=6, noise=syn.NoiseModel(pixel_px=0.5))
    err = geo.rotation_error_deg(p.cam_T_target, p.true_cam_T_target)
    assert 0 < err.max() < 2.0


def test_flange_problem_relation_and_outlier():
    f = syn.make_flange(0, n_points=20, n_outliers=1, outlier_mm=12.0)
    predicted = geo.transform_points(geo.invert(f.base_T_cam_true), f.base_points)
    miss = np.linalg.norm(predicted - f.cam_points, axis=1) * 1000
    (bad,) = f.outlier_indices
    assert miss[bad] == pytest.approx(12.0)
    assert np.delete(miss, bad).max() < 1e-9
    assert np.allclose(f.base_T_flange[:, :3, :3], f.base_T_flange[0, :3, :3])


def test_three_point_problem_geometry():
    tp = syn.make_three_point(0)
    np.testing.assert_allclose(tp.base_T_cam_true @ tp.cam_T_world_true, tp.base_T_world_true, atol=1e-12)
    np.testing.assert_allclose(geo.transform_points(tp.base_T_cam_true, tp.cam_points), tp.base_points, atol=1e-12)
    assert tp.check_cam.shape == (12, 3)


@pytest.mark.parametrize("bad", [None, 1.5, "0"])
def test_seed_must_be_an_int_or_generator(bad):
    with pytest.raises(ValueError, match="seed"):
        syn.make_hand_eye(bad)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="mount"):
        syn.make_hand_eye(0, mount="eye_on_hand")
    with pytest.raises(ValueError, match="n_poses"):
        syn.make_hand_eye(0, n_poses=2)
    with pytest.raises(ValueError, match="robot_rot_deg"):
        syn.NoiseModel(robot_rot_deg=-1)


def test_small_motions_can_be_requested():
    p = syn.make_hand_eye(0, n_poses=10, motion_deg=(1, 8))
    angles = geo.rotation_error_deg(p.cam_T_target[:-1], p.cam_T_target[1:])
    assert np.all((angles >= 1) & (angles <= 8))
    assert np.all((p.pixels[..., 0] > 0) & (p.pixels[..., 0] < p.camera.width))

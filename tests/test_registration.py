"""Rigid registration, the three-point frame and flange calibration (solutions/registration.py).

Synthetic fixtures are built here from known poses; the real Aubo-i5 + RealSense capture
(autograder/data/bionicdl_aubo_i5_flange) checks the documented facts of a real rig.
"""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from autograder.datasets import load_aubo_flange_capture
from autograder.synthetic import make_flange
from robots import geometry as geo
from solutions import registration as reg


def random_pose(rng) -> np.ndarray:
    return geo.make_pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-1, 1, 3))


def cloud(rng, n=12) -> np.ndarray:
    return rng.uniform(-0.3, 0.3, (n, 3))


def assert_pose_close(A, B, rot_deg=1e-7, trans_m=1e-9):
    assert geo.rotation_error_deg(A, B) < rot_deg
    assert geo.translation_error(A, B) < trans_m


def assert_proper_rotation(T):
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


# --------------------------------------------------------------------------- fit_rigid


@pytest.mark.parametrize("seed", range(5))
def test_exact_recovery_at_zero_noise(seed):
    rng = np.random.default_rng(seed)
    dst_T_src = random_pose(rng)
    src = cloud(rng)
    dst = geo.transform_points(dst_T_src, src)
    fit = reg.fit_rigid_report(src, dst)
    assert_pose_close(fit.dst_T_src, dst_T_src)
    assert fit.rms < 1e-12
    assert fit.outlier_indices == ()
    assert fit.inlier_mask.all()


@settings(max_examples=50)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 30), planar=st.booleans())
def test_any_rigid_motion_is_recovered_exactly(seed, n, planar):
    rng = np.random.default_rng(seed)
    dst_T_src = random_pose(rng)
    src = cloud(rng, n)
    if planar:
        src[:, 2] = 0.0
    src[:3] = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.2, 0.0]]  # never degenerate
    T = reg.fit_rigid(src, geo.transform_points(dst_T_src, src))
    assert_proper_rotation(T)
    assert_pose_close(T, dst_T_src)


def test_three_points_are_enough_for_an_exact_fit():
    rng = np.random.default_rng(7)
    dst_T_src = random_pose(rng)
    src = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.1, 0.0]])
    assert_pose_close(reg.fit_rigid(src, geo.transform_points(dst_T_src, src)), dst_T_src)


def test_planar_sets_that_fool_the_naive_svd_still_give_a_proper_rotation():
    # For a planar set the cross-covariance has rank 2, so the sign of the third singular
    # vector is arbitrary and the naive V U^T is a reflection about half the time.
    src = np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.2, 0], [0.3, 0.2, 0], [0.1, 0.05, 0]], float)
    naive_reflections = 0
    for seed in range(20):
        dst_T_src = geo.make_pose(Rotation.random(random_state=seed).as_matrix(), [0.1, 0.2, 0.3])
        dst = geo.transform_points(dst_T_src, src)
        U, _, Vt = np.linalg.svd((src - src.mean(0)).T @ (dst - dst.mean(0)))
        naive_reflections += np.linalg.det(Vt.T @ U.T) < 0
        T = reg.fit_rigid(src, dst)
        assert_proper_rotation(T)
        assert_pose_close(T, dst_T_src)
    assert naive_reflections > 0, "fixture no longer exercises the reflection case"


def test_mirrored_data_gives_the_best_proper_rotation_not_a_reflection():
    rng = np.random.default_rng(3)
    src = cloud(rng)
    dst = src * [1.0, 1.0, -1.0]  # a true mirror image: no rotation fits it exactly
    with pytest.warns(UserWarning, match="mirror image"):
        fit = reg.fit_rigid_report(src, dst)
    assert_proper_rotation(fit.dst_T_src)
    assert fit.rms > 1e-3


def test_zero_weight_is_the_same_as_removing_the_point():
    rng = np.random.default_rng(11)
    dst_T_src = random_pose(rng)
    src = cloud(rng, 10)
    dst = geo.transform_points(dst_T_src, src) + rng.normal(0, 1e-3, (10, 3))
    dst[4] += [0.05, -0.02, 0.03]
    weights = rng.uniform(0.5, 2.0, 10)
    weights[4] = 0.0
    keep = np.arange(10) != 4
    with_zero = reg.fit_rigid_report(src, dst, weights=weights)
    removed = reg.fit_rigid(src[keep], dst[keep], weights=weights[keep])
    np.testing.assert_allclose(with_zero.dst_T_src, removed, atol=1e-12)
    assert not with_zero.inlier_mask[4]
    assert with_zero.outlier_indices == ()  # left out by weight, not flagged


def test_weights_change_the_fit_towards_heavy_points():
    rng = np.random.default_rng(12)
    dst_T_src = random_pose(rng)
    src = cloud(rng, 8)
    dst = geo.transform_points(dst_T_src, src)
    dst[0] += [0.01, 0.0, 0.0]
    plain = reg.residuals(reg.fit_rigid(src, dst), src, dst)
    heavy = np.ones(8)
    heavy[0] = 100.0
    weighted = reg.residuals(reg.fit_rigid(src, dst, weights=heavy), src, dst)
    assert np.linalg.norm(weighted[0]) < 0.2 * np.linalg.norm(plain[0])


def test_permuting_the_points_gives_the_same_pose():
    rng = np.random.default_rng(5)
    src = cloud(rng, 15)
    dst = geo.transform_points(random_pose(rng), src) + rng.normal(0, 2e-3, (15, 3))
    weights = rng.uniform(0.1, 1.0, 15)
    perm = rng.permutation(15)
    np.testing.assert_allclose(
        reg.fit_rigid(src, dst, weights), reg.fit_rigid(src[perm], dst[perm], weights[perm]),
        atol=1e-12,
    )


@pytest.mark.parametrize(
    ("src", "dst", "message"),
    [
        (np.zeros((2, 3)), np.zeros((2, 3)), "at least 3"),
        (np.zeros((4, 3)), np.zeros((5, 3)), "4 points but dst has 5"),
        (np.zeros((4, 2)), np.zeros((4, 2)), r"shape \(N, 3\)"),
        (np.eye(3), np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 1.0]]), r"dst\[1\].*NaN"),
        (np.outer(np.arange(5.0), [0.1, 0.2, 0.3]), np.eye(5, 3), "src are .*collinear"),
        (np.eye(5, 3), np.outer(np.arange(5.0), [0.1, 0.2, 0.3]), "dst are .*collinear"),
        (np.ones((4, 3)), np.eye(4, 3), "collinear"),  # all points coincide
    ],
)
def test_bad_input_raises_with_a_useful_message(src, dst, message):
    with pytest.raises(ValueError, match=message):
        reg.fit_rigid(src, dst)


def test_nearly_collinear_message_reports_the_singular_values():
    line = np.outer(np.linspace(0, 1, 6), [1.0, 0.0, 0.0])
    line[2, 1] = 1e-6  # one micrometre off a one-metre line
    with pytest.raises(ValueError, match=r"singular values .* m, ratio s2/s1 = [0-9.e-]+"):
        reg.fit_rigid(line, line)


def test_weights_that_leave_too_few_points_raise():
    src = np.eye(4, 3)
    with pytest.raises(ValueError, match="positive weight"):
        reg.fit_rigid(src, src, weights=[1.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"weights\[2\]"):
        reg.fit_rigid(src, src, weights=[1.0, 1.0, -1.0, 1.0])


def test_robust_mode_flags_a_planted_outlier_by_index():
    rng = np.random.default_rng(21)
    dst_T_src = random_pose(rng)
    src = cloud(rng, 20)
    dst = geo.transform_points(dst_T_src, src) + rng.normal(0, 5e-4, (20, 3))
    dst[13] += [0.0, 0.02, 0.0]
    fit = reg.fit_rigid_report(src, dst, robust=True)
    assert fit.outlier_indices == (13,)
    assert not fit.inlier_mask[13]
    clean = np.arange(20) != 13
    np.testing.assert_allclose(fit.dst_T_src, reg.fit_rigid(src[clean], dst[clean]), atol=1e-12)
    assert fit.residual_norms[13] > 0.015  # residuals still cover the flagged point


def test_robust_mode_on_exact_data_flags_nothing_and_recovers_exactly():
    rng = np.random.default_rng(22)
    dst_T_src = random_pose(rng)
    src = cloud(rng, 10)
    dst = geo.transform_points(dst_T_src, src)
    fit = reg.fit_rigid_report(src, dst, robust=True)
    assert fit.outlier_indices == ()
    assert_pose_close(fit.dst_T_src, dst_T_src)
    dst[2] += [0.0, 0.0, 0.01]
    fit = reg.fit_rigid_report(src, dst, robust=True)
    assert fit.outlier_indices == (2,)
    assert_pose_close(fit.dst_T_src, dst_T_src)


def test_robust_absolute_threshold():
    rng = np.random.default_rng(23)
    src = cloud(rng, 12)
    dst = geo.transform_points(random_pose(rng), src)
    dst[[3, 8]] += [[0.004, 0, 0], [0, 0.03, 0]]
    assert reg.fit_rigid_report(src, dst, robust=True, threshold_m=0.002).outlier_indices == (3, 8)
    assert reg.fit_rigid_report(src, dst, robust=True, threshold_m=0.01).outlier_indices == (8,)


def test_robust_mode_refuses_when_there_is_no_consistent_majority():
    rng = np.random.default_rng(24)
    src = cloud(rng, 10)
    dst = rng.uniform(-0.3, 0.3, (10, 3))  # unrelated point sets
    with pytest.raises(ValueError, match="no consistent majority"):
        reg.fit_rigid(src, dst, robust=True, threshold_m=1e-3)
    with pytest.raises(ValueError, match="at least 5"):
        reg.fit_rigid(src[:4], dst[:4], robust=True)


def test_residuals_and_per_axis_rmse_in_other_frames():
    rng = np.random.default_rng(31)
    dst_T_src = random_pose(rng)
    src = cloud(rng, 6)
    # Error only along the src z axis, e.g. depth noise of a camera.
    src_err = np.zeros((6, 3))
    src_err[:, 2] = [0.002, -0.002, 0.001, -0.001, 0.003, -0.003]
    dst = geo.transform_points(dst_T_src, src + src_err)
    r_dst = reg.residuals(dst_T_src, src, dst)
    np.testing.assert_allclose(r_dst, -src_err @ dst_T_src[:3, :3].T, atol=1e-15)
    np.testing.assert_allclose(reg.residuals(dst_T_src, src, dst, "src"), -src_err, atol=1e-15)
    np.testing.assert_allclose(reg.residuals(dst_T_src, src, dst, dst_T_src), -src_err, atol=1e-15)
    rmse_src = reg.per_axis_rmse(dst_T_src, src, dst, expressed_in="src")
    np.testing.assert_allclose(rmse_src, [0, 0, np.sqrt(np.mean(src_err[:, 2] ** 2))], atol=1e-15)
    # The length of the residual does not depend on the axes it is written in.
    assert np.sum(reg.per_axis_rmse(dst_T_src, src, dst) ** 2) == pytest.approx(np.sum(rmse_src**2))
    with pytest.raises(ValueError, match="expressed_in"):
        reg.residuals(dst_T_src, src, dst, "camera")


def test_report_metrics_are_consistent():
    rng = np.random.default_rng(32)
    src = cloud(rng, 9)
    dst = geo.transform_points(random_pose(rng), src) + rng.normal(0, 1e-3, (9, 3))
    fit = reg.fit_rigid_report(src, dst)
    np.testing.assert_allclose(fit.residuals, reg.residuals(fit.dst_T_src, src, dst), atol=1e-15)
    np.testing.assert_allclose(fit.residual_norms, np.linalg.norm(fit.residuals, axis=1))
    assert fit.rms == pytest.approx(np.sqrt(np.sum(fit.per_axis_rmse**2)))
    centred = src - src.mean(axis=0)
    np.testing.assert_allclose(fit.src_spread, np.linalg.svd(centred, compute_uv=False) / 3.0)
    np.testing.assert_allclose(
        fit.per_axis_rmse_src, reg.per_axis_rmse(fit.dst_T_src, src, dst, "src")
    )


# --------------------------------------------------------------------------- three-point frame


def test_frame_from_three_points_matches_a_known_frame():
    rng = np.random.default_rng(41)
    parent_T_frame = random_pose(rng)
    # Origin, a point on +x, and a point in the x-y plane that is not on the y axis.
    local = np.array([[0.0, 0.0, 0.0], [0.35, 0.0, 0.0], [0.1, 0.25, 0.0]])
    p = geo.transform_points(parent_T_frame, local)
    assert_pose_close(reg.frame_from_three_points(*p), parent_T_frame, 1e-9, 1e-12)


def test_frame_from_three_points_is_right_handed_and_x_follows_the_first_edge():
    o, px, pxy = np.array([0.4, -0.1, 0.02]), np.array([0.7, 0.1, 0.05]), np.array([0.3, 0.3, 0.0])
    T = reg.frame_from_three_points(o, px, pxy)
    assert_proper_rotation(T)
    R = T[:3, :3]
    np.testing.assert_allclose(R[:, 0], (px - o) / np.linalg.norm(px - o), atol=1e-15)
    np.testing.assert_allclose(np.cross(R[:, 0], R[:, 1]), R[:, 2], atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], o)
    local = geo.transform_points(geo.invert(T), pxy)
    assert local[1] > 0 and abs(local[2]) < 1e-15  # p_xy lies in the x-y plane, +y side


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (([0, 0, 0], [0, 0, 0], [0, 1, 0]), r"p_x coincides .*distance 0 m"),
        (([0, 0, 0], [1, 0, 0], [0, 0, 0]), "p_xy coincides"),
        (([0, 0, 0], [1, 0, 0], [2, 0.001, 0]), r"collinear.*angle .*0.0286 deg"),
        (([0, 0, 0], [1, 0, 0], [-1, 0, 0]), r"collinear.*angle .*is 180 deg"),
        (([0, 0, 0], [1, 0, np.nan], [0, 1, 0]), "p_x contains NaN"),
        (([0, 0], [1, 0, 0], [0, 1, 0]), "p_origin must be a 3-vector"),
    ],
)
def test_frame_from_three_points_rejects_degenerate_points(points, message):
    with pytest.raises(ValueError, match=message):
        reg.frame_from_three_points(*points)


# --------------------------------------------------------------------------- flange calibration


def test_calibrate_flange_exact_on_synthetic_data():
    p = make_flange(0, n_points=12)
    assert_pose_close(reg.calibrate_flange(p.cam_points, p.base_points), p.base_T_cam_true)


@pytest.mark.parametrize("seed", range(10))
def test_calibrate_flange_robust_finds_the_synthetic_outlier(seed):
    p = make_flange(seed, n_points=30, noise_mm=0.5, n_outliers=1, outlier_mm=12.0)
    fit = reg.calibrate_flange_report(p.cam_points, p.base_points, robust=True)
    assert fit.outlier_indices == p.outlier_indices
    clean = make_flange(seed, n_points=30, noise_mm=0.5)
    clean_fit = reg.calibrate_flange_report(clean.cam_points, clean.base_points, robust=True)
    assert clean_fit.outlier_indices == ()


def test_calibrate_flange_needs_four_poses_and_explains_why():
    p = make_flange(1, n_points=3)
    with pytest.raises(ValueError, match=r"at least 4 poses.*no redundancy"):
        reg.calibrate_flange(p.cam_points, p.base_points)


def test_calibrate_flange_collinear_poses_explain_the_unobservable_rotation():
    base = np.array([[0.3, 0.0, 0.2], [0.4, 0.0, 0.2], [0.5, 0.0, 0.2], [0.6, 0.0, 0.2]])
    cam = base - [0.5, 0.0, -0.5]
    with pytest.raises(ValueError, match=r"collinear.*flange positions lie on one line"):
        reg.calibrate_flange(cam, base)
    with pytest.raises(ValueError, match=r"cam_points\[2\] contains NaN"):
        reg.calibrate_flange(np.where(np.arange(4)[:, None] == 2, np.nan, cam), base)


@pytest.mark.parametrize("offset", [[0.01, -0.02, 0.03], [0.05, 0.04, 0.12]])
def test_offset_variant_recovers_a_known_offset_with_varied_orientations(offset):
    p = make_flange(2, n_points=15, fixed_orientation=False, marker_offset_m=offset)
    base_T_cam, p_marker = reg.calibrate_flange_with_offset(p.cam_points, p.base_T_flange)
    assert_pose_close(base_T_cam, p.base_T_cam_true)
    np.testing.assert_allclose(p_marker, offset, atol=1e-9)
    # The zero-offset method is visibly wrong on the same data.
    wrong = reg.calibrate_flange(p.cam_points, p.base_points)
    assert geo.translation_error(wrong, p.base_T_cam_true) > 0.005


def test_offset_variant_with_noise_beats_ignoring_the_offset():
    offset = [0.0, 0.03, 0.04]
    p = make_flange(3, n_points=25, noise_mm=0.5, fixed_orientation=False, marker_offset_m=offset)
    base_T_cam, p_marker = reg.calibrate_flange_with_offset(p.cam_points, p.base_T_flange)
    assert geo.translation_error(base_T_cam, p.base_T_cam_true) < 0.003
    assert np.linalg.norm(p_marker - offset) < 0.003
    naive = reg.calibrate_flange(p.cam_points, p.base_points)
    assert geo.translation_error(naive, p.base_T_cam_true) > 3 * geo.translation_error(
        base_T_cam, p.base_T_cam_true
    )


def test_offset_variant_raises_on_fixed_orientation():
    p = make_flange(4, n_points=15, fixed_orientation=True, marker_offset_m=[0.01, 0.0, 0.02])
    with pytest.raises(ValueError, match="fixed orientation cannot separate the marker offset"):
        reg.calibrate_flange_with_offset(p.cam_points, p.base_T_flange)


def test_offset_variant_raises_when_orientations_vary_about_one_axis_only():
    p = make_flange(5, n_points=12)
    spin = Rotation.from_euler("z", np.linspace(-40, 40, 12)[:, None], degrees=True).as_matrix()
    poses = p.base_T_flange.copy()
    poses[:, :3, :3] = poses[:, :3, :3] @ spin  # rotate about the flange's own z axis
    with pytest.raises(ValueError, match="about one axis only"):
        reg.calibrate_flange_with_offset(p.cam_points, poses)


def test_offset_variant_validates_its_inputs():
    p = make_flange(6, n_points=8, fixed_orientation=False)
    poses = p.base_T_flange.copy()
    poses[3, :3, :3] *= -1.0
    with pytest.raises(ValueError, match=r"base_T_flange\[3\]"):
        reg.calibrate_flange_with_offset(p.cam_points, poses)
    with pytest.raises(ValueError, match="7 points but base_T_flange has 8"):
        reg.calibrate_flange_with_offset(p.cam_points[:7], p.base_T_flange)


# --------------------------------------------------------------------------- the real capture


@pytest.fixture(scope="module")
def aubo():
    return load_aubo_flange_capture()


def test_packaged_capture_loads(aubo):
    cam, base = aubo
    assert cam.shape == base.shape == (50, 3)
    assert cam.dtype == base.dtype == np.float64
    # The README's facts about the grid: tool0 x 0.22..0.38, z at 0.48 / 0.52 m.
    assert base[:, 0].min() == pytest.approx(0.22) and base[:, 0].max() == pytest.approx(0.38)
    assert set(np.round(base[:, 2], 3)) == {0.48, 0.52}


def test_real_capture_plain_fit_leaves_about_2_7_mm(aubo):
    cam, base = aubo
    fit = reg.calibrate_flange_report(cam, base)
    assert 2.5e-3 < fit.rms < 2.8e-3
    assert np.argmax(fit.residual_norms) == 45
    assert 11e-3 < fit.residual_norms[45] < 13e-3


def test_real_capture_robust_fit_flags_the_one_clear_outlier(aubo):
    cam, base = aubo
    fit = reg.calibrate_flange_report(cam, base, robust=True)
    assert fit.outlier_indices == (45,)
    assert fit.rms < 2.1e-3
    keep = np.arange(50) != 45
    without_45 = reg.calibrate_flange(cam[keep], base[keep])
    np.testing.assert_allclose(fit.dst_T_src, without_45, atol=1e-12)


def test_real_capture_error_lies_along_the_camera_depth_axis(aubo):
    cam, base = aubo
    for robust in (False, True):
        fit = reg.calibrate_flange_report(cam, base, robust=robust)
        rmse_cam = fit.per_axis_rmse_src
        assert np.argmax(rmse_cam) == 2
        assert rmse_cam[2] > 2.5 * max(rmse_cam[0], rmse_cam[1])
        np.testing.assert_allclose(
            rmse_cam,
            reg.per_axis_rmse(fit.dst_T_src, cam[fit.inlier_mask], base[fit.inlier_mask], "src"),
        )


def test_real_capture_cannot_reveal_a_marker_offset(aubo):
    cam, base = aubo
    # The capture has one tool orientation throughout (tool pointing down).
    base_T_flange = np.array([geo.make_pose(np.diag([1.0, -1.0, -1.0]), t) for t in base])
    with pytest.raises(ValueError, match="all flange orientations are the same"):
        reg.calibrate_flange_with_offset(cam, base_T_flange)


def test_rotation_agrees_with_opencv_umeyama(aubo):
    cam, base = aubo
    M, scale = cv2.estimateAffine3D(cam, base, force_rotation=True)
    T = reg.fit_rigid(cam, base)
    # Umeyama's similarity has the same rotation; its translation goes with its scale.
    np.testing.assert_allclose(T[:3, :3], M[:, :3], atol=1e-9)
    np.testing.assert_allclose(M[:, 3], base.mean(0) - scale * T[:3, :3] @ cam.mean(0), atol=1e-9)
    rng = np.random.default_rng(51)
    dst_T_src = random_pose(rng)
    src = cloud(rng)
    dst = geo.transform_points(dst_T_src, src)
    M, scale = cv2.estimateAffine3D(src, dst, force_rotation=True)
    assert scale == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(reg.fit_rigid(src, dst)[:3], M, atol=1e-9)

"""Maximum-likelihood hand-eye refinement (poses) and reprojection refinement (corners)."""

import numpy as np
import pytest

from autograder.synthetic import NoiseModel, make_hand_eye, make_opencv_scenario
from robots import geometry as geo
from solutions import mle
from solutions.mle import pose_residuals, refine_hand_eye, refine_reprojection

MOUNTS = ("eye_in_hand", "eye_to_hand")


def _errors(X, X_true):
    return geo.rotation_error_deg(X, X_true), geo.translation_error(X, X_true)


@pytest.mark.parametrize("mount", MOUNTS)
def test_refine_hand_eye_exact_recovery(mount):
    p = make_hand_eye(0, mount, n_poses=8)
    res = refine_hand_eye(p.base_T_flange, p.cam_T_target, mount)
    for est, true in ((res.X, p.X_true), (res.Y, p.Y_true)):
        r, t = _errors(est, true)
        assert r < 1e-9 and t < 1e-9
    assert res.outlier_indices == ()
    assert res.converged


@pytest.mark.parametrize("mount", MOUNTS)
def test_refine_reprojection_exact_recovery_from_a_poor_start(mount):
    p = make_hand_eye(1, mount, n_poses=6)
    X0 = geo.pose_from_rotvec([0.02, -0.01, 0.015], [0.004, -0.003, 0.005]) @ p.X_true
    Y0 = p.Y_true @ geo.pose_from_rotvec([-0.01, 0.02, 0.0], [0.003, 0.002, -0.004])
    res = refine_reprojection(p.board.object_points(), p.pixels, p.camera.K, p.camera.dist,
                              p.base_T_flange, mount, X0=X0, Y0=Y0)
    r, t = _errors(res.X, p.X_true)
    assert r < 1e-9 and t < 1e-9
    assert res.reprojection_rms_px < 1e-6


def test_residuals_vanish_at_the_truth_and_match_the_noise():
    p = make_hand_eye(2, "eye_in_hand", n_poses=5)
    rot, trans = pose_residuals(p.X_true, p.Y_true, p.base_T_flange, p.cam_T_target)
    assert np.abs(rot).max() < 1e-12 and np.abs(trans).max() < 1e-12
    # A known error on one camera pose shows up as exactly that residual, in camera axes.
    cam = p.cam_T_target.copy()
    cam[3] = geo.pose_from_rotvec([0.01, 0, 0], [0, 0.002, 0]) @ cam[3]
    cam[3, :3, 3] = p.cam_T_target[3, :3, 3] + [0, 0.002, 0]
    rot, trans = pose_residuals(p.X_true, p.Y_true, p.base_T_flange, cam)
    np.testing.assert_allclose(rot[3], [0.01, 0, 0], atol=1e-12)
    np.testing.assert_allclose(trans[3], [0, 0.002, 0], atol=1e-12)


@pytest.mark.parametrize("mount", MOUNTS)
def test_bad_pose_is_named_and_ignored(mount):
    noise = NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5, n_outliers=1)
    errors = []
    for seed in range(5):
        p = make_hand_eye(seed, mount, n_poses=10, noise=noise)
        res = refine_hand_eye(p.base_T_flange, p.cam_T_target, mount)
        assert res.outlier_indices == p.outlier_indices
        assert res.weights[p.outlier_indices[0]] == 0.0
        # Ignored means ignored: the answer is the fit of the good poses alone.
        good = [i for i in range(10) if i not in p.outlier_indices]
        clean = refine_hand_eye(p.base_T_flange[good], p.cam_T_target[good], mount, robust=False)
        r, t = _errors(res.X, clean.X)
        assert r < 0.01 and t < 1e-4
        errors.append(_errors(res.X, p.X_true))
    # The target for this scenario (a median: single draws of 0.1 deg noise on nine
    # views can land above 0.3 deg even for the fit that knows the noise and the bad pose).
    r_med, t_med = np.median(errors, axis=0)
    assert r_med < 0.3 and t_med < 0.02


def test_no_outliers_named_on_clean_data():
    noise = NoiseModel(cam_rot_deg=0.2, cam_trans_mm=1.0)
    for seed in range(5):
        p = make_hand_eye(seed, "eye_in_hand", n_poses=12, noise=noise)
        assert refine_hand_eye(p.base_T_flange, p.cam_T_target).outlier_indices == ()


def test_noise_levels_are_estimated():
    p = make_hand_eye(3, "eye_to_hand", n_poses=40, noise=NoiseModel(cam_rot_deg=0.5, cam_trans_mm=2))
    res = refine_hand_eye(p.base_T_flange, p.cam_T_target, "eye_to_hand")
    total_rot = np.hypot(res.rotation_sigma_rad, res.robot_rotation_sigma_rad)
    assert total_rot == pytest.approx(np.radians(0.5), rel=0.25)
    assert res.translation_sigma_m == pytest.approx(0.002, rel=0.25)


def test_known_sigma_is_used_as_given():
    p = make_hand_eye(4, "eye_in_hand", n_poses=10, noise=NoiseModel(cam_rot_deg=0.2, cam_trans_mm=1))
    res = refine_hand_eye(p.base_T_flange, p.cam_T_target, sigma=(np.radians(0.2), 0.001))
    assert res.rotation_sigma_rad == pytest.approx(np.radians(0.2))
    assert res.translation_sigma_m == pytest.approx(0.001)
    r, t = _errors(res.X, p.X_true)
    assert r < 0.3 and t < 0.005


def test_order_of_poses_does_not_matter():
    p = make_hand_eye(5, "eye_in_hand", n_poses=10, noise=NoiseModel(cam_rot_deg=0.3, cam_trans_mm=1))
    perm = np.random.default_rng(1).permutation(10)
    a = refine_hand_eye(p.base_T_flange, p.cam_T_target)
    b = refine_hand_eye(p.base_T_flange[perm], p.cam_T_target[perm])
    assert np.abs(a.X - b.X).max() < 1e-8 and np.abs(a.Y - b.Y).max() < 1e-8


def test_start_from_one_given_pose():
    p = make_hand_eye(6, "eye_to_hand", n_poses=8)
    res = refine_hand_eye(p.base_T_flange, p.cam_T_target, "eye_to_hand", X0=p.X_true)
    assert geo.translation_error(res.Y, p.Y_true) < 1e-9


def test_reprojection_beats_pose_based_under_pixel_noise():
    noise = NoiseModel(pixel_px=1.0, robot_rot_deg=0.02, robot_trans_mm=0.1)
    pose_err, pix_err = [], []
    for seed in range(5):
        p = make_hand_eye(seed, "eye_in_hand", n_poses=8, noise=noise)
        start = refine_hand_eye(p.base_T_flange, p.cam_T_target)
        res = refine_reprojection(p.board.object_points(), p.pixels, p.camera.K, p.camera.dist,
                                  p.base_T_flange, X0=start.X, Y0=start.Y)
        pose_err.append(_errors(start.X, p.X_true))
        pix_err.append(_errors(res.X, p.X_true))
        assert 0.8 < res.reprojection_rms_px < 1.2
    pose_med, pix_med = np.median(pose_err, axis=0), np.median(pix_err, axis=0)
    assert pix_med[0] < pose_med[0] and pix_med[1] < pose_med[1]


def test_reprojection_skips_missing_views_and_corners():
    p = make_hand_eye(7, "eye_to_hand", n_poses=8, noise=NoiseModel(pixel_px=0.3))
    pixels = p.pixels.copy()
    pixels[2] = np.nan          # board not seen in view 2
    pixels[5, :10] = np.nan     # part of the board hidden in view 5
    start = refine_hand_eye(p.base_T_flange, p.cam_T_target, "eye_to_hand")
    res = refine_reprojection(p.board.object_points(), pixels, p.camera.K, p.camera.dist,
                              p.base_T_flange, "eye_to_hand", X0=start.X, Y0=start.Y)
    assert np.isfinite(res.X).all() and np.isfinite(res.reprojection_rms_px)
    assert res.weights[2] == 0.0
    r, t = _errors(res.X, p.X_true)
    assert r < 0.3 and t < 0.003


# --------------------------------------------------------------------------- refusals


def test_refusals_name_the_problem():
    p = make_hand_eye(8, "eye_in_hand", n_poses=6)
    with pytest.raises(ValueError, match="mount"):
        refine_hand_eye(p.base_T_flange, p.cam_T_target, "eye_on_base")
    with pytest.raises(ValueError, match="at least 3 poses"):
        refine_hand_eye(p.base_T_flange[:2], p.cam_T_target[:2])
    with pytest.raises(ValueError, match="one cam_T_target per base_T_flange"):
        refine_hand_eye(p.base_T_flange, p.cam_T_target[:5])
    with pytest.raises(ValueError, match="sigma"):
        refine_hand_eye(p.base_T_flange, p.cam_T_target, sigma=(0.01,))
    bad = p.cam_T_target.copy()
    bad[4, 1, 1] = np.nan
    with pytest.raises(ValueError, match=r"cam_T_target\[4\]"):
        refine_hand_eye(p.base_T_flange, bad)
    pts, K = p.board.object_points(), p.camera.K
    with pytest.raises(ValueError, match="X0 and Y0"):
        refine_reprojection(pts, p.pixels, K, None, p.base_T_flange)
    with pytest.raises(ValueError, match="pixels must have shape"):
        refine_reprojection(pts, p.pixels[:, :5], K, None, p.base_T_flange, X0=p.X_true, Y0=p.Y_true)
    few = p.pixels.copy()
    few[2:] = np.nan
    with pytest.raises(ValueError, match="only 2 views"):
        refine_reprojection(pts, few, K, None, p.base_T_flange, X0=p.X_true, Y0=p.Y_true)


# --------------------------------------------------------------------------- noise models

PIXEL_NOISE = NoiseModel(pixel_px=0.5, robot_rot_deg=0.02, robot_trans_mm=0.1)


@pytest.mark.parametrize("mount", MOUNTS)
def test_solvepnp_poses_get_the_planar_target_model_and_no_false_outliers(mount):
    # Poses from solvePnP on noisy corners: depth and tilt are several times worse than the
    # rest, which an isotropic model reads as outliers. The planar-target model expects it.
    chosen = []
    for seed in range(10):
        p = make_hand_eye(seed, mount, n_poses=10, noise=PIXEL_NOISE)
        res = refine_hand_eye(p.base_T_flange, p.cam_T_target, mount)
        assert res.outlier_indices == (), seed
        chosen.append(res.noise_model)
    assert chosen.count("planar_target") >= 8


def test_tracker_poses_get_the_isotropic_model():
    noise = NoiseModel(cam_rot_deg=0.2, cam_trans_mm=1.0)
    chosen = []
    for seed in range(6):
        p = make_hand_eye(seed, "eye_in_hand", n_poses=12, noise=noise)
        chosen.append(refine_hand_eye(p.base_T_flange, p.cam_T_target).noise_model)
    assert chosen.count("isotropic") >= 5


@pytest.mark.parametrize("mount", MOUNTS)
def test_beats_the_best_opencv_method_under_pixel_noise(mount):
    from solutions.opencv_baseline import (
        HAND_EYE_METHODS,
        ROBOT_WORLD_METHODS,
        opencv_hand_eye,
        opencv_robot_world,
    )

    ours, theirs = [], {}
    for seed in range(20):
        p = make_hand_eye(seed, mount, n_poses=10, noise=PIXEL_NOISE)
        ours.append(_errors(refine_hand_eye(p.base_T_flange, p.cam_T_target, mount).X, p.X_true))
        for m in HAND_EYE_METHODS:
            X = opencv_hand_eye(p.base_T_flange, p.cam_T_target, mount, m)
            theirs.setdefault(m, []).append(_errors(X, p.X_true))
        for m in ROBOT_WORLD_METHODS:
            X = opencv_robot_world(p.base_T_flange, p.cam_T_target, mount, m)[0]
            theirs.setdefault("RW " + m, []).append(_errors(X, p.X_true))
    r_ours, t_ours = np.median(ours, axis=0)
    r_best = min(np.median(v, axis=0)[0] for v in theirs.values())
    t_best = min(np.median(v, axis=0)[1] for v in theirs.values())
    # The target: at least 15 % better than OpenCV's best, in both.
    assert r_ours <= 0.85 * r_best and t_ours <= 0.85 * t_best


def test_planar_model_scale_follows_the_pixel_noise():
    scales = []
    for px in (0.25, 1.0):
        p = make_hand_eye(3, "eye_to_hand", n_poses=20, noise=NoiseModel(pixel_px=px))
        res = refine_hand_eye(p.base_T_flange, p.cam_T_target, "eye_to_hand")
        assert res.noise_model == "planar_target" and res.rotation_sigma_rad == 0.0
        # Weighted by the fitted model the normalised residuals scatter as they should
        # (chi-square(6) less the fit's share: mean 6 * (1 - 12 / 120) = 5.4).
        assert 3.0 < np.mean(res.per_pose_chi2) < 8.0
        scales.append(res.image_sigma_rad)
    # Four times the pixel noise, four times the fitted scale (within what 20 views tell).
    assert 3.0 < scales[1] / scales[0] < 5.5


def test_noise_model_choice_and_refusals():
    p = make_hand_eye(11, "eye_in_hand", n_poses=10, noise=PIXEL_NOISE)
    iso = refine_hand_eye(p.base_T_flange, p.cam_T_target, noise_model="isotropic")
    planar = refine_hand_eye(p.base_T_flange, p.cam_T_target, noise_model="planar_target")
    assert iso.noise_model == "isotropic" and iso.image_sigma_rad is None
    assert planar.noise_model == "planar_target" and planar.image_sigma_rad > 0
    with pytest.raises(ValueError, match="noise_model"):
        refine_hand_eye(p.base_T_flange, p.cam_T_target, noise_model="pnp")
    # A board plane behind every camera is no PnP view of a board.
    behind = p.cam_T_target.copy()
    behind[:, 2, 3] = -1.0
    with pytest.raises(ValueError, match="planar_target"):
        refine_hand_eye(p.base_T_flange, behind, noise_model="planar_target")
    # OpenCV's test perturbs poses isotropically; "auto" sees that.
    q = make_opencv_scenario(0, "eye_in_hand")
    assert refine_hand_eye(q.base_T_flange, q.cam_T_target).noise_model == "isotropic"


@pytest.mark.parametrize("mount", MOUNTS)
def test_few_poses_under_pixel_noise_do_not_fail_and_rarely_flag(mount):
    # Five views leave 18 redundant residual components: the noise model is kept small and
    # the outlier threshold allows for noise levels estimated from so little. A good pose may
    # still be named now and then; the target is at most one run in twenty.
    flagged = 0
    for seed in range(20):
        p = make_hand_eye(seed, mount, n_poses=5, noise=NoiseModel(pixel_px=1.0))
        res = refine_hand_eye(p.base_T_flange, p.cam_T_target, mount)
        flagged += bool(res.outlier_indices)
        r, t = _errors(res.X, p.X_true)
        assert r < 2.0 and t < 0.02
    assert flagged <= 1


def _error_vectors(X_est, X_true):
    """X's error in its child frame, (rotation vector rad, translation m), as the bound has it."""
    rotvec, t = geo.rotvec_from_pose(geo.invert(X_true) @ X_est)
    return np.concatenate([rotvec, t])


def _noisy_draws(truth, deg, mm, draws, seed):
    from autograder.synthetic import perturb_pose

    rng = np.random.default_rng(seed)
    for _ in range(draws):
        yield np.stack([perturb_pose(T, np.radians(deg), mm / 1000, rng)
                        for T in truth.true_cam_T_target])


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_default_reaches_the_cramer_rao_bound_and_opencv_does_not_beat_it(mount):
    """One fixed geometry, 300 noise draws: the spread of our estimate is the bound's (an
    efficient estimator), and OpenCV's best closed form is no tighter than the bound."""
    from solutions.mle import cramer_rao_covariance
    from solutions.opencv_baseline import opencv_hand_eye

    deg, mm, draws = 0.2, 1.0, 300
    truth = make_hand_eye(7, mount, n_poses=10)
    bound = cramer_rao_covariance(truth.X_true, truth.Y_true, truth.true_base_T_flange, mount,
                                  rotation_sigma_rad=np.radians(deg), translation_sigma_m=mm / 1000)
    ours, park = [], []
    for cam in _noisy_draws(truth, deg, mm, draws, seed=1):
        ours.append(_error_vectors(refine_hand_eye(truth.true_base_T_flange, cam, mount=mount).X,
                                   truth.X_true))
        park.append(_error_vectors(opencv_hand_eye(truth.true_base_T_flange, cam, mount, "PARK"),
                                   truth.X_true))
    ours, park = np.array(ours), np.array(park)
    bound_rot, bound_trans = np.trace(bound[:3, :3]), np.trace(bound[3:, 3:])
    # Mean squared error (bias included) over the bound's trace; 300 draws put about +-10 %
    # of sampling error on each ratio.
    ours_rot = np.mean(np.sum(ours[:, :3] ** 2, axis=1)) / bound_rot
    ours_trans = np.mean(np.sum(ours[:, 3:] ** 2, axis=1)) / bound_trans
    park_rot = np.mean(np.sum(park[:, :3] ** 2, axis=1)) / bound_rot
    assert 0.8 < ours_rot < 1.25, ours_rot
    assert 0.8 < ours_trans < 1.25, ours_trans
    assert park_rot > 0.9, park_rot


def test_cramer_rao_bound_scales_with_the_noise_and_refuses_one_axis():
    from solutions.mle import cramer_rao_covariance

    truth = make_hand_eye(3, "eye_in_hand", n_poses=8)
    args = (truth.X_true, truth.Y_true, truth.true_base_T_flange)
    small = cramer_rao_covariance(*args, rotation_sigma_rad=1e-3, translation_sigma_m=1e-3)
    big = cramer_rao_covariance(*args, rotation_sigma_rad=2e-3, translation_sigma_m=2e-3)
    np.testing.assert_allclose(big, 4 * small, rtol=1e-9, atol=1e-20)
    assert np.all(np.linalg.eigvalsh(small) > 0)
    # Robot rotation noise can only add uncertainty.
    more = cramer_rao_covariance(*args, rotation_sigma_rad=1e-3, translation_sigma_m=1e-3,
                                 robot_rotation_sigma_rad=1e-3)
    assert np.all(np.linalg.eigvalsh(more - small) > -1e-15)

    about_z = np.stack([geo.pose_from_rotvec([0, 0, a], [0.4, 0.1 * a, 0.3])
                        for a in np.radians([0, 20, 45, 70, 95])])
    with pytest.raises(ValueError, match="two different axes"):
        cramer_rao_covariance(truth.X_true, truth.Y_true, about_z,
                              rotation_sigma_rad=1e-3, translation_sigma_m=1e-3)
    with pytest.raises(ValueError, match="finite and > 0"):
        cramer_rao_covariance(*args, rotation_sigma_rad=0.0, translation_sigma_m=1e-3)


# --------------------------------------------------------------------------- intrinsics refined


def test_reprojection_intrinsics_jacobian_matches_finite_differences():
    """The intrinsics columns of the corner system: its gradient g = J^T W r (J = d residual /
    d parameter) must be half the finite-difference derivative of the pixel cost r^T W r,
    and, with the robot nuisance marginalised, close to that of the marginal cost (not exact:
    the nuisance's own Jacobian depends on the intrinsics too, which Gauss-Newton ignores)."""
    p = make_hand_eye(3, "eye_in_hand", n_poses=6, noise=NoiseModel(pixel_px=0.5))
    P = p.board.object_points()
    px = p.pixels
    valid = np.all(np.isfinite(px), axis=2)
    views = np.arange(len(px))
    A = p.base_T_flange
    H = mle._chain(A, "eye_in_hand")
    Z, Y = geo.invert(p.X_true), p.Y_true
    K, dist = p.camera.K.astype(float), np.array([-0.1, 0.05, 0.001, -0.001, 0.0])
    w = np.ones(len(px))

    for noise, rel in (((0.25, 0.0, 0.0), 1e-6), ((0.25, 1e-7, 1e-7), 3e-2)):
        def cost(delta, noise=noise):
            Kd, dd = mle._with_intrinsics(K, dist, delta)
            return float(mle._reprojection_system(P, px, valid, Kd, dd, Z, Y, A, H,
                                                  "eye_in_hand", views, w, noise, False,
                                                  True)[2].sum())

        _, g, _, _, _ = mle._reprojection_system(P, px, valid, K, dist, Z, Y, A, H,
                                                 "eye_in_hand", views, w, noise, False, True)
        assert g.shape == (18,)
        for k, h in zip(range(6), (1e-3, 1e-3, 1e-3, 1e-3, 1e-6, 1e-6)):
            e = np.zeros(6)
            e[k] = h
            fd = (cost(e) - cost(-e)) / (2 * h)
            assert 2 * g[12 + k] == pytest.approx(fd, rel=rel), mle.INTRINSIC_PARAMETERS[k]


@pytest.mark.parametrize("fit_board_scale", (False, True))
def test_refine_reprojection_recovers_perturbed_intrinsics(fit_board_scale):
    p = make_hand_eye(4, "eye_in_hand", n_poses=10)
    K_true, dist_true = p.camera.K.astype(float), np.asarray(p.camera.dist, float).ravel()
    K0 = K_true.copy()
    K0[0, 0] *= 1.01
    K0[1, 1] *= 0.99
    K0[0, 2] += 4.0
    K0[1, 2] -= 3.0
    dist0 = np.zeros(5) if dist_true.size == 0 else dist_true.copy()
    dist0[0] += 0.01
    X0 = geo.pose_from_rotvec([0.01, -0.01, 0.01], [0.003, -0.002, 0.004]) @ p.X_true
    kept = refine_reprojection(p.board.object_points(), p.pixels, K0, dist0, p.base_T_flange,
                               X0=X0, Y0=p.Y_true, robot_sigma=(0.0, 0.0),
                               fit_board_scale=fit_board_scale)
    assert kept.camera_matrix is None and kept.reprojection_rms_px > 0.1
    res = refine_reprojection(p.board.object_points(), p.pixels, K0, dist0, p.base_T_flange,
                              X0=X0, Y0=p.Y_true, robot_sigma=(0.0, 0.0),
                              fit_board_scale=fit_board_scale, fit_intrinsics=True)
    assert res.reprojection_rms_px < 1e-5
    np.testing.assert_allclose(res.camera_matrix, K_true, atol=1e-5)
    np.testing.assert_allclose(res.dist_coeffs[:2], dist0[:2] - [0.01, 0.0], atol=1e-7)
    r, t = _errors(res.X, p.X_true)
    assert r < 1e-7 and t < 1e-8
    # predicted_corners uses the refined intrinsics, not the K it is handed.
    pred = mle.predicted_corners(res, p.board.object_points(), K0, dist0, p.base_T_flange)
    assert np.nanmax(np.abs(pred - p.pixels)) < 1e-4


def test_refine_reprojection_intrinsics_needs_enough_views():
    p = make_hand_eye(5, "eye_in_hand", n_poses=6)
    few = p.pixels.copy()
    few[3:] = np.nan
    with pytest.raises(ValueError, match="fit_intrinsics needs at least 4 views"):
        refine_reprojection(p.board.object_points(), few, p.camera.K, p.camera.dist,
                            p.base_T_flange, X0=p.X_true, Y0=p.Y_true, fit_intrinsics=True)


def _choice(scale_free: bool, per_view_px) -> tuple:
    px = np.asarray(per_view_px, float)
    choice = mle.CornerNoiseChoice(1.0, (0.0, 0.0), scale_free,
                                   float(np.exp(np.mean(np.log(px)))))
    return choice, np.log(px)


@pytest.mark.parametrize("free_px, chosen", [
    # a tie in the fourth decimal, as on a capture whose views all look at the board's centre
    # from one distance (there the board's scale trades off against the camera's depth)
    (np.full(12, 0.0879), "fixed"),
    # consistent but small: under 0.5 % is not worth a parameter, 1 % on every view is
    (np.full(12, 0.0879 * 0.997), "fixed"),
    (np.full(12, 0.0879 * 0.99), "free"),
    # 11 % better on average though half the views got worse: the cross-validation's
    # average decides (a one-standard-error rule cost kuka_2's free scale 5 % of its median)
    (0.0879 * np.where(np.arange(12) % 2 == 0, 0.5, 1.6), "free"),
    # kuka_2: the printed board is 6 % small, the free scale wins by 25 % on every view
    (np.full(12, 0.0879 * 0.75), "free"),
])
def test_corner_fit_keeps_an_extra_parameter_only_for_a_gain_that_matters(free_px, chosen):
    fixed = _choice(False, np.full(12, 0.0879))
    free = _choice(True, free_px)
    pose_based = (mle.CornerNoiseChoice(np.nan, None, False, np.inf, method="shah"),
                  np.full(12, np.inf))
    options = [free, fixed, pose_based]
    k = mle._simplest_within_noise([c for c, _ in options], [r for _, r in options])
    assert options[k][0].fit_board_scale == (chosen == "free")


def test_the_noise_steps_bounded_solve_holds_floors_and_solves_the_rest():
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(1, 6))
        M = rng.normal(size=(n, n))
        F, rhs = M @ M.T + 0.1 * np.eye(n), rng.normal(size=n)
        lower = np.where(rng.random(n) < 0.6, 0.1 * rng.normal(size=n), -np.inf)
        held, held_value = rng.random(n) < 0.2, rng.normal(size=n)
        x = mle._bounded_solve(F, rhs, lower, held, held_value)
        np.testing.assert_array_equal(x[held], held_value[held])
        assert np.all(x[~held] >= lower[~held])
        free = ~held & (x > lower)  # the entries not at a bound solve their own equations
        np.testing.assert_allclose((F @ x)[free], rhs[free], atol=1e-9)
        if not held.any() and np.all(np.linalg.solve(F, rhs) >= lower):
            np.testing.assert_allclose(x, np.linalg.solve(F, rhs), atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        mle._solve_small([[1.0, 2.0], [2.0, 4.0]], [1.0, 2.0])

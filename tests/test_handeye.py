"""AX = XB reference solvers (solutions/handeye.py) against the truth and against real OpenCV."""

import itertools
import warnings

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from autograder import synthetic as syn
from robots import geometry as geo
from solutions import handeye as he

CALIBRATE = {"eye_in_hand": he.calibrate_eye_in_hand, "eye_to_hand": he.calibrate_eye_to_hand}
REPORT = {"eye_in_hand": he.calibrate_eye_in_hand_report,
          "eye_to_hand": he.calibrate_eye_to_hand_report}
CLOSED_FORMS = ("tsai", "park", "daniilidis", "axes_ls")
# Noise for the comparisons: a careful student's rig (std-devs per axis).
NOISE = syn.NoiseModel(robot_rot_deg=0.05, robot_trans_mm=0.5, cam_rot_deg=0.1, cam_trans_mm=1.0)


def rot_err(X, Y):
    return geo.rotation_error_deg(X, Y)


def trans_err(X, Y):
    return geo.translation_error(X, Y)


def opencv(base_T_flange, cam_T_target, mount, method):
    """cv2.calibrateHandEye called exactly as its documentation says, written out here."""
    robot = base_T_flange if mount == "eye_in_hand" else geo.invert(base_T_flange)  # base2gripper
    R, t = cv2.calibrateHandEye(list(robot[:, :3, :3]), list(robot[:, :3, 3]),
                                list(cam_T_target[:, :3, :3]), list(cam_T_target[:, :3, 3]),
                                method=method)
    return geo.make_pose(geo.project_to_so3(R), t.ravel())


def random_poses(rng, n):
    R = Rotation.random(n, random_state=rng).as_matrix()
    return np.stack([geo.make_pose(R[i], rng.normal(0, 0.5, 3)) for i in range(n)])


# --------------------------------------------------------------------------- motions


def test_motion_pairs_consecutive_and_all():
    P = random_poses(np.random.default_rng(0), 6)
    motions, pairs = he.motion_pairs(P, "consecutive")
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]])
    motions, pairs = he.motion_pairs(P, "all")
    assert [tuple(p) for p in pairs] == list(itertools.combinations(range(6), 2))  # i < j only
    for (i, j), T in zip(pairs, motions):
        np.testing.assert_allclose(T, np.linalg.inv(P[i]) @ P[j], atol=1e-12)
    with pytest.raises(ValueError, match="strategy"):
        he.motion_pairs(P, "random")


@pytest.mark.parametrize("mount", he.MOUNTS)
@pytest.mark.parametrize("strategy", he.PAIR_STRATEGIES)
def test_hand_eye_motions_are_the_documented_products_and_satisfy_ax_xb(mount, strategy):
    p = syn.make_hand_eye(1, mount, n_poses=7)
    F, C, X = p.base_T_flange, p.cam_T_target, p.X_true
    A, B, pairs = he.hand_eye_motions(F, C, mount, strategy)
    assert len(A) == len(B) == len(pairs) == (21 if strategy == "all" else 6)
    for (i, j), Ak, Bk in zip(pairs, A, B):
        if mount == "eye_in_hand":
            expected_A = np.linalg.inv(F[i]) @ F[j]
        else:
            expected_A = F[i] @ np.linalg.inv(F[j])
        np.testing.assert_allclose(Ak, expected_A, atol=1e-12)
        np.testing.assert_allclose(Bk, C[i] @ np.linalg.inv(C[j]), atol=1e-12)
    # The algebra: eliminating the constant pose between i and j leaves A X = X B.
    np.testing.assert_allclose(A @ X, X @ B, atol=1e-12)
    # ... and the same products with the wrong X do not satisfy it.
    assert np.abs(A @ p.Y_true - p.Y_true @ B).max() > 1e-3


# --------------------------------------------------------------------------- exact recovery


@pytest.mark.parametrize("method", he.METHODS)
@pytest.mark.parametrize("mount", he.MOUNTS)
def test_exact_recovery_without_noise(method, mount):
    p = syn.make_hand_eye(2, mount, n_poses=8)
    for strategy in he.PAIR_STRATEGIES:
        A, B, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target, mount, strategy)
        X = he.solve_ax_xb(A, B, method)
        assert rot_err(X, p.X_true) < 1e-9 and trans_err(X, p.X_true) < 1e-9, strategy
        X = CALIBRATE[mount](p.base_T_flange, p.cam_T_target, method=method, pairs=strategy)
        assert rot_err(X, p.X_true) < 1e-9 and trans_err(X, p.X_true) < 1e-9, strategy


@pytest.mark.parametrize("method", he.METHODS)
def test_exact_recovery_from_three_poses(method):
    # Two consecutive motions are the minimum; OpenCV's Tsai pair filter can leave too few.
    p = syn.make_hand_eye(3, "eye_in_hand", n_poses=3)
    X = he.calibrate_eye_in_hand(p.base_T_flange, p.cam_T_target, method=method,
                                 pairs="consecutive")
    assert rot_err(X, p.X_true) < 1e-9 and trans_err(X, p.X_true) < 1e-9


@pytest.mark.parametrize("method", he.METHODS)
@pytest.mark.parametrize("angle_deg", [150.0, 180.0])
def test_exact_recovery_when_X_is_nearly_or_exactly_a_half_turn(method, angle_deg):
    # A fixed camera looking down has X near a half-turn, where Tsai's tan(theta/2) blows up.
    rng = np.random.default_rng(4)
    axis = np.array([0.6, 0.0, 0.8])
    X = geo.make_pose(Rotation.from_rotvec(np.radians(angle_deg) * axis).as_matrix(),
                      [0.9, -0.2, 0.7])
    F = random_poses(rng, 8)
    Y = geo.make_pose(Rotation.random(random_state=rng).as_matrix(), [0.02, 0.01, 0.05])
    C = geo.invert(X) @ F @ Y  # eye_to_hand: F Y = X C
    X_hat = he.calibrate_eye_to_hand(F, C, method=method)
    assert rot_err(X_hat, X) < 1e-9 and trans_err(X_hat, X) < 1e-9


def test_exact_recovery_with_opencv_test_scenario():
    for mount in he.MOUNTS:
        p = syn.make_opencv_scenario(5, mount, noise=False)
        for method in he.METHODS:
            X = CALIBRATE[mount](p.base_T_flange, p.cam_T_target, method=method)
            assert rot_err(X, p.X_true) < 1e-9 and trans_err(X, p.X_true) < 1e-9, (mount, method)


# --------------------------------------------------------------------------- OpenCV


@pytest.mark.parametrize("mount", he.MOUNTS)
def test_agrees_with_opencv_on_the_same_noisy_data(mount):
    p = syn.make_hand_eye(6, mount, n_poses=12, noise=NOISE)
    F, C = p.base_T_flange, p.cam_T_target
    ours = {m: CALIBRATE[mount](F, C, method=m) for m in he.METHODS}
    cv = {name: opencv(F, C, mount, flag) for name, flag in [
        ("TSAI", cv2.CALIB_HAND_EYE_TSAI), ("PARK", cv2.CALIB_HAND_EYE_PARK),
        ("DANIILIDIS", cv2.CALIB_HAND_EYE_DANIILIDIS)]}
    # Same formulas: Park's rotation and the whole Daniilidis solution are OpenCV's.
    assert rot_err(ours["park"], cv["PARK"]) < 1e-9
    assert rot_err(ours["daniilidis"], cv["DANIILIDIS"]) < 1e-9
    assert trans_err(ours["daniilidis"], cv["DANIILIDIS"]) < 1e-9
    # The orthogonalised axis least squares is the Procrustes solution, i.e. Park's rotation.
    assert rot_err(ours["axes_ls"], cv["PARK"]) < 1e-6
    # Translation (order-symmetric least squares) and Tsai (OpenCV filters pairs) differ
    # from OpenCV only within the noise: at this noise both are ~0.1-0.3 deg / 1-5 mm off
    # the truth.
    assert trans_err(ours["park"], cv["PARK"]) < 2e-3
    assert rot_err(ours["tsai"], cv["TSAI"]) < 0.5 and trans_err(ours["tsai"], cv["TSAI"]) < 3e-3
    assert rot_err(ours["nonlinear"], cv["PARK"]) < 0.5
    assert trans_err(ours["nonlinear"], cv["PARK"]) < 5e-3
    # Against the truth: no method of ours is worse than the worst of the three OpenCV
    # methods it mirrors on the same data (all sit near 0.3 deg / 5 mm at this noise).
    worst_rot = max(rot_err(T, p.X_true) for T in cv.values())
    worst_trans = max(trans_err(T, p.X_true) for T in cv.values())
    for m, X in ours.items():
        assert rot_err(X, p.X_true) <= 1.1 * worst_rot, m
        assert trans_err(X, p.X_true) <= 1.1 * worst_trans, m


# --------------------------------------------------------------------------- conventions


@pytest.mark.parametrize("method", he.METHODS)
@pytest.mark.parametrize("mount", he.MOUNTS)
def test_same_answer_whatever_the_order_of_the_poses(method, mount):
    p = syn.make_hand_eye(7, mount, n_poses=10, noise=NOISE)
    X = CALIBRATE[mount](p.base_T_flange, p.cam_T_target, method=method)
    perm = np.random.default_rng(7).permutation(10)
    X_perm = CALIBRATE[mount](p.base_T_flange[perm], p.cam_T_target[perm], method=method)
    # A permutation reverses some pairs (j, i) and reorders the motions.
    tol_deg, tol_m = (1e-6, 1e-8) if method == "nonlinear" else (1e-9, 1e-12)
    assert rot_err(X, X_perm) < tol_deg and trans_err(X, X_perm) < tol_m
    assert rot_err(X, p.X_true) > 1e-3  # the data really are noisy


@pytest.mark.parametrize("method", he.METHODS)
def test_eye_to_hand_is_eye_in_hand_with_base2gripper(method):
    # OpenCV's eye-to-hand recipe: pass base2gripper = inv(base_T_flange) to the eye-in-hand
    # solver. Ours takes base_T_flange itself; on motions the two routes are the same problem.
    p = syn.make_hand_eye(8, "eye_to_hand", n_poses=10, noise=NOISE)
    A1, B1, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target, "eye_to_hand")
    A2, B2, _ = he.hand_eye_motions(geo.invert(p.base_T_flange), p.cam_T_target, "eye_in_hand")
    np.testing.assert_allclose(A1, A2, atol=1e-12)
    np.testing.assert_allclose(B1, B2, atol=1e-12)
    X1 = he.calibrate_eye_to_hand(p.base_T_flange, p.cam_T_target, method=method)
    X2 = he.calibrate_eye_in_hand(geo.invert(p.base_T_flange), p.cam_T_target, method=method)
    if method == "nonlinear" and he._absolute_refinement() is not None:
        # The absolute-pose refinement models robot noise per mount, so the two routes agree
        # within the noise (errors here are ~0.1 deg, ~1 mm), not to rounding.
        assert rot_err(X1, X2) < 0.05 and trans_err(X1, X2) < 5e-4
    else:
        assert rot_err(X1, X2) < 1e-6 and trans_err(X1, X2) < 1e-8
    cv_X = opencv(p.base_T_flange, p.cam_T_target, "eye_to_hand", cv2.CALIB_HAND_EYE_PARK)
    assert rot_err(X1, cv_X) < 0.5 and trans_err(X1, cv_X) < 5e-3


@pytest.mark.parametrize("mount", he.MOUNTS)
def test_inputs_in_the_other_convention_through_the_documented_conversion(mount):
    p = syn.make_hand_eye(9, mount, n_poses=10, noise=NOISE)
    flange_T_base = geo.invert(p.base_T_flange)  # what a "base2gripper" API reports
    target_T_cam = geo.invert(p.cam_T_target)    # what a "cam2target" tracker reports
    X = CALIBRATE[mount](p.base_T_flange, p.cam_T_target, method="park")
    X_conv = CALIBRATE[mount](geo.invert(flange_T_base), geo.invert(target_T_cam), method="park")
    assert rot_err(X, X_conv) < 1e-9 and trans_err(X, X_conv) < 1e-9
    # Skipping the conversion is the trap: it used to give a wrong X silently; now it is
    # refused, and the message names both conversions (the data cannot say which was skipped).
    for F, C in [(flange_T_base, p.cam_T_target), (p.base_T_flange, target_T_cam)]:
        with pytest.raises(ValueError, match=r"invert\(base_T_flange\).*invert\(cam_T_target\)"):
            CALIBRATE[mount](F, C, method="park")


def test_reversed_motions_have_equal_residuals_and_solutions():
    p = syn.make_hand_eye(10, "eye_in_hand", n_poses=8, noise=NOISE)
    A, B, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target)
    A_rev, B_rev = geo.invert(A), geo.invert(B)  # the (j, i) motions
    # Rotation residual: equal for any X, even with noisy rotations.
    X_any = geo.pose_from_rotvec([0.3, -0.2, 0.5], [0.1, 0.2, 0.3])
    rot, _ = he.motion_residuals(A, B, X_any)
    rot_rev, _ = he.motion_residuals(A_rev, B_rev, X_any)
    np.testing.assert_allclose(rot, rot_rev, rtol=1e-10)
    # Translation residual: equal for any t_X when the rotations agree with R_X (here: exact
    # rotations, noisy translations).
    q = syn.make_hand_eye(10, "eye_in_hand", n_poses=8,
                          noise=syn.NoiseModel(robot_trans_mm=1.0, cam_trans_mm=2.0))
    A, B, _ = he.hand_eye_motions(q.base_T_flange, q.cam_T_target)
    X_t = geo.make_pose(q.X_true[:3, :3], [0.3, -0.1, 0.2])
    rot, trans = he.motion_residuals(A, B, X_t)
    rot_rev, trans_rev = he.motion_residuals(geo.invert(A), geo.invert(B), X_t)
    assert rot.max() < 1e-20 and trans.min() > 1e-6
    np.testing.assert_allclose(trans, trans_rev, rtol=1e-9)
    # Every solver gives the same X from the reversed motions (noisy data).
    A, B, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target)
    for method in he.METHODS:
        X = he.solve_ax_xb(A, B, method)
        X_rev = he.solve_ax_xb(geo.invert(A), geo.invert(B), method)
        assert rot_err(X, X_rev) < 1e-6 and trans_err(X, X_rev) < 1e-8, method


# --------------------------------------------------------------------------- metrics


def test_residual_metrics_against_a_hand_computation():
    A = np.array([geo.pose_from_rotvec([0.4, 0.0, 0.0], [0.1, 0.0, 0.0]),
                  geo.pose_from_rotvec([0.0, 0.0, -0.7], [0.0, 0.2, 0.05])])
    B = np.array([geo.pose_from_rotvec([0.0, 0.38, 0.0], [0.0, 0.1, -0.02]),
                  geo.pose_from_rotvec([0.0, 0.1, 0.7], [0.03, 0.0, 0.1])])
    X = geo.pose_from_rotvec([0.0, 0.0, 0.5], [0.01, -0.02, 0.03])
    rot_terms, trans_terms = [], []
    for Ak, Bk in zip(A, B):
        RA, tA, RB, tB, RX, tX = Ak[:3, :3], Ak[:3, 3], Bk[:3, :3], Bk[:3, 3], X[:3, :3], X[:3, 3]
        rot_terms.append(sum((RA @ RX - RX @ RB)[r, c] ** 2 for r in range(3) for c in range(3)))
        v = RA @ tX + tA - RX @ tB - tX
        trans_terms.append(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    rot_mean, trans_mean = (rot_terms[0] + rot_terms[1]) / 2, (trans_terms[0] + trans_terms[1]) / 2
    assert he.rotation_residual(A, B, X) == pytest.approx(rot_mean, rel=1e-12)
    assert he.translation_residual(A, B, X) == pytest.approx(trans_mean, rel=1e-12)
    rot, trans = he.motion_residuals(A, B, X)
    np.testing.assert_allclose(rot, rot_terms, rtol=1e-12)
    np.testing.assert_allclose(trans, trans_terms, rtol=1e-12)
    # Zero at the truth.
    p = syn.make_hand_eye(11, "eye_to_hand", n_poses=5)
    A, B, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target, "eye_to_hand")
    assert he.rotation_residual(A, B, p.X_true) < 1e-25
    assert he.translation_residual(A, B, p.X_true) < 1e-25


def test_report_is_consistent_with_the_plain_functions():
    p = syn.make_hand_eye(12, "eye_in_hand", n_poses=8, noise=NOISE)
    A, B, pairs = he.hand_eye_motions(p.base_T_flange, p.cam_T_target)
    for method in he.METHODS:
        r = he.solve_ax_xb_report(A, B, method, pairs=pairs)
        np.testing.assert_array_equal(r.X, he.solve_ax_xb(A, B, method))
        assert r.method == method and r.n_motions == len(A) == r.used.sum()
        assert r.rotation_residual == pytest.approx(he.rotation_residual(A, B, r.X), rel=1e-12)
        assert r.translation_residual == pytest.approx(he.translation_residual(A, B, r.X),
                                                       rel=1e-12)
        assert r.rotation_residuals.shape == r.translation_residuals.shape == (len(A),)
    # The nonlinear refinement lowers the course's residuals below its start's.
    r_nl = he.solve_ax_xb_report(A, B, "nonlinear", robust=False)
    r_start = he.solve_ax_xb_report(A, B, r_nl.start_method)
    assert r_nl.translation_residual < r_start.translation_residual


def test_analytic_jacobian_matches_finite_differences():
    p = syn.make_hand_eye(13, "eye_in_hand", n_poses=6, noise=NOISE)
    A, B, _ = he.hand_eye_motions(p.base_T_flange, p.cam_T_target)
    m = he._prepare(A, B)
    weights = np.random.default_rng(0).uniform(0.2, 1.0, len(A))
    problem = he._RefineProblem(m, p.X_true, weights, s_rot=2e-3, s_trans=1e-3)
    x = np.array([0.3, -0.2, 0.4, 0.01, 0.02, -0.03])  # far from 0, so J_l(d) != I matters
    J = problem.jacobian(x)
    h = 1e-6
    J_fd = np.column_stack([(problem.residuals(x + h * e) - problem.residuals(x - h * e)) / (2 * h)
                            for e in np.eye(6)])
    np.testing.assert_allclose(J, J_fd, atol=1e-6 * np.abs(J_fd).max())


# --------------------------------------------------------------------------- degenerate input


@pytest.fixture
def clean():
    return syn.make_hand_eye(14, "eye_in_hand", n_poses=6)


def test_two_poses_are_refused(clean):
    with pytest.raises(ValueError, match="at least 3 poses"):
        he.calibrate_eye_in_hand(clean.base_T_flange[:2], clean.cam_T_target[:2])
    A, B, _ = he.hand_eye_motions(clean.base_T_flange, clean.cam_T_target)
    with pytest.raises(ValueError, match="at least 2 motions"):
        he.solve_ax_xb(A[:1], B[:1])


def test_mismatched_lengths_are_refused(clean):
    with pytest.raises(ValueError, match="mismatched lengths.*6 poses.*5"):
        he.calibrate_eye_to_hand(clean.base_T_flange, clean.cam_T_target[:5])
    A, B, _ = he.hand_eye_motions(clean.base_T_flange, clean.cam_T_target)
    with pytest.raises(ValueError, match="mismatched lengths"):
        he.solve_ax_xb(A, B[:-1], "tsai")


def test_nan_and_non_rotations_are_refused_naming_the_pose(clean):
    F = clean.base_T_flange.copy()
    F[3, 1, 2] = np.nan
    with pytest.raises(ValueError, match=r"base_T_flange\[3\].*NaN"):
        he.calibrate_eye_in_hand(F, clean.cam_T_target)
    C = clean.cam_T_target.copy()
    C[2, :3, 0] *= -1.0  # a reflection: det -1
    with pytest.raises(ValueError, match=r"cam_T_target\[2\].*det"):
        he.calibrate_eye_in_hand(clean.base_T_flange, C, method="park")
    C = clean.cam_T_target.copy()
    C[4, :3, :3] *= 1.01  # scaled, not orthonormal
    with pytest.raises(ValueError, match=r"cam_T_target\[4\].*orthonormal"):
        he.calibrate_eye_in_hand(clean.base_T_flange, C)
    A, B, _ = he.hand_eye_motions(clean.base_T_flange, clean.cam_T_target)
    A[1, 0, 0] = np.inf
    with pytest.raises(ValueError, match=r"A\[1\].*NaN or inf"):
        he.solve_ax_xb(A, B, "daniilidis")


@pytest.mark.parametrize("method", he.METHODS)
def test_pure_translation_motions_are_refused(method):
    rng = np.random.default_rng(15)
    R = Rotation.random(random_state=rng).as_matrix()
    F = np.stack([geo.make_pose(R, rng.normal(0, 0.2, 3)) for _ in range(6)])
    X = geo.pose_from_rotvec([0.1, 0.2, 0.3], [0.05, 0.0, 0.08])
    C = geo.invert(X) @ geo.invert(F) @ geo.make_pose(np.eye(3), [0.5, 0.0, 0.0])
    with pytest.raises(ValueError,
                       match=r"15 motions rotate less than 1.0 deg.*[Pp]ure translations"):
        he.calibrate_eye_in_hand(F, C, method=method)


@pytest.mark.parametrize("method", he.METHODS)
@pytest.mark.parametrize("noisy", [False, True])
def test_all_rotation_axes_parallel_are_refused(method, noisy):
    # The flange only ever turns about its own z: rotation of X about z is unobservable.
    rng = np.random.default_rng(16)
    base_R = Rotation.random(random_state=rng).as_matrix()
    F = np.stack([geo.make_pose(base_R @ Rotation.from_euler("z", a, degrees=True).as_matrix(),
                                rng.normal(0, 0.2, 3)) for a in (0, 20, 45, 70, 100, 130)])
    X = geo.pose_from_rotvec([0.1, 0.2, 0.3], [0.05, 0.0, 0.08])
    Y = geo.pose_from_rotvec([3.0, 0.0, 0.0], [0.5, 0.0, 0.0])
    C = geo.invert(X) @ geo.invert(F) @ Y
    if noisy:
        C = np.stack([syn.perturb_pose(T, np.radians(0.1), 1e-3, rng) for T in C])
    with pytest.raises(ValueError,
                       match="rotation axes are parallel.*rotate the flange about at least two"):
        he.calibrate_eye_in_hand(F, C, method=method)


def test_sub_degree_motions_are_dropped_with_a_warning_or_refused(clean):
    F, C = clean.base_T_flange.copy(), clean.cam_T_target.copy()
    # Pose 5 repeats pose 4's orientation 2 cm away: motion 4->5 is a pure translation.
    shift = geo.make_pose(np.eye(3), [0.02, 0.0, 0.0])
    F[5], C[5] = F[4] @ shift, geo.invert(clean.X_true) @ geo.invert(F[4] @ shift) @ clean.Y_true
    with pytest.warns(UserWarning, match=r"dropped 1 of 5 motions.*4 \(poses 4->5\)"):
        r = he.calibrate_eye_in_hand_report(F, C, method="park", pairs="consecutive")
    assert r.dropped_motion_indices == (4,) and r.n_motions == 4 and not r.used[4]
    assert rot_err(r.X, clean.X_true) < 1e-9 and trans_err(r.X, clean.X_true) < 1e-9
    # Every motion below a degree: refused, naming the motions.
    small = [geo.pose_from_rotvec(np.radians(0.5) * ax, [0.1, 0.0, 0.0]) for ax in np.eye(3)]
    A = np.stack(small)
    B = geo.invert(clean.X_true) @ A @ clean.X_true
    with pytest.raises(ValueError,
                       match=r"3 of 3 motions rotate less than 1.0 deg.*motions 0, 1, 2"):
        he.solve_ax_xb(A, B, "nonlinear")


def test_bad_options_are_refused(clean):
    F, C = clean.base_T_flange, clean.cam_T_target
    with pytest.raises(ValueError, match="unknown hand-eye method 'horaud'"):
        he.calibrate_eye_in_hand(F, C, method="horaud")
    with pytest.raises(ValueError, match="pair strategy"):
        he.calibrate_eye_in_hand(F, C, pairs="every")
    with pytest.raises(ValueError, match="mount"):
        he.hand_eye_motions(F, C, mount="eye_on_base")
    with pytest.raises(ValueError, match="robust=True needs method='nonlinear'"):
        he.calibrate_eye_in_hand(F, C, method="park", robust=True)


# --------------------------------------------------------------------------- outliers


@pytest.mark.parametrize("mount", he.MOUNTS)
def test_robust_refinement_names_an_injected_bad_pose(mount):
    noise = syn.NoiseModel(robot_rot_deg=0.05, robot_trans_mm=0.5, cam_rot_deg=0.1,
                           cam_trans_mm=1.0, n_outliers=1, outlier_rot_deg=5, outlier_trans_mm=50)
    p = syn.make_hand_eye(17, mount, n_poses=10, noise=noise)
    A, B, pairs = he.hand_eye_motions(p.base_T_flange, p.cam_T_target, mount)
    robust = he.solve_ax_xb_report(A, B, "nonlinear", robust=True, pairs=pairs)
    plain = he.solve_ax_xb_report(A, B, "nonlinear", robust=False, pairs=pairs)
    assert robust.outlier_pose_indices == p.outlier_indices
    bad = p.outlier_indices[0]
    touching = {k for k, (i, j) in enumerate(pairs) if bad in (i, j)}
    assert set(robust.downweighted_motion_indices) == touching
    assert plain.outlier_pose_indices == () and plain.weights.min() == 1.0
    assert rot_err(robust.X, p.X_true) < 0.5 * rot_err(plain.X, p.X_true)
    assert trans_err(robust.X, p.X_true) < 0.5 * trans_err(plain.X, p.X_true)
    # The calibrate_* report names the same pose (whatever refinement runs behind it).
    assert REPORT[mount](p.base_T_flange, p.cam_T_target).outlier_pose_indices == p.outlier_indices


def test_robust_refinement_flags_nothing_on_clean_data():
    for seed in range(5):
        for mount in he.MOUNTS:
            p = syn.make_hand_eye(100 + seed, mount, n_poses=10, noise=NOISE)
            r = REPORT[mount](p.base_T_flange, p.cam_T_target)
            assert r.outlier_pose_indices == (), (seed, mount)


def test_no_warning_and_no_drop_on_good_data():
    p = syn.make_hand_eye(18, "eye_to_hand", n_poses=10, noise=NOISE)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = he.calibrate_eye_to_hand_report(p.base_T_flange, p.cam_T_target)
    assert r.dropped_motion_indices == () and r.n_motions == 45
    assert np.all(np.isfinite(r.X)) and r.mount == "eye_to_hand"

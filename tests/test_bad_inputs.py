"""Bad inputs that used to give a silent wrong answer (issue 17, section 3).

Each group has tests that fail on the code before the change (a wrong X returned, or a
correct input refused) and a test that correct inputs still pass without a warning.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from autograder import synthetic as syn
from robots import geometry as geo
from solutions import diagnostics, handeye, mle, registration, robot_world

NOISE = syn.NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5)


def _no_warnings(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args, **kwargs)


# --------------------------------------------------------------------------- the six solvers
# Pose-level entry points, each called the documented way on (base_T_flange, cam_T_target).


def _calibrate(mount, method):
    solve = handeye.calibrate_eye_in_hand if mount == "eye_in_hand" else handeye.calibrate_eye_to_hand
    return lambda F, C: solve(F, C, method=method)


def _ax_yb(mount, method):
    def run(F, C):
        X, Y = robot_world.solve_ax_yb(F, geo.invert(C) if mount == "eye_in_hand" else C, method)
        return X if mount == "eye_in_hand" else Y
    return run


def _refine(mount):
    return lambda F, C: mle.refine_hand_eye(F, C, mount).X


def _entry_points(mount):
    return {
        f"calibrate {mount} nonlinear": _calibrate(mount, "nonlinear"),
        f"calibrate {mount} park": _calibrate(mount, "park"),
        "solve_ax_yb li": _ax_yb(mount, "li"),
        "solve_ax_yb nonlinear": _ax_yb(mount, "nonlinear"),
        "refine_hand_eye": _refine(mount),
    }


CASES = [(mount, name) for mount in handeye.MOUNTS for name in _entry_points(mount)]


@pytest.mark.parametrize(("mount", "name"), CASES)
def test_correct_poses_pass_silently_and_accurately(mount, name):
    p = syn.make_hand_eye(3, mount, n_poses=12, noise=NOISE)
    X = _no_warnings(_entry_points(mount)[name], p.base_T_flange, p.cam_T_target)
    assert geo.rotation_error_deg(X, p.X_true) < 0.5
    assert geo.translation_error(X, p.X_true) < 0.01


@pytest.mark.parametrize(("mount", "name"), CASES)
@pytest.mark.parametrize("side", ["robot", "camera"])
def test_inverted_poses_are_refused_naming_the_fix(mount, name, side):
    p = syn.make_hand_eye(3, mount, n_poses=12, noise=NOISE)
    F, C = p.base_T_flange, p.cam_T_target
    F, C = (geo.invert(F), C) if side == "robot" else (F, geo.invert(C))
    with pytest.raises(ValueError, match=r"do not fit.*invert"):
        _entry_points(mount)[name](F, C)


@pytest.mark.parametrize(("mount", "name"), CASES)
def test_shuffled_pairing_is_refused_with_the_order_that_fits(mount, name):
    p = syn.make_hand_eye(3, mount, n_poses=12, noise=NOISE)
    order = np.random.default_rng(1).permutation(12)
    with pytest.raises(ValueError, match=r"not come from the same view.*order = \[") as err:
        _entry_points(mount)[name](p.base_T_flange, p.cam_T_target[order])
    # The message gives the order that pairs the lists again (it undoes the shuffle).
    listed = str(err.value).split("order = [")[1].split("]")[0]
    fix = np.array([int(v) for v in listed.split(",")])
    np.testing.assert_array_equal(order[fix], np.arange(12))


def test_a_list_shifted_by_one_view_is_named_as_a_shift():
    p = syn.make_hand_eye(4, "eye_in_hand", n_poses=10, noise=NOISE)
    # cam_T_target starts one view late (its first view dropped, a spare one at the end).
    with pytest.raises(ValueError, match=r"shifted by 1 view: base_T_flange\[i\] goes with "
                                         r"cam_T_target\[i - 1\]"):
        handeye.calibrate_eye_in_hand(p.base_T_flange, np.roll(p.cam_T_target, -1, axis=0))


def test_wrong_mount_is_refused_and_the_hint_points_at_the_robot_side():
    p = syn.make_hand_eye(5, "eye_to_hand", n_poses=12, noise=NOISE)
    with pytest.raises(ValueError, match=r"calibrate_eye_to_hand.*board in front of the camera"):
        handeye.calibrate_eye_in_hand(p.base_T_flange, p.cam_T_target)


def test_inverted_camera_poses_are_pointed_at_by_the_board_behind_the_camera():
    p = syn.make_hand_eye(5, "eye_in_hand", n_poses=12, noise=NOISE)
    with pytest.raises(ValueError, match="camera poses are most likely inverted"):
        handeye.calibrate_eye_in_hand(p.base_T_flange, geo.invert(p.cam_T_target))


@pytest.mark.parametrize("method", handeye.METHODS)
def test_motions_from_inverted_poses_warn_and_mispaired_motions_are_refused(method):
    p = syn.make_hand_eye(6, "eye_in_hand", n_poses=12, noise=NOISE)
    A, B, _ = handeye.hand_eye_motions(p.base_T_flange, p.cam_T_target)
    X = _no_warnings(handeye.solve_ax_xb, A, B, method)
    assert geo.rotation_error_deg(X, p.X_true) < 0.5
    A_bad, B_bad, _ = handeye.hand_eye_motions(geo.invert(p.base_T_flange), p.cam_T_target)
    with pytest.warns(UserWarning, match="wrong convention"):
        handeye.solve_ax_xb(A_bad, B_bad, method)
    order = np.random.default_rng(2).permutation(len(B))
    with pytest.raises(ValueError, match="not the same motion"):
        handeye.solve_ax_xb(A, B[order], method)


@pytest.mark.parametrize("mount", handeye.MOUNTS)
def test_no_false_alarm_on_the_benchmark_rows(mount):
    # The rows of benchmarks/handeye_accuracy.py at their noise levels, 5 and 10 poses, a few
    # seeds each (the full sweep, 8000 diagnoses, gave no alarm on correct data).
    problems = [syn.make_opencv_scenario(s, mount, 10) for s in range(3)]
    rows = [syn.NoiseModel(cam_rot_deg=0.1, cam_trans_mm=0.5, n_outliers=1),
            syn.NoiseModel(cam_rot_deg=1.0, cam_trans_mm=5.0),
            syn.NoiseModel(pixel_px=1.0, robot_rot_deg=0.02, robot_trans_mm=0.1)]
    problems += [syn.make_hand_eye(s, mount, n, noise) for noise in rows for n in (5, 10)
                 for s in range(3)]
    problems += [syn.make_hand_eye(s, mount, 10, NOISE, motion_deg=(1.0, 8.0)) for s in range(3)]
    for p in problems:
        d = diagnostics.diagnose_hand_eye(p.base_T_flange, p.cam_T_target, mount)
        assert d.verdict == "ok", (d, p.noise)


# --------------------------------------------------------------------------- small motions


@pytest.mark.parametrize(("n_poses", "seed"), [(3, 18), (4, 1)])
def test_solve_ax_yb_refuses_the_small_motions_that_calibrate_refuses(n_poses, seed):
    # 0.5-1.5 deg between views: the old solve_ax_yb returned X 48-1335 mm off here.
    p = syn.make_hand_eye(seed, n_poses=n_poses, noise=NOISE, motion_deg=(0.5, 1.5))
    with pytest.raises(ValueError, match="rotate less than 1.0 deg"):
        handeye.calibrate_eye_in_hand(p.base_T_flange, p.cam_T_target, method="park")
    for method in robot_world.METHODS:
        with pytest.raises(ValueError, match="rotate less than 1.0 deg"):
            robot_world.solve_ax_yb(p.base_T_flange, geo.invert(p.cam_T_target), method)


# --------------------------------------------------------------------------- point sets


def _flange(seed=1, noise_mm=0.5):
    return syn.make_flange(seed, n_points=12, noise_mm=noise_mm)


def test_points_spread_over_less_than_their_noise_are_refused():
    # 1 mm cube, 0.5 mm noise: the old fit returned a rotation 151 deg / 904 mm off.
    rng = np.random.default_rng(0)
    T = _flange().base_T_cam_true
    src = rng.uniform(-0.0005, 0.0005, (12, 3)) + [0.0, 0.0, 0.8]
    dst = geo.transform_points(T, src) + rng.normal(0.0, 0.0005, (12, 3))
    for fit in (registration.fit_rigid, registration.calibrate_flange):
        with pytest.raises(ValueError, match=r"spread over too little against their noise"):
            fit(src, dst)


def test_a_small_but_precise_point_set_is_still_fitted():
    # The same 1 mm cube measured to 1 micrometre: the rotation is determined, no refusal.
    rng = np.random.default_rng(0)
    T = _flange().base_T_cam_true
    src = rng.uniform(-0.0005, 0.0005, (12, 3)) + [0.0, 0.0, 0.8]
    dst = geo.transform_points(T, src) + rng.normal(0.0, 1e-6, (12, 3))
    fit = _no_warnings(registration.fit_rigid, src, dst)
    assert geo.rotation_error_deg(fit, T) < 2.0


@pytest.mark.parametrize(("scale", "which"), [(1000.0, "base_points look like millimetres"),
                                              (0.001, "cam_points look like millimetres")])
def test_millimetres_passed_as_metres_warn_with_the_cause(scale, which):
    p = _flange()
    cam, base = p.cam_points, p.base_points
    if scale > 1:
        base = base * scale
    else:
        cam = cam / scale
    with pytest.warns(UserWarning, match=which):
        registration.calibrate_flange(cam, base)


@pytest.mark.parametrize("mirror", [[1.0, -1.0, 1.0], [1.0, 1.0, -1.0]])
def test_a_mirrored_point_set_warns_with_the_cause(mirror):
    p = _flange()
    with pytest.warns(UserWarning, match="mirror image far better.*axis flipped"):
        registration.calibrate_flange(p.cam_points * mirror, p.base_points)


def test_correct_point_sets_pass_silently_including_the_real_aubo_capture():
    from autograder.datasets import load_aubo_flange_capture

    cam, base = load_aubo_flange_capture()
    T = _no_warnings(registration.calibrate_flange, cam, base)
    _no_warnings(registration.calibrate_flange, cam, base, robust=True)
    assert registration.fit_rigid_report(cam, base).rms < 0.004
    geo.as_pose(T)
    for seed in range(20):
        for noise_mm in (0.0, 0.5, 2.0):
            p = syn.make_flange(seed, n_points=6 + seed % 10, noise_mm=noise_mm,
                                fixed_orientation=bool(seed % 2))
            _no_warnings(registration.calibrate_flange, p.cam_points, p.base_points)
    # A planar set whose best orthogonal fit is a reflection only by noise: no mirror warning.
    rng = np.random.default_rng(3)
    flat = np.c_[rng.uniform(-0.1, 0.1, (8, 2)), np.zeros(8)]
    _no_warnings(registration.fit_rigid, flat, flat + rng.normal(0, 1e-4, flat.shape))


# --------------------------------------------------------------------------- rotations, dtypes


def _poses_printed_to_6_decimals(n=10):
    p = syn.make_hand_eye(7, n_poses=n, noise=NOISE)
    return p, np.round(p.base_T_flange, 6), np.round(p.cam_T_target, 6)


def test_rotations_printed_to_6_decimals_are_repaired_with_a_note_naming_the_pose():
    p, F6, C6 = _poses_printed_to_6_decimals()
    gram = np.abs(np.swapaxes(F6[:, :3, :3], 1, 2) @ F6[:, :3, :3] - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(gram > geo.ORTHONORMAL_TOL)
    assert bad.size, "fixture no longer has a rounding error above 1e-6"
    with pytest.warns(UserWarning, match=rf"re-orthonormalised.*base_T_flange\[{bad[0]}\]"):
        out = geo.as_poses(F6, "base_T_flange")
    repaired = np.abs(np.swapaxes(out[:, :3, :3], 1, 2) @ out[:, :3, :3] - np.eye(3)).max()
    assert repaired <= geo.ORTHONORMAL_TOL
    assert np.array_equal(F6, np.round(p.base_T_flange, 6))  # the caller's array is untouched
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        X = handeye.calibrate_eye_in_hand(F6, C6)
    assert geo.rotation_error_deg(X, p.X_true) < 0.5


def test_rotations_off_by_more_than_rounding_are_still_refused():
    R = geo.pose_from_rpy(0.1, 0.2, 0.3)
    R[:3, :3] *= 1.0 + 2e-4
    with pytest.raises(ValueError, match=r"pose\[0\] rotation is not orthonormal.*> 0.0001"):
        geo.as_poses([np.eye(4), R][1:], "pose")
    with pytest.raises(ValueError, match="not orthonormal"):
        geo.as_rotation(R[:3, :3])


def test_exact_rotations_pass_silently_and_unchanged():
    p = syn.make_hand_eye(7, n_poses=10, noise=NOISE)
    out = _no_warnings(geo.as_poses, p.base_T_flange)
    assert np.array_equal(out, p.base_T_flange)
    _no_warnings(geo.as_rotation, p.base_T_flange[0, :3, :3])


@pytest.mark.parametrize("call", [
    lambda z: geo.as_poses(z),
    lambda z: geo.as_poses(list(z)),
    lambda z: geo.as_pose(z[0]),
    lambda z: geo.as_rotation(z[0, :3, :3]),
    lambda z: handeye.calibrate_eye_in_hand(z, z),
    lambda z: robot_world.solve_ax_yb(z, z),
    lambda z: registration.fit_rigid(z[:, :3, 3], z[:, :3, 3]),
    lambda z: registration.calibrate_flange(z[:, :3, 3], z[:, :3, 3]),
])
def test_complex_arrays_are_refused(call):
    p = syn.make_hand_eye(8, n_poses=6, noise=NOISE)
    z = p.base_T_flange.astype(complex)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # never numpy's ComplexWarning: a ValueError first
        with pytest.raises(ValueError, match="is complex"):
            call(z)

"""Library calls tell a student what went wrong (issue 38, item 5), and good inputs pass as before.

Each mistake gets a message naming the argument and the fix: a non-rigid pose to the geometry
fast paths, points transposed, pixels where the servo laws want normalised coordinates, and
angular speeds in deg/s. Each good input gives exactly what the unchecked arithmetic gives.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from robots import geometry as geo
from robots import perception as P
from robots.interfaces import Intrinsics
from robots.labkit import lab3
from robots.safety import Safety, SafetyError
from solutions import servoing as S

T1 = geo.pose_from_rotvec([0.1, 0.2, 0.3], [0.1, 0.2, 0.3])
T2 = geo.pose_from_rotvec([0.3, -0.2, 0.1], [0.3, 0.1, 0.2])
PTS = np.array([[0.1, 0.2, 0.3], [-0.1, 0.0, 0.5], [0.0, 0.3, 1.0], [0.2, -0.2, 0.8]])
K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
S_STAR = np.array([[-0.08, -0.08], [0.08, -0.08], [0.08, 0.08], [-0.08, 0.08]])
S_NOW = S_STAR * 1.1 + [0.02, -0.01]
Z = np.full(4, 0.5)


def scaled(T, factor=1.01):
    """T with its rotation block scaled: max |R^T R - I| = factor^2 - 1 (0.0201 for 1.01)."""
    out = T.copy()
    out[:3, :3] *= factor
    return out


def sheared(T, amount):
    """T with R's first column tilted towards its second: off-diagonal |R^T R - I| = amount."""
    out = T.copy()
    out[:3, 0] += amount * out[:3, 1]
    return out


# --------------------------------------------------------------------------- non-rigid poses


@pytest.mark.parametrize("call, names", [
    (lambda bad: geo.invert(bad), ("invert: T",)),
    (lambda bad: geo.compose(T1, bad), ("compose argument 1",)),
    (lambda bad: geo.compose(bad, T1, T2), ("compose argument 0",)),
    (lambda bad: geo.relative(bad, T1), ("relative: a_T_b",)),
    (lambda bad: geo.relative(T1, bad), ("relative: a_T_c",)),
    (lambda bad: geo.transform_points(bad, PTS), ("transform_points: a_T_b",)),
])
def test_a_non_rigid_pose_is_refused_naming_the_argument_the_error_and_the_fix(call, names):
    with pytest.raises(ValueError) as err:
        call(scaled(T1))
    message = str(err.value)
    for name in names:
        assert f"{name} is not a rigid pose" in message, message
    assert "max |R^T R - I| = 2.01e-02 > 0.001" in message, message
    assert "column lengths 1.01, 1.01, 1.01" in message, message
    assert "make_pose" in message and "project_to_so3" in message, message


def test_a_stack_names_the_index_of_its_first_non_rigid_pose():
    stack = np.stack([T1, T2, scaled(T2, 2.0), scaled(T1, 3.0)])
    with pytest.raises(ValueError, match=re.escape("invert: T[2] is not a rigid pose")):
        geo.invert(stack)
    with pytest.raises(ValueError, match=re.escape("compose argument 1[2] is not a rigid pose")):
        geo.compose(T1, stack)
    with pytest.raises(ValueError, match=re.escape("= 3.00e+00 > 0.001")):
        geo.compose(stack, T1)


def test_the_tolerance_sits_at_fast_path_rigid_tol_on_the_max_entry():
    # The single-pose check sums |R^T R - I| over its entries (a bound of the max); a shear
    # puts its whole error in one pair of entries, so the sum is twice the max: a block whose
    # max is just within the tolerance must still pass, one just beyond it must not.
    tol = geo.FAST_PATH_RIGID_TOL
    inside, outside = sheared(T1, 0.9 * tol), sheared(T1, 1.1 * tol)
    for fn in (geo.invert, lambda T: geo.compose(T2, T), lambda T: geo.transform_points(T, PTS)):
        fn(inside)
        with pytest.raises(ValueError, match="not a rigid pose"):
            fn(outside)
    for T in (inside, outside):  # the stacked check draws the same line
        stack = np.stack([T1, T])
        if T is inside:
            geo.invert(stack)
        else:
            with pytest.raises(ValueError, match=re.escape("T[1] is not a rigid pose")):
                geo.invert(stack)


def test_rounding_and_float32_poses_still_pass_unrepaired():
    # Printed to 4 decimals (|R^T R - I| ~ 1e-4): beyond as_pose's repair band, within the
    # fast path's tolerance; the fast path neither warns nor repairs it.
    rounded = np.round(T1, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = geo.invert(rounded)
        geo.invert(T1.astype(np.float32))
    np.testing.assert_array_equal(out[:3, :3], rounded[:3, :3].T)


def test_good_poses_give_exactly_the_unchecked_arithmetic():
    stack = np.stack([T1, T2, T1 @ T2])
    inv = geo.invert(T1)
    R_t = T1[:3, :3].T
    np.testing.assert_array_equal(inv[:3, :3], R_t)
    np.testing.assert_array_equal(inv[:3, 3], -R_t @ T1[:3, 3])
    np.testing.assert_array_equal(inv[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(geo.invert(stack)[1], geo.invert(T2))
    np.testing.assert_array_equal(geo.compose(T1, T2), T1 @ T2)
    np.testing.assert_array_equal(geo.compose(stack, T2), stack @ T2)
    np.testing.assert_array_equal(geo.relative(T1, T2), geo.invert(T1) @ T2)
    np.testing.assert_array_equal(geo.transform_points(T1, PTS),
                                  PTS @ T1[:3, :3].T + T1[:3, 3])


def test_nan_reflections_and_bad_bottom_rows_are_refused_by_the_fast_paths():
    # Issue 50: they used to pass through (NaN in, NaN out; a reflection inverted as it is).
    bad = T1.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match=re.escape("invert: T contains NaN or inf (at (0, 0))")):
        geo.invert(bad)
    with pytest.raises(ValueError, match=re.escape("compose argument 0[1] contains NaN")):
        geo.compose(np.stack([T1, bad]), T2)
    mirrored = T1 @ np.diag([1.0, -1.0, 1.0, 1.0])
    for call, label in ((lambda: geo.invert(mirrored), "invert: T's"),
                        (lambda: geo.compose(T1, np.stack([T2, mirrored])), "argument 1[1]'s"),
                        (lambda: geo.relative(mirrored, T1), "a_T_b's"),
                        (lambda: geo.transform_points(mirrored, PTS), "a_T_b's")):
        with pytest.raises(ValueError, match=re.escape(f"{label} rotation block has det -1.0 "
                                                       "(determinant): it is a reflection")):
            call()
    flat = T1.copy()
    flat[3] = 0.0
    for T in (flat, np.stack([T1, flat])):
        with pytest.raises(ValueError, match=r"has bottom row \[0\.0, 0\.0, 0\.0, 0\.0\]"):
            geo.compose(T2, T)


# --------------------------------------------------------------------------- transposed points


@pytest.mark.parametrize("call, name", [
    (lambda: geo.transform_points(T1, PTS.T), "points_b"),
    (lambda: P.project(PTS.T + [[0.0], [0.0], [1.0]], None), "points_cam"),
    (lambda: P.deproject(np.ones((2, 5)), 0.5, None), "uv"),
    (lambda: S.normalised_projection(PTS.T), "points_cam"),
    (lambda: S.ibvs_velocity(S_NOW.T, S_STAR, Z), "s"),
    (lambda: S.interaction_matrix(S_NOW.T, Z), "points_xy"),
    (lambda: lab3.to_pixels(S_NOW.T, K), "s"),
    (lambda: P.check_normalised(S_NOW.T, "features"), "features"),
])
def test_transposed_points_are_named_with_the_fix(call, name):
    with pytest.raises(ValueError) as err:
        call()
    message = str(err.value)
    assert message.startswith(name) or f" {name} " in message or f"{name} must" in message, message
    assert f"transposed? pass {name}.T" in message, message


# --------------------------------------------------------------------------- pixels for normalised


PIXELS = S_NOW * 300.0 + [160.0, 120.0]  # the same features, in pixels of K


@pytest.mark.parametrize("call, name", [
    (lambda: S.ibvs_velocity(PIXELS, S_STAR, Z), "s"),
    (lambda: S.ibvs_velocity(S_NOW, PIXELS, Z), "s_star"),
    (lambda: S.ibvs_velocity(S_NOW, PIXELS, Z, depths_star=Z, mode="desired"), "s_star"),
    (lambda: S.interaction_matrix(PIXELS, Z), "points_xy"),
    (lambda: S.decoupled_velocity([200.0, 150.0, 900.0, 0.0], [0.0, 0.0, 0.01, 0.0], 0.5),
     "features[:2]"),
    (lambda: lab3.to_pixels(PIXELS, K), "s"),
    (lambda: lab3.to_pixels(PIXELS, K, "s_star"), "s_star"),
])
def test_pixels_where_normalised_coordinates_belong_are_named_with_k_inverse(call, name):
    with pytest.raises(ValueError) as err:
        call()
    message = str(err.value)
    assert message.startswith(f"{name} look like pixel coordinates"), message
    assert "np.linalg.inv(K)" in message and "x = (u - cx) / fx" in message, message
    assert "cv2.undistortPoints" in message, message


def test_check_normalised_names_the_first_pixel_and_draws_the_line_at_ten():
    edge = np.array([[0.1, -10.0], [10.0, 0.2]])
    np.testing.assert_array_equal(P.check_normalised(edge, "s"), edge)
    tracks = np.zeros((5, 4, 2))
    tracks[3, 2] = [0.1, 10.5]
    with pytest.raises(ValueError, match=re.escape("tracks[3, 2] = [ 0.1 10.5]")):
        P.check_normalised(tracks, "tracks")
    many = np.zeros((100, 2))  # beyond the plain-float path: the numpy one
    many[77] = [-12.0, 0.0]
    with pytest.raises(ValueError, match=re.escape("many[77]")):
        P.check_normalised(many, "many")
    with pytest.raises(ValueError, match=re.escape("s must have shape (N, 2)")):
        P.check_normalised(np.zeros((4, 3)), "s")


def test_good_normalised_features_give_the_same_twist_and_pixels_as_before():
    L = S.interaction_matrix(S_NOW, Z)
    x, y = S_NOW[:, 0], S_NOW[:, 1]
    expected = np.zeros((4, 2, 6))
    expected[:, 0] = np.column_stack([-1 / Z, 0 * Z, x / Z, x * y, -(1 + x * x), y])
    expected[:, 1] = np.column_stack([0 * Z, -1 / Z, y / Z, 1 + y * y, -x * y, -x])
    np.testing.assert_array_equal(L, expected.reshape(-1, 6))
    v = S.ibvs_velocity(S_NOW, S_STAR, Z, 1.5)
    np.testing.assert_allclose(v, -1.5 * np.linalg.pinv(L) @ (S_NOW - S_STAR).reshape(-1),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(lab3.to_pixels(S_NOW, K), S_NOW @ K[:2, :2].T + K[:2, 2])


# --------------------------------------------------------------------------- deg/s


def test_an_angular_speed_limit_in_deg_per_s_warns_naming_it():
    with pytest.warns(UserWarning, match=r"max_angular = 30 rad/s .* looks like deg/s.*"
                                         r"np\.radians\(30\) = 0\.5236"):
        out = S.saturate(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), 0.25, 30.0)
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.0, 1.0, 0.0, 0.0])  # still applied
    with pytest.warns(UserWarning, match=r"Safety\.max_joint_speed = 90 rad/s .* deg/s"):
        Safety(max_joint_speed=90.0)
    with pytest.warns(UserWarning, match=r"Safety\.max_rotation_step = 45 rad .* degrees"):
        Safety(max_rotation_step=45.0)


def test_the_safety_warning_comes_once_per_value_and_points_at_the_callers_line():
    with pytest.warns(UserWarning) as record:
        safety = Safety(max_joint_speed=90.0)
        safety.check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)
        safety.check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)
    assert len(record) == 1, [str(w.message) for w in record]
    assert record[0].filename == __file__
    safety.max_joint_speed = 120.0
    with pytest.warns(UserWarning, match="120 rad/s"):
        safety.validate()


def test_a_joint_speed_in_deg_per_s_is_refused_with_the_conversion():
    with pytest.raises(SafetyError, match=r"exceeds Safety\.max_joint_speed.*if you meant 30 "
                                          r"deg/s, pass np\.radians\(30\) = 0\.5236"):
        Safety().check_joint_move(np.zeros(6), np.full(6, 0.1), 30.0)
    with pytest.raises(SafetyError) as err:  # too fast but plausible rad/s: no deg/s hint
        Safety().check_joint_move(np.zeros(6), np.full(6, 0.1), 1.5)
    assert "deg/s" not in str(err.value)


def test_plausible_angular_speeds_and_no_limit_are_silent():
    twist = np.array([0.3, 0.0, 0.0, 2.0, 0.0, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(S.saturate(twist, np.inf, np.inf), twist)
        np.testing.assert_array_equal(S.saturate(twist, 0.3, 6.0), twist)
        np.testing.assert_allclose(S.saturate(twist, 1.0, 1.0), twist / 2.0, rtol=1e-15)
        Safety(max_joint_speed=3.0, max_rotation_step=np.pi)
        Safety().check_joint_move(np.zeros(6), np.full(6, 0.1), 0.5)


def test_a_kinematic_servo_run_is_unchanged_by_the_checks():
    # The whole loop (invert, compose, transform_points, ibvs_velocity, saturate each
    # iteration) on good inputs: converges as before, without a warning.
    intr = Intrinsics.from_K(K, 320, 240)
    goal = geo.make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5])
    square = np.array([[-.04, -.04, 0], [.04, -.04, 0], [.04, .04, 0], [-.04, .04, 0]])
    start = S.offset_start(goal, [0, 0, 0], 0.10, 20.0, np.random.default_rng(0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for method in ("ibvs", "pbvs"):
            result = S.simulate_servo(method, start, goal, square, intr)
            assert result.converged and result.position_error_m < 1e-3, result


# --------------------------------------------------------------------------- issue 50, Required 7


def _message(call) -> str:
    with pytest.raises(ValueError) as err:
        call()
    return str(err.value)


def test_the_named_findings_of_issue_50_name_the_argument_the_problem_and_the_fix():
    from robots.interfaces import Intrinsics as Intr
    from solutions import perception as SP

    intr = Intr.from_K(K, 320, 240)
    depth = np.full((240, 320), 0.5)
    findings = [
        # (call, the argument, the problem, the fix), each a piece of the message
        (lambda: geo.make_pose(np.diag([1.0, 1.0, -1.0])), "R", "det -1", "left-handed frame"),
        (lambda: geo.make_pose(None, [0.1, np.nan, 0.2]), "t", "NaN", "3 finite numbers"),
        (lambda: geo.rotation_error_deg(2.0 * np.eye(3), np.eye(3)), "A", "not orthonormal",
         "project_to_so3"),
        (lambda: S.integrate_twist(T1, [0, 0, 0, 0, 0, 30.0], 0.1), "twist",
         "30 rad/s, more than a turn per second", "np.radians(twist[3:]) (0.5236 rad/s)"),
        (lambda: S.decoupled_velocity([0.01, 0.02, 900.0, 0.0], [0.0, 0.0, 0.01, 0.0], 0.5),
         "features[2]", "looks like pixels^2", "Divide it by fx * fy"),
        (lambda: S.normalised_projection(np.array([[0.1, 0.2, 1.0], [-0.1, 0.1, 1.2],
                                                   [0.0, 0.3, 0.9]]).T),
         "points_cam", "puts a point behind the camera", "transposed? pass points_cam.T"),
        (lambda: SP.fit_flange(depth, intr, roi=[10, 10, np.nan, 100]), "roi", "NaN",
         "4 finite pixel bounds"),
        (lambda: SP.fit_flange(depth, intr, roi=[10, 10, 100]), "roi", "shape (3,)",
         "(u0, v0, u1, v1)"),
        (lambda: SP.fit_flange(depth, intr, radius_m=31.5), "radius_m", "millimetres",
         "radius_m=0.0315"),
        (lambda: SP.fit_flange(depth, K), "intrinsics", "ndarray of shape (3, 3)",
         "Intrinsics.from_K"),
    ]
    for call, argument, problem, fix in findings:
        message = _message(call)
        for piece in (argument, problem, fix):
            assert piece in message, (piece, message)


def test_a_reflection_is_named_by_its_determinant_wherever_a_pose_goes():
    mirrored = T1 @ np.diag([1.0, 1.0, -1.0, 1.0])
    for call in (lambda: geo.invert(mirrored), lambda: geo.compose(T2, mirrored),
                 lambda: geo.transform_points(mirrored, PTS),
                 lambda: geo.rotation_error_deg(mirrored, T2),
                 lambda: geo.translation_error(T2, mirrored)):
        message = _message(call)
        assert "det -1.0 (determinant): it is a reflection, not a rotation" in message, message
        assert "handedness" in message, message


def test_the_step_rule_of_integrate_twist_sits_at_half_a_turn():
    w = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 6.0])  # under a turn per second: rad/s is plausible
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        S.integrate_twist(T1, w, 0.99 * np.pi / 6.0)
        S.integrate_twist(T1, w, -0.99 * np.pi / 6.0)  # backwards in time: the inverse motion
    assert "more than half a turn" in _message(lambda: S.integrate_twist(T1, w, 1.01 * np.pi / 6))


def test_two_pixel_areas_give_the_right_twist_and_a_mixed_pair_is_refused():
    # Only the ratio of the areas counts, so both in pixels^2 (under 400) is harmless.
    fx_fy = 300.0 * 300.0
    now, goal = np.array([0.02, 0.01, 0.0012, 0.0]), np.array([0.0, 0.0, 0.0016, 0.0])
    in_pixels = S.decoupled_velocity(now * [1, 1, fx_fy, 1], goal * [1, 1, fx_fy, 1], 0.4)
    np.testing.assert_allclose(in_pixels, S.decoupled_velocity(now, goal, 0.4), rtol=1e-12)
    message = _message(lambda: S.decoupled_velocity(now * [1, 1, fx_fy, 1], goal, 0.4))
    assert "features[2] looks like pixels^2 and desired[2] normalised" in message, message

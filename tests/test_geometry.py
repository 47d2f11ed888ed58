"""Pose math: round trips (property tests), validation messages, errors and averages."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robots import geometry as geo

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
# Rotation vectors with angle below pi, where the rotation-vector chart is one-to-one.
rotvecs = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0.0, 3.1)).filter(
    lambda a: np.linalg.norm(a[:3]) > 1e-3
).map(lambda a: np.array(a[:3]) / np.linalg.norm(a[:3]) * a[3])
quats = st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 1e-3).map(np.array)
poses = st.tuples(quats, vec3).map(lambda qt: geo.pose_from_quat_xyzw(qt[0], qt[1]))


@given(poses)
def test_invert_is_a_true_inverse(T):
    np.testing.assert_allclose(geo.invert(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(geo.compose(T, geo.invert(T)), np.eye(4), atol=1e-12)


@given(poses, poses, poses)
def test_compose_is_associative_and_relative_undoes_it(A, B, C):
    np.testing.assert_allclose(geo.compose(A, B, C), A @ (B @ C), atol=1e-9)
    np.testing.assert_allclose(geo.relative(A, A @ B), B, atol=1e-9)


@given(rotvecs, vec3)
def test_rotvec_round_trip(rv, t):
    rv2, t2 = geo.rotvec_from_pose(geo.pose_from_rotvec(rv, t))
    np.testing.assert_allclose(rv2, rv, atol=1e-9)
    np.testing.assert_allclose(t2, t)


@given(quats, vec3)
def test_quat_xyzw_round_trip_up_to_sign(q, t):
    q = q / np.linalg.norm(q)
    q2, t2 = geo.quat_xyzw_from_pose(geo.pose_from_quat_xyzw(q, t))
    assert q2[3] >= 0
    # q and -q are the same rotation; with w = 0 both signs satisfy w >= 0.
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9
    np.testing.assert_allclose(t2, t)


@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_rpy_and_euler_zyx_name_the_same_rotation(roll, pitch, yaw):
    T = geo.pose_from_rpy(roll, pitch, yaw)
    Rz = Rotation.from_euler("z", yaw).as_matrix()
    Ry = Rotation.from_euler("y", pitch).as_matrix()
    Rx = Rotation.from_euler("x", roll).as_matrix()
    np.testing.assert_allclose(T[:3, :3], Rz @ Ry @ Rx, atol=1e-12)
    np.testing.assert_allclose(geo.pose_from_euler_zyx(yaw, pitch, roll), T, atol=1e-12)
    np.testing.assert_allclose(geo.rpy_from_pose(T), [roll, pitch, yaw], atol=1e-9)
    np.testing.assert_allclose(geo.euler_zyx_from_pose(T), [yaw, pitch, roll], atol=1e-9)


def test_pose_convention_maps_child_coordinates_to_parent():
    base_T_cam = geo.make_pose(Rotation.from_euler("z", 90, degrees=True).as_matrix(), [1.0, 0, 0])
    # A point 1 m along the camera's x axis lies 1 m along the base's y axis, offset by t.
    np.testing.assert_allclose(geo.transform_points(base_T_cam, [1.0, 0, 0]), [1.0, 1.0, 0.0], atol=1e-12)


@given(rotvecs)
def test_rotation_error_is_the_geodesic_angle(rv):
    R = geo.pose_from_rotvec(rv)
    assert geo.rotation_error_deg(np.eye(4), R) == pytest.approx(np.degrees(np.linalg.norm(rv)), abs=1e-7)


def test_rotation_error_is_precise_for_tiny_angles():
    # acos((tr - 1) / 2) would return 0 or ~1e-6 deg noise here.
    R = geo.pose_from_rotvec([1e-9, 0, 0])
    assert geo.rotation_error_deg(np.eye(4), R) == pytest.approx(np.degrees(1e-9), rel=1e-6)


# Angles at the branch points of the plain-float conversions: the Taylor series below 1e-4
# rad, the switch to the symmetric part at cos = -0.9 (154 deg), and 180 deg itself.
EDGE_ANGLES = (0.0, 1e-12, 1e-8, 0.99e-4, 1.01e-4, 0.3, 2.69, 2.70, 3.0, np.pi - 1e-6, np.pi)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_fast_conversions_agree_with_scipy_at_every_branch(angle):
    rng = np.random.default_rng(7)
    for _ in range(20):
        axis = rng.normal(size=3)
        rv = angle * axis / np.linalg.norm(axis)
        R = Rotation.from_rotvec(rv).as_matrix()
        np.testing.assert_allclose(geo.rotation_from_rotvec(rv), R, atol=1e-15)
        back = geo.rotvec_from_rotation(R)
        # At 180 deg +axis and -axis are the same rotation: compare as rotations there.
        np.testing.assert_allclose(Rotation.from_rotvec(back).as_matrix(), R, atol=2e-15)
        if angle < 3.0:
            np.testing.assert_allclose(back, rv, atol=2e-15)
        assert geo.rotation_angle_deg(R) == pytest.approx(np.degrees(angle), abs=1e-12)
        assert geo.rotation_angle_deg(R[None])[0] == pytest.approx(np.degrees(angle), abs=1e-12)
        q = Rotation.from_matrix(R).as_quat()
        np.testing.assert_allclose(geo.pose_from_quat_xyzw(3.0 * q)[:3, :3], R, atol=2e-15)
        # each of Shepperd's four branches meets these (trace or a diagonal entry largest)
        mine = geo.quat_xyzw_from_rotation(R)
        assert mine[3] >= 0.0
        np.testing.assert_allclose(mine, q if q[3] >= 0 else -q, atol=1e-15)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_slerp_follows_scipys_shortest_arc_at_every_branch(angle):
    from scipy.spatial.transform import Slerp

    rng = np.random.default_rng(11)
    fractions = np.linspace(0.0, 1.0, 9)
    for _ in range(10):
        R0 = Rotation.random(random_state=rng).as_matrix()
        axis = rng.normal(size=3)
        R1 = R0 @ Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
        mine = geo.slerp_rotations(R0, R1, fractions)
        np.testing.assert_allclose(mine[0], R0, atol=1e-15)
        np.testing.assert_allclose(mine[-1], R1, atol=2e-15)
        if angle < np.pi:   # at 180 deg either way round is a shortest arc
            scipys = Slerp([0.0, 1.0], Rotation.from_matrix([R0, R1]))(fractions).as_matrix()
            np.testing.assert_allclose(mine, scipys, atol=1e-14)
        steps = [geo.rotation_angle_deg(a.T @ b) for a, b in zip(mine[:-1], mine[1:])]
        np.testing.assert_allclose(steps, np.degrees(angle) / 8, atol=1e-9)


def test_stacked_rotvecs_equal_the_single_conversion_at_every_branch():
    rng = np.random.default_rng(8)
    axes = rng.normal(size=(len(EDGE_ANGLES) * 5, 3))
    rv = np.repeat(EDGE_ANGLES, 5)[:, None] * axes / np.linalg.norm(axes, axis=1)[:, None]
    R = Rotation.from_rotvec(rv).as_matrix()
    R[-1] += 1e-6 * rng.normal(size=(3, 3))  # off by rounding: projected first, as one by one
    one_by_one = np.array([geo.rotvec_from_rotation(m) for m in R])
    np.testing.assert_allclose(geo.rotvecs_from_rotations(R), one_by_one, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"\(N, 3, 3\)"):
        geo.rotvecs_from_rotations(R[0])


def _with(T, index, value):
    T = np.array(T, dtype=float)
    T[index] = value
    return T


# One pose: a clean one takes the plain-float check, everything else the stack's full check.
SINGLE_POSES = {
    "clean, huge t": (geo.pose_from_rotvec([0.3, -1.0, 2.0], [1e308, -1e308, 1e308]), None),
    "nan in t": (_with(np.eye(4), (1, 3), np.nan), "NaN or inf"),
    "inf - inf in t": (_with(_with(np.eye(4), (0, 3), np.inf), (1, 3), -np.inf), "NaN or inf"),
    "nan in R": (_with(np.eye(4), (1, 2), np.nan), "NaN or inf"),
    "bottom row": (_with(np.eye(4), (3, 2), 1e-6), "bottom row"),
    "bottom row off by rounding": (_with(np.eye(4), (3, 2), 1e-12), None),
    "reflection": (np.diag([1.0, 1.0, -1.0, 1.0]), "det -1"),
    "not orthonormal": (np.diag([1.1, 1.0, 1.0, 1.0]), "not orthonormal"),
}


@pytest.mark.parametrize("case", SINGLE_POSES)
def test_single_pose_validation_agrees_with_the_stack_check(case):
    T, message = SINGLE_POSES[case]
    if message is None:
        np.testing.assert_array_equal(geo.as_pose(T), geo.as_poses(T[None])[0])
        return
    for check in (lambda: geo.as_pose(T, "X"), lambda: geo.as_poses(T[None], "X")):
        with pytest.raises(ValueError, match=message):
            check()


def test_a_rotation_off_by_rounding_is_repaired_with_a_warning_one_pose_or_many():
    T = geo.pose_from_rotvec([0.3, -1.0, 2.0], [0.1, 0.2, 0.3])
    T[:3, :3] += 2e-6 * np.random.default_rng(3).normal(size=(3, 3))
    for check in (lambda: geo.as_pose(T), lambda: geo.as_poses(T[None])[0],
                  lambda: geo.make_pose(T[:3, :3])):
        with pytest.warns(UserWarning, match="re-orthonormalised"):
            fixed = check()
        np.testing.assert_allclose(fixed[:3, :3].T @ fixed[:3, :3], np.eye(3), atol=1e-12)


def test_a_slightly_off_rotation_gets_its_nearest_rotations_angle_and_nan_is_refused():
    R = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    off = R + 1e-5 * np.random.default_rng(0).normal(size=(3, 3))
    expected = Rotation.from_matrix(off)  # scipy orthonormalises first too
    np.testing.assert_allclose(geo.rotvec_from_rotation(off), expected.as_rotvec(), atol=1e-9)
    assert geo.rotation_angle_deg(off) == pytest.approx(np.degrees(expected.magnitude()), abs=1e-7)
    nan_corner = np.eye(3)
    nan_corner[2, 2] = np.nan  # NaN only in the last column, which a max() would have dropped
    with pytest.raises(ValueError, match="NaN or inf"):
        geo.rotation_angle_deg(nan_corner)
    with pytest.raises(ValueError, match="NaN or inf"):
        geo.rotvec_from_rotation(nan_corner)


def test_stacks_broadcast():
    rng = np.random.default_rng(0)
    Ts = np.stack([geo.pose_from_rotvec(rng.normal(size=3), rng.normal(size=3)) for _ in range(5)])
    errs = geo.rotation_error_deg(Ts, Ts)
    assert errs.shape == (5,) and np.all(errs < 1e-6)
    np.testing.assert_allclose(geo.invert(Ts) @ Ts, np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)
    assert geo.translation_error(Ts, Ts).shape == (5,)


def test_translation_error_in_metres():
    assert geo.translation_error(geo.make_pose(t=[0.003, 0.004, 0]), np.eye(4)) == pytest.approx(0.005)


def test_chordal_mean_of_symmetric_rotations_is_the_middle():
    Rs = [Rotation.from_euler("z", a, degrees=True).as_matrix() for a in (-10, 0, 10)]
    np.testing.assert_allclose(geo.chordal_mean_rotation(Rs), np.eye(3), atol=1e-12)
    weighted = geo.chordal_mean_rotation(Rs[1:], weights=[1, 1])
    assert geo.rotation_error_deg(weighted, Rs[2]) == pytest.approx(5.0, abs=1e-9)


def test_project_to_so3_gives_a_proper_rotation():
    rng = np.random.default_rng(1)
    R = geo.project_to_so3(rng.normal(size=(3, 3)))
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.diag([1.0, 1.0, -1.0, 1.0]), "det -1"),
        (np.diag([1.1, 1.0, 1.0, 1.0]), "not orthonormal"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.eye(3), "shape (4, 4)"),
        (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "bottom row"),
        (np.vstack([np.eye(4)[:3], [0, 0, 0, 1 + 1e-6]]), "bottom row"),
    ],
)
def test_validation_names_the_index_and_the_problem(bad, message):
    with pytest.raises(ValueError) as excinfo:
        geo.as_poses([np.eye(4), np.eye(4), bad], name="base_T_flange")
    assert "base_T_flange[2]" in str(excinfo.value)
    assert message in str(excinfo.value)


def test_validation_rejects_a_single_pose_where_a_list_is_expected():
    with pytest.raises(ValueError, match="single"):
        geo.as_poses(np.eye(4))


def test_validation_enforces_minimum_count():
    with pytest.raises(ValueError, match="at least 3"):
        geo.as_poses([np.eye(4)] * 2, min_count=3)


def test_quaternion_must_be_non_zero():
    with pytest.raises(ValueError, match="non-zero"):
        geo.pose_from_quat_xyzw([0, 0, 0, 0])

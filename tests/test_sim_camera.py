"""The simulated camera: projection from K, metric depth, distortion, noise, mounts, stereo."""

import cv2
import numpy as np
import pybullet as p
import pytest

from robots.geometry import compose, invert, make_pose, pose_from_rpy, transform_points
from robots.interfaces import Frame, Intrinsics, RobotDisconnectedError
from sim_backends import scene, textures
from sim_backends.camera import SimCamera, depth_from_buffer, lighting_from, projection_matrix

# Deliberately awkward intrinsics: fx != fy and a principal point well off the centre, so a
# projection matrix that ignores either would miss by many pixels.
INTR = Intrinsics(fx=610.0, fy=590.0, cx=301.3, cy=257.8, width=640, height=480)


@pytest.fixture
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _sphere(client, centre, radius):
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client)
    return p.createMultiBody(0, -1, vis, list(centre), physicsClientId=client)


def _sphere_image_centre(K, c_cam, r):
    """Exact centre of the ellipse a sphere (centre c_cam, radius r) projects to.

    The silhouette cone is {x : (x . c)^2 = |x|^2 (|c|^2 - r^2)}; as a conic on the normalised
    image plane its centre is -A^-1 b. The sphere centre's own projection differs from it by
    up to ~0.1 px off-axis, which this test must not absorb into its tolerance.
    """
    C = np.outer(c_cam, c_cam) - (c_cam @ c_cam - r * r) * np.eye(3)
    xy = -np.linalg.solve(C[:2, :2], C[:2, 2])
    return K[:2, :2] @ xy + K[:2, 2]


# A camera pose that is not aligned with the world, so the view matrix is exercised too.
WORLD_T_CAM = pose_from_rpy(2.6, 0.3, -0.7, t=[0.4, -0.2, 0.9])


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.12, -0.09), (-0.15, 0.11), (0.16, 0.13)])
def test_known_point_lands_at_the_pixel_k_predicts_with_true_depth(client, offset):
    r = 0.012
    c_cam = np.array([offset[0], offset[1], 0.55])
    centre_world = transform_points(WORLD_T_CAM, c_cam)
    body = _sphere(client, centre_world, r)
    cam = SimCamera(client, INTR, world_T_cam=WORLD_T_CAM)
    _, depth, seg = cam.render(segmentation=True)
    vv, uu = np.nonzero(seg == body)
    assert len(uu) > 300, "sphere not rendered where expected"
    expected = _sphere_image_centre(INTR.K, c_cam, r)
    assert np.hypot(uu.mean() - expected[0], vv.mean() - expected[1]) <= 0.5
    # Depth at the pixel nearest the sphere centre's projection: z of the first hit on the
    # sphere along that pixel's ray.
    u0, v0 = np.rint(INTR.K[:2, :2] @ (c_cam[:2] / c_cam[2]) + INTR.K[:2, 2]).astype(int)
    ray = np.linalg.solve(INTR.K, [u0, v0, 1.0])
    a, b, c = ray @ ray, -2 * ray @ c_cam, c_cam @ c_cam - r * r
    s = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
    assert abs(depth[v0, u0] - s * ray[2]) <= 1e-3


def test_plate_depth_is_metric_everywhere(client):
    """A fronto-parallel plate at z = 0.8 m: every pixel on it reads 0.8 m, and its mask is
    centred where K puts the plate's centre."""
    half = (0.101, 0.0763)
    # Turned about the optical axis so its edges are slanted: an axis-aligned mask would
    # quantise its centroid to half pixels.
    cam_T_plate = pose_from_rpy(0, 0, 0.3, t=[0.05, -0.03, 0.8])
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[*half, 1e-4], physicsClientId=client)
    world_T_plate = compose(WORLD_T_CAM, cam_T_plate, make_pose(t=[0, 0, 1e-4]))
    from scipy.spatial.transform import Rotation

    body = p.createMultiBody(0, -1, vis, world_T_plate[:3, 3].tolist(),
                             Rotation.from_matrix(world_T_plate[:3, :3]).as_quat().tolist(),
                             physicsClientId=client)
    cam = SimCamera(client, INTR, world_T_cam=WORLD_T_CAM)
    _, depth, seg = cam.render(segmentation=True)
    mask = seg == body
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.abs(depth[inner] - 0.8).max() <= 1e-3
    vv, uu = np.nonzero(mask)
    expected = INTR.K[:2, :2] @ (cam_T_plate[:2, 3] / 0.8) + INTR.K[:2, 2]
    assert np.hypot(uu.mean() - expected[0], vv.mean() - expected[1]) <= 0.1
    assert np.isnan(depth[~mask]).all(), "empty pixels must read NaN (no measurement)"


def test_projection_matrix_matches_formula():
    P = projection_matrix(INTR.K, 640, 480, 0.01, 10.0)
    X = np.array([0.07, -0.05, -0.6, 1.0])  # OpenGL eye coordinates (looking along -z)
    clip = P @ X
    ndc = clip[:3] / clip[3]
    # Window coordinates back to OpenCV pixels with the convention documented in camera.py.
    u = (ndc[0] + 1) * 640 / 2
    v = 480 - 1 - (ndc[1] + 1) * 480 / 2
    x, y, z = X[0], -X[1], -X[2]
    assert np.allclose([u, v], [INTR.fx * x / z + INTR.cx, INTR.fy * y / z + INTR.cy])
    d = (ndc[2] + 1) / 2
    assert np.isclose(depth_from_buffer(np.array([d]), 0.01, 10.0)[0], 0.6, atol=1e-6)


def _board_scene(client, cam_T_target, intr, **kw):
    target = textures.chessboard()
    cam = SimCamera(client, intr, world_T_cam=np.eye(4), **kw)
    scene.add_target(client, target, cam_T_target)
    return cam, target


def _chessboard_corners(gray, target):
    ok, corners = cv2.findChessboardCorners(gray, target.pattern_size)
    assert ok, "chessboard not found"
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)


def _order_like(pred, found):
    """Undo the 180-degree order ambiguity of a symmetric chessboard (closest to pred)."""
    if np.linalg.norm(pred[0] - found[0]) > np.linalg.norm(pred[0] - found[-1]):
        return found[::-1]
    return found


def test_distortion_round_trip(client):
    dist = np.array([-0.28, 0.09, 0.0012, -0.0008, -0.01])
    intr_d = Intrinsics(INTR.fx, INTR.fy, INTR.cx, INTR.cy, 640, 480, dist)
    cam_T_target = pose_from_rpy(0.25, -0.2, 0.05, t=[-0.16, -0.12, 0.55])
    cam_d, target = _board_scene(client, cam_T_target, intr_d)
    cam_p = SimCamera(client, INTR, world_T_cam=np.eye(4))
    distorted, _, _ = cam_d.render()
    pinhole, _, _ = cam_p.render()
    # The distorted image really is distorted: corners sit where OpenCV's model puts them.
    rv = cv2.Rodrigues(cam_T_target[:3, :3])[0]
    pred_d, _ = cv2.projectPoints(target.object_points, rv, cam_T_target[:3, 3], INTR.K, dist)
    pred_d = pred_d.reshape(-1, 2)
    found_d = _order_like(pred_d, _chessboard_corners(cv2.cvtColor(distorted, cv2.COLOR_RGB2GRAY),
                                                      target))
    assert np.linalg.norm(found_d - pred_d, axis=1).max() < 0.3
    pred_p, _ = cv2.projectPoints(target.object_points, rv, cam_T_target[:3, 3], INTR.K, None)
    assert np.linalg.norm(pred_d - pred_p.reshape(-1, 2), axis=1).max() > 5, "no visible distortion"
    # cv2.undistort with the same coefficients gives back the pinhole image.
    restored = cv2.undistort(distorted, INTR.K, dist)
    diff = np.abs(restored.astype(int) - pinhole.astype(int))[40:-40, 40:-40]
    assert diff.mean() < 2.0
    found_r = _order_like(pred_p.reshape(-1, 2),
                          _chessboard_corners(cv2.cvtColor(restored, cv2.COLOR_RGB2GRAY), target))
    assert np.linalg.norm(found_r - pred_p.reshape(-1, 2), axis=1).max() < 0.3


def test_too_strong_distortion_is_refused(client):
    # A wide lens whose barrel model folds over inside the image: no inverse exists.
    bad = Intrinsics(300, 300, 320, 240, 640, 480, [-0.5, 0.0, 0, 0, 0.0])
    with pytest.raises(ValueError, match="distortion"):
        SimCamera(client, bad, world_T_cam=np.eye(4))


def test_noise_is_seeded_and_scaled(client):
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[2, 2, 0.001],
                              rgbaColor=[0.5, 0.5, 0.5, 1], physicsClientId=client)
    p.createMultiBody(0, -1, vis, [0, 0, 1.0 + 0.001], physicsClientId=client)
    small = Intrinsics(300, 300, 159.5, 119.5, 320, 240)

    def frame(seed):
        cam = SimCamera(client, small, world_T_cam=np.eye(4), pixel_noise=4.0, depth_noise=0.002,
                        rng=np.random.default_rng(seed))
        return cam.capture()

    a, b, c = frame(1), frame(1), frame(2)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert not np.array_equal(a.rgb, c.rgb)
    clean, depth, _ = SimCamera(client, small, world_T_cam=np.eye(4)).render()
    assert np.std(a.rgb.astype(float) - clean) == pytest.approx(4.0, rel=0.05)
    # RealSense-like depth noise: sigma = k z^2 = 0.002 * 1^2 m at the 1 m plate.
    assert np.std(a.depth - depth) == pytest.approx(0.002, rel=0.05)
    assert isinstance(a, Frame) and a.depth.dtype == np.float32


def test_camera_on_a_link_follows_the_link(client):
    """A camera riding on a moving link (as eye-in-hand does) uses the link's true pose."""
    box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.02] * 3, physicsClientId=client)
    arm = p.createMultiBody(
        0, box, -1, [0, 0, 0], linkMasses=[1.0], linkCollisionShapeIndices=[box],
        linkVisualShapeIndices=[-1], linkPositions=[[0, 0, 0.3]],
        linkOrientations=[[0, 0, 0, 1]], linkInertialFramePositions=[[0, 0, 0]],
        linkInertialFrameOrientations=[[0, 0, 0, 1]], linkParentIndices=[0],
        linkJointTypes=[p.JOINT_REVOLUTE], linkJointAxis=[[0, 0, 1]], physicsClientId=client,
    )
    link_T_cam = pose_from_rpy(np.pi, 0, 0, t=[0.07, 0.0, 0.02])  # off the joint axis
    cam = SimCamera(client, Intrinsics(200, 200, 79.5, 59.5, 160, 120), parent=(arm, 0),
                    link_T_cam=link_T_cam)
    for q in (0.0, 0.8):
        p.resetJointState(arm, 0, q, physicsClientId=client)
        expected = compose(pose_from_rpy(0, 0, q, t=[0, 0, 0.3]), link_T_cam)
        assert np.allclose(cam.world_T_cam(), expected, atol=1e-9)
    cam.capture()  # renders without hanging


def test_stereo_pair_sees_the_baseline(client):
    """Two cameras 6 cm apart along the left camera's x: PnP in each recovers left_T_right."""
    baseline = 0.06
    world_T_left = pose_from_rpy(0.1, 0.2, 0.3, t=[0.1, 0.0, -0.1])
    left_T_right = make_pose(t=[baseline, 0, 0])
    cam_T_target = pose_from_rpy(0.2, -0.15, 0.05, t=[-0.14, -0.11, 0.6])
    target = textures.chessboard()
    scene.add_target(client, target, compose(world_T_left, cam_T_target))
    poses = []
    for world_T_cam in (world_T_left, compose(world_T_left, left_T_right)):
        cam = SimCamera(client, INTR, world_T_cam=world_T_cam)
        gray = cv2.cvtColor(cam.render()[0], cv2.COLOR_RGB2GRAY)
        cam_T_t = compose(invert(world_T_cam), world_T_left, cam_T_target)
        rv = cv2.Rodrigues(cam_T_t[:3, :3])[0]
        pred = cv2.projectPoints(target.object_points, rv, cam_T_t[:3, 3], INTR.K, None)[0]
        found = _order_like(pred.reshape(-1, 2), _chessboard_corners(gray, target))
        _, rvec, tvec = cv2.solvePnP(target.object_points, found, INTR.K, None,
                                     flags=cv2.SOLVEPNP_ITERATIVE)
        poses.append(make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel()))
    estimated = compose(poses[0], invert(poses[1]))
    assert np.linalg.norm(estimated[:3, 3] - [baseline, 0, 0]) < 1e-3


def test_bad_arguments_raise(client):
    with pytest.raises(ValueError, match="exactly one mount"):
        SimCamera(client, INTR)
    with pytest.raises(ValueError, match="pixel_noise"):
        SimCamera(client, INTR, world_T_cam=np.eye(4), pixel_noise=-1)
    with pytest.raises(ValueError, match="near"):
        SimCamera(client, INTR, world_T_cam=np.eye(4), near=1.0, far=0.5)
    with pytest.raises(ValueError, match="lighting"):
        lighting_from("disco")
    with pytest.raises(ValueError):
        SimCamera(client, INTR, world_T_cam=np.full((4, 4), np.nan))
    cam = SimCamera(client, INTR, world_T_cam=np.eye(4))
    cam.close()
    with pytest.raises(RobotDisconnectedError):
        cam.capture()


def test_lighting_changes_the_image(client):
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[2, 2, 0.001],
                              rgbaColor=[0.8, 0.8, 0.8, 1], physicsClientId=client)
    p.createMultiBody(0, -1, vis, [0, 0, 1.0], physicsClientId=client)
    small = Intrinsics(200, 200, 79.5, 59.5, 160, 120)
    means = {name: SimCamera(client, small, world_T_cam=np.eye(4), lighting=name).render()[0].mean()
             for name in ("default", "dim", "side", "overhead")}
    assert means["dim"] < 0.8 * means["default"]
    assert len({round(m, 1) for m in means.values()}) == 4, "every preset should look different"

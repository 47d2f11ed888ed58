"""Lab 5's simulator: ISO 9409-1 flange faces in depth, the RealSense D4xx depth model, and the
100 mm rectangle mark. Real PyBullet (DIRECT, TinyRenderer, CPU)."""

import cv2
import numpy as np
import pybullet as p
import pytest

from robots import connect
from robots.geometry import compose, invert, make_pose, pose_from_rpy, transform_points
from sim_backends.camera import SimCamera, depth_from_buffer, projection_matrix, view_matrix
from sim_backends.depth_noise import RealSenseDepthModel
from sim_backends.flanges import FLANGE_PROUD_M, FLANGES
from sim_backends.world import default_intrinsics

INTR = default_intrinsics(640, 480)


def _look_at(eye, point, up):
    z = np.asarray(point, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)


def _render_with_links(client, intr, world_T_cam, near=0.01, far=10.0):
    """Exact depth (m) and per-pixel (body, link) of a view, as SimCamera renders it."""
    proj = projection_matrix(intr.K, intr.width, intr.height, near, far)
    _, _, _, buf, seg = p.getCameraImage(
        intr.width, intr.height, viewMatrix=view_matrix(world_T_cam).T.ravel().tolist(),
        projectionMatrix=proj.T.ravel().tolist(), renderer=p.ER_TINY_RENDERER,
        flags=p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX, physicsClientId=client)
    seg = np.reshape(seg, (intr.height, intr.width)).astype(np.int64)
    depth = depth_from_buffer(np.reshape(buf, (intr.height, intr.width)), near, far)
    body = np.where(seg >= 0, seg & ((1 << 24) - 1), -1)
    link = np.where(seg >= 0, (seg >> 24) - 1, -2)
    return depth, body, link


def _rays(uv, intr):
    return np.column_stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy,
                            np.ones(len(uv))])


def _fit_face(depth, mask, intr):
    """Plane (centre, unit normal towards the camera) through the masked pixels' points, the
    circle through the mask's outline in that plane (centre), and the radius from the mask's
    area on the plane."""
    # The flange link's pixels include the disc's rim wall where the view is oblique: rounds
    # of plane fit with a shrinking band keep only the face (the wall runs 6.5 mm back).
    for band in (2e-3, 5e-4, 2e-4):
        v, u = np.nonzero(mask)
        pts = _rays(np.column_stack([u, v]).astype(float), intr) * depth[v, u, None]
        c = pts.mean(axis=0)
        n = np.linalg.svd(pts - c, full_matrices=False)[2][2]
        n = -n if n @ c > 0 else n
        mask = mask.copy()
        mask[v, u] = np.abs((pts - c) @ n) < band
    v, u = np.nonzero(mask)
    pts = _rays(np.column_stack([u, v]).astype(float), intr) * depth[v, u, None]
    c = pts.mean(axis=0)
    n = np.linalg.svd(pts - c, full_matrices=False)[2][2]
    n = -n if n @ c > 0 else n
    # Outline pixels back-projected onto the plane; an algebraic circle fit is unbiased in
    # the centre (the outline's pixel centres sit the same ~half pixel inside the rim all
    # round), but not in the radius, which comes from the area instead.
    contour = max(cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)[0], key=len).reshape(-1, 2)
    rays = _rays(contour.astype(float), intr)
    edge = rays * ((c @ n) / (rays @ n))[:, None]
    e1 = np.cross(n, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    xy = np.column_stack([(edge - c) @ e1, (edge - c) @ e2])
    sol = np.linalg.lstsq(np.column_stack([2 * xy, np.ones(len(xy))]), (xy ** 2).sum(1),
                          rcond=None)[0]
    centre = c + sol[0] * e1 + sol[1] * e2
    # Each pixel's footprint on the plane: the quadrilateral its corners' rays cut out.
    corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
    q = [(r := _rays(np.column_stack([u + du, v + dv]).astype(float), intr))
         * ((c @ n) / (r @ n))[:, None] for du, dv in corners]
    area = 0.5 * np.linalg.norm(np.cross(q[2] - q[0], q[3] - q[1]), axis=1).sum()
    return centre, n, float(np.sqrt(area / np.pi))


@pytest.mark.parametrize("arm", ["panda", "ur5e", "ur10e", "aubo_i5", "cobotta"])
def test_bare_flange_is_an_iso_9409_disc_in_depth(arm):
    spec = FLANGES[arm]
    with connect("sim", engine="pybullet", arm=arm, mount="eye_to_hand", tool=None,
                 flange_target=False,
                 seed=0, width=160, height=120) as cell:
        assert cell.truth.flange is spec and cell.truth.flange_target is None
        assert cell.robot.tool is None
        world_T_flange = cell.arm.world_T_flange()
        R = world_T_flange[:3, :3]
        # A fixed camera 25 deg off the flange axis, as far as a D435 would sit from a bare
        # flange it calibrates against (the Cobotta's is small: closer).
        dist = 0.3 if arm == "cobotta" else 0.45
        eye = world_T_flange[:3, 3] + R @ pose_from_rpy(np.deg2rad(20), np.deg2rad(-15), 0)[
            :3, :3] @ [0, 0, dist]
        world_T_cam = _look_at(eye, world_T_flange[:3, 3], up=R @ [1.0, 0, 0])
        depth, body, link = _render_with_links(cell.client, INTR, world_T_cam)
    face = (body == cell.arm.body_id) & (link == cell.arm.flange_link)
    cam_T_flange = compose(invert(world_T_cam), world_T_flange)
    z = cam_T_flange[2, 3]
    pixel = z / INTR.fx  # one pixel's footprint at the flange, m
    assert face.sum() > 1000  # drawn (whole: the radius below comes from its area)
    # The wrist behind the face is a step of FLANGE_PROUD_M, not part of the face's plane.
    ring = cv2.dilate(face.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) & ~face
    ring &= (body == cell.arm.body_id) & np.isfinite(depth)
    if ring.any():
        ring_pts = (_rays(np.column_stack(np.nonzero(ring)[::-1]).astype(float), INTR)
                    * depth[ring][:, None])
        behind = (ring_pts - cam_T_flange[:3, 3]) @ cam_T_flange[:3, 2]
        assert np.all(behind < -0.8 * FLANGE_PROUD_M)

    centre, normal, radius = _fit_face(depth, face, INTR)
    # Tolerances from the pixel grid (depth is exact here: TinyRenderer's float32 buffer
    # steps by ~2 um at 0.5 m, and the face is a mesh, flat to float precision): the outline
    # pixels sit 0-1 px inside the rim, the same all round, so the circle's centre is off by
    # well under half a pixel's footprint (0.37 mm at 0.45 m, 0.25 mm at 0.3 m); the area
    # counts whole pixels, so the radius from it is good to a fraction of a pixel too.
    assert np.linalg.norm(centre - cam_T_flange[:3, 3]) < 0.5 * pixel
    assert np.degrees(np.arccos(min(1.0, normal @ cam_T_flange[:3, 2]))) < 0.2  # +z to camera
    assert abs(radius - spec.radius) < 0.25 * pixel


def test_lab5_options_are_off_by_default():
    with connect("sim", arm="ur5e", mount="eye_to_hand", seed=0, width=160, height=120) as cell:
        assert cell.truth.flange_target is not None and cell.truth.flange is FLANGES["ur5e"]
        assert cell.truth.base_T_rectangle is None and cell.camera.depth_model is None
    with pytest.raises(ValueError, match="flange_target must be True or False"):
        connect("sim", arm="ur5e", flange_target="no")


# --------------------------------------------------------------------------- depth model


@pytest.fixture
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _plate(client, z, half=(2.0, 2.0), world_T_cam=None, tilt_deg=0.0):
    """A plate facing the camera (optical frame = world here unless given) at depth z."""
    world_T_cam = np.eye(4) if world_T_cam is None else world_T_cam
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[*half, 1e-3], physicsClientId=client)
    T = compose(world_T_cam, make_pose(t=[0, 0, z + 1e-3]), pose_from_rpy(np.deg2rad(tilt_deg),
                                                                          0, 0))
    from scipy.spatial.transform import Rotation

    return p.createMultiBody(0, -1, vis, T[:3, 3].tolist(),
                             Rotation.from_matrix(T[:3, :3]).as_quat().tolist(),
                             physicsClientId=client)


SMALL = default_intrinsics(320, 240)


def test_depth_model_is_off_by_default_and_seeded(client):
    _plate(client, 0.8)
    exact = SimCamera(client, SMALL, world_T_cam=np.eye(4))
    assert exact.depth_model is None and exact.depth_scale is None
    assert np.array_equal(exact.capture().depth, exact.render()[1])
    frames = [SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model="d435",
                        rng=np.random.default_rng(5)).capture().depth for _ in range(2)]
    assert np.array_equal(frames[0], frames[1], equal_nan=True)
    other = SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model="d435",
                      rng=np.random.default_rng(6)).capture().depth
    assert not np.array_equal(frames[0], other, equal_nan=True)
    with pytest.raises(ValueError, match="not both"):
        SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_noise=0.001, depth_model="d435")
    with pytest.raises(ValueError, match="unknown depth_model field"):
        SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model={"sub_pixel": 0.1})


def test_default_model_is_a_d435_at_848x480():
    m = RealSenseDepthModel()
    # sigma_z = z^2 subpixel / (f B): 0.08 px, f = 424 / tan(43.5 deg) px, B = 50 mm.
    assert m.sigma_coefficient == pytest.approx(0.08 / (424 / np.tan(np.radians(43.5)) * 0.05))
    assert m.sigma_z(2.0) == pytest.approx(0.0143, abs=2e-4)  # 0.7 %: within "<= 2 % at 2 m"
    assert m.min_range == pytest.approx(0.178, abs=1e-3) and m.depth_unit == 0.001


@pytest.mark.parametrize("z", [0.5, 1.0])
def test_noise_grows_with_z_squared_and_is_quantised_to_1_mm(client, z):
    _plate(client, z)
    model = RealSenseDepthModel()
    raw = RealSenseDepthModel(depth_unit=None, edge_dropout_px=0)
    cam = SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model=raw,
                    rng=np.random.default_rng(1))
    truth = cam.render()[1].astype(np.float64)[20:-20, 20:-20]
    err = cam.capture().depth.astype(np.float64)[20:-20, 20:-20] - truth
    sigma = model.sigma_coefficient * z * z
    n = err.size
    # The sample std of n Gaussian draws has relative standard error 1/sqrt(2n) (0.25 % here);
    # 5 of them is the tolerance.
    assert abs(err.std() / sigma - 1) < 5 / np.sqrt(2 * n)
    assert abs(err.mean()) < 5 * sigma / np.sqrt(n)

    cam = SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model=model,
                    rng=np.random.default_rng(2))
    depth = cam.capture().depth[20:-20, 20:-20].astype(np.float64)
    assert cam.depth_scale == 0.001 and np.isfinite(depth).all()
    mm = depth / 0.001
    assert np.abs(mm - np.rint(mm)).max() < 1e-3  # whole millimetres (float32 of raw * 0.001)
    assert len(np.unique(np.rint(mm))) > 3
    # Rounding to steps of 1 mm adds 1/12 mm^2 of variance (Sheppard's correction, exact to
    # 1e-4 for sigma >= half a step, as here: 0.9 and 3.6 mm).
    var = (depth - truth).var() - 0.001 ** 2 / 12
    assert abs(np.sqrt(var) / sigma - 1) < 5 / np.sqrt(2 * n) + 0.01


def test_dropouts_at_edges_grazing_angles_and_out_of_range(client):
    _plate(client, 1.0)  # background
    _plate(client, 0.5, half=(0.05, 0.05))  # a square in front: its outline is a depth edge
    model = RealSenseDepthModel()
    cam = SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model=model,
                    rng=np.random.default_rng(0))
    exact = cam.render()[1]
    depth = cam.capture().depth
    near = np.isclose(exact, 0.5, atol=0.01)
    outline = cv2.morphologyEx(near.astype(np.uint8), cv2.MORPH_GRADIENT,
                               np.ones((3, 3), np.uint8)).astype(bool)
    assert np.isnan(depth[outline]).all()  # both sides of the edge lost
    inner = cv2.erode(near.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    far = cv2.erode((~near).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    far[:3], far[-3:], far[:, :3], far[:, -3:] = False, False, False, False  # image border
    assert inner.sum() > 500 and np.isfinite(depth[inner]).all()  # the middle of a flat face
    assert np.isfinite(depth[far]).all()
    lost = np.isnan(depth) & ~outline
    # Nothing else is lost but the band within edge_dropout_px of the edge.
    band = cv2.dilate(outline.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert not (lost & ~band).any()

    # Too near: inside the D435's min-z (0.18 m at 848x480) there is no depth at all.
    near_cam = SimCamera(client, SMALL, world_T_cam=make_pose(t=[0, 0, 0.5 - 0.15]),
                         depth_model=model)
    assert np.isnan(near_cam.capture().depth[100:140, 140:180]).all()


@pytest.mark.parametrize("tilt, lost", [(60.0, False), (80.0, True)])
def test_surfaces_seen_at_grazing_angles_give_no_depth(client, tilt, lost):
    _plate(client, 0.6, half=(0.3, 0.3), tilt_deg=tilt)
    cam = SimCamera(client, SMALL, world_T_cam=np.eye(4), depth_model="d435")
    centre = cam.capture().depth[110:130, 150:170]
    assert np.isnan(centre).all() if lost else np.isfinite(centre).all()


def test_depth_model_reaches_the_cameras_through_connect():
    with connect("sim", arm="ur5e", mount="eye_to_hand", seed=0, width=160, height=120,
                 depth_model={"subpixel": 0.1}) as cell:
        assert cell.camera.depth_model == RealSenseDepthModel(subpixel=0.1)
        depth = cell.camera.capture().depth
        ok = np.isfinite(depth)
        assert ok.mean() > 0.5 and (~ok).any()
        assert np.abs(depth[ok] / 0.001 - np.rint(depth[ok] / 0.001)).max() < 1e-3
    with pytest.raises(ValueError, match="not both"):
        connect("sim", arm="ur5e", depth_noise=0.001, depth_model="d435")


# --------------------------------------------------------------------------- rectangle mark


@pytest.mark.parametrize("arm, scene", [("panda", "calibration"), ("cobotta", "chess")])
def test_rectangle_mark_lies_on_the_table_with_its_true_size(arm, scene):
    with connect("sim", engine="pybullet", arm=arm, scene=scene, mount="eye_to_hand",
                 seed=3, width=160, height=120, rectangle_mark=True) as cell:
        truth = cell.truth
        assert truth.rectangle_size == (0.1, 0.1)
        base_T_rect = truth.base_T_rectangle
        assert np.allclose(base_T_rect[:3, 2], [0, 0, 1], atol=1e-9)  # face up, on the table
        assert base_T_rect[2, 3] == pytest.approx(0.003)
        world_T_rect = compose(invert(truth.base_T_pybullet), base_T_rect)
        # Straight down from 0.5 m above the mark, image turned 20 deg from its edges.
        world_T_cam = compose(world_T_rect, pose_from_rpy(0, 0, np.deg2rad(20)),
                              make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 0.5]))
        cam = SimCamera(cell.client, INTR, world_T_cam=world_T_cam)
        rgb, depth, _ = cam.render()
    w, h = truth.rectangle_size
    corners = transform_points(world_T_rect, [[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0],
                                              [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])
    uv = cam.project(corners)
    dark = (rgb.max(axis=2) < 60).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(dark)
    mark = labels == labels[240, 320]
    assert labels[240, 320] > 0
    # Its area in the image is the projected square's (to the outline's pixels, ~1.5 %).
    d1, d2 = uv[2] - uv[0], uv[3] - uv[1]
    expected = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
    assert abs(mark.sum() / expected - 1) < 0.015
    found = cv2.boxPoints(cv2.minAreaRect(np.column_stack(np.nonzero(mark)[::-1])
                                         .astype(np.float32)))
    miss = [np.min(np.linalg.norm(found - c, axis=1)) for c in uv]
    assert max(miss) < 1.5  # px
    # In depth it is a 3 mm card: its top 0.5 m away, the table 3 mm further.
    assert np.nanmedian(depth[mark]) == pytest.approx(0.5, abs=2e-4)
    ring = cv2.dilate(mark.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    ring &= ~cv2.dilate(mark.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert np.nanmedian(depth[ring]) == pytest.approx(0.503, abs=3e-4)


def _grazing_by_cross_products(z, K, max_incidence_deg):
    # The mask's definition, written the plain way: the normal n = d/du x d/dv of the
    # back-projected points by central differences, steep where |n.r| / (|n| |r|) is below
    # cos(max_incidence_deg) (NaN, no normal, never steep).
    H, W = z.shape
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    pts = rays * z[..., None]
    du, dv = np.zeros_like(pts), np.zeros_like(pts)
    du[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dv[1:-1, :] = pts[2:, :] - pts[:-2, :]
    n = np.cross(du, dv)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.sum(n * rays, -1)) / (np.linalg.norm(n, axis=-1)
                                              * np.linalg.norm(rays, axis=-1))
    return cos < np.cos(np.radians(max_incidence_deg))


@pytest.mark.parametrize("engine", ["mujoco", "pybullet"])
def test_the_grazing_mask_is_the_cross_product_definition_bit_for_bit(engine):
    model = RealSenseDepthModel()
    with connect("sim", engine=engine, arm="ur5e", mount="eye_to_hand", seed=3, tool=None,
                 flange_target=False, width=160, height=120) as cell:
        K = cell.camera.intrinsics.K
        frames = []
        for q in (None, [0.3, -0.4, 0.5, -0.6, 0.2, 0.4]):
            if q is not None:
                cell.robot.move_joints(np.asarray(cell.robot.joint_positions()) + q, speed=1.0)
            frames.append(cell.camera.render()[1].astype(np.float64))
    for z in frames:
        expected = _grazing_by_cross_products(z, K, model.max_incidence_deg)
        assert expected.any() and not expected.all()
        np.testing.assert_array_equal(model._grazing(z, K), expected)

"""Simulated pinhole RGB-D camera rendered with PyBullet's TinyRenderer (headless, CPU).

Frames and conventions
----------------------
* The camera frame ``cam`` is OpenCV's optical frame: x right, y down, z forward (into the
  scene). ``world_T_cam`` is its pose in PyBullet's world frame.
* OpenGL's eye frame has x right, y up and looks along -z, so ``gl_T_cam = diag(1, -1, -1)``
  and the view matrix is ``gl_T_world = diag(1, -1, -1, 1) @ invert(world_T_cam)``.
* Pixel (u, v) is OpenCV's: the centre of the top-left pixel is (0, 0), u grows right, v down.

The projection matrix from K (derivation)
-----------------------------------------
A point with OpenCV camera coordinates (x, y, z), z > 0, has eye coordinates
(X, Y, Z) = (x, -y, -z). OpenCV projects it to ``u = fx x / z + cx``, ``v = fy y / z + cy``.

OpenGL maps eye coordinates to clip coordinates with ``P``, divides by ``w_c = -Z = z`` to get
normalised device coordinates (NDC) in [-1, 1], and the viewport maps NDC x to window
``x_w = (x_ndc + 1) W / 2``. TinyRenderer samples each pixel at integer window coordinates
and PyBullet returns rows top-down, row ``r`` holding window row ``y_w = H - 1 - r``
(measured: a fronto-parallel plate's mask centroid lands within 0.05 px of this model, and
half a pixel off in both u and v with the textbook "pixel centres at +0.5" model). Hence::

    u = x_w               ->  x_ndc = 2 u / W - 1
    v = H - 1 - y_w       ->  y_ndc = 1 - 2 (v + 1) / H

Substituting u and v and multiplying by ``w_c = -Z``::

    x_c = (2 fx / W) X + (1 - 2 cx / W) Z
    y_c = (2 fy / H) Y + (2 (cy + 1) / H - 1) Z
    z_c = -(f + n) / (f - n) Z - 2 f n / (f - n)       (standard depth row, near n, far f)
    w_c = -Z

so ``P[0, 2] = 1 - 2 cx / W`` and ``P[1, 2] = 2 (cy + 1) / H - 1``: an off-centre principal
point moves the frustum, and the y flip lives in the sign of that term.

Metric depth
------------
The depth buffer holds ``d = (z_ndc + 1) / 2``; inverting the depth row gives the z distance
along the optical axis (what a RealSense reports)::

    z = 2 f n / (f + n - (2 d - 1)(f - n))

Pixels where nothing was drawn (d == 1) get depth NaN, the ``Frame`` convention for "no
measurement". TinyRenderer's depth buffer is float32; with n = 0.01 m and f = 10 m the depth
step at 0.5 m is a few micrometres (measured: 2 um on a plate at 0.5 m).

Lens distortion
---------------
With non-zero ``Intrinsics.dist`` (k1 k2 p1 p2 k3, OpenCV's model) the camera renders an ideal
pinhole image on a canvas padded so it covers every ray the distorted image sees, then
resamples it: each output pixel (u_d, v_d) looks up the pinhole pixel of its undistorted ray,
found with ``cv2.undistortPointsIter`` and polished by Newton steps (round trip < 1e-3 px;
a lens whose model folds over inside the image is refused). ``cv2.undistort(frame.rgb, K,
dist)`` therefore returns (up to interpolation blur) the pinhole image, as with a real
camera. The depth image is resampled nearest-neighbour, so no depth is invented across an
edge; it stays the z distance of the surface seen through each distorted pixel.

Speed: TinyRenderer is single-threaded and its cost grows with covered pixels and with
triangles (the Panda's visual meshes are ~100k triangles); see benchmarks/sim_speed.py.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import pybullet as p

from robots.geometry import as_pose, compose, invert, make_pose
from robots.interfaces import Camera, Frame, Intrinsics, RobotDisconnectedError
from sim_backends.depth_noise import depth_model_from

__all__ = [
    "LIGHTING_PRESETS",
    "Lighting",
    "SimCamera",
    "depth_from_buffer",
    "lighting_from",
    "projection_matrix",
    "view_matrix",
]

# OpenCV optical frame -> OpenGL eye frame (y and z flipped).
GL_T_CV = np.diag([1.0, -1.0, -1.0, 1.0])


# --------------------------------------------------------------------------- lighting


@dataclass(frozen=True)
class Lighting:
    """TinyRenderer light settings, passed straight to ``p.getCameraImage``.

    ``direction`` is the direction the light comes FROM, in PyBullet world coordinates
    (it need not be unit length); ``color`` is RGB in [0, 1]; ``distance`` (m) places the
    shadow-casting light; the coefficients weight the ambient, diffuse and specular terms.
    """

    direction: tuple[float, float, float] = (0.3, -0.4, 1.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    distance: float = 3.0
    shadow: bool = False
    ambient: float = 0.6
    diffuse: float = 0.35
    specular: float = 0.05

    def __post_init__(self):
        for name in ("direction", "color"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"Lighting.{name} must be 3 finite numbers, got {v!r}")
        if not np.any(np.asarray(self.direction, dtype=float)):
            raise ValueError("Lighting.direction must not be the zero vector")
        for name in ("distance", "ambient", "diffuse", "specular"):
            x = getattr(self, name)
            if not (math.isfinite(x) and x >= 0):
                raise ValueError(f"Lighting.{name} must be finite and >= 0, got {x!r}")

    def as_kwargs(self) -> dict:
        return {
            "lightDirection": list(map(float, self.direction)),
            "lightColor": list(map(float, self.color)),
            "lightDistance": float(self.distance),
            "shadow": int(bool(self.shadow)),
            "lightAmbientCoeff": float(self.ambient),
            "lightDiffuseCoeff": float(self.diffuse),
            "lightSpecularCoeff": float(self.specular),
        }


LIGHTING_PRESETS: dict[str, Lighting] = {
    # Even, bright light: every target is easy to detect.
    "default": Lighting(),
    # A dim room: low contrast, detectors must cope with a darker image.
    "dim": Lighting(color=(0.55, 0.55, 0.6), ambient=0.35, diffuse=0.25, specular=0.0),
    # Low warm light from the side with shadows: strong gradients across the board.
    "side": Lighting(direction=(1.0, 0.2, 0.35), color=(1.0, 0.93, 0.8), shadow=True,
                     ambient=0.35, diffuse=0.7, specular=0.15),
    # Overhead spot with shadows, like a lab with ceiling lights.
    "overhead": Lighting(direction=(0.0, 0.0, 1.0), shadow=True, ambient=0.5, diffuse=0.5,
                         specular=0.1),
}


def lighting_from(lighting) -> Lighting:
    """A ``Lighting`` from a preset name (see ``LIGHTING_PRESETS``), a dict of fields, or as is."""
    if isinstance(lighting, Lighting):
        return lighting
    if isinstance(lighting, str):
        try:
            return LIGHTING_PRESETS[lighting]
        except KeyError:
            raise ValueError(
                f"unknown lighting {lighting!r}; use one of {sorted(LIGHTING_PRESETS)} or a "
                "sim_backends.camera.Lighting"
            ) from None
    if isinstance(lighting, dict):
        return Lighting(**lighting)
    raise ValueError(f"lighting must be a preset name, a dict or a Lighting, got {lighting!r}")


# --------------------------------------------------------------------------- matrices


def projection_matrix(K, width: int, height: int, near: float, far: float) -> np.ndarray:
    """OpenGL projection matrix (4, 4), row-major, for a pinhole K (pixels) and an image size.

    ``near`` and ``far`` (m) bound the rendered depth range. See the module docstring for the
    derivation, including TinyRenderer's pixel-sampling convention. PyBullet wants the
    column-major flattening ``P.T.ravel()``.
    """
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite (3, 3) matrix, got shape {K.shape}")
    if not (0 < near < far):
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * fx / width
    P[0, 1] = -2.0 * K[0, 1] / width  # skew (zero for real cameras); Y = -y hence the sign
    P[0, 2] = 1.0 - 2.0 * cx / width
    P[1, 1] = 2.0 * fy / height
    P[1, 2] = 2.0 * (cy + 1.0) / height - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P


def view_matrix(world_T_cam) -> np.ndarray:
    """OpenGL view matrix (4, 4), row-major: ``gl_T_world`` for an OpenCV-frame camera pose."""
    return GL_T_CV @ invert(as_pose(world_T_cam, "world_T_cam"))


def depth_from_buffer(depth_buffer, near: float, far: float) -> np.ndarray:
    """Metric z depth (m, float32) from an OpenGL depth buffer in [0, 1]; NaN where empty."""
    d = np.asarray(depth_buffer, dtype=np.float64)
    z = 2.0 * far * near / (far + near - (2.0 * d - 1.0) * (far - near))
    z[d >= 1.0] = np.nan
    return z.astype(np.float32)


# --------------------------------------------------------------------------- distortion


def _distort_normalised(x, y, dist):
    """OpenCV's (k1, k2, p1, p2, k3) model on normalised coordinates, vectorised."""
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def _undistort_normalised(xd, yd, dist, iterations=8):
    """Invert the distortion model: OpenCV's iterative start, then Newton steps.

    ``cv2.undistortPoints`` alone stalls at tenths of a pixel near the corners of wide lenses;
    Newton with a central-difference Jacobian brings the round trip to ~1e-9.
    """
    pts = np.stack([xd.ravel(), yd.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    x, y = cv2.undistortPointsIter(pts, np.eye(3), dist, None, None, criteria).reshape(-1, 2).T
    xd, yd = xd.ravel(), yd.ravel()
    h = 1e-7
    for _ in range(iterations):
        fx, fy = _distort_normalised(x, y, dist)
        ex, ey = fx - xd, fy - yd
        ax, ay = _distort_normalised(x + h, y, dist)
        bx, by = _distort_normalised(x - h, y, dist)
        cx_, cy_ = _distort_normalised(x, y + h, dist)
        dx_, dy_ = _distort_normalised(x, y - h, dist)
        j11, j21 = (ax - bx) / (2 * h), (ay - by) / (2 * h)
        j12, j22 = (cx_ - dx_) / (2 * h), (cy_ - dy_) / (2 * h)
        det = j11 * j22 - j12 * j21
        with np.errstate(divide="ignore", invalid="ignore"):
            x = x - (j22 * ex - j12 * ey) / det
            y = y - (-j21 * ex + j11 * ey) / det
    return x, y


def _distortion_lookup(intr: Intrinsics, max_pad_fraction: float = 0.5):
    """Maps for cv2.remap from a padded pinhole render to the distorted image.

    Returns (map_x, map_y, pad_x, pad_y): output pixel (u, v) samples canvas pixel
    (map_x[v, u], map_y[v, u]) of a render with ``cx + pad_x, cy + pad_y`` and size
    ``(W + 2 pad_x, H + 2 pad_y)``.
    """
    W, H = intr.width, intr.height
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
    dist = np.asarray(intr.dist, dtype=float)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    x, y = _undistort_normalised((u - cx) / fx, (v - cy) / fy, dist)
    # The inverse can fail for strong distortion (the model folds over); check it by
    # distorting the answer forward again, so a bad coefficient set errors out instead of
    # smearing the image.
    xd, yd = _distort_normalised(x, y, dist)
    miss_u = (xd - ((u - cx) / fx).ravel()) * fx
    miss_v = (yd - ((v - cy) / fy).ravel()) * fy
    miss = np.max(np.hypot(miss_u, miss_v))
    if not np.isfinite(miss) or miss > 1e-3:
        raise ValueError(
            f"lens distortion {dist.tolist()} cannot be inverted over the {W}x{H} image (round "
            f"trip misses by {miss:.3g} px); use smaller coefficients (|k1| < 0.5 is typical)"
        )
    und = np.stack([(fx * x + cx).reshape(H, W), (fy * y + cy).reshape(H, W)], axis=2)
    over_x = max(0.0, -und[..., 0].min(), und[..., 0].max() - (W - 1))
    over_y = max(0.0, -und[..., 1].min(), und[..., 1].max() - (H - 1))
    pad_x, pad_y = math.ceil(over_x) + 2, math.ceil(over_y) + 2
    if pad_x > max_pad_fraction * W or pad_y > max_pad_fraction * H:
        raise ValueError(
            f"lens distortion {dist.tolist()} needs a render {pad_x}x{pad_y} px larger on each "
            "side than the image; that is a fisheye-like lens this pinhole simulator does not "
            "model. Use smaller distortion coefficients"
        )
    map_x = (und[..., 0] + pad_x).astype(np.float32)
    map_y = (und[..., 1] + pad_y).astype(np.float32)
    return map_x, map_y, pad_x, pad_y


# --------------------------------------------------------------------------- camera


class SimCamera(Camera):
    """A simulated RGB-D camera: fixed in the world, or rigidly attached to a robot link.

    Parameters
    ----------
    client : PyBullet physics client id.
    intrinsics : ``robots.interfaces.Intrinsics`` (K, image size, distortion).
    world_T_cam : (4, 4) pose of the optical frame in the PyBullet world, for a fixed camera.
    parent : ``(body_id, link_index)`` to ride on (link -1 is the base), with ``link_T_cam``
        the optical frame in that link's URDF frame; the pose is read from the simulation at
        every capture, so it follows the TRUE arm (not the encoder readings). Mount it off the
        joint axes: TinyRenderer can hang when the eye sits exactly on a joint.
    name : camera name reported in each Frame.
    near, far : clipping planes in metres.
    pixel_noise : std of Gaussian noise added to each RGB channel, in 0..255 units.
    depth_noise : k in ``sigma_z = k * z**2`` (1/m), the RealSense-like growth of depth noise
        with range; 0.001 gives 1 mm at 1 m and 4 mm at 2 m.
    depth_model : a ``sim_backends.depth_noise.RealSenseDepthModel`` (or "d435", a dict of its
        fields): the whole D4xx depth behaviour instead of ``depth_noise`` (noise growing
        with z**2, dropouts at depth edges, grazing angles and out of range, 1 mm steps).
        None (the default): exact depth. ``depth_scale`` is then its depth unit (m), as on
        ``robots.drivers.realsense.RealSenseCamera``.
    with_depth : False makes ``capture`` return ``depth=None``.
    lighting : a ``Lighting`` or a preset name.
    rng : ``numpy.random.Generator`` for the noise (seed it for repeatable frames).
    clock : callable giving the timestamp in seconds (the workcell passes simulated time).
    """

    def __init__(
        self,
        client: int,
        intrinsics: Intrinsics,
        *,
        world_T_cam=None,
        parent: tuple[int, int] | None = None,
        link_T_cam=None,
        name: str = "cam",
        near: float = 0.01,
        far: float = 10.0,
        pixel_noise: float = 0.0,
        depth_noise: float = 0.0,
        depth_model=None,
        with_depth: bool = True,
        lighting="default",
        rng: np.random.Generator | None = None,
        clock: Callable[[], float] | None = None,
    ):
        super().__init__(name, intrinsics)
        if (world_T_cam is None) == (parent is None):
            raise ValueError(
                "give exactly one mount: world_T_cam=(4, 4) for a fixed camera, or "
                "parent=(body_id, link_index) with link_T_cam=(4, 4) for a camera on a link"
            )
        if parent is not None and link_T_cam is None:
            raise ValueError("a camera with a parent link needs link_T_cam, the (4, 4) mount pose")
        for label, x in (("pixel_noise", pixel_noise), ("depth_noise", depth_noise)):
            if not (math.isfinite(x) and x >= 0):
                raise ValueError(f"{label} must be finite and >= 0, got {x!r}")
        if not (0 < near < far):
            raise ValueError(f"need 0 < near < far (metres), got near={near}, far={far}")
        self.depth_model = depth_model_from(depth_model)
        if self.depth_model is not None and depth_noise > 0:
            raise ValueError("give depth_noise or depth_model, not both: the RealSense model "
                             "has its own noise (its subpixel field)")
        self.depth_scale = None if self.depth_model is None else self.depth_model.depth_unit
        self.client = client
        self.near, self.far = float(near), float(far)
        self.pixel_noise = float(pixel_noise)
        self.depth_noise = float(depth_noise)
        self.with_depth = bool(with_depth)
        self.lighting = lighting_from(lighting)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._clock = clock or time.time
        self._fixed_pose = None if world_T_cam is None else as_pose(world_T_cam, "world_T_cam")
        self.parent = parent
        self.link_T_cam = None if link_T_cam is None else as_pose(link_T_cam, "link_T_cam")
        self._closed = False

        W, H = intrinsics.width, intrinsics.height
        if np.any(np.asarray(intrinsics.dist, dtype=float) != 0):
            map_x, map_y, pad_x, pad_y = _distortion_lookup(intrinsics)
            self._maps = (map_x, map_y)
        else:
            self._maps, pad_x, pad_y = None, 0, 0
        # The render canvas: the image itself, or the image padded for distortion.
        K_canvas = intrinsics.K.copy()
        K_canvas[0, 2] += pad_x
        K_canvas[1, 2] += pad_y
        self._canvas_size = (W + 2 * pad_x, H + 2 * pad_y)
        self._proj = projection_matrix(K_canvas, *self._canvas_size, self.near, self.far)
        self._proj_gl = self._proj.T.ravel().tolist()

    # ----------------------------------------------------------------- pose

    def world_T_cam(self) -> np.ndarray:
        """Current true pose of the optical frame in the PyBullet world (4, 4)."""
        if self._fixed_pose is not None:
            return self._fixed_pose.copy()
        body, link = self.parent
        if link < 0:
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        else:
            state = p.getLinkState(body, link, computeForwardKinematics=True,
                                   physicsClientId=self.client)
            pos, quat = state[4], state[5]  # the URDF link frame, not the inertial frame
        R = np.reshape(p.getMatrixFromQuaternion(quat), (3, 3))
        return compose(make_pose(R, pos), self.link_T_cam)

    def set_world_T_cam(self, world_T_cam) -> None:
        """Move a fixed camera (tests, scene set-up). A link-mounted camera refuses."""
        if self._fixed_pose is None:
            raise ValueError("this camera rides on a link; move the link instead")
        self._fixed_pose = as_pose(world_T_cam, "world_T_cam")

    # ----------------------------------------------------------------- rendering

    def render(self, world_T_cam=None, segmentation: bool = False):
        """Noise-free render: (rgb uint8 (H, W, 3), depth float32 (H, W) m, seg or None).

        ``world_T_cam`` overrides the mount for this one render. ``seg`` holds PyBullet body
        ids (-1 for background); it is only computed when asked for, since it costs time.
        """
        self._check_open()
        pose = self.world_T_cam() if world_T_cam is None else as_pose(world_T_cam, "world_T_cam")
        Wc, Hc = self._canvas_size
        flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
        _, _, rgba, depth_buf, seg = p.getCameraImage(
            Wc, Hc,
            viewMatrix=view_matrix(pose).T.ravel().tolist(),
            projectionMatrix=self._proj_gl,
            renderer=p.ER_TINY_RENDERER,
            flags=flags,
            physicsClientId=self.client,
            **self.lighting.as_kwargs(),
        )
        rgb = np.ascontiguousarray(np.reshape(rgba, (Hc, Wc, 4))[..., :3], dtype=np.uint8)
        depth = depth_from_buffer(np.reshape(depth_buf, (Hc, Wc)), self.near, self.far)
        seg = np.reshape(seg, (Hc, Wc)).astype(np.int32) if segmentation else None
        if self._maps is not None:
            map_x, map_y = self._maps
            rgb = cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            # Nearest for depth and ids: blending across an edge would invent points in mid-air.
            depth = cv2.remap(depth, map_x, map_y, cv2.INTER_NEAREST)
            if seg is not None:
                seg = cv2.remap(seg, map_x, map_y, cv2.INTER_NEAREST)
        return rgb, depth, seg

    def capture(self) -> Frame:
        """One frame: rgb (H, W, 3) uint8, depth (H, W) float32 metres (NaN = no data) or None."""
        rgb, depth, _ = self.render()
        if self.pixel_noise > 0:
            noisy = rgb.astype(np.float32) + self.rng.normal(0.0, self.pixel_noise, rgb.shape)
            rgb = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        if not self.with_depth:
            depth = None
        elif self.depth_model is not None:
            # K of the undistorted canvas would be exact for the normals; with distortion the
            # image's own K is a close enough guide to which surfaces are grazing.
            depth = self.depth_model.apply(depth, self.intrinsics.K, self.rng)
        elif self.depth_noise > 0:
            z = depth.astype(np.float64)
            noisy = z + self.rng.normal(0.0, 1.0, z.shape) * (self.depth_noise * z**2)
            depth = np.maximum(noisy, self.near).astype(np.float32)  # NaN stays NaN
        return Frame(rgb=rgb, depth=depth, timestamp=float(self._clock()), camera_name=self.name)

    def project(self, points_world) -> np.ndarray:
        """Pixels (N, 2) where world points (N, 3) land in this camera's (distorted) image."""
        pts = np.atleast_2d(np.asarray(points_world, dtype=float))
        cam_T_world = invert(self.world_T_cam())
        pc = pts @ cam_T_world[:3, :3].T + cam_T_world[:3, 3]
        if np.any(pc[:, 2] <= 0):
            raise ValueError("some points are behind the camera (z <= 0); they do not project")
        uv, _ = cv2.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                  self.intrinsics.K, np.asarray(self.intrinsics.dist, float))
        return uv.reshape(-1, 2)

    def _check_open(self):
        if self._closed:
            raise RobotDisconnectedError(f"camera {self.name!r} is closed; reconnect the workcell")

    def close(self) -> None:
        self._closed = True

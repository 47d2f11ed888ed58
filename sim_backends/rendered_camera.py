"""A simulated pinhole RGB-D camera around any engine's renderer: lens, noise, depth model.

The engine renders an ideal pinhole image (``RenderedCamera._render_canvas``); this module
turns it into what a real camera streams, the same for every engine.

Frames: the camera frame ``cam`` is OpenCV's optical frame (x right, y down, z forward) and
``world_T_cam`` its pose in the engine's world frame; pixel (u, v) is OpenCV's (the centre of
the top-left pixel is (0, 0), u grows right, v down). Depth is the z distance along the
optical axis in metres (what a RealSense reports), NaN where nothing was drawn.

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

Lighting
--------
``Lighting`` (presets in ``LIGHTING_PRESETS``) describes the light engine-neutrally: the
direction it comes from, its colour and the ambient, diffuse and specular weights; each
engine maps it onto its own lights.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from robots.geometry import as_pose, compose, invert
from robots.interfaces import Camera, Frame, Intrinsics, RobotDisconnectedError
from sim_backends.depth_noise import depth_model_from

__all__ = ["LIGHTING_PRESETS", "Lighting", "RenderedCamera", "lighting_from"]


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


class RenderedCamera(Camera):
    """A simulated RGB-D camera around an engine's renderer: fixed in the world, or rigidly
    attached to a robot link.

    Parameters
    ----------
    intrinsics : ``robots.interfaces.Intrinsics`` (K, image size, distortion).
    world_T_cam : (4, 4) pose of the optical frame in the PyBullet world, for a fixed camera.
    parent : the link to ride on, in the engine's own terms (PyBullet: ``(body_id,
        link_index)``), with ``link_T_cam`` the optical frame in that link's URDF frame; the
        pose is read from the simulation at every capture (``_world_T_parent``), so it follows
        the TRUE arm (not the encoder readings).
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

    An engine's camera implements ``_render_canvas(world_T_cam, canvas_K, canvas_size,
    segmentation)`` (a noise-free pinhole render of the canvas: rgb, metric z depth with NaN
    where nothing was drawn, ids or None) and ``_world_T_parent()`` for a camera on a link;
    distortion, noise, the depth model, timestamps and projection are done here, the same for
    every engine.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        *,
        world_T_cam=None,
        parent=None,
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
                "parent=<the link> with link_T_cam=(4, 4) for a camera on a link"
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
        self._canvas_K = K_canvas
        self._canvas_size = (W + 2 * pad_x, H + 2 * pad_y)

    # ----------------------------------------------------------------- pose

    def world_T_cam(self) -> np.ndarray:
        """Current true pose of the optical frame in the engine's world (4, 4)."""
        if self._fixed_pose is not None:
            return self._fixed_pose.copy()
        return compose(self._world_T_parent(), self.link_T_cam)

    def _world_T_parent(self) -> np.ndarray:
        """The parent link's URDF frame in the world now (engine's part)."""
        raise NotImplementedError

    def _render_canvas(self, world_T_cam, canvas_K, canvas_size, segmentation):
        """Noise-free pinhole render of the canvas (engine's part; see the class docstring)."""
        raise NotImplementedError

    def set_world_T_cam(self, world_T_cam) -> None:
        """Move a fixed camera (tests, scene set-up). A link-mounted camera refuses."""
        if self._fixed_pose is None:
            raise ValueError("this camera rides on a link; move the link instead")
        self._fixed_pose = as_pose(world_T_cam, "world_T_cam")

    # ----------------------------------------------------------------- rendering

    def render(self, world_T_cam=None, segmentation: bool = False):
        """Noise-free render: (rgb uint8 (H, W, 3), depth float32 (H, W) m, seg or None).

        ``world_T_cam`` overrides the mount for this one render. ``seg`` holds the engine's
        body ids (-1 for background); it is only computed when asked for, since it costs time.
        """
        self._check_open()
        pose = self.world_T_cam() if world_T_cam is None else as_pose(world_T_cam, "world_T_cam")
        rgb, depth, seg = self._render_canvas(pose, self._canvas_K, self._canvas_size,
                                              segmentation)
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

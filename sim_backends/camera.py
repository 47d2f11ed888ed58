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

Lens distortion, noise and the depth model: ``sim_backends.rendered_camera`` (the same
for every engine).

Speed: TinyRenderer is single-threaded and its cost grows with covered pixels and with
triangles (the Panda's visual meshes are ~100k triangles); see benchmarks/sim_speed.py.
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from robots.geometry import as_pose, invert, make_pose
from robots.interfaces import Intrinsics
from sim_backends.rendered_camera import (  # noqa: F401  (re-exported: their home before the split)
    LIGHTING_PRESETS,
    Lighting,
    RenderedCamera,
    _distort_normalised,
    _distortion_lookup,
    _undistort_normalised,
    lighting_from,
)

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


# --------------------------------------------------------------------------- camera


class SimCamera(RenderedCamera):
    """A simulated RGB-D camera rendered by PyBullet's TinyRenderer (see ``RenderedCamera``).

    ``client`` is the PyBullet physics client id; ``parent`` is ``(body_id, link_index)``
    (link -1 is the base). Mount it off the joint axes: TinyRenderer can hang when the eye
    sits exactly on a joint. ``lighting`` goes to ``p.getCameraImage`` as is.
    """

    def __init__(self, client: int, intrinsics: Intrinsics, **options):
        super().__init__(intrinsics, **options)
        self.client = client
        self._proj = projection_matrix(self._canvas_K, *self._canvas_size, self.near, self.far)
        self._proj_gl = self._proj.T.ravel().tolist()

    def _world_T_parent(self) -> np.ndarray:
        body, link = self.parent
        if link < 0:
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        else:
            state = p.getLinkState(body, link, computeForwardKinematics=True,
                                   physicsClientId=self.client)
            pos, quat = state[4], state[5]  # the URDF link frame, not the inertial frame
        R = np.reshape(p.getMatrixFromQuaternion(quat), (3, 3))
        return make_pose(R, pos)

    def _render_canvas(self, world_T_cam, canvas_K, canvas_size, segmentation):
        Wc, Hc = canvas_size
        flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
        _, _, rgba, depth_buf, seg = p.getCameraImage(
            Wc, Hc,
            viewMatrix=view_matrix(world_T_cam).T.ravel().tolist(),
            projectionMatrix=self._proj_gl,
            renderer=p.ER_TINY_RENDERER,
            flags=flags,
            physicsClientId=self.client,
            **self.lighting.as_kwargs(),
        )
        rgb = np.ascontiguousarray(np.reshape(rgba, (Hc, Wc, 4))[..., :3], dtype=np.uint8)
        depth = depth_from_buffer(np.reshape(depth_buf, (Hc, Wc)), self.near, self.far)
        seg = np.reshape(seg, (Hc, Wc)).astype(np.int32) if segmentation else None
        return rgb, depth, seg

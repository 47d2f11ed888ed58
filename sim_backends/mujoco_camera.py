"""The simulated RGB-D camera rendered by MuJoCo off-screen (EGL, OSMesa, CGL or WGL).

:class:`MujocoCamera` is a ``rendered_camera.RenderedCamera``: MuJoCo renders the ideal
pinhole canvas, and lens distortion, noise and the RealSense depth model are applied there,
exactly as for the PyBullet camera.

Intrinsics: each camera is a MuJoCo model camera whose sensor is given in pixels
(``cam_sensorsize = cam_resolution = canvas size``) with ``cam_intrinsic = (fx, fy, px, py)``.
MuJoCo's principal-point offset (px, py) is measured from the canvas centre towards -u and -v
in pixel units, so OpenCV's (cx, cy) (centre of the top-left pixel at (0, 0)) gives
``px = (W - 1) / 2 - cx`` and ``py = (H - 1) / 2 - cy`` (measured: fronto-parallel squares
land within the half-pixel quantisation of a binary mask of OpenCV's projection, and
``tests/test_sim_mujoco.py`` checks detected corners against projected truth to 0.1 px).

Depth: MuJoCo's depth buffer d in [0, 1] is turned into z along the optical axis with its
clipping planes: ``z = near / (1 - d (1 - near / far))``; d = 1 (nothing drawn) is NaN.
"""

from __future__ import annotations

import os
import weakref

import numpy as np

from robots.geometry import as_pose, compose
from robots.interfaces import Intrinsics
from sim_backends.mujoco_gl import OpenGLUnavailableError, gl_hint, import_mujoco
from sim_backends.mujoco_model import FAR_M, GL_T_CV, NEAR_M, SCENE_GROUP, VISUAL_GROUP
from sim_backends.rendered_camera import RenderedCamera

mujoco = import_mujoco()

__all__ = ["MujocoCamera", "OffscreenRenderer"]

BACKGROUND_RGB = (255, 255, 255)


def _free(context, gl) -> None:
    try:
        gl.make_current()
        context.free()
        gl.free()
    except Exception:  # noqa: BLE001  (at interpreter exit the GL library may be gone)
        pass


def _gl_context_class():
    # MuJoCo binds mujoco.GLContext when it is first imported; if someone imported it before
    # sim_backends could choose (MUJOCO_GL unset, no display), ask for the chosen one by name.
    platform = os.environ.get("MUJOCO_GL", "")
    if platform == "egl":
        from mujoco.egl import GLContext
    elif platform == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        GLContext = mujoco.GLContext  # noqa: N806
    return GLContext


class OffscreenRenderer:
    """One off-screen OpenGL context and MuJoCo scene for a model, shared by its cameras.

    ``max_size`` (width, height) pixels: the largest canvas any camera renders (the model's
    off-screen buffer is made that big by ``mujoco_model.configure_visual``).
    """

    def __init__(self, model, max_size: tuple[int, int]):
        try:
            self._gl = _gl_context_class()(int(max_size[0]), int(max_size[1]))
            self._gl.make_current()
        except Exception as error:  # noqa: BLE001  (EGL/OSMesa raise their own types)
            raise OpenGLUnavailableError(
                f"MuJoCo could not open an off-screen OpenGL context ({error!r}); on Linux "
                f"install {gl_hint()}, or set MUJOCO_GL to a platform that works here") from None
        self._scene = mujoco.MjvScene(model, maxgeom=10_000)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = 0
        self._option.geomgroup[VISUAL_GROUP] = 1
        self._option.geomgroup[SCENE_GROUP] = 1
        self._perturb = mujoco.MjvPerturb()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        # The smallest font atlas: nothing here draws text.
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._finalizer = weakref.finalize(self, _free, self._context, self._gl)

    def render(self, model, data, camera_id: int, width: int, height: int,
               segmentation: bool = False):
        """(rgb uint8 (H, W, 3), depth buffer float32 (H, W) in [0, 1], body ids int32 (H, W)
        or None), rows top-down; ids (``segment``) only when ``segmentation`` is asked for."""
        if not self._finalizer.alive:
            raise RuntimeError("this renderer is closed")
        self._gl.make_current()
        self._camera.fixedcamid = camera_id
        mujoco.mjv_updateScene(model, data, self._option, self._perturb, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        viewport = mujoco.MjrRect(0, 0, width, height)
        mujoco.mjr_render(viewport, self._scene, self._context)
        rgb = np.empty((height, width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(rgb, None, viewport, self._context)
        # Depth from the flat (segmentation) pass, which MuJoCo draws without multisampling:
        # read back from the multisampled pass, depth is one sample's, off the pixel centre
        # (every depth silhouette sat 0.37 px up and 0.1 px right of its truth and of the RGB
        # image, measured with Mesa), where colour is the samples' average (antialiased).
        colours, depth = self._flat_pass(viewport, segmentation)
        ids = None if colours is None else self._body_ids(model, colours)
        # OpenGL's rows run bottom-up.
        return np.ascontiguousarray(rgb[::-1]), np.ascontiguousarray(depth[::-1]), ids

    def _flat_pass(self, viewport, with_colours: bool):
        """The scene last updated drawn again with each object in a colour that encodes its
        index: (colours (H, W, 3) uint8 or None, depth buffer (H, W) float32), bottom-up."""
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_render(viewport, self._scene, self._context)
            depth = np.empty((viewport.height, viewport.width), dtype=np.float32)
            colours = (np.empty((viewport.height, viewport.width, 3), dtype=np.uint8)
                       if with_colours else None)
            mujoco.mjr_readPixels(colours, depth, viewport, self._context)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        return colours, depth

    def _body_ids(self, model, colours) -> np.ndarray:
        """Body ids (H, W) int32, rows top-down, -1 where nothing was drawn, from the flat
        pass's colours (bottom-up)."""
        index = (colours[::-1].astype(np.int32) @ np.array([1, 1 << 8, 1 << 16])) - 1
        # Scene geom index -> model body id (geoms only; decorations count as background).
        ngeom = self._scene.ngeom
        bodies = np.full(ngeom + 1, -1, dtype=np.int32)
        for k in range(ngeom):
            geom = self._scene.geoms[k]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                bodies[k] = model.geom_bodyid[geom.objid]
        return bodies[np.where((index >= 0) & (index < ngeom), index, ngeom)]

    def close(self) -> None:
        """Free the OpenGL context. Idempotent."""
        self._finalizer()


def depth_from_mujoco_buffer(buffer, near: float = NEAR_M, far: float = FAR_M) -> np.ndarray:
    """Metric z depth (m, float32) from MuJoCo's depth buffer; NaN where nothing was drawn."""
    d = np.asarray(buffer, dtype=np.float64)
    z = near / (1.0 - d * (1.0 - near / far))
    z[d >= 1.0] = np.nan
    return z.astype(np.float32)


class MujocoCamera(RenderedCamera):
    """A simulated RGB-D camera in a MuJoCo world (see ``RenderedCamera`` for the options).

    ``world``: the ``mujoco_world.MujocoWorld`` (model, data, renderer); ``camera_name``: the
    model camera this camera drives (``mujoco_model.add_camera``); ``parent``: the name of the
    body it rides on (with ``link_T_cam``), or None with ``world_T_cam`` for a fixed camera.
    ``render(segmentation=True)`` gives MuJoCo body ids (-1: background), as PyBullet's gives
    its body ids.
    """

    def __init__(self, world, intrinsics: Intrinsics, *, camera_name: str, **options):
        super().__init__(intrinsics, near=NEAR_M, far=FAR_M, **options)
        self.world = world
        model = world.model
        self.camera_id = int(model.camera(camera_name).id)
        (Wc, Hc), K = self._canvas_size, self._canvas_K
        model.cam_sensorsize[self.camera_id] = (Wc, Hc)
        model.cam_resolution[self.camera_id] = (Wc, Hc)
        model.cam_intrinsic[self.camera_id] = (K[0, 0], K[1, 1], (Wc - 1) / 2 - K[0, 2],
                                               (Hc - 1) / 2 - K[1, 2])
        if abs(K[0, 1]) > 1e-12:
            raise ValueError("the MuJoCo camera has no skew term; give intrinsics with K[0, 1] = 0")

    def _world_T_parent(self) -> np.ndarray:
        return self.world.body_pose(self.parent)

    def _render_canvas(self, world_T_cam, canvas_K, canvas_size, segmentation):
        mj_pose = compose(as_pose(world_T_cam, "world_T_cam"), GL_T_CV)
        data = self.world.data
        data.cam_xpos[self.camera_id] = mj_pose[:3, 3]
        data.cam_xmat[self.camera_id] = mj_pose[:3, :3].ravel()
        rgb, buffer, seg = self.world.renderer().render(self.world.model, data, self.camera_id,
                                                        *canvas_size, segmentation)
        depth = depth_from_mujoco_buffer(buffer, self.near, self.far)
        rgb[np.isnan(depth)] = BACKGROUND_RGB  # as PyBullet's: nothing drawn reads white
        return rgb, depth, seg

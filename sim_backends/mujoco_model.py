"""The workcell's parts as MuJoCo model elements, merged into one ``MjSpec``.

Each function adds one part of the engine-neutral description (``sim_backends.layout``) to a
spec: the arm (compiled from the generated URDF, ``arm_specs.portable_urdf``), the
table, a textured calibration target (the same OBJ slab and image as PyBullet's), a plain
box, the lights and the cameras. ``mujoco_world`` calls them in order and compiles once.

Geom groups: the URDF's visual geoms are group 1 and its collision geoms group 0 (MuJoCo's URDF
import); the scene's own geoms are group 2. Cameras draw groups 1 and 2 only, so every shape
is drawn once; rays (``mujoco_world``'s flange-face check) see group 0.

Frames: MuJoCo's world is the engine's world (z up, table top at z = 0, robot base at the
origin) exactly as in the PyBullet engine. A MuJoCo camera looks along its -z with y up
(OpenGL's eye frame), so its frame is ``world_T_cam @ GL_T_CV`` of the OpenCV optical frame.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from robots.geometry import quat_xyzw_from_rotation
from sim_backends.arm_specs import (
    ArmSpec,
    _write_if_changed,
    portable_urdf,
    render_portable_urdf,
)
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.rendered_camera import Lighting
from sim_backends.textures import Target, cache_dir, write_textured_slab

mujoco = import_mujoco()

__all__ = ["GL_T_CV", "SCENE_GROUP", "arm_spec", "add_box", "add_target", "add_lights",
           "mj_quat", "pos_quat"]

GL_T_CV = np.diag([1.0, -1.0, -1.0, 1.0])
COLLISION_GROUP, VISUAL_GROUP, SCENE_GROUP = 0, 1, 2
# Clipping planes (m) of every camera; MuJoCo scales them by the model's extent, fixed at 1.
NEAR_M, FAR_M = 0.01, 10.0


def mj_quat(R: np.ndarray) -> list[float]:
    """MuJoCo's quaternion (w, x, y, z) of a rotation matrix."""
    x, y, z, w = quat_xyzw_from_rotation(np.asarray(R, dtype=float))
    return [float(w), float(x), float(y), float(z)]


def pos_quat(T: np.ndarray) -> dict:
    """``pos`` and ``quat`` keyword arguments for a MuJoCo element at pose ``T`` (4, 4)."""
    return {"pos": [float(v) for v in T[:3, 3]], "quat": mj_quat(T[:3, :3])}


def _mujoco_urdf(path: Path, name: str) -> Path:
    """The URDF with MuJoCo's compiler settings: keep the visuals (drawn) and every link as a
    body (tool0 is a fixed link: fusing it away would lose the flange frame), and keep the
    absolute mesh paths (the flange face's OBJ lives in the texture cache)."""
    text = path.read_text()
    opening = re.search(r"<robot[^>]*>", text)
    if opening is None:
        raise RuntimeError(f"{path} is not a URDF (no <robot> element)")
    settings = ('<mujoco><compiler discardvisual="false" fusestatic="false" '
                'strippath="false"/></mujoco>')
    text = text[:opening.end()] + settings + text[opening.end():]
    return _write_if_changed(cache_dir() / f"{name}_mujoco.urdf", text)


def arm_spec(spec: ArmSpec, drawn: bool = True):
    """An ``MjSpec`` of the arm alone, base at the world origin, from the generated URDF
    (``arm_specs.portable_urdf``: the Panda's without pybullet_data, and without its hand).

    ``drawn``: the URDF the cameras see (with its flange face); False gives the controller's
    nominal model, as the PyBullet engine uses for IK.
    """
    source = render_portable_urdf(spec) if drawn else portable_urdf(spec)
    suffix = "render" if drawn else "nominal"
    return mujoco.MjSpec.from_file(str(_mujoco_urdf(source, f"{spec.name}_{suffix}")))


def configure_visual(s, max_canvas: tuple[int, int], shadows: bool = False) -> None:
    """Off-screen buffer big enough for the largest camera canvas, fixed clipping planes; a
    shadow map only as big as the lighting needs (making it costs time in every new cell)."""
    s.visual.global_.offwidth = int(max_canvas[0])
    s.visual.global_.offheight = int(max_canvas[1])
    s.stat.extent = 1.0  # so znear and zfar below are metres
    s.visual.map.znear = NEAR_M
    s.visual.map.zfar = FAR_M
    s.visual.headlight.active = 0  # only the described lights
    s.visual.quality.shadowsize = 2048 if shadows else 256


def add_lights(s, lighting: Lighting) -> None:
    """One directional light from ``lighting.direction`` (the direction light comes FROM) with
    the description's colour and ambient, diffuse and specular weights."""
    direction = np.asarray(lighting.direction, dtype=float)
    direction = direction / np.linalg.norm(direction)
    colour = np.asarray(lighting.color, dtype=float)
    s.worldbody.add_light(
        name="sun",
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        pos=(3.0 * direction).tolist(),
        dir=(-direction).tolist(),
        ambient=(colour * lighting.ambient).tolist(),
        diffuse=(colour * lighting.diffuse).tolist(),
        specular=(colour * lighting.specular).tolist(),
        castshadow=bool(lighting.shadow),
    )


def add_box(parent, name: str, half_size, T: np.ndarray, rgba, offset=(0.0, 0.0, 0.0),
            collide: bool = True):
    """A box body (static) at pose ``T`` under ``parent`` (a spec body), its geom shifted by
    ``offset`` (m) in the body frame. Returns the body."""
    body = parent.add_body(name=name, **pos_quat(T))
    body.add_geom(name=f"{name}_geom", type=mujoco.mjtGeom.mjGEOM_BOX,
                  size=[float(v) for v in half_size], pos=[float(v) for v in offset],
                  rgba=[float(v) for v in rgba], group=SCENE_GROUP,
                  contype=int(collide), conaffinity=int(collide))
    return body


def add_target(s, parent, name: str, target: Target, T: np.ndarray, thickness: float = 0.003):
    """The target's textured slab (``textures.write_textured_slab``: its frame is the target
    frame) as a body at pose ``T`` under ``parent``. Returns the body."""
    _, obj = write_textured_slab(target, thickness)
    height, width = target.image.shape[:2]
    texture = s.add_texture(name=f"{name}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D,
                            width=width, height=height, nchannel=3)
    texture.data = np.ascontiguousarray(target.image, dtype=np.uint8).tobytes()
    material = s.add_material(name=f"{name}_mat", specular=0.0, shininess=0.0,
                              reflectance=0.0)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = texture.name
    s.add_mesh(name=f"{name}_mesh", file=str(obj))
    body = parent.add_body(name=name, **pos_quat(T))
    body.add_geom(name=f"{name}_geom", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{name}_mesh",
                  material=material.name, group=SCENE_GROUP, contype=0, conaffinity=0)
    return body


def add_camera(s, name: str) -> None:
    """A world camera whose pose and intrinsics the camera object sets before each render."""
    s.worldbody.add_camera(name=name)


def add_tool(s, flange_link: str, urdf: Path, name: str):
    """A tool's URDF (``sim_backends/urdf``: its frame is the flange) fixed to the flange body.
    Its bodies are named ``<name>_<link>``. Returns the tool's root body."""
    tool = mujoco.MjSpec.from_file(str(_mujoco_urdf(urdf, f"tool_{name}")))
    root = tool.worldbody.first_body()
    s.body(flange_link).add_frame().attach_body(root, f"{name}_", "")
    return s.body(f"{name}_{root.name}")


def make_kinematic(s) -> None:
    """The arm (and what it carries) collides with nothing: it is moved by setting its joints,
    so a contact would only push the pieces with a made-up force. (PyBullet's arm did push.)"""
    for geom in s.geoms:
        if geom.group in (COLLISION_GROUP, VISUAL_GROUP):
            geom.contype = 0
            geom.conaffinity = 0


_PIECE_GEOMS = {"cylinder": "mjGEOM_CYLINDER", "box": "mjGEOM_BOX", "sphere": "mjGEOM_SPHERE",
                "capsule": "mjGEOM_CAPSULE"}


def add_piece(s, name: str, parts, rgba, T: np.ndarray, mass: float):
    """A free chess piece: ``parts`` as ``chess._PIECE_PARTS`` ((geometry, size, z), PyBullet's
    sizes: cylinder and capsule lengths are full lengths, MuJoCo's half), scaled already.
    Its body frame is the piece frame (base centre, z up). Returns the body."""
    body = s.worldbody.add_body(name=name, **pos_quat(T))
    body.add_freejoint(name=f"{name}_free")
    for k, (geometry, size, z) in enumerate(parts):
        if geometry in ("cylinder", "capsule"):
            size = (size[0], size[1] / 2)
        body.add_geom(name=f"{name}_{k}", type=getattr(mujoco.mjtGeom, _PIECE_GEOMS[geometry]),
                      size=[float(v) for v in size] + [0.0] * (3 - len(size)), pos=[0, 0, float(z)],
                      rgba=[float(v) for v in rgba], mass=mass / len(parts), group=SCENE_GROUP,
                      friction=[0.9, 0.01, 0.001])
    return body


def add_slab_collider(body, target: Target, thickness: float) -> None:
    """A collision box for a target slab (``add_target`` draws it without one): the slab as
    ``textures.write_textured_slab`` builds it, in the target frame."""
    w, h = target.size
    target_T_print = np.linalg.inv(target.print_T_target)
    centre = target_T_print @ np.array([w / 2, h / 2, thickness / 2, 1.0])
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[w / 2, h / 2, thickness / 2],
                  pos=centre[:3].tolist(), quat=mj_quat(target_T_print[:3, :3]), group=3,
                  friction=[1.0, 0.005, 0.0001])

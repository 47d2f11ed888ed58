"""A MuJoCo workcell as plain shapes and frames for ``robots.viewer`` (read-only).

``MujocoSceneReader(cell).read()`` returns the same ``robots.viewer.VisualScene`` as the
PyBullet engine's reader: every drawn geom (arm links, tool, table, targets, chess board and
pieces) as a part of its body, each body's pose in the robot base frame, and the true frames
(``scene_shapes.truth_frames``). Geometry is read once; each ``read()`` only reads poses.

MuJoCo moves a mesh's vertices into the mesh's own centred frame and shifts its geom to match
(``mesh_pos``, ``mesh_quat``); a mesh read back from its .obj file (to keep the targets'
printed textures) is placed with that shift undone.
"""

from __future__ import annotations

import numpy as np

from robots.geometry import make_pose
from robots.viewer import ShapePart, VisualScene, VisualShape
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.mujoco_model import SCENE_GROUP, VISUAL_GROUP
from sim_backends.scene_shapes import _texture_png, read_obj, truth_frames

mujoco = import_mujoco()

__all__ = ["MujocoSceneReader"]

_NAMES = {"table": ("table", "table"), "board": ("calibration board", "board"),
          "flange_target": ("flange target", "target"), "chess_board": ("chess board", "board")}


def _quat_matrix(quat_wxyz) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat_wxyz, dtype=float))
    return R.reshape(3, 3)


def _geom_part(model, geom: int, mesh_files: dict) -> ShapePart | None:
    rgba = tuple(float(c) for c in model.geom_rgba[geom])
    if model.geom_group[geom] not in (VISUAL_GROUP, SCENE_GROUP) or rgba[3] <= 0:
        return None
    body_T_geom = make_pose(_quat_matrix(model.geom_quat[geom]), model.geom_pos[geom])
    kind, size = int(model.geom_type[geom]), model.geom_size[geom]
    t = mujoco.mjtGeom
    if kind == t.mjGEOM_BOX:
        return ShapePart("box", tuple(2 * size[:3]), body_T_geom, rgba)
    if kind in (t.mjGEOM_CYLINDER, t.mjGEOM_CAPSULE):
        name = "cylinder" if kind == t.mjGEOM_CYLINDER else "capsule"
        return ShapePart(name, (size[0], 2 * size[1]), body_T_geom, rgba)
    if kind == t.mjGEOM_SPHERE:
        return ShapePart("sphere", (size[0],), body_T_geom, rgba)
    if kind != t.mjGEOM_MESH:
        return None
    mesh = int(model.geom_dataid[geom])
    path = mesh_files.get(model.mesh(mesh).name)
    shift = make_pose(_quat_matrix(model.mesh_quat[mesh]), model.mesh_pos[mesh])
    if model.geom_matid[geom] >= 0:  # a material carries the colour (the textured slabs)
        rgba = tuple(float(c) for c in model.mat_rgba[model.geom_matid[geom]])
    if path is not None:
        vertices, triangles, uvs = read_obj(path)
        texture = _texture_png(path) if uvs is not None else None
        return ShapePart("mesh", (), body_T_geom @ np.linalg.inv(shift), rgba, vertices,
                         triangles, uvs if texture is not None else None, texture)
    first, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    faces = model.mesh_face[model.mesh_faceadr[mesh]:model.mesh_faceadr[mesh]
                            + model.mesh_facenum[mesh]]
    return ShapePart("mesh", (), body_T_geom, rgba, model.mesh_vert[first:first + count].copy(),
                     faces.astype(np.uint32))


class MujocoSceneReader:
    """Reads a ``MujocoWorkcell`` for the viewer: geometry once, poses on every :meth:`read`."""

    def __init__(self, cell):
        self.cell = cell
        model = cell.world.model
        chess = cell.truth._chess
        pieces = {} if chess is None else chess.bodies
        tool = cell.tool_name
        self._bodies = []  # (name, group, body id, parts)
        for body in range(1, model.nbody):
            parts = [part for g in range(model.body_geomadr[body],
                                         model.body_geomadr[body] + model.body_geomnum[body])
                     if (part := _geom_part(model, g, cell.world.mesh_files)) is not None]
            if not parts:
                continue
            name = model.body(body).name
            if name in _NAMES:
                label, group = _NAMES[name]
            elif body in pieces:
                kind, colour = pieces[body]
                label, group = f"piece {body}: {colour} {kind}", "piece"
            elif tool is not None and name.startswith(f"{tool}_"):
                label, group = f"tool/{name}", "tool"
            elif name == "rectangle_mark":
                label, group = f"object {body}", "object"
            else:
                label, group = f"arm/{name}", "arm"
            self._bodies.append((label, group, body, tuple(parts)))

    def read(self) -> VisualScene:
        """The shapes at their poses now and the true frames, all in the robot base frame."""
        data = self.cell.world.data
        base_T_world = self.cell.truth.base_T_pybullet
        shapes = tuple(
            VisualShape(label, group,
                        base_T_world @ make_pose(data.xmat[body].reshape(3, 3), data.xpos[body]),
                        parts)
            for label, group, body, parts in self._bodies)
        return VisualScene(shapes, truth_frames(self.cell))

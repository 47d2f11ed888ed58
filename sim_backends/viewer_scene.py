"""The simulated workcell as plain shapes and frames for ``robots.viewer`` (read-only).

``SceneReader(cell).read()`` returns a ``robots.viewer.VisualScene``: every PyBullet body's
visual shapes (arm links, tool, table, calibration targets, chess board and pieces) with the
pose of its link frame in the robot base frame, and the true frames from ``cell.truth``.
The geometry (primitives, meshes read from their .obj files, the targets' printed textures)
is read once when the reader is made; each ``read()`` only reads poses.

PyBullet reports a visual shape's local frame relative to the URDF link frame (measured with
a link whose inertial and visual origins differ), while ``getBasePositionAndOrientation``
gives the base's centre-of-mass frame: the base's link frame is that times the inverse of its
local inertial frame. Meshes are drawn from the files PyBullet loaded, scaled as it scaled
them; the Panda's are its collision meshes, which the simulation also renders (see
``sim_backends.arms``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as p

from robots.geometry import invert, pose_from_quat_xyzw
from robots.viewer import ShapePart, VisualScene, VisualShape
from sim_backends.scene_shapes import (  # noqa: F401  (re-exported: their home before)
    TABLE_MIN_SIZE_M,
    TEXTURE_MAX_PX,
    _texture_png,
    read_obj,
    truth_frames,
)

__all__ = ["SceneReader", "read_obj"]

_KINDS = {p.GEOM_BOX: "box", p.GEOM_CYLINDER: "cylinder", p.GEOM_CAPSULE: "capsule",
          p.GEOM_SPHERE: "sphere", p.GEOM_MESH: "mesh"}
def _part(shape) -> ShapePart | None:
    geometry, dims, filename = shape[2], shape[3], shape[4]
    local = pose_from_quat_xyzw(shape[6], shape[5])
    rgba = tuple(float(c) for c in shape[7])
    kind = _KINDS.get(geometry)
    if kind is None or rgba[3] <= 0:  # planes, heightfields, hidden links (the Panda's hand)
        return None
    if kind == "box":
        return ShapePart("box", tuple(dims[:3]), local, rgba)
    if kind in ("cylinder", "capsule"):
        return ShapePart(kind, (dims[1], dims[0]), local, rgba)  # PyBullet: length, radius
    if kind == "sphere":
        return ShapePart("sphere", (dims[0],), local, rgba)
    path = filename.decode() if isinstance(filename, bytes) else str(filename)
    if not Path(path).exists():
        return None
    vertices, triangles, uvs = read_obj(path)
    vertices = vertices * np.asarray(dims[:3], dtype=float)
    texture = _texture_png(path) if uvs is not None else None
    return ShapePart("mesh", (), local, rgba, vertices, triangles,
                     uvs if texture is not None else None, texture)


def _pose(position, quat_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.reshape(p.getMatrixFromQuaternion(quat_xyzw), (3, 3))
    T[:3, 3] = position
    return T


class SceneReader:
    """Reads a ``SimWorkcell`` for the viewer: geometry once, poses on every :meth:`read`."""

    def __init__(self, cell):
        self.cell = cell
        self.client = cell.client
        truth = cell.truth
        chess = truth._chess
        arm = cell.arm
        attached = set(getattr(arm, "_attached", {}) or {})
        boards = {getattr(truth.board, "key", None): "board",
                  getattr(truth.flange_target, "key", None): "target"}
        self._bodies = []  # (name, group, body, link, parts)
        self._com_T_base_link = {}  # body -> inverse of its base's local inertial frame
        for index in range(p.getNumBodies(physicsClientId=self.client)):
            body = p.getBodyUniqueId(index, physicsClientId=self.client)
            links: dict[int, list[ShapePart]] = {}
            for shape in p.getVisualShapeData(body, physicsClientId=self.client):
                part = _part(shape)
                if part is not None:
                    links.setdefault(shape[1], []).append(part)
            info = p.getDynamicsInfo(body, -1, physicsClientId=self.client)
            self._com_T_base_link[body] = invert(pose_from_quat_xyzw(info[4], info[3]))
            for link, parts in sorted(links.items()):
                name, group = self._name(body, link, parts, arm, chess, attached, boards)
                self._bodies.append((name, group, body, link, tuple(parts)))

    def _name(self, body, link, parts, arm, chess, attached, boards) -> tuple[str, str]:
        c = self.client
        if body == arm.body_id:
            link_name = (p.getBodyInfo(body, physicsClientId=c)[0] if link == -1 else
                         p.getJointInfo(body, link, physicsClientId=c)[12]).decode()
            return f"arm/{link_name}", "arm"
        if chess is not None and body == chess.board_body:
            return "chess board", "board"
        if chess is not None and body in chess.bodies:
            kind, colour = chess.bodies[body]
            return f"piece {body}: {colour} {kind}", "piece"
        for key, group in boards.items():
            if key and self._mesh_is(body, key):
                return ("calibration board" if group == "board" else "flange target"), group
        if body in attached:
            return f"tool/{p.getBodyInfo(body, physicsClientId=c)[1].decode() or body}", "tool"
        if parts[0].kind == "box" and max(parts[0].size[:2]) >= TABLE_MIN_SIZE_M:
            return "table", "table"
        return f"object {body}", "object"

    def _mesh_is(self, body: int, key: str) -> bool:
        return any(key in (s[4].decode() if isinstance(s[4], bytes) else str(s[4]))
                   for s in p.getVisualShapeData(body, physicsClientId=self.client))

    def _world_T_link(self, body: int, link: int) -> np.ndarray:
        # PyBullet's own quaternion-to-matrix: this runs for every shape at every redraw,
        # and the poses come straight from the simulator (no validation to do).
        c = self.client
        if link == -1:
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=c)
            return _pose(pos, quat) @ self._com_T_base_link[body]
        state = p.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=c)
        return _pose(state[4], state[5])

    def read(self) -> VisualScene:
        """The shapes at their poses now and the true frames, all in the robot base frame."""
        truth = self.cell.truth
        base_T_world = truth.base_T_pybullet
        shapes = tuple(
            VisualShape(name, group, base_T_world @ self._world_T_link(body, link), parts)
            for name, group, body, link, parts in self._bodies)
        return VisualScene(shapes, truth_frames(self.cell))

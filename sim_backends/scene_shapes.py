"""What the 3-D viewer draws of a simulated cell, engine-neutral: meshes read from their .obj
files with the targets' printed textures, and the true frames from ``cell.truth``.

Each engine's reader (``viewer_scene.SceneReader`` for PyBullet,
``mujoco_viewer_scene.MujocoSceneReader`` for MuJoCo) lists its bodies' shapes with these.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from robots.geometry import compose

__all__ = ["TABLE_MIN_SIZE_M", "TEXTURE_MAX_PX", "read_obj", "truth_frames"]

TEXTURE_MAX_PX = 1024  # the printed pattern as the viewer shows it; the sim's is finer
TABLE_MIN_SIZE_M = 1.0  # a box this wide is the table, not a part of anything


@lru_cache(maxsize=64)
def read_obj(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices (n, 3), triangles (m, 3) and per-vertex uvs (n, 2) or None of a Wavefront .obj.

    Polygons are split into triangle fans. When every face corner has a texture coordinate,
    the vertices are unrolled per corner so that each carries its own uv (the slab's printed
    face and its white sides share corner positions but not uvs).
    """
    positions, uvs, corners = [], [], []
    for line in Path(path).read_text().splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "v":
            positions.append([float(w) for w in words[1:4]])
        elif words[0] == "vt":
            uvs.append([float(w) for w in words[1:3]])
        elif words[0] == "f":
            face = []
            for word in words[1:]:
                refs = word.split("/")
                v = int(refs[0])
                t = int(refs[1]) if len(refs) > 1 and refs[1] else 0
                face.append((v - 1 if v > 0 else len(positions) + v,
                             (t - 1 if t > 0 else len(uvs) + t) if t else None))
            corners += [(face[0], face[k], face[k + 1]) for k in range(1, len(face) - 1)]
    positions = np.array(positions, dtype=float).reshape(-1, 3)
    if corners and all(c[1] is not None for tri in corners for c in tri):
        flat = [c for tri in corners for c in tri]
        vertices = positions[[v for v, _ in flat]]
        texcoords = np.array(uvs, dtype=float)[[t for _, t in flat]]
        triangles = np.arange(len(flat), dtype=np.uint32).reshape(-1, 3)
        return vertices, triangles, texcoords
    triangles = np.array([[c[0] for c in tri] for tri in corners], dtype=np.uint32).reshape(-1, 3)
    return positions, triangles, None


@lru_cache(maxsize=16)
def _texture_png(obj_path: str) -> bytes | None:
    """The PNG beside a textured target slab, shrunk for the viewer; None for other meshes.

    ``textures.write_textured_slab`` names the pair ``<key>.png`` and ``<key>_<um>um.obj``.
    """
    obj = Path(obj_path)
    key = obj.stem.rsplit("_", 1)[0]
    png = obj.with_name(f"{key}.png")
    if "_" not in obj.stem or not png.exists():
        return None
    image = cv2.imread(str(png), cv2.IMREAD_COLOR)
    if image is None:
        return None
    scale = TEXTURE_MAX_PX / max(image.shape[:2])
    if scale < 1:
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    ok, data = cv2.imencode(".png", image)
    return data.tobytes() if ok else None


def truth_frames(cell) -> dict:
    """The true frames a view shows, in the robot base frame: "flange", "cam", "tcp" (with a
    tool), "target" (the board a wrist camera looks at, or the flange's target) and "world"
    (the chess frame)."""
    truth = cell.truth
    base_T_flange = truth.base_T_flange()
    frames = {"flange": base_T_flange, "cam": truth.base_T_cam_now()}
    tool = cell.robot.tool
    if tool is not None:
        frames["tcp"] = compose(base_T_flange, tool.flange_T_tcp)
    if truth.mount == "eye_in_hand" and truth.base_T_board is not None:
        frames["target"] = truth.base_T_board
    elif truth.flange_T_marker is not None:
        frames["target"] = compose(base_T_flange, truth.flange_T_marker)
    if truth._chess is not None:
        frames["world"] = truth.base_T_world
    return frames

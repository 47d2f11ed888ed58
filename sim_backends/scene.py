"""Scene objects for the PyBullet workcell: table, textured calibration targets, a chess set.

World layout (PyBullet world frame): z up, the table top is the plane z = 0, the robot base
stands on it at the origin (the workcell may move it) and faces +x.

Chess frame and square names
----------------------------
The chess frame (``chess``) has its origin at the OUTER corner of square a1 on the playing
surface, x along the files (a -> h), y along the ranks (1 -> 8), z up out of the board. Square
``file f (0 = a), rank r (0 = rank 1)`` has its centre at ``((f + 0.5) s, (r + 0.5) s, 0)``.
a1 is a dark square, White's pieces start on ranks 1 and 2.

A piece's frame sits at the centre of its base, z up, x along the chess frame's x when placed;
that is the pose ``ChessSet.pieces`` reports, read from the live simulation so it follows the
pieces as they are picked and placed.
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from robots.geometry import (
    as_pose,
    compose,
    invert,
    make_pose,
    quat_xyzw_from_rotation,
)

# Square names come from the student-facing helpers (robots never imports sim_backends).
from robots.perception import square_index, square_name
from sim_backends.chess import (  # noqa: F401  (re-exported: their home before chess.py)
    _PIECE_PARTS,
    COLOURS,
    PIECE_HEIGHT,
    PIECE_KINDS,
    PIECE_SQUARE_M,
    START_POSITION,
    ChessLayout,
    PieceTruth,
    chess_texture,
    piece_height,
    random_position,
)
from sim_backends.layout import board_pose_on_table  # noqa: F401  (re-exported: its home before layout)
from sim_backends.textures import Target, write_textured_slab

__all__ = [
    "PIECE_HEIGHT",
    "PIECE_KINDS",
    "PIECE_SQUARE_M",
    "START_POSITION",
    "ChessSet",
    "PieceTruth",
    "add_table",
    "add_target",
    "board_pose_on_table",
    "chess_texture",
    "piece_height",
    "pose_of_body",
    "random_position",
    "set_pose_of_body",
    "square_index",
    "square_name",
]

# --------------------------------------------------------------------------- pose helpers


def pose_of_body(client: int, body: int) -> np.ndarray:
    """World pose (4, 4) of a body's base frame.

    Bodies made here put the inertial frame on the link frame, so PyBullet's base pose (which
    is the centre-of-mass frame) is the link frame.
    """
    pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=client)
    return make_pose(np.reshape(p.getMatrixFromQuaternion(quat), (3, 3)), pos)


def set_pose_of_body(client: int, body: int, world_T_body) -> None:
    """Teleport a body's base frame to a world pose (and zero its velocity)."""
    T = as_pose(world_T_body, "world_T_body")
    quat = quat_xyzw_from_rotation(T[:3, :3])
    p.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), quat.tolist(),
                                      physicsClientId=client)
    p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=client)


# --------------------------------------------------------------------------- table, targets


def add_table(client: int, size=(1.6, 1.6), thickness=0.04, centre_xy=(0.35, 0.0),
              colour=(0.78, 0.70, 0.58, 1.0)) -> int:
    """A static table whose top surface is the world plane z = 0. Returns the body id."""
    half = [size[0] / 2, size[1] / 2, thickness / 2]
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=list(colour),
                              physicsClientId=client)
    body = p.createMultiBody(0, col, vis, [centre_xy[0], centre_xy[1], -thickness / 2],
                             physicsClientId=client)
    p.changeDynamics(body, -1, lateralFriction=1.0, physicsClientId=client)
    return body


def add_target(client: int, target: Target, world_T_target, thickness: float = 0.003,
               mass: float = 0.0, collide: bool = True) -> int:
    """Put a textured target slab in the world with its target frame at ``world_T_target``.

    The body's frame is the target frame (see ``sim_backends.textures``), so
    ``pose_of_body(client, body)`` returns the true ``world_T_target``. Mass 0 makes it
    static. Returns the body id.
    """
    world_T_target = as_pose(world_T_target, "world_T_target")
    png, obj = write_textured_slab(target, thickness)
    vis = p.createVisualShape(p.GEOM_MESH, fileName=str(obj), rgbaColor=[1, 1, 1, 1],
                              physicsClientId=client)
    col = -1
    if collide:
        # The slab as a box, expressed in the target frame like the mesh.
        w, h = target.size
        centre_print = np.array([w / 2, h / 2, thickness / 2, 1.0])
        target_T_print = invert(target.print_T_target)
        quat = quat_xyzw_from_rotation(target_T_print[:3, :3])
        col = p.createCollisionShape(
            p.GEOM_BOX, halfExtents=[w / 2, h / 2, thickness / 2],
            collisionFramePosition=(target_T_print @ centre_print)[:3].tolist(),
            collisionFrameOrientation=quat.tolist(),
            physicsClientId=client,
        )
    body = p.createMultiBody(
        mass, col, vis, world_T_target[:3, 3].tolist(),
        quat_xyzw_from_rotation(world_T_target[:3, :3]).tolist(),
        physicsClientId=client,
    )
    tex = p.loadTexture(str(png), physicsClientId=client)
    p.changeVisualShape(body, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1],
                        physicsClientId=client)
    return body


# --------------------------------------------------------------------------- chess


def _piece_body(client: int, kind: str, colour: str, world_T_piece, mass=0.03,
                scale: float = 1.0) -> int:
    shapes = {"cylinder": p.GEOM_CYLINDER, "box": p.GEOM_BOX, "sphere": p.GEOM_SPHERE,
              "capsule": p.GEOM_CAPSULE}
    parts = [(g, tuple(scale * v for v in size), scale * z) for g, size, z in _PIECE_PARTS[kind]]
    mass = mass * scale ** 3
    types = [shapes[g] for g, _, _ in parts]
    radii = [s[0] if g in ("cylinder", "sphere", "capsule") else 0.0 for g, s, _ in parts]
    lengths = [s[1] if g in ("cylinder", "capsule") else 0.0 for g, s, _ in parts]
    halves = [list(s) if g == "box" else [0.0, 0.0, 0.0] for g, s, _ in parts]
    frames = [[0.0, 0.0, z] for _, _, z in parts]
    rgba = list(COLOURS[colour])
    col = p.createCollisionShapeArray(types, radii=radii, halfExtents=halves, lengths=lengths,
                                      collisionFramePositions=frames, physicsClientId=client)
    vis = p.createVisualShapeArray(types, radii=radii, halfExtents=halves, lengths=lengths,
                                   rgbaColors=[rgba] * len(parts), visualFramePositions=frames,
                                   physicsClientId=client)
    T = as_pose(world_T_piece, "world_T_piece")
    # Inertial frame at the base centre (low and stable); the link frame is the piece frame.
    body = p.createMultiBody(mass, col, vis, T[:3, 3].tolist(),
                             quat_xyzw_from_rotation(T[:3, :3]).tolist(),
                             baseInertialFramePosition=[0, 0, 0], physicsClientId=client)
    p.changeDynamics(body, -1, lateralFriction=0.9, spinningFriction=0.01,
                     rollingFriction=0.001, physicsClientId=client)
    return body


class ChessSet(ChessLayout):
    """A textured chess board on the table and its pieces, with live ground truth.

    ``world_T_chess`` places the chess frame (outer corner of a1, see the module docstring).
    ``position`` maps square names to (kind, colour); defaults to the starting position.

    The pieces are proportioned to the board, as a real set is: the set of ``PIECE_HEIGHT`` is
    made for 50 mm squares, and on smaller squares every dimension shrinks by
    ``square / 0.05`` (a travel set: on the Cobotta's 30 mm board a king is 43 mm tall, not
    72 mm, so the pieces no longer hide the board's inner corners from the wrist camera).
    """

    def __init__(self, client: int, world_T_chess, position=None, square=0.05,
                 board_thickness=0.01):
        self.client = client
        self.square = float(square)
        self.texture = chess_texture(square)
        # The texture's printed face is the board's top; the chess frame sits on it.
        self.world_T_chess = as_pose(world_T_chess, "world_T_chess")
        self.board_body = add_target(client, self.texture, self.world_T_chess,
                                     thickness=board_thickness)
        p.changeDynamics(self.board_body, -1, lateralFriction=1.0, physicsClientId=client)
        position = START_POSITION if position is None else position
        self.bodies: dict[int, tuple[str, str]] = {}
        for sq, (kind, colour) in position.items():
            if kind not in PIECE_KINDS or colour not in COLOURS:
                raise ValueError(f"bad piece {kind!r}/{colour!r} on {sq}; kinds are "
                                 f"{PIECE_KINDS}, colours {tuple(COLOURS)}")
            body = _piece_body(client, kind, colour,
                               compose(self.world_T_chess, self.chess_T_square(sq)),
                               scale=self.square / PIECE_SQUARE_M)
            self.bodies[body] = (kind, colour)

    def _world_T_body(self, body: int) -> np.ndarray:
        return pose_of_body(self.client, body)

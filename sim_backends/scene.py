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

from dataclasses import dataclass

import cv2
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
from robots.perception import FILES, square_index, square_name
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

PIECE_KINDS = ("pawn", "rook", "knight", "bishop", "queen", "king")
COLOURS = {"white": (0.93, 0.88, 0.74, 1.0), "black": (0.12, 0.10, 0.10, 1.0)}


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


_BACK_RANK = ("rook", "knight", "bishop", "queen", "king", "bishop", "knight", "rook")
START_POSITION: dict[str, tuple[str, str]] = {}
for _f in range(8):
    START_POSITION[square_name(_f, 0)] = (_BACK_RANK[_f], "white")
    START_POSITION[square_name(_f, 1)] = ("pawn", "white")
    START_POSITION[square_name(_f, 6)] = ("pawn", "black")
    START_POSITION[square_name(_f, 7)] = (_BACK_RANK[_f], "black")


def random_position(rng: np.random.Generator, n_pieces: int = 12) -> dict[str, tuple[str, str]]:
    """A seeded random legal-looking position: both kings plus ``n_pieces - 2`` others.

    Pawns never stand on ranks 1 or 8; piece counts never exceed a normal set.
    """
    if not (2 <= n_pieces <= 32):
        raise ValueError(f"n_pieces must be in 2..32, got {n_pieces}")
    pool = [(kind, colour) for kind, colour in START_POSITION.values() if kind != "king"]
    order = rng.permutation(len(pool))
    chosen = [("king", "white"), ("king", "black")] + [pool[i] for i in order[: n_pieces - 2]]
    free = [square_name(f, r) for f in range(8) for r in range(8)]
    position = {}
    for kind, colour in chosen:
        allowed = [s for s in free if not (kind == "pawn" and s[1] in "18")]
        sq = allowed[int(rng.integers(len(allowed)))]
        free.remove(sq)
        position[sq] = (kind, colour)
    return position


def chess_texture(square=0.05, border=0.02, texel=5e-4, blur=6e-4) -> Target:
    """The chess board's texture (8x8 squares, a1 dark, file letters and rank digits printed
    in the border). Its target frame is the chess frame (see the module docstring)."""
    s = max(8, round(square / texel))
    m = round(border / square * s)
    light, dark, frame = (236, 214, 170), (150, 100, 60), (95, 60, 35)
    img = np.empty((8 * s + 2 * m, 8 * s + 2 * m, 3), np.uint8)
    img[:] = frame
    for f in range(8):
        for r in range(8):
            row = 7 - r  # rank 8 is the image's top row
            colour = dark if (f + r) % 2 == 0 else light
            img[m + row * s:m + (row + 1) * s, m + f * s:m + (f + 1) * s] = colour
    scale = m / 40.0
    for f in range(8):
        org = (m + f * s + s // 2 - int(10 * scale), img.shape[0] - int(m * 0.25))
        cv2.putText(img, FILES[f], org, cv2.FONT_HERSHEY_SIMPLEX, scale, light, 2, cv2.LINE_AA)
    for r in range(8):
        org = (int(m * 0.25), m + (7 - r) * s + s // 2 + int(10 * scale))
        cv2.putText(img, str(r + 1), org, cv2.FONT_HERSHEY_SIMPLEX, scale, light, 2, cv2.LINE_AA)
    texel = square / s
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur / texel)
    # Print frame: x right, y down, z into the board; chess frame: x files, y ranks, z up.
    print_T_chess = make_pose(np.diag([1.0, -1.0, -1.0]), [m * texel, (m + 8 * s) * texel, 0.0])
    centres = np.array([[(f + 0.5) * square, (r + 0.5) * square, 0.0]
                        for r in range(8) for f in range(8)])
    return Target(kind="chess", image=img, size=(img.shape[1] * texel, img.shape[0] * texel),
                  print_T_target=print_T_chess, object_points=centres,
                  params={"square": square, "border": border})


# Primitive parts of each piece: (geometry, size, height of the part's centre above the base).
# Sizes are metres: cylinder (radius, length), box (half extents), sphere (radius,),
# capsule (radius, length). Every kind has a distinct silhouette from above and the side.
_PIECE_PARTS = {
    "pawn": [("cylinder", (0.013, 0.018), 0.009), ("sphere", (0.009,), 0.025)],
    "rook": [("box", (0.013, 0.013, 0.020), 0.020), ("box", (0.016, 0.016, 0.004), 0.040)],
    "knight": [("cylinder", (0.014, 0.016), 0.008), ("box", (0.007, 0.012, 0.014), 0.028),
               ("box", (0.007, 0.016, 0.006), 0.042)],
    "bishop": [("cylinder", (0.013, 0.020), 0.010), ("capsule", (0.009, 0.024), 0.036)],
    "queen": [("cylinder", (0.015, 0.030), 0.015), ("cylinder", (0.011, 0.018), 0.039),
              ("sphere", (0.012,), 0.054)],
    "king": [("cylinder", (0.015, 0.036), 0.018), ("cylinder", (0.012, 0.016), 0.044),
             ("box", (0.003, 0.003, 0.010), 0.062), ("box", (0.009, 0.003, 0.003), 0.064)],
}


def _part_top(geometry: str, size, z: float) -> float:
    """Height of a part's highest point above the piece's base (m)."""
    if geometry == "box":
        return z + size[2]
    if geometry == "cylinder":
        return z + size[1] / 2
    if geometry == "capsule":
        return z + size[1] / 2 + size[0]
    return z + size[0]  # sphere


# Height of each kind (m): where a suction cup meets the top of the piece.
PIECE_HEIGHT = {kind: max(_part_top(*part) for part in parts)
                for kind, parts in _PIECE_PARTS.items()}


# The square size (m) the pieces of ``_PIECE_PARTS`` are made for. A set for another board is
# the same set scaled by square / PIECE_SQUARE_M (see ``ChessSet``).
PIECE_SQUARE_M = 0.05


def piece_height(kind: str, square: float = PIECE_SQUARE_M) -> float:
    """Height (m) of a piece of ``kind`` in the set that goes with squares of ``square`` m."""
    return PIECE_HEIGHT[kind] * square / PIECE_SQUARE_M


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


@dataclass(frozen=True)
class PieceTruth:
    """Ground truth for one piece. Unpacks as ``kind, colour, base_T_piece``."""

    kind: str
    colour: str
    base_T_piece: np.ndarray
    body_id: int = -1

    def __iter__(self):
        return iter((self.kind, self.colour, self.base_T_piece))


class ChessSet:
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

    def chess_T_square(self, name: str) -> np.ndarray:
        """Pose of a square's centre on the playing surface, chess-frame axes."""
        f, r = square_index(name)
        return make_pose(t=[(f + 0.5) * self.square, (r + 0.5) * self.square, 0.0])

    def world_T_square(self, name: str) -> np.ndarray:
        return compose(self.world_T_chess, self.chess_T_square(name))

    def square_at(self, world_T_piece, max_height=0.005) -> str | None:
        """Name of the square a piece stands on, or None when it is lifted or off the board."""
        chess_T_piece = compose(invert(self.world_T_chess), as_pose(world_T_piece))
        x, y, z = chess_T_piece[:3, 3]
        f, r = int(np.floor(x / self.square)), int(np.floor(y / self.square))
        if 0 <= f < 8 and 0 <= r < 8 and abs(z) <= max_height:
            return square_name(f, r)
        return None

    def pieces(self, base_T_world=None) -> dict[str, PieceTruth]:
        """Live piece truth keyed by square; a lifted or off-board piece is keyed
        ``"lifted:<body id>"``. Poses are in the robot base frame when ``base_T_world`` is
        given, else in the world frame."""
        base_T_world = np.eye(4) if base_T_world is None else base_T_world
        out = {}
        for body, (kind, colour) in self.bodies.items():
            world_T_piece = pose_of_body(self.client, body)
            key = self.square_at(world_T_piece) or f"lifted:{body}"
            if key in out:  # two pieces on one square: keep both visible, never drop one
                key = f"{key}:{body}"
            out[key] = PieceTruth(kind, colour, compose(base_T_world, world_T_piece), body)
        return out

"""The chess set, engine-neutral: positions, the board's texture, the pieces' shapes, and the
live ground truth of where pieces stand.

Chess frame and square names: see ``sim_backends.scene`` (the chess frame's origin is the
OUTER corner of a1 on the playing surface, x along the files, y along the ranks, z up). An
engine's chess set subclasses :class:`ChessLayout` and gives ``_world_T_body(body)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from robots.geometry import as_pose, compose, invert, make_pose
from robots.perception import FILES, square_index, square_name
from sim_backends.textures import Target

__all__ = ["COLOURS", "PIECE_HEIGHT", "PIECE_KINDS", "PIECE_SQUARE_M", "START_POSITION",
           "ChessLayout", "PieceTruth", "chess_texture", "piece_height", "random_position"]

PIECE_KINDS = ("pawn", "rook", "knight", "bishop", "queen", "king")
COLOURS = {"white": (0.93, 0.88, 0.74, 1.0), "black": (0.12, 0.10, 0.10, 1.0)}


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


@dataclass(frozen=True)
class PieceTruth:
    """Ground truth for one piece. Unpacks as ``kind, colour, base_T_piece``."""

    kind: str
    colour: str
    base_T_piece: np.ndarray
    body_id: int = -1

    def __iter__(self):
        return iter((self.kind, self.colour, self.base_T_piece))


class ChessLayout:
    """The squares of a chess set placed at ``world_T_chess`` (square size ``square`` m) and
    the live truth of its pieces (``bodies``: body id -> (kind, colour))."""

    world_T_chess: np.ndarray
    square: float
    bodies: dict

    def _world_T_body(self, body: int) -> np.ndarray:
        """A piece's world pose (4, 4) now (the engine's part)."""
        raise NotImplementedError

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
            world_T_piece = self._world_T_body(body)
            key = self.square_at(world_T_piece) or f"lifted:{body}"
            if key in out:  # two pieces on one square: keep both visible, never drop one
                key = f"{key}:{body}"
            out[key] = PieceTruth(kind, colour, compose(base_T_world, world_T_piece), body)
        return out

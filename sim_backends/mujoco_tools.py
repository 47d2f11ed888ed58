"""The suction cup and the pointer on a MuJoCo arm, and the MuJoCo chess set's live truth.

The tools are the PyBullet engine's (``sim_backends.tools``): the same URDFs fixed to the
flange, the same TCPs, the same rule for a grasp (the vacuum holds the nearest liftable
object whose surface lies within ``SUCTION_REACH_M`` of the cup tip along the tool axis, seen
by five rays over the cup face; the table and the board are never lifted). Holding means the
arm carries the piece (``MujocoArm.attach``); releasing hands it back to MuJoCo's physics,
where it settles on what is below it.

Not here yet: the parallel gripper (the Panda's Franka Hand and the generic gripper).
"""

from __future__ import annotations

import numpy as np

from robots.geometry import make_pose
from robots.interfaces import Pointer, SuctionCup
from sim_backends.chess import ChessLayout, chess_texture
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.mujoco_model import SCENE_GROUP
from sim_backends.tool_specs import (
    POINTER_TIP_M,
    SUCTION_CUP_RADIUS_M,
    SUCTION_REACH_M,
    SUCTION_TIP_M,
)

mujoco = import_mujoco()

__all__ = ["MujocoChessSet", "MujocoPointer", "MujocoSuctionCup", "TOOL_URDFS"]

# tool -> (URDF in sim_backends/urdf, its root link)
TOOL_URDFS = {"suction": "suction_cup.urdf", "pointer": "pointer.urdf"}


def _free_body(model, body: int) -> bool:
    """A body MuJoCo moves by physics (a chess piece), not one fixed to the world or the arm."""
    adr = model.body_jntadr[body]
    return adr >= 0 and model.jnt_type[adr] == mujoco.mjtJoint.mjJNT_FREE


class MujocoSuctionCup(SuctionCup):
    """The suction cup (``tools.SimSuctionCup``'s geometry and grasp rule) on a ``MujocoArm``."""

    TIP_M = SUCTION_TIP_M
    CUP_RADIUS_M = SUCTION_CUP_RADIUS_M

    def __init__(self, arm):
        super().__init__("suction", make_pose(t=[0.0, 0.0, self.TIP_M]))
        self._arm = arm
        self.held_body: int | None = None

    def _first_object_hit(self, starts, axis) -> int | None:
        model, data = self._arm.world.model, self._arm.world.data
        groups = np.zeros(6, dtype=np.uint8)
        groups[SCENE_GROUP] = 1  # the scene's geoms only: never the arm or the tool
        geom = np.zeros(1, dtype=np.int32)
        length = 0.003 + SUCTION_REACH_M
        best = None
        for start in starts:
            # flg_static=0: the table and the board (fixed to the world) are never lifted.
            distance = mujoco.mj_ray(model, data, start, axis * length, groups, 0, -1, geom)
            if 0 <= distance <= 1:
                body = int(model.geom_bodyid[geom[0]])
                if _free_body(model, body) and (best is None or distance < best[1]):
                    best = (body, distance)
        return None if best is None else best[0]

    def grasp(self) -> bool:
        if self.held_body is not None:
            return True
        world_T_tcp = self._arm.world_T_flange() @ self.flange_T_tcp
        tip, axis = world_T_tcp[:3, 3], world_T_tcp[:3, 2]
        x, y, r = world_T_tcp[:3, 0], world_T_tcp[:3, 1], self.CUP_RADIUS_M
        # Start a little behind the tip: a cup pressed onto a part sinks into it slightly.
        starts = [tip + o - 0.003 * axis for o in (np.zeros(3), r * x, -r * x, r * y, -r * y)]
        body = self._first_object_hit(starts, axis)
        if body is None:
            return False
        self._arm.attach(body)
        self.held_body = body
        return True

    def release(self) -> None:
        if self.held_body is not None:
            self._arm.detach(self.held_body)
            self.held_body = None

    @property
    def is_holding(self) -> bool:
        return self.held_body is not None


class MujocoPointer(Pointer):
    """The pointer (``tools.SimPointer``'s rod, tip ``TIP_M`` along the flange z axis)."""

    TIP_M = POINTER_TIP_M

    def __init__(self, arm):
        super().__init__("pointer", make_pose(t=[0.0, 0.0, self.TIP_M]))
        self._arm = arm


class MujocoChessSet(ChessLayout):
    """The chess set's squares and live piece truth in a MuJoCo world.

    ``names``: piece body name -> (kind, colour), as ``mujoco_world`` built them.
    """

    def __init__(self, world, world_T_chess, square: float, names: dict):
        self.world = world
        self.world_T_chess = world_T_chess
        self.square = float(square)
        self.texture = chess_texture(self.square)  # layout.rectangle_mark_pose reads its border
        self.bodies = {int(world.model.body(n).id): kc for n, kc in names.items()}

    def _world_T_body(self, body: int) -> np.ndarray:
        data = self.world.data
        return make_pose(data.xmat[body].reshape(3, 3), data.xpos[body])

"""The suction cup and the pointer on a MuJoCo arm, and the MuJoCo chess set's live truth.

The tools are the PyBullet engine's (``sim_backends.tools``): the same URDFs fixed to the
flange, the same TCPs, the same rule for a grasp (the vacuum holds the nearest liftable
object whose surface lies within ``SUCTION_REACH_M`` of the cup tip along the tool axis, seen
by five rays over the cup face; the table and the board are never lifted). Holding means the
arm carries the piece (``MujocoArm.attach``); releasing hands it back to MuJoCo's physics,
where it settles on what is below it.

The parallel gripper is the generic one (``gripper.urdf``, TCP 80 mm along z, fingers closing
along the flange's y) on every arm but the Panda, whose gripper is the Franka Hand
(``franka_hand.urdf``, generated with boxes for PyBullet's meshes; TCP: Desk's default).
"""

from __future__ import annotations

import numpy as np

from robots.geometry import make_pose
from robots.interfaces import Gripper, Pointer, SuctionCup
from sim_backends.chess import ChessLayout, chess_texture
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.mujoco_model import SCENE_GROUP
from sim_backends.tool_specs import (
    GRIPPER_TCP_M,
    PANDA_F_T_EE,
    POINTER_TIP_M,
    SUCTION_CUP_RADIUS_M,
    SUCTION_REACH_M,
    SUCTION_TIP_M,
    gripper_grasp,
)

mujoco = import_mujoco()

__all__ = ["MujocoChessSet", "MujocoGripper", "MujocoPointer", "MujocoSuctionCup", "TOOL_URDFS"]

# tool -> its URDF in sim_backends/urdf (frame: the flange); the Panda's gripper is its hand
TOOL_URDFS = {"suction": "suction_cup.urdf", "pointer": "pointer.urdf", "gripper": "gripper.urdf"}
PANDA_HAND_URDF = "franka_hand.urdf"


def _free_body(model, body: int) -> bool:
    """A body MuJoCo moves by physics (a chess piece), not one fixed to the world or the arm."""
    adr = model.body_jntadr[body]
    return adr >= 0 and model.jnt_type[adr] == mujoco.mjtJoint.mjJNT_FREE


def _ray_hit(arm, start, vector):
    """(free body, hit point) of the nearest scene geom along ``start + s vector``, s in
    [0, 1], or None (the table and the board, fixed to the world, are skipped)."""
    model, data = arm.world.model, arm.world.data
    groups = np.zeros(6, dtype=np.uint8)
    groups[SCENE_GROUP] = 1  # the scene's geoms only: never the arm or the tool
    geom = np.zeros(1, dtype=np.int32)
    distance = mujoco.mj_ray(model, data, np.asarray(start, float), np.asarray(vector, float),
                             groups, 0, -1, geom)
    if not 0 <= distance <= 1:
        return None
    body = int(model.geom_bodyid[geom[0]])
    if not _free_body(model, body):
        return None
    return body, np.asarray(start, float) + distance * np.asarray(vector, float), distance


class _Carrying:
    """What a MuJoCo tool holds: the arm carries the body (``MujocoArm.attach``) until the tool
    lets go, and it returns to physics."""

    _arm = None
    held_body: int | None = None

    def _hold(self, body: int) -> bool:
        self._arm.attach(body)
        self.held_body = body
        return True

    def _drop(self) -> None:
        if self.held_body is not None:
            self._arm.detach(self.held_body)
            self.held_body = None

    @property
    def is_holding(self) -> bool:
        return self.held_body is not None


class MujocoGripper(_Carrying, Gripper):
    """The generic two-finger gripper (``tools.SimGripper``'s rule: ``grasp`` closes on what
    lies between the fingers, found by rays across the gap at three heights, and holds it;
    with nothing there it closes fully and returns False). ``opening()`` is the gap, m."""

    MAX_OPENING_EACH = 0.04  # m, each finger from the centre

    def __init__(self, arm):
        # On the Panda, the Franka Hand (franka_hand.urdf) with Desk's default TCP.
        flange_T_tcp = (PANDA_F_T_EE if arm.spec.hand_links
                        else make_pose(t=[0.0, 0.0, GRIPPER_TCP_M]))
        super().__init__("gripper", flange_T_tcp)
        self._arm = arm
        model = arm.world.model
        self._fingers = [int(model.jnt_qposadr[model.joint(f"gripper_{n}_finger_joint").id])
                         for n in ("left", "right")]
        self.held_body: int | None = None
        self._set_fingers(self.MAX_OPENING_EACH)

    def _set_fingers(self, each: float) -> None:
        self._each = float(np.clip(each, 0.0, self.MAX_OPENING_EACH))
        for adr in self._fingers:
            self._arm.hold_joint(adr, self._each)

    def opening(self) -> float:
        """Current gap between the fingers, metres."""
        return 2 * self._each

    def grasp(self) -> bool:
        if self.held_body is not None:
            return True
        world_T_tcp = self._arm.world_T_flange() @ self.flange_T_tcp
        found = gripper_grasp(world_T_tcp, self._each,
                              lambda a, b: _ray_hit(self._arm, a, np.subtract(b, a)))
        if found is None:
            self._set_fingers(0.0)
            return False
        body, width = found
        self._set_fingers(width / 2)
        return self._hold(body)

    def release(self) -> None:
        self._drop()
        self._set_fingers(self.MAX_OPENING_EACH)


class MujocoSuctionCup(_Carrying, SuctionCup):
    """The suction cup (``tools.SimSuctionCup``'s geometry and grasp rule) on a ``MujocoArm``."""

    TIP_M = SUCTION_TIP_M
    CUP_RADIUS_M = SUCTION_CUP_RADIUS_M

    def __init__(self, arm):
        super().__init__("suction", make_pose(t=[0.0, 0.0, self.TIP_M]))
        self._arm = arm
        self.held_body: int | None = None

    def _first_object_hit(self, starts, axis) -> int | None:
        hits = [h for start in starts
                if (h := _ray_hit(self._arm, start, axis * (0.003 + SUCTION_REACH_M)))]
        return min(hits, key=lambda h: h[2])[0] if hits else None

    def grasp(self) -> bool:
        if self.held_body is not None:
            return True
        world_T_tcp = self._arm.world_T_flange() @ self.flange_T_tcp
        tip, axis = world_T_tcp[:3, 3], world_T_tcp[:3, 2]
        x, y, r = world_T_tcp[:3, 0], world_T_tcp[:3, 1], self.CUP_RADIUS_M
        # Start a little behind the tip: a cup pressed onto a part sinks into it slightly.
        starts = [tip + o - 0.003 * axis for o in (np.zeros(3), r * x, -r * x, r * y, -r * y)]
        body = self._first_object_hit(starts, axis)
        return False if body is None else self._hold(body)

    def release(self) -> None:
        self._drop()


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

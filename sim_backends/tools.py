"""Simulated tools on the flange (gripper, suction cup, pointer) and the simulated robot.

Tools are PyBullet bodies carried kinematically with the flange (``SimArm.attach``), or, for
the Panda's gripper, the Panda's own hand. Holding an object means: a fixed constraint between
the tool and the object (so physics steps keep it in place) *and* the object carried with the
flange (so it follows kinematic moves exactly). Releasing removes both; the object then falls
or rests under the world's physics.

Every tool exposes ``flange_T_tcp`` (4, 4): the tool tip in the flange frame, metres.
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from robots.geometry import (
    invert,
    make_pose,
    pose_from_quat_xyzw,
    quat_xyzw_from_rotation,
)
from robots.interfaces import Gripper, Pointer, SuctionCup
from sim_backends.arms import URDF_DIR, SimArm
from sim_backends.sim_robot import SimRobot  # noqa: F401  (re-exported: its home before sim_robot)
from sim_backends.tool_specs import (
    GRIPPER_TCP_M,
    PANDA_F_T_EE,
    POINTER_TIP_M,
    SUCTION_CUP_RADIUS_M,
    SUCTION_REACH_M,
    SUCTION_TIP_M,
    gripper_grasp,
)

__all__ = ["TOOL_NAMES", "SimGripper", "SimPointer", "SimRobot", "SimSuctionCup", "make_tool"]

def _com_pose(client: int, body: int, link: int = -1) -> np.ndarray:
    # Constraint frames in PyBullet are given relative to the centre-of-mass frames.
    if link == -1:
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=client)
    else:
        s = p.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=client)
        pos, quat = s[0], s[1]
    return pose_from_quat_xyzw(quat, pos)


class _Holder:
    """Shared grasp bookkeeping: constraint + kinematic attachment of one object."""

    def __init__(self, arm: SimArm, parent_body: int, parent_link: int, own_bodies):
        self._arm = arm
        self._c = arm.client
        self._parent = (parent_body, parent_link)
        self._own = set(own_bodies)  # bodies that are the robot itself, never "an object"
        self.held_body: int | None = None
        self._constraint: int | None = None

    def hold(self, body: int) -> None:
        parent_T_child = invert(_com_pose(self._c, *self._parent)) @ _com_pose(self._c, body)
        quat = _quat(parent_T_child)
        self._constraint = p.createConstraint(
            self._parent[0], self._parent[1], body, -1, p.JOINT_FIXED, [0, 0, 0],
            list(parent_T_child[:3, 3]), [0, 0, 0], list(quat), [0, 0, 0, 1],
            physicsClientId=self._c)
        p.changeConstraint(self._constraint, maxForce=2000.0, physicsClientId=self._c)
        self._set_collisions(body, enable=False)  # the tool and its load must not fight
        self._arm.attach(body)
        self.held_body = body

    def drop(self) -> None:
        if self.held_body is None:
            return
        p.removeConstraint(self._constraint, physicsClientId=self._c)
        self._arm.detach(self.held_body)
        self._set_collisions(self.held_body, enable=True)
        self.held_body, self._constraint = None, None

    def _set_collisions(self, body: int, enable: bool) -> None:
        for own in self._own:
            for link in range(-1, p.getNumJoints(own, physicsClientId=self._c)):
                p.setCollisionFilterPair(own, body, link, -1, int(enable), physicsClientId=self._c)

    def first_object_hit(self, starts, ends):
        """(body, hit point) of the nearest object the tool can lift along any of the rays:
        not the robot, and not a body fixed to the world (mass 0: the table, the chess board),
        which a cup may seal on but never lifts."""
        best = None
        for hit, start in zip(p.rayTestBatch([list(s) for s in starts], [list(e) for e in ends],
                                             physicsClientId=self._c), starts):
            body, fraction, point = hit[0], hit[2], np.asarray(hit[3])
            if body < 0 or body in self._own:
                continue
            if p.getDynamicsInfo(body, -1, physicsClientId=self._c)[0] == 0.0:
                continue
            if best is None or fraction < best[2]:
                best = (body, point, fraction)
        return None if best is None else best[:2]


def _quat(T: np.ndarray) -> np.ndarray:
    return quat_xyzw_from_rotation(T[:3, :3])


def _mount_tool_body(arm: SimArm, urdf_name: str) -> int:
    """Load a tool URDF at the flange, carry it with the arm, no collisions with the arm."""
    c = arm.client
    T = arm.world_T_flange()
    body = p.loadURDF(str(URDF_DIR / urdf_name), list(T[:3, 3]), list(_quat(T)),
                      useFixedBase=False, physicsClientId=c)
    for link_a in range(-1, p.getNumJoints(arm.body_id, physicsClientId=c)):
        for link_b in range(-1, p.getNumJoints(body, physicsClientId=c)):
            p.setCollisionFilterPair(arm.body_id, body, link_a, link_b, 0, physicsClientId=c)
    arm.attach(body, np.eye(4))
    return body


def _hide_builtin_hand(arm: SimArm) -> None:
    # The Panda URDF includes the Franka Hand; with another tool on the flange it must vanish
    # from camera images and collisions (alpha 0 is skipped by TinyRenderer).
    for link in arm.hand_link_indices:
        p.changeVisualShape(arm.body_id, link, rgbaColor=[0, 0, 0, 0], physicsClientId=arm.client)
        p.setCollisionFilterGroupMask(arm.body_id, link, 0, 0, physicsClientId=arm.client)


class SimGripper(Gripper):
    """Two-finger parallel gripper. On the Panda it is the Franka Hand (TCP = Franka's default
    ``F_T_EE``: 0.1034 m along z, turned -45 deg); on other arms a generic gripper body at
    tool0 (TCP 0.080 m along z). ``grasp`` closes the fingers on whatever lies between them
    (found by rays across the finger gap) and holds it; with nothing there it closes fully
    and returns False. ``opening()`` is the finger gap in metres.
    """

    MAX_OPENING_EACH = 0.04  # m, each finger from the centre

    def __init__(self, client: int, arm: SimArm):
        if client != arm.client:
            raise ValueError("the tool must live in the arm's PyBullet client")
        self._arm = arm
        self._c = client
        if arm.spec.hand_links:  # Panda: use its own hand and fingers
            self.body_id = arm.body_id
            super().__init__("gripper", PANDA_F_T_EE)
            self._holder = _Holder(arm, arm.body_id, arm.flange_link, {arm.body_id})
        else:
            self.body_id = _mount_tool_body(arm, "gripper.urdf")
            super().__init__("gripper", make_pose(t=[0.0, 0.0, GRIPPER_TCP_M]))
            self._holder = _Holder(arm, self.body_id, -1, {arm.body_id, self.body_id})
        self._each = self.MAX_OPENING_EACH
        self._set_fingers(self._each)

    def _set_fingers(self, each: float) -> None:
        self._each = float(np.clip(each, 0.0, self.MAX_OPENING_EACH))
        if self.body_id == self._arm.body_id:
            self._arm.set_finger_positions(self._each)
        else:
            for j in range(2):
                p.resetJointState(self.body_id, j, self._each, physicsClientId=self._c)
                p.setJointMotorControl2(self.body_id, j, p.POSITION_CONTROL, self._each,
                                        force=40.0, physicsClientId=self._c)

    def opening(self) -> float:
        """Current gap between the fingers, metres."""
        return 2 * self._each

    def grasp(self) -> bool:
        if self._holder.held_body is not None:
            return True
        world_T_tcp = self._arm.world_T_flange() @ self.flange_T_tcp
        # The Panda's fingers close along the hand's y axis; the generic one along tool0's y.
        found = gripper_grasp(world_T_tcp, self._each,
                              lambda a, b: self._holder.first_object_hit([a], [b]))
        if found is None:
            self._set_fingers(0.0)
            return False
        body, width = found
        self._set_fingers(width / 2)
        self._holder.hold(body)
        return True

    def release(self) -> None:
        self._holder.drop()
        self._set_fingers(self.MAX_OPENING_EACH)

    @property
    def is_holding(self) -> bool:
        return self._holder.held_body is not None

    @property
    def held_body(self) -> int | None:
        """PyBullet id of the held object, or None (sim only)."""
        return self._holder.held_body


class SimSuctionCup(SuctionCup):
    """A suction cup at tool0 whose tip (TCP) is 0.080 m along the flange z axis.

    ``grasp`` switches the vacuum on: it holds the object whose surface lies within
    ``SUCTION_REACH_M`` (5 mm) of the cup tip along the tool axis (five rays over the cup
    face) and returns True, or returns False when nothing it can lift touches the cup (a cup
    pressed on the board or the table holds nothing).
    """

    TIP_M = SUCTION_TIP_M
    CUP_RADIUS_M = SUCTION_CUP_RADIUS_M

    def __init__(self, client: int, arm: SimArm):
        if client != arm.client:
            raise ValueError("the tool must live in the arm's PyBullet client")
        super().__init__("suction", make_pose(t=[0.0, 0.0, self.TIP_M]))
        self._arm = arm
        _hide_builtin_hand(arm)
        self.body_id = _mount_tool_body(arm, "suction_cup.urdf")
        self._holder = _Holder(arm, self.body_id, -1, {arm.body_id, self.body_id})

    def grasp(self) -> bool:
        if self._holder.held_body is not None:
            return True
        world_T_tcp = self._arm.world_T_flange() @ self.flange_T_tcp
        tip, axis = world_T_tcp[:3, 3], world_T_tcp[:3, 2]
        x, y = world_T_tcp[:3, 0], world_T_tcp[:3, 1]
        r = self.CUP_RADIUS_M
        offsets = [np.zeros(3), r * x, -r * x, r * y, -r * y]
        # Start a little behind the tip: a cup pressed onto a part sinks into it slightly.
        starts = [tip + o - 0.003 * axis for o in offsets]
        ends = [tip + o + SUCTION_REACH_M * axis for o in offsets]
        hit = self._holder.first_object_hit(starts, ends)
        if hit is None:
            return False
        self._holder.hold(hit[0])
        return True

    def release(self) -> None:
        self._holder.drop()

    @property
    def is_holding(self) -> bool:
        return self._holder.held_body is not None

    @property
    def held_body(self) -> int | None:
        """PyBullet id of the held object, or None (sim only)."""
        return self._holder.held_body


class SimPointer(Pointer):
    """A thin rod on the flange; its tip (TCP) is ``TIP_M`` = 0.150 m along the flange z axis."""

    TIP_M = POINTER_TIP_M

    def __init__(self, client: int, arm: SimArm):
        if client != arm.client:
            raise ValueError("the tool must live in the arm's PyBullet client")
        super().__init__("pointer", make_pose(t=[0.0, 0.0, self.TIP_M]))
        _hide_builtin_hand(arm)
        self.body_id = _mount_tool_body(arm, "pointer.urdf")


TOOL_NAMES = ("gripper", "suction", "pointer", "none")


def make_tool(kind: str | None, client: int, arm: SimArm):
    """Build the named tool on ``arm`` ("gripper", "suction", "pointer"; "none"/None: no tool)."""
    if kind in (None, "none"):
        if arm.spec.hand_links:
            _hide_builtin_hand(arm)
        return None
    classes = {"gripper": SimGripper, "suction": SimSuctionCup, "pointer": SimPointer}
    if kind not in classes:
        raise ValueError(f"unknown tool {kind!r}; choose one of {TOOL_NAMES}")
    return classes[kind](client, arm)

"""The simulated ``robots.Robot``: an engine's arm (an ``arm_motion.ArmMotion``) and a tool
behind the same Safety checks as a real robot (the base class runs them before any motion)."""

from __future__ import annotations

import numpy as np

from robots.geometry import as_pose
from robots.interfaces import Robot
from sim_backends.arm_motion import ArmMotion

__all__ = ["SimRobot"]


class SimRobot(Robot):
    """A :class:`robots.interfaces.Robot` backed by a simulated arm (``SimArm``, ``MujocoArm``) (and a simulated tool).

    The base class runs the Safety checks before ``_move_to`` / ``_move_joints``. Reported
    poses and joints are what the simulated controller reports (with encoder offsets, if any).
    """

    def __init__(self, arm: ArmMotion, tool=None, safety=None, name: str | None = None):
        super().__init__(name or arm.name, safety=safety, tool=tool)
        self.arm = arm

    def flange_pose(self) -> np.ndarray:
        self._require_open()
        return self.arm.flange_pose()

    def joint_positions(self) -> np.ndarray:
        self._require_open()
        return self.arm.joint_positions()

    def joint_limits(self) -> np.ndarray:
        return self.arm.joint_limits()

    def stop(self) -> None:
        self.arm.stop()

    def solve_ik(self, base_T_flange, q_seed=None) -> np.ndarray:
        """Joint angles (n,) rad reaching ``base_T_flange`` (raises UnreachableError)."""
        self._require_open()
        return self.arm.solve_ik(as_pose(base_T_flange, "base_T_flange"), q_seed)

    def _move_to(self, base_T_flange: np.ndarray, speed: float) -> None:
        self.arm.move_linear(base_T_flange, speed)

    def _move_joints(self, q: np.ndarray, speed: float) -> None:
        self.arm.move_joints(q, speed)

    def _close(self) -> None:
        if self.tool is not None and self.tool.is_holding:
            self.tool.release()
        self.arm.close()

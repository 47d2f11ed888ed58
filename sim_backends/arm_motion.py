"""What every simulated arm does whatever the engine: controller joints, IK, planned motion.

An engine's arm (``sim_backends.arms.SimArm`` for PyBullet, ``sim_backends.mujoco_arm.MujocoArm``
for MuJoCo) subclasses :class:`ArmMotion` and supplies four things: where the flange truly is
(``world_T_flange``), how to put the joints somewhere (``_apply_true``), one step of its world
(``_step_world``) and how to carry a body (``attach``). The rest (encoder offsets, verified
IK, joint and linear paths with their checks, simulated time) is here, once, so the two
engines move an arm the same way.

Motion is kinematic: joint states are set along an interpolated path and the world is stepped
once per waypoint, so held objects (moved with the flange) and everything else stay
deterministic.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from robots.geometry import as_pose, invert, slerp_rotations
from robots.interfaces import UnreachableError
from sim_backends.arm_specs import ARM_NAMES, ARM_SPECS, ArmSpec, _as_q, _as_speed
from sim_backends.ik_core import pose_error

__all__ = ["ArmMotion", "LINEAR_STEP_M", "LINEAR_STEP_RAD", "JOINT_STEP_RAD",
           "MAX_WAYPOINT_JOINT_JUMP_RAD"]

DEG = np.pi / 180

# Path resolution for linear moves: one IK waypoint per this much translation or rotation.
LINEAR_STEP_M = 0.01
LINEAR_STEP_RAD = 3 * DEG
JOINT_STEP_RAD = 0.05
# Between two neighbouring waypoints no joint should turn more than this; more means the IK
# jumped to another configuration branch (a "flip"), which a real controller refuses too.
MAX_WAYPOINT_JOINT_JUMP_RAD = 20 * DEG



class ArmMotion:
    """The engine-neutral part of a simulated arm (see the module docstring).

    ``name``: one of ``ARM_NAMES``. ``world_T_base`` (4, 4, default identity): where the
    controller's base frame sits in the world. ``encoder_offsets`` (n,) rad: reported = true +
    offset (None: zeros). ``rng``: a ``np.random.Generator`` or int; it picks the seed of the
    IK restarts, so a run is reproducible for a seed. ``model`` is the controller's kinematic
    model (an ``ik_core.KinematicSolver``), set by the subclass.
    """

    model = None
    spec: ArmSpec

    def _init_state(self, name: str, world_T_base=None, encoder_offsets=None, rng=None) -> None:
        if name not in ARM_SPECS:
            raise ValueError(f"unknown arm {name!r}; choose one of {ARM_NAMES}")
        self.spec = spec = ARM_SPECS[name]
        self.name = name
        self.n_joints = spec.n_joints
        self.world_T_base = np.eye(4) if world_T_base is None else as_pose(world_T_base, "world_T_base")
        self.encoder_offsets = (np.zeros(self.n_joints) if encoder_offsets is None
                                else _as_q(encoder_offsets, self.n_joints, "encoder_offsets"))
        if isinstance(rng, np.random.Generator):
            self.ik_seed = int(rng.integers(2**31))
        else:
            self.ik_seed = 0 if rng is None else int(rng)
        # Objects carried with the flange: body id -> flange_T_body (set by the tools).
        self._attached: dict[int, np.ndarray] = {}
        # Called after every waypoint (e.g. a scene updating its ground truth).
        self.on_step: list[Callable[[], None]] = []
        self.motion_time = 0.0
        self._q_true = np.zeros(self.n_joints)

    # ----------------------------------------------------------------- engine's part

    def world_T_flange(self) -> np.ndarray:
        """True pose (4, 4) of the flange in the world (ground truth; where the camera really is)."""
        raise NotImplementedError

    def _apply_true(self, q_true: np.ndarray) -> None:
        """Put the arm's TRUE joints at ``q_true`` (n,) rad, and carried bodies with it."""
        raise NotImplementedError

    def _step_world(self) -> None:
        """One step of the world between waypoints; the joints end where they were."""
        raise NotImplementedError

    # ----------------------------------------------------------------- state

    def joint_limits(self) -> np.ndarray:
        """(n, 2) published joint limits, rad (controller joint angles)."""
        return self.spec.joint_limits.copy()

    def joint_positions(self) -> np.ndarray:
        """Joint angles (n,) rad as the controller reports them: true + encoder offset."""
        return self._q_true + self.encoder_offsets

    def true_joint_positions(self) -> np.ndarray:
        """The physical joint angles (n,) rad (ground truth, not visible on a real robot)."""
        return self._q_true.copy()

    def flange_pose(self) -> np.ndarray:
        """``base_T_flange`` (4, 4) as the controller reports it: FK of the reported joints."""
        return self.model.fk(self.joint_positions())

    def true_flange_pose(self) -> np.ndarray:
        """True ``base_T_flange`` (4, 4) (ground truth; differs from ``flange_pose`` by the encoder error)."""
        return invert(self.world_T_base) @ self.world_T_flange()

    def set_joint_positions(self, q) -> None:
        """Teleport to reported joint angles ``q`` (n,) rad, for set-up. No checks, no path."""
        q = _as_q(q, self.n_joints, "q")
        self._apply_true(q - self.encoder_offsets)

    # ----------------------------------------------------------------- IK

    # ----------------------------------------------------------------- IK

    def solve_ik(self, base_T_flange, q_seed=None, max_restarts: int = 24) -> np.ndarray:
        """Controller joint angles (n,) rad reaching ``base_T_flange`` within 0.1 mm / 0.05 deg.

        Seeded from ``q_seed`` (default: the current reported joints). Raises
        ``robots.interfaces.UnreachableError`` with the position/orientation miss otherwise.
        """
        seed = self.joint_positions() if q_seed is None else _as_q(q_seed, self.n_joints, "q_seed")
        seed = np.clip(seed, self.spec.joint_limits[:, 0], self.spec.joint_limits[:, 1])
        return self.model.solve(base_T_flange, seed, max_restarts=max_restarts, seed=self.ik_seed)

    # ----------------------------------------------------------------- motion

    def move_joints(self, q, speed: float = 0.5) -> None:
        """Move to reported joint angles ``q`` (n,) rad, fastest joint at ``speed`` rad/s.

        Joint-space interpolation, one physics step per waypoint, ends exactly at ``q``.
        Raises ValueError if ``q`` is outside the joint limits (nothing moves).
        """
        target = _as_q(q, self.n_joints, "q")
        speed = _as_speed(speed, "rad/s")
        self._check_limits(target)
        start = self.joint_positions()
        n = max(1, int(np.ceil(np.abs(target - start).max() / JOINT_STEP_RAD)))
        path = [start + (target - start) * (k / n) for k in range(1, n + 1)]
        self._execute(path, self._joint_move_duration(start, target, speed))

    def move_linear(self, base_T_flange, speed: float = 0.1) -> None:
        """Move the flange in a straight line (position lerp, rotation slerp) at ``speed`` m/s.

        The whole path is solved and verified before anything moves: IK per waypoint seeded
        from the previous one, each within 0.1 mm / 0.05 deg. Raises UnreachableError if a
        waypoint cannot be reached or the joints would jump between waypoints (a
        configuration flip); the arm then stays where it was. Ends exactly at the target
        (as the controller sees it).
        """
        target = as_pose(base_T_flange, "base_T_flange target")
        speed = _as_speed(speed, "m/s")
        start_q = self.joint_positions()
        start = self.model.fk(start_q)
        dist = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
        angle = np.radians(pose_error(start, target)[1])
        n = max(1, int(np.ceil(max(dist / LINEAR_STEP_M, angle / LINEAR_STEP_RAD))))
        rotations = slerp_rotations(start[:3, :3], target[:3, :3], np.arange(1, n + 1) / n)
        path, q_prev = [], start_q
        for k in range(1, n + 1):
            s = k / n
            waypoint = np.eye(4)
            waypoint[:3, :3] = rotations[k - 1]
            waypoint[:3, 3] = (1 - s) * start[:3, 3] + s * target[:3, 3]
            try:
                # Few restarts: far from the seed a solution is on another branch anyway.
                q = self.solve_ik(waypoint, q_prev, max_restarts=0)
            except UnreachableError as err:
                raise UnreachableError(
                    f"linear move blocked at {100 * s:.0f}% of the way ({s * dist:.3f} m): {err}"
                ) from None
            jump = np.abs(q - q_prev)
            if jump.max() > MAX_WAYPOINT_JOINT_JUMP_RAD:
                j = int(np.argmax(jump))
                raise UnreachableError(
                    f"{self.name}: linear move would flip configuration at {100 * s:.0f}% of the "
                    f"way (joint {j} jumps {np.degrees(jump[j]):.1f} deg between waypoints, near a "
                    "singularity or a joint limit); nothing moved. Go around it: move_joints to a "
                    "configuration near the target first, or split the move via another waypoint")
            path.append(q)
            q_prev = q
        self._execute(path, dist / speed)

    def stop(self) -> None:
        """Moves are blocking and atomic in sim, so there is never a motion to stop."""

    # ----------------------------------------------------------------- attachments

    def detach(self, body_id: int) -> None:
        """Stop carrying ``body_id`` (no error if it was not attached)."""
        self._attached.pop(int(body_id), None)

    # ----------------------------------------------------------------- internals

    def _check_limits(self, q: np.ndarray) -> None:
        lo, hi = self.spec.joint_limits[:, 0], self.spec.joint_limits[:, 1]
        bad = np.flatnonzero((q < lo) | (q > hi))
        if bad.size:
            j = bad[0]
            raise ValueError(
                f"{self.name} joint {j} target {q[j]:+.4f} rad is outside its limits "
                f"[{lo[j]:+.4f}, {hi[j]:+.4f}] rad; choose angles within joint_limits()")

    def _joint_move_duration(self, start, target, speed) -> float:
        # The fastest joint runs at `speed`, slowed if that breaks a joint's velocity limit.
        dq = np.abs(target - start)
        return float(max(dq.max() / speed, (dq / self.spec.velocity_limits).max()))

    def _execute(self, path, duration: float) -> None:
        dt = duration / max(len(path), 1)
        for q in path:
            self._apply_true(q - self.encoder_offsets)
            self._step_world()
            self.motion_time += dt
            for callback in self.on_step:
                callback()

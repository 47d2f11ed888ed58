"""Simulated robot arms in PyBullet: Franka Panda, UR5e, UR10e, Aubo-i5, Denso Cobotta.

Frames (what ``flange_pose`` returns, chosen to equal what the real controller reports):

* ``panda``: base = ``panda_link0`` (Franka's O frame); flange = ``panda_link8``, 0.107 m
  beyond joint 7 along its z axis. This is Franka's ``O_T_EE`` with the end effector set to
  "none" (``F_T_EE = NE_T_EE = identity``), i.e. ``O_T_F``. With the Franka Hand configured,
  Desk's default is ``F_T_EE = Rz(-45 deg)`` with 0.1034 m along z; that is the gripper tool's
  ``flange_T_tcp`` here, not part of the flange.
* ``ur5e`` / ``ur10e``: base = the controller's ``base`` frame (ROS ``base``, which is ROS
  ``base_link`` turned 180 deg about z); flange = ``tool0`` = DH frame 6. The pose equals
  RTDE ``actual_TCP_pose`` / the teach pendant with a zero TCP offset.
* ``aubo_i5``: base = Aubo's DH frame 0 (98.5 mm below the J2 axis; the mounting face, ROS
  ``base_link``, is 23.5 mm lower, see ``ArmSpec.base_T_mount``); flange = DH frame 6.
* ``cobotta``: base = Denso's ``base_link`` (mounting face on the J1 axis); flange = J6 frame.

Motion is kinematic: joint states are set directly (``resetJointState``) along an
interpolated path and the world is stepped once per waypoint, so held objects (moved with the
flange) and everything else stay deterministic. Realism knob: ``encoder_offsets``, added to
the true joint angles in everything the "controller" reports, so the reported flange pose is
slightly wrong, as on a real robot whose joint zeros are off.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pybullet as p
import pybullet_data

from robots.geometry import (
    as_pose,
    invert,
    pose_from_quat_xyzw,
    quat_xyzw_from_pose,
    quat_xyzw_from_rotation,
    slerp_rotations,
)
from robots.interfaces import UnreachableError
from sim_backends.ik import KinematicModel, pose_error

__all__ = ["ARM_NAMES", "ARM_SPECS", "ArmSpec", "SimArm"]

URDF_DIR = Path(__file__).resolve().parent / "urdf"
DEG = np.pi / 180

# Path resolution for linear moves: one IK waypoint per this much translation or rotation.
LINEAR_STEP_M = 0.01
LINEAR_STEP_RAD = 3 * DEG
JOINT_STEP_RAD = 0.05
# Between two neighbouring waypoints no joint should turn more than this; more means the IK
# jumped to another configuration branch (a "flip"), which a real controller refuses too.
MAX_WAYPOINT_JOINT_JUMP_RAD = 20 * DEG


@dataclass(frozen=True)
class ArmSpec:
    """Static description of one arm model. Angles in rad, speeds in rad/s, lengths in m."""

    name: str
    urdf: Path
    joint_names: tuple[str, ...]
    flange_link: str
    joint_limits: np.ndarray  # (n, 2), the maker's published limits
    velocity_limits: np.ndarray  # (n,)
    home: np.ndarray  # (n,) a tidy start configuration, flange above the table, tool down
    reach: float  # published reach, m
    base_T_mount: np.ndarray = field(default_factory=lambda: np.eye(4))  # mounting face in base
    other_joints: dict[str, float] = field(default_factory=dict)  # held fixed (Panda fingers)
    hand_links: tuple[str, ...] = ()  # built-in hand, hidden when another tool is mounted

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)


def _write_if_changed(path: Path, text: str) -> Path:
    if not path.exists() or path.read_text() != text:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")  # atomic: parallel workers share it
        tmp.write_text(text)
        os.replace(tmp, path)
    return path


def _with_flange_face(text: str, link: str, arm: str, material: str) -> str:
    """URDF text with the arm's ISO 9409-1 flange face (``sim_backends.flanges``) added to
    ``link`` as a visual (its face on the link's xy plane): visual only, so kinematics,
    collisions and tool mounting are untouched."""
    from sim_backends.flanges import flange_face_obj

    found = re.search(rf'<link name="{link}"\s*(/>|>.*?</link>)', text, re.S)
    if found is None:
        raise RuntimeError(f"URDF of {arm}: no link {link!r} to put the flange face on")
    face = (f'<visual><origin rpy="0 0 0" xyz="0 0 0"/><geometry>'
            f'<mesh filename="{flange_face_obj(arm).as_posix()}"/></geometry>'
            f'<material name="{material}"/></visual>')
    body = found.group(0)
    if body.endswith("/>"):
        drawn = f'<link name="{link}">{face}</link>'
    else:
        drawn = body[:-len("</link>")] + face + "</link>"
    return text[:found.start()] + drawn + text[found.end():]


def _render_urdf(spec: ArmSpec) -> Path:
    """The URDF the simulator draws ``spec``'s arm from: its own, plus the flange face.

    Written into the texture cache (meshes need absolute paths there). The Panda's is
    pybullet_data's with its collision meshes drawn as the visuals: the visual meshes carry
    ~100k triangles, and TinyRenderer's time goes almost all into them; drawn with the
    (coarser, same-shaped) collision meshes a 640 x 480 RGB-D frame renders ~35 % faster.
    The Panda's link7 mesh ends in a flat face on panda_link8's xy plane whose rounded rim
    (63-70 mm across) has no clean edge in depth, so link7 is drawn ``FLANGE_PROUD_M``
    further back along its axis (``generate_urdfs.py`` does the same for the other arms'
    last links). Kinematics and collisions are untouched.
    """
    from sim_backends.flanges import FLANGE_PROUD_M
    from sim_backends.textures import cache_dir

    if spec.name != "panda":
        text = _with_flange_face(spec.urdf.read_text(), spec.flange_link, spec.name, "flange")
        text = text.replace('<material name="accent">', '<material name="flange"><color rgba='
                            '"0.62 0.63 0.66 1"/></material>\n  <material name="accent">', 1)
        return _write_if_changed(cache_dir() / f"{spec.name}_render.urdf", text)
    source = spec.urdf
    meshes = (source.parent / "meshes" / "collision").as_posix()
    text = source.read_text()
    link7 = re.search(r'<link name="panda_link7">.*?</link>', text, re.S)
    if link7 is None:
        raise RuntimeError(f"{source}: no panda_link7")
    drawn7 = link7.group(0).replace(
        "<visual>", f'<visual>\n      <origin rpy="0 0 0" xyz="0 0 {-FLANGE_PROUD_M}"/>', 1)
    text = text[:link7.start()] + drawn7 + text[link7.end():]
    text = _with_flange_face(text, "panda_link8", "panda", "panda_white")
    text = text.replace("package://meshes/visual/", meshes + "/")
    text = text.replace("package://meshes/collision/", meshes + "/")
    return _write_if_changed(cache_dir() / "panda_light.urdf", text)


def _limits(lo_hi) -> np.ndarray:
    return np.array(lo_hi, dtype=float)


_SIX = tuple(f"joint_{k}" for k in range(1, 7))
_AUBO_MOUNT = np.eye(4)
_AUBO_MOUNT[2, 3] = -0.0235

ARM_SPECS: dict[str, ArmSpec] = {
    # Franka Panda datasheet limits (tighter than pybullet_data's URDF).
    "panda": ArmSpec(
        "panda", Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf",
        tuple(f"panda_joint{k}" for k in range(1, 8)), "panda_link8",
        _limits([(-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
                 (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)]),
        np.array([2.175] * 4 + [2.61] * 3),
        np.array([0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]),
        0.855,
        other_joints={"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04},
        hand_links=("panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_grasptarget"),
    ),
    "ur5e": ArmSpec(
        "ur5e", URDF_DIR / "ur5e.urdf", _SIX, "tool0",
        _limits([(-2 * np.pi, 2 * np.pi)] * 6), np.full(6, 180 * DEG),
        np.array([0.0, -1.570796, 1.570796, -1.570796, -1.570796, 0.0]), 0.850),
    "ur10e": ArmSpec(
        "ur10e", URDF_DIR / "ur10e.urdf", _SIX, "tool0",
        _limits([(-2 * np.pi, 2 * np.pi)] * 6), np.array([120 * DEG] * 2 + [180 * DEG] * 4),
        np.array([0.0, -1.570796, 1.570796, -1.570796, -1.570796, 0.0]), 1.300),
    "aubo_i5": ArmSpec(
        "aubo_i5", URDF_DIR / "aubo_i5.urdf", _SIX, "tool0",
        _limits([(-175 * DEG, 175 * DEG)] * 6), np.array([150 * DEG] * 3 + [180 * DEG] * 3),
        np.array([0.0, -0.26179, 1.74532, 0.436, 1.5708, 0.0]), 0.8865, base_T_mount=_AUBO_MOUNT),
    "cobotta": ArmSpec(
        "cobotta", URDF_DIR / "cobotta.urdf", _SIX, "tool0",
        _limits([(-2.617994, 2.617994), (-1.047198, 1.745329), (0.3141593, 2.443461),
                 (-2.96706, 2.96706), (-1.658063, 2.356194), (-2.96706, 2.96706)]),
        np.array([0.40317105721069, 0.392175482923126, 0.725707902979242, 0.739146938219599,
                  0.739146938219599, 1.1093312725676]),
        np.array([0.0, 0.3, 1.6, 0.0, 1.2, 0.0]), 0.342),
}
ARM_NAMES = tuple(ARM_SPECS)


def _as_q(q, n: int, name: str) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) (one angle per joint, rad), got {q.shape}")
    bad = np.flatnonzero(~np.isfinite(q))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is {q[bad[0]]}; joint angles must be finite radians")
    return q


def _as_speed(speed, unit: str) -> float:
    speed = float(speed)
    if not np.isfinite(speed) or speed <= 0:
        raise ValueError(f"speed must be a positive number of {unit}, got {speed}")
    return speed


class SimArm:
    """One arm in a PyBullet world (``client``, a DIRECT physics client id).

    ``name``: one of ``ARM_NAMES``. ``world_T_base`` (4, 4, default identity): where the controller's base frame
    sits in the world. ``encoder_offsets`` (n,) rad: reported = true + offset (None: zeros).
    ``rng``: a ``np.random.Generator`` or int; it picks the seed of the IK restarts, so a run
    is reproducible for a seed. The arm starts at ``spec.home`` (as reported).

    Attributes: ``body_id``, ``flange_link`` (tool0 link index in the world body),
    ``n_joints``, ``spec`` (:class:`ArmSpec`), ``model`` (the controller's
    :class:`~sim_backends.ik.KinematicModel`), ``motion_time`` (s of simulated motion so far).
    """

    def __init__(self, client: int, name: str, world_T_base=None, encoder_offsets=None,
                 rng=None):
        if name not in ARM_SPECS:
            raise ValueError(f"unknown arm {name!r}; choose one of {ARM_NAMES}")
        if not p.isConnected(physicsClientId=client):
            raise ValueError(f"PyBullet client {client} is not connected; create it with "
                             "pybullet.connect(pybullet.DIRECT) first")
        self.client = client
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

        pos, quat = self.world_T_base[:3, 3], quat_xyzw_from_pose(self.world_T_base)[0]
        visual_urdf = _render_urdf(spec)
        self.body_id = p.loadURDF(str(visual_urdf), list(pos), list(quat), useFixedBase=True,
                                  physicsClientId=client)
        index = {}
        for j in range(p.getNumJoints(self.body_id, physicsClientId=client)):
            info = p.getJointInfo(self.body_id, j, physicsClientId=client)
            index[info[1].decode()] = j
            index["link:" + info[12].decode()] = j
        self.joint_indices = [index[n] for n in spec.joint_names]
        self.flange_link = index["link:" + spec.flange_link]
        self.hand_link_indices = [index["link:" + n] for n in spec.hand_links]
        self._other = {index[n]: v for n, v in spec.other_joints.items()}
        self.model = KinematicModel(spec.urdf, spec.joint_names, spec.flange_link,
                                    spec.joint_limits, spec.home, spec.reach,
                                    other_joints=spec.other_joints, name=name)
        # Objects carried with the flange: body id -> flange_T_body (set by the tools).
        self._attached: dict[int, np.ndarray] = {}
        # Called after every waypoint (e.g. a scene updating its ground truth).
        self.on_step: list[Callable[[], None]] = []
        self.motion_time = 0.0
        self._q_true = np.zeros(self.n_joints)
        self.set_joint_positions(spec.home)

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

    def world_T_flange(self) -> np.ndarray:
        """True pose (4, 4) of the flange in the world (ground truth; where the camera really is)."""
        s = p.getLinkState(self.body_id, self.flange_link, computeForwardKinematics=True,
                           physicsClientId=self.client)
        return pose_from_quat_xyzw(s[5], s[4])

    def true_flange_pose(self) -> np.ndarray:
        """True ``base_T_flange`` (4, 4) (ground truth; differs from ``flange_pose`` by the encoder error)."""
        return invert(self.world_T_base) @ self.world_T_flange()

    def set_joint_positions(self, q) -> None:
        """Teleport to reported joint angles ``q`` (n,) rad, for set-up. No checks, no path."""
        q = _as_q(q, self.n_joints, "q")
        self._apply_true(q - self.encoder_offsets)

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

    def attach(self, body_id: int, flange_T_body=None) -> None:
        """Carry ``body_id`` with the flange (kinematically) at ``flange_T_body`` (default: as it is now)."""
        if flange_T_body is None:
            pos, quat = p.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
            flange_T_body = invert(self.world_T_flange()) @ pose_from_quat_xyzw(quat, pos)
        self._attached[int(body_id)] = as_pose(flange_T_body, "flange_T_body")

    def detach(self, body_id: int) -> None:
        """Stop carrying ``body_id`` (no error if it was not attached)."""
        self._attached.pop(int(body_id), None)

    def close(self) -> None:
        """Release the private kinematics client. The world body stays (the world owns it)."""
        self.model.close()

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
            p.stepSimulation(physicsClientId=self.client)
            # A step may nudge the joints (gravity against the holding motors); the kinematic
            # state is the truth, so put it back exactly.
            self._apply_true(self._q_true)
            self.motion_time += dt
            for callback in self.on_step:
                callback()

    def _apply_true(self, q_true: np.ndarray) -> None:
        self._q_true = np.array(q_true, dtype=float)
        c = self.client
        for j, qi in zip(self.joint_indices, self._q_true):
            p.resetJointState(self.body_id, j, float(qi), physicsClientId=c)
        for j, qi in self._other.items():
            p.resetJointState(self.body_id, j, float(qi), physicsClientId=c)
        # Position motors hold the pose during physics steps.
        joints = self.joint_indices + list(self._other)
        targets = list(self._q_true) + list(self._other.values())
        p.setJointMotorControlArray(self.body_id, joints, p.POSITION_CONTROL,
                                    targetPositions=targets, forces=[500.0] * len(joints),
                                    physicsClientId=c)
        if self._attached:
            world_T_flange = self.world_T_flange()
            for body, flange_T_body in self._attached.items():
                T = world_T_flange @ flange_T_body
                pos, quat = T[:3, 3], quat_xyzw_from_rotation(T[:3, :3])
                p.resetBasePositionAndOrientation(body, list(pos), list(quat), physicsClientId=c)
                p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=c)

    def set_finger_positions(self, opening_each: float) -> None:
        """Set the built-in fingers (Panda) to ``opening_each`` m from the centre, held there."""
        for j in self._other:
            self._other[j] = float(opening_each)
        self._apply_true(self._q_true)

    def __repr__(self) -> str:
        return f"SimArm(name={self.name!r}, client={self.client}, body={self.body_id})"

"""The simulated workcell: arm + tool + camera(s) + scene, behind ``robots.connect("sim", ...)``.

``create_workcell(**options)`` checks the options with ``sim_backends.layout.describe_workcell``
(where they are documented) and ``build_workcell`` builds that engine-neutral description as
a headless PyBullet world (DIRECT mode, TinyRenderer) that is deterministic for a seed, and
returns a :class:`SimWorkcell` (a ``robots.Workcell``) whose ``truth`` holds the ground truth that instructors and tests compare against.

Layout (PyBullet world frame, z up): the table top is z = 0 and the robot base stands on it at
the origin facing +x. Scenes:

* ``calibration``: a calibration target lying face-up on the table in front of the robot
  (seeded position and yaw), and a target on the flange centred on tool0. With the camera on
  the flange (eye-in-hand) the flange carries a small ArUco marker (it must not block the
  camera); with a fixed camera (eye-to-hand) it carries a small chessboard, the target the
  fixed camera calibrates against. The arm starts at a pose from which the camera sees its
  target.
* ``chess``: a chess board on the table (White on the robot's side, a1 to the robot's left)
  with the pieces in their starting squares, or a seeded random position.

Options for depth-camera work (lab 5), all off by default: ``flange_target=False`` leaves the
flange bare, so the arm's ISO 9409-1 flange face (``sim_backends.flanges``, in ``truth.flange``)
is what a camera sees there; ``depth_model="d435"`` gives every camera a RealSense D4xx's depth
(``sim_backends.depth_noise``); ``rectangle_mark=True`` lays a dark 100 mm x 100 mm square on
the table beside the work area (``truth.base_T_rectangle``, ``truth.rectangle_size``).

Frames in ``truth`` (all 4x4, metres): ``base`` is the robot base, ``flange`` tool0 as the
simulation really has it (without encoder offsets), ``cam`` the OpenCV optical frame of the
main (left) camera, ``board`` the calibration target's OpenCV frame (see
``sim_backends.textures``), ``world`` the scene's reference frame (the board's origin corner
in ``calibration``, the a1 corner of the chess board in ``chess``), ``pybullet`` the
simulator's own world frame, ``rectangle`` the rectangle mark's centre on its top face (x, y
along its edges, z up out of the table, as OpenCV's marker frame: out of the print).
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from robots.geometry import (
    compose,
    invert,
    make_pose,
    quat_xyzw_from_rotation,
)
from robots.interfaces import Workcell
from sim_backends import layout, textures
from sim_backends import scene as scn
from sim_backends.camera import SimCamera
from sim_backends.flanges import FLANGES
from sim_backends.layout import (  # noqa: F401  (re-exported: their home before layout)
    ARM_REACH,
    MOUNTS,
    RECTANGLE_MARK_SIZE,
    RECTANGLE_MARK_THICKNESS,
    SCENES,
    TARGETS,
    TOOLS,
    _calibration_target,
    _look_at,
    _parse_mount_error,
    _random_pose_error,
    default_intrinsics,
    describe_workcell,
    nominal_flange_T_cam,
)
from sim_backends.truth import SimTruth

__all__ = [
    "MOUNTS",
    "SCENES",
    "TOOLS",
    "SimTruth",
    "SimWorkcell",
    "build_workcell",
    "create_workcell",
    "default_intrinsics",
    "nominal_flange_T_cam",
]

TIME_STEP = 1.0 / 240.0

class SimWorkcell(Workcell):
    """A ``robots.Workcell`` that also owns the PyBullet client (disconnected on close)."""

    def __init__(self, robot, cameras, truth, client, arm):
        super().__init__(robot, camera=cameras.get("cam"), cameras=cameras, truth=truth,
                         kind="sim")
        self.client = client
        self.arm = arm

    def _close(self) -> None:
        if p.isConnected(self.client):
            p.disconnect(self.client)

    def visual_scene(self):
        """Every PyBullet body's visual shapes and the true frames (see Workcell.visual_scene)."""
        from sim_backends.viewer_scene import SceneReader

        if getattr(self, "_scene_reader", None) is None:
            self._scene_reader = SceneReader(self)  # geometry read once, poses every call
        return self._scene_reader.read()


# --------------------------------------------------------------------------- helpers


def _flange_face_height(arm, half_size) -> float:
    """How far (m) the arm's own geometry reaches beyond tool0 along flange +z over a
    rectangle of ``half_size = (hx, hy)`` metres around the flange axis (0 when tool0 is on
    the flange face and nothing sticks out, as on most arms).

    Found with a grid of rays shot back at the flange, so a target plate laid that far out
    is never pierced by a link.
    """
    T = arm.world_T_flange()
    reach = 0.15
    grid = [(x, y) for x in np.linspace(-half_size[0], half_size[0], 15)
            for y in np.linspace(-half_size[1], half_size[1], 15)]
    starts = [T[:3, :3] @ [x, y, reach] + T[:3, 3] for x, y in grid]
    ends = [T[:3, :3] @ [x, y, 0.0] + T[:3, 3] for x, y in grid]
    height = 0.0
    # Links hidden by a tool (collision group 0, e.g. the Panda's hand) never match the mask.
    hits = p.rayTestBatch(starts, ends, collisionFilterMask=-1, physicsClientId=arm.client)
    for body, _, fraction, *_ in hits:
        if body == arm.body_id:
            height = max(height, reach * (1.0 - fraction))
    return height


def _target_on_flange(mount: str, arm, reach: float) -> tuple[textures.Target, np.ndarray]:
    """The flange target and ``flange_T_marker`` (``layout.flange_target``), 1 mm in front of
    the flange face or of whatever of the arm's own geometry sticks out beyond tool0."""
    target = layout.flange_target(mount, reach)
    gap = 0.001 + _flange_face_height(arm, (target.size[0] / 2, target.size[1] / 2))
    return target, layout.flange_T_marker(target, gap)


# --------------------------------------------------------------------------- factory


def create_workcell(**options) -> SimWorkcell:
    """Build the simulated workcell on PyBullet from ``connect("sim", ...)``'s options
    (documented on ``sim_backends.layout.describe_workcell``, which checks them)."""
    return build_workcell(describe_workcell(**options))


def build_workcell(d: layout.WorkcellDescription) -> SimWorkcell:
    """Build the workcell ``d`` describes in a new headless PyBullet world (DIRECT mode)."""
    from sim_backends import arms as arms_mod
    from sim_backends import tools as tools_mod

    arm, mount, scene, intrinsics, reach = d.arm, d.mount, d.scene, d.intrinsics, d.reach
    s = d.streams
    rng_scene, rng_mount, rng_enc, rng_cam = s.scene, s.mount, s.enc, s.cam
    rng_right, rng_chess, rng_overview, rng_mark = s.right, s.chess, s.overview, s.mark
    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        p.setTimeStep(TIME_STEP, physicsClientId=client)
        size, centre = layout.table_size(reach)
        scn.add_table(client, size=size, centre_xy=centre)
        world_T_base = np.eye(4)  # the robot base is the world origin (kept general below)
        base_T_pybullet = invert(world_T_base)
        offsets = layout.encoder_offsets(d, arms_mod.ARM_SPECS[arm].n_joints)
        sim_arm = arms_mod.SimArm(client, arm, world_T_base=world_T_base,
                                  encoder_offsets=offsets, rng=rng_enc)

        board = world_T_board = chess = None
        if scene == "calibration":
            board, world_T_board = _add_table_target(client, d.target, reach, rng_scene)
            world_T_world = world_T_board
        else:
            if d.chess_position == "start":
                position = None  # ChessSet's default: the starting position
            elif d.chess_position == "random":
                position = scn.random_position(rng_chess)
            else:
                position = d.chess_position
            chess = _add_chess_set(client, reach, rng_scene, position)
            world_T_world = chess.world_T_chess
        world_T_rectangle = None
        if d.rectangle_mark:
            world_T_rectangle = _add_rectangle_mark(client, reach, rng_mark, board,
                                                    world_T_board, chess)

        # The tool first: "no tool" hides the Panda's built-in hand, which the flange target
        # below must then not make room for.
        robot_tool = tools_mod.make_tool(d.tool, client, sim_arm)
        flange_target = flange_T_marker = None
        if scene == "calibration" and d.flange_target:
            flange_target, flange_T_marker = _target_on_flange(mount, sim_arm, reach)
            body = scn.add_target(client, flange_target,
                                  compose(sim_arm.world_T_flange(), flange_T_marker),
                                  thickness=0.001, collide=False)
            sim_arm.attach(body, flange_T_marker)  # carried kinematically, exactly

        # ----- cameras: the true mount is the nominal one times the mounting error
        cam_kw = {"pixel_noise": d.pixel_noise, "depth_noise": d.depth_noise,
                  "depth_model": d.depth_model, "lighting": d.lighting,
                  "clock": lambda: float(sim_arm.motion_time)}
        error = _random_pose_error(rng_mount, d.mount_mm, d.mount_deg)
        cam_T_right = (None if d.stereo_baseline is None
                       else make_pose(t=[d.stereo_baseline, 0, 0]))
        if mount == "eye_in_hand":
            nominal_mount = nominal_flange_T_cam(arm)
            flange_T_cam = compose(nominal_mount, error)
            left = flange_T_cam  # the camera's pose in its parent (the flange)
            nominal_base_T_cam = base_T_cam = world_T_cam = None
        else:
            nominal_world_T_cam = layout.fixed_camera_nominal_pose(reach)
            world_T_cam = compose(nominal_world_T_cam, error)
            nominal_base_T_cam = compose(base_T_pybullet, nominal_world_T_cam)
            base_T_cam = compose(base_T_pybullet, world_T_cam)
            left = world_T_cam
            nominal_mount = flange_T_cam = None

        def make_camera(name, pose, rng):
            if mount == "eye_in_hand":
                return SimCamera(client, intrinsics, parent=(sim_arm.body_id, sim_arm.flange_link),
                                 link_T_cam=pose, name=name, rng=rng, **cam_kw)
            return SimCamera(client, intrinsics, world_T_cam=pose, name=name, rng=rng, **cam_kw)

        cameras = {"cam": make_camera("cam", left, rng_cam)}
        if cam_T_right is not None:  # the right camera of the pair, +baseline along left x
            cameras["right"] = make_camera("right", compose(left, cam_T_right), rng_right)
        world_T_overview = None
        if d.overview_camera:
            world_T_overview = layout.overview_camera_pose(chess.world_T_chess, chess.square)
            cameras["overview"] = SimCamera(client, intrinsics, world_T_cam=world_T_overview,
                                            name="overview", rng=rng_overview, **cam_kw)

        layout.start_pose(sim_arm, mount, scene, base_T_pybullet, world_T_board, board,
                    flange_T_cam, flange_T_marker, flange_target, world_T_cam, reach, intrinsics)
        for _ in range(10):  # let the pieces settle on the board
            p.stepSimulation(physicsClientId=client)
        # Stepping sags the arm a little against its motors; the kinematic state is the truth.
        sim_arm.set_joint_positions(sim_arm.joint_positions())

        robot = tools_mod.SimRobot(sim_arm, tool=robot_tool, safety=d.safety)
        truth = SimTruth(
            mount=mount,
            base_T_cam=base_T_cam,
            flange_T_cam=flange_T_cam,
            nominal_base_T_cam=nominal_base_T_cam,
            nominal_flange_T_cam=nominal_mount,
            base_T_board=None if world_T_board is None else compose(base_T_pybullet, world_T_board),
            base_T_world=compose(base_T_pybullet, world_T_world),
            flange_T_marker=flange_T_marker,
            base_T_pybullet=base_T_pybullet,
            cam_T_right=cam_T_right,
            base_T_overview_cam=(None if world_T_overview is None
                                 else compose(base_T_pybullet, world_T_overview)),
            encoder_offsets=None if offsets is None else offsets.copy(),
            board=board,
            flange_target=flange_target,
            flange=FLANGES[arm],
            base_T_rectangle=(None if world_T_rectangle is None
                              else compose(base_T_pybullet, world_T_rectangle)),
            rectangle_size=None if world_T_rectangle is None else RECTANGLE_MARK_SIZE,
            _chess=chess,
            _arm=sim_arm,
        )
        return SimWorkcell(robot, cameras, truth, client, sim_arm)
    except BaseException:
        p.disconnect(client)
        raise


def _add_table_target(client, kind, reach, rng):
    """The calibration target on the table (``layout.table_target_pose``), built. Returns
    (Target, world_T_board)."""
    board, world_T_board = layout.table_target_pose(kind, reach, rng)
    scn.add_target(client, board, world_T_board)
    return board, world_T_board


def _add_rectangle_mark(client, reach, rng, board, world_T_board, chess) -> np.ndarray:
    """Lay the dark rectangle mark (``layout.rectangle_mark_pose``) on the table. Returns
    world_T_rectangle (centre of the top face, z up)."""
    w, h = RECTANGLE_MARK_SIZE
    world_T_rectangle = layout.rectangle_mark_pose(reach, rng, board, world_T_board, chess)
    half = [w / 2, h / 2, RECTANGLE_MARK_THICKNESS / 2]
    below = [0.0, 0.0, -RECTANGLE_MARK_THICKNESS / 2]  # the body frame is the top face
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, visualFramePosition=below,
                              rgbaColor=[0.06, 0.06, 0.07, 1.0], physicsClientId=client)
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, collisionFramePosition=below,
                                 physicsClientId=client)
    quat = quat_xyzw_from_rotation(world_T_rectangle[:3, :3])
    p.createMultiBody(0, col, vis, world_T_rectangle[:3, 3].tolist(), quat.tolist(),
                      physicsClientId=client)
    return world_T_rectangle


def _add_chess_set(client, reach, rng, position) -> scn.ChessSet:
    """The chess set (``layout.chess_pose``) with its pieces, built."""
    world_T_chess, square, thickness = layout.chess_pose(reach, rng)
    return scn.ChessSet(client, world_T_chess, position=position, square=square,
                        board_thickness=thickness)

"""The simulated workcell built by MuJoCo, behind ``robots.connect("sim", engine="mujoco")``.

``create_workcell`` takes the options of every engine, checks them and draws the random
streams with ``sim_backends.layout.describe_workcell`` (where they are documented), and
``build_workcell`` builds that description: it lays the cell out with the
same ``layout`` functions, and builds one MuJoCo model from the parts
(``sim_backends.mujoco_model``): for a seed, the board, the camera mounts, the encoder
offsets and the start pose are the same as on PyBullet. ``cell.truth`` is the same
``SimTruth``; ``base_T_pybullet`` is the identity, MuJoCo's world being placed as PyBullet's.

What this engine builds today: the five arms (the Panda from its generated URDF, with Franka's
kinematics and cylinders for links, without the Franka Hand), both mounts, the calibration and
chess scenes (pieces under MuJoCo's physics), the overview camera, the suction cup and the
pointer and the gripper (the Franka Hand on the Panda, drawn with boxes), the flange target or
the bare ISO flange face, the rectangle mark, a stereo pair,
lens distortion, pixel noise, the D4xx depth model, encoder noise, mount error, Safety,
segmentation masks and the 3-D viewer's scene: everything the PyBullet engine builds. A
future option it lacked would raise ``robots.backends.BackendNotAvailableError`` naming the
PyBullet engine (``unsupported``), so a lab never silently runs differently.

Images differ from PyBullet's in shading (MuJoCo's OpenGL lighting against TinyRenderer's)
and in the Panda's links (cylinders, not Franka's meshes), not in geometry: the same
intrinsics and poses put every corner on the same pixel. One measured difference in the
layout: the flange target stands 1 mm in front of tool0 on MuJoCo and 2 mm on PyBullet, whose
rays stop at Bullet's 1 mm collision margin; ``truth.flange_T_marker`` holds each.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from robots.backends import BackendNotAvailableError
from robots.geometry import compose, make_pose
from robots.interfaces import Workcell
from robots.perception import square_index
from sim_backends import layout
from sim_backends import mujoco_model as mjm
from sim_backends.arm_specs import ARM_SPECS, URDF_DIR
from sim_backends.chess import (
    _PIECE_PARTS,
    COLOURS,
    PIECE_KINDS,
    PIECE_SQUARE_M,
    START_POSITION,
    chess_texture,
    random_position,
)
from sim_backends.flanges import FLANGES
from sim_backends.layout import RECTANGLE_MARK_SIZE, RECTANGLE_MARK_THICKNESS, WorkcellDescription
from sim_backends.mujoco_arm import MujocoArm, _body_pose
from sim_backends.mujoco_camera import MujocoCamera, OffscreenRenderer
from sim_backends.mujoco_gl import import_mujoco
from sim_backends.mujoco_tools import (
    PANDA_HAND_URDF,
    TOOL_URDFS,
    MujocoChessSet,
    MujocoGripper,
    MujocoPointer,
    MujocoSuctionCup,
)
from sim_backends.sim_robot import SimRobot
from sim_backends.truth import SimTruth

mujoco = import_mujoco()

__all__ = ["MujocoWorkcell", "MujocoWorld", "build_workcell", "create_workcell", "unsupported"]

TIME_STEP = 1.0 / 240.0  # as the PyBullet engine's
_PIECE_MASS = 0.03  # kg, a piece of the 50 mm set (scaled with the cube of the set's size)
_TOOL_CLASSES = {"suction": MujocoSuctionCup, "pointer": MujocoPointer, "gripper": MujocoGripper}

MUJOCO_ARMS = ("panda", "ur5e", "ur10e", "aubo_i5", "cobotta")
_TABLE_THICKNESS = 0.04
_TABLE_RGBA = (0.78, 0.70, 0.58, 1.0)
_MARK_RGBA = (0.06, 0.06, 0.07, 1.0)
_SCENE_BODIES = ("table", "board", "rectangle_mark")


def unsupported(d: WorkcellDescription) -> str | None:
    """What of the described cell this engine cannot build yet, or None."""
    if d.arm not in MUJOCO_ARMS:
        return f"the {d.arm!r} arm (it has {', '.join(MUJOCO_ARMS)})"
    if d.tool not in (None,) + tuple(TOOL_URDFS):
        return (f"the {d.tool!r} tool (it has {', '.join(TOOL_URDFS)} and the bare flange, "
                "tool=None)")
    return None


class MujocoWorld:
    """A compiled MuJoCo model, its data and (made on the first render) its renderer."""

    def __init__(self, model, max_canvas: tuple[int, int], dynamic: bool = False,
                 mesh_files: dict | None = None):
        self.model = model
        self.mesh_files = mesh_files or {}  # mesh name -> the .obj it was read from (viewer)
        self.data = mujoco.MjData(model)
        self.dynamic = dynamic  # something moves by physics: step the world at each waypoint
        self._max_canvas = max_canvas
        self._renderer = None
        mujoco.mj_kinematics(model, self.data)
        mujoco.mj_camlight(model, self.data)  # the lights' world directions (they never move)

    def body_pose(self, name: str) -> np.ndarray:
        """World pose (4, 4) of a body by name, from the last forward kinematics."""
        return _body_pose(self.data, int(self.model.body(name).id))

    def renderer(self) -> OffscreenRenderer:
        if self._renderer is None:
            self._renderer = OffscreenRenderer(self.model, self._max_canvas)
        return self._renderer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class MujocoWorkcell(Workcell):
    """A ``robots.Workcell`` that owns a MuJoCo world (its renderer is freed on close)."""

    def __init__(self, robot, cameras, truth, world, arm, tool_name=None):
        super().__init__(robot, camera=cameras.get("cam"), cameras=cameras, truth=truth,
                         kind="sim")
        self.world = world
        self.arm = arm
        self.engine = "mujoco"
        self.tool_name = tool_name  # the tool's bodies are named "<tool>_<link>"
        self._scene_reader = None

    def _close(self) -> None:
        self.world.close()

    def visual_scene(self):
        """Every drawn body's shapes and the true frames (see Workcell.visual_scene)."""
        from sim_backends.mujoco_viewer_scene import MujocoSceneReader

        if self._scene_reader is None:
            self._scene_reader = MujocoSceneReader(self)  # geometry read once, poses every call
        return self._scene_reader.read()


# --------------------------------------------------------------------------- building


def _max_canvas(d: WorkcellDescription) -> tuple[int, int]:
    # A distorted camera renders a padded canvas, at most half the image again on each side
    # (rendered_camera refuses more).
    W, H = d.intrinsics.width, d.intrinsics.height
    if np.any(np.asarray(d.intrinsics.dist, dtype=float) != 0):
        return 2 * W, 2 * H
    return W, H


def _flange_face_height(model, data, flange_body: int, arm_bodies: set[int], half_size) -> float:
    """How far (m) the arm's collision geometry reaches beyond tool0 along flange +z over a
    rectangle of ``half_size`` around the flange axis (``world._flange_face_height``'s
    measure, with MuJoCo's rays)."""
    T = _body_pose(data, flange_body)
    reach = 0.15
    groups = np.zeros(6, dtype=np.uint8)
    groups[mjm.COLLISION_GROUP] = 1
    geom = np.zeros(1, dtype=np.int32)
    direction = -T[:3, 2] * reach  # from in front of the flange back towards it
    height = 0.0
    for x in np.linspace(-half_size[0], half_size[0], 15):
        for y in np.linspace(-half_size[1], half_size[1], 15):
            start = T[:3, :3] @ [x, y, reach] + T[:3, 3]
            fraction = mujoco.mj_ray(model, data, start, direction, groups, 1, -1, geom)
            if fraction >= 0 and fraction <= 1 and model.geom_bodyid[geom[0]] in arm_bodies:
                height = max(height, reach * (1.0 - fraction))
    return height


def _arm_bodies(model) -> set[int]:
    """Ids of the arm's bodies: every body but the world and the scene's own."""
    return {b for b in range(1, model.nbody) if model.body(b).name not in _SCENE_BODIES}


def _camera_poses(d: WorkcellDescription):
    """(flange_T_cam, nominal flange_T_cam, world_T_cam, nominal world_T_cam): the true mount
    is the nominal one times the seeded mounting error; the pair not used by the mount is None."""
    error = layout._random_pose_error(d.streams.mount, d.mount_mm, d.mount_deg)
    if d.mount == "eye_in_hand":
        nominal = layout.nominal_flange_T_cam(d.arm)
        return compose(nominal, error), nominal, None, None
    nominal = layout.fixed_camera_nominal_pose(d.reach)
    return None, None, compose(nominal, error), nominal


def _chess_position(d: WorkcellDescription) -> dict:
    if d.chess_position == "start":
        return START_POSITION
    if d.chess_position == "random":
        return random_position(d.streams.chess)
    return d.chess_position


def _add_chess(s, d: WorkcellDescription):
    """The chess board and its pieces (``layout.chess_pose``). Returns (world_T_chess, square,
    texture, piece body name -> (kind, colour))."""
    position = _chess_position(d)  # drawn first, as on PyBullet (the streams are independent)
    world_T_chess, square, thickness = layout.chess_pose(d.reach, d.streams.scene)
    texture = chess_texture(square)
    board = mjm.add_target(s, s.worldbody, "chess_board", texture, world_T_chess, thickness)
    mjm.add_slab_collider(board, texture, thickness)
    scale = square / PIECE_SQUARE_M
    names = {}
    for k, (sq, (kind, colour)) in enumerate(position.items()):
        if kind not in PIECE_KINDS or colour not in COLOURS:
            raise ValueError(f"bad piece {kind!r}/{colour!r} on {sq}; kinds are "
                             f"{PIECE_KINDS}, colours {tuple(COLOURS)}")
        parts = [(g, tuple(scale * v for v in size), scale * z) for g, size, z in _PIECE_PARTS[kind]]
        T = compose(world_T_chess, make_pose(t=_square_centre(sq, square)))
        name = f"piece_{k}_{sq}"
        mjm.add_piece(s, name, parts, COLOURS[colour], T, _PIECE_MASS * scale**3)
        names[name] = (kind, colour)
    return world_T_chess, square, texture, names


def _square_centre(name: str, square: float) -> list[float]:
    f, r = square_index(name)
    return [(f + 0.5) * square, (r + 0.5) * square, 0.0]


def create_workcell(**options) -> MujocoWorkcell:
    """Build the simulated workcell on MuJoCo from ``connect("sim", ...)``'s options
    (documented on ``sim_backends.layout.describe_workcell``, which checks them).

    Raises ValueError for a bad option (naming it) and BackendNotAvailableError for a part
    this engine does not build yet (naming the PyBullet engine).
    """
    return build_workcell(layout.describe_workcell(**options))


def build_workcell(d: layout.WorkcellDescription) -> MujocoWorkcell:
    """Build the workcell ``d`` describes as one MuJoCo model (see ``create_workcell``)."""
    missing = unsupported(d)
    if missing is not None:
        raise BackendNotAvailableError(
            f"the MuJoCo simulator engine does not build {missing} yet; use the PyBullet engine: "
            "connect('sim', engine='pybullet', ...) or COBOTLAB_SIM_ENGINE=pybullet "
            "(`pip install pybullet`)")
    spec = ARM_SPECS[d.arm]
    s = mjm.arm_spec(spec)
    max_canvas = _max_canvas(d)
    mjm.configure_visual(s, max_canvas, shadows=d.lighting.shadow)
    mjm.add_lights(s, d.lighting)
    (sx, sy), (cx, cy) = layout.table_size(d.reach)
    mjm.add_box(s.worldbody, "table", (sx / 2, sy / 2, _TABLE_THICKNESS / 2),
                make_pose(t=[cx, cy, -_TABLE_THICKNESS / 2]), _TABLE_RGBA)
    board = world_T_board = chess = None
    if d.scene == "calibration":
        board, world_T_board = layout.table_target_pose(d.target, d.reach, d.streams.scene)
        mjm.add_target(s, s.worldbody, "board", board, world_T_board)
        world_T_world = world_T_board
    else:
        world_T_chess, square, texture, piece_names = _add_chess(s, d)
        chess = SimpleNamespace(world_T_chess=world_T_chess, square=square, texture=texture)
        world_T_world = world_T_chess
    world_T_rectangle = None
    if d.rectangle_mark:
        world_T_rectangle = layout.rectangle_mark_pose(d.reach, d.streams.mark, board,
                                                       world_T_board, chess)
        w, h = RECTANGLE_MARK_SIZE
        mjm.add_box(s.worldbody, "rectangle_mark", (w / 2, h / 2, RECTANGLE_MARK_THICKNESS / 2),
                    world_T_rectangle, _MARK_RGBA, offset=(0, 0, -RECTANGLE_MARK_THICKNESS / 2))

    # The arm, its kinematics and (before the flange target goes on) its own geometry.
    offsets = layout.encoder_offsets(d, spec.n_joints)
    nominal_model = mjm.arm_spec(spec, drawn=False).compile()
    flange_target = flange_T_marker = None
    if d.scene == "calibration" and d.flange_target:
        probe = MujocoWorld(s.compile(), max_canvas)
        MujocoArm(probe, d.arm, nominal_model).set_joint_positions(spec.home)
        flange_target = layout.flange_target(d.mount, d.reach)
        half = (flange_target.size[0] / 2, flange_target.size[1] / 2)
        gap = 0.001 + _flange_face_height(probe.model, probe.data,
                                          int(probe.model.body(spec.flange_link).id),
                                          _arm_bodies(probe.model), half)
        flange_T_marker = layout.flange_T_marker(flange_target, gap)
        mjm.add_target(s, s.body(spec.flange_link), "flange_target", flange_target,
                       flange_T_marker, thickness=0.001)

    # The tool after the probe above: its geometry is not the arm's.
    if d.tool is not None:
        urdf = PANDA_HAND_URDF if (d.tool == "gripper" and spec.hand_links) else TOOL_URDFS[d.tool]
        mjm.add_tool(s, spec.flange_link, URDF_DIR / urdf, d.tool)
    flange_T_cam, nominal_flange_T_cam, world_T_cam, nominal_world_T_cam = _camera_poses(d)
    cam_T_right = (None if d.stereo_baseline is None
                   else make_pose(t=[d.stereo_baseline, 0, 0]))
    names = (["cam"] + (["right"] if cam_T_right is not None else [])
             + (["overview"] if d.overview_camera else []))
    for name in names:
        mjm.add_camera(s, name)
    mjm.make_kinematic(s)
    s.option.timestep = TIME_STEP
    world = MujocoWorld(s.compile(), max_canvas, dynamic=chess is not None,
                        mesh_files={m.name: m.file for m in s.meshes})
    arm = MujocoArm(world, d.arm, nominal_model, encoder_offsets=offsets, rng=d.streams.enc)
    tool = None if d.tool is None else _TOOL_CLASSES[d.tool](arm)

    cam_kw = {"pixel_noise": d.pixel_noise, "depth_noise": d.depth_noise,
              "depth_model": d.depth_model, "lighting": d.lighting,
              "clock": lambda: float(arm.motion_time)}
    left = flange_T_cam if d.mount == "eye_in_hand" else world_T_cam

    def make_camera(name, pose, rng):
        if d.mount == "eye_in_hand":
            return MujocoCamera(world, d.intrinsics, camera_name=name, parent=spec.flange_link,
                                link_T_cam=pose, name=name, rng=rng, **cam_kw)
        return MujocoCamera(world, d.intrinsics, camera_name=name, world_T_cam=pose, name=name,
                            rng=rng, **cam_kw)

    cameras = {"cam": make_camera("cam", left, d.streams.cam)}
    if cam_T_right is not None:
        cameras["right"] = make_camera("right", compose(left, cam_T_right), d.streams.right)
    world_T_overview = None
    if d.overview_camera:
        world_T_overview = layout.overview_camera_pose(chess.world_T_chess, chess.square)
        cameras["overview"] = MujocoCamera(world, d.intrinsics, camera_name="overview",
                                           world_T_cam=world_T_overview, name="overview",
                                           rng=d.streams.overview, **cam_kw)

    base_T_world = np.eye(4)  # the robot base is the world origin, as on PyBullet
    layout.start_pose(arm, d.mount, d.scene, base_T_world, world_T_board, board, flange_T_cam,
                      flange_T_marker, flange_target, world_T_cam, d.reach, d.intrinsics)
    for _ in range(10):  # let the pieces settle on the board
        arm._step_world()
    robot = SimRobot(arm, tool=tool, safety=d.safety)
    truth = SimTruth(
        mount=d.mount,
        base_T_cam=world_T_cam,
        flange_T_cam=flange_T_cam,
        nominal_base_T_cam=nominal_world_T_cam,
        nominal_flange_T_cam=nominal_flange_T_cam,
        base_T_board=world_T_board,
        base_T_world=world_T_world,
        flange_T_marker=flange_T_marker,
        base_T_pybullet=base_T_world,
        cam_T_right=cam_T_right,
        base_T_overview_cam=world_T_overview,
        encoder_offsets=None if offsets is None else offsets.copy(),
        board=board,
        flange_target=flange_target,
        flange=FLANGES[d.arm],
        base_T_rectangle=world_T_rectangle,
        rectangle_size=None if world_T_rectangle is None else RECTANGLE_MARK_SIZE,
        _chess=(None if chess is None
                else MujocoChessSet(world, chess.world_T_chess, chess.square, piece_names)),
        _arm=arm,
    )
    return MujocoWorkcell(robot, cameras, truth, world, arm, tool_name=d.tool)

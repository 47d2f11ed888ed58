"""The simulated workcell described once, for every engine: options, random streams, poses.

``describe_workcell(**options)`` checks every option of ``robots.connect("sim", ...)`` and
returns a :class:`WorkcellDescription`: the arm, mount, scene, camera model, noise and the
seeded random streams, one per knob, so turning one knob never reshuffles another's draws.
The functions below lay the cell out from it (where the table, the calibration target, the
fixed camera and the camera's mount go), with no simulator involved. An engine's builder
(``sim_backends.world`` for PyBullet, ``sim_backends.mujoco_world`` for MuJoCo) turns the
description into a running world; drawing from the same streams in the same order, both put
everything at the same poses for a seed.

Layout (world frame, z up): the table top is z = 0 and the robot base stands on it at the
origin facing +x. Frame conventions are those of ``sim_backends.world``'s docstring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robots.geometry import (
    compose,
    invert,
    make_pose,
    pose_from_rotvec,
    pose_from_rpy,
    transform_points,
)
from robots.interfaces import Intrinsics, UnreachableError
from sim_backends import textures
from sim_backends.arm_specs import ARM_NAMES
from sim_backends.depth_noise import RealSenseDepthModel, depth_model_from
from sim_backends.rendered_camera import Lighting, lighting_from

__all__ = [
    "MOUNTS",
    "SCENES",
    "TOOLS",
    "TARGETS",
    "ARM_REACH",
    "WorkcellDescription",
    "describe_workcell",
    "default_intrinsics",
    "nominal_flange_T_cam",
    "board_pose_on_table",
    "table_target_pose",
    "fixed_camera_nominal_pose",
]

MOUNTS = ("eye_in_hand", "eye_to_hand")
SCENES = ("calibration", "chess")
TOOLS = ("suction", "gripper", "pointer", None)
TARGETS = ("chessboard", "charuco", "circles", "aruco")
# Published reach (m) of each arm, used to lay the scene out where the arm can work.
ARM_REACH = {"panda": 0.855, "ur5e": 0.85, "ur10e": 1.3, "aubo_i5": 0.886, "cobotta": 0.342}
# The approach-to-grasp chapter's rectangular mark, (width, height) m, and its thickness (a
# card on a backing plate, like the calibration board: a step the depth image shows).
RECTANGLE_MARK_SIZE = (0.1, 0.1)
RECTANGLE_MARK_THICKNESS = 0.003



def nominal_flange_T_cam(arm: str) -> np.ndarray:
    """The design pose of the eye-in-hand camera on an arm's flange (tool0).

    The camera sits 7.5 cm off the flange axis and 2-3 cm in front of the flange face, well
    clear of every joint axis (TinyRenderer can hang when the eye sits on one), looking along
    the flange z axis; camera x runs along the mount's y so the image is upright when the
    flange x axis points away from the robot. On the Panda the mount is turned -45 degrees
    about z, to the side of the Franka Hand (whose fingers open along the hand's y axis), and
    looks straight ahead so the fingers stay out of the picture; on the other arms it is
    tilted 10 degrees back towards the flange axis so a tool tip stays in view.
    """
    if arm == "panda":
        yaw, forward, tilt = -np.pi / 4, 0.03, 0.0
    else:
        yaw, forward, tilt = 0.0, 0.02, np.deg2rad(10.0)
    return compose(
        pose_from_rpy(0.0, 0.0, yaw),
        make_pose(t=[0.075, 0.0, forward]),
        pose_from_rpy(0.0, -tilt, 0.0),
        pose_from_rpy(0.0, 0.0, np.pi / 2),
    )


def default_intrinsics(width: int = 640, height: int = 480) -> Intrinsics:
    """A RealSense-D435-like colour camera (about 69 x 54 degrees at 640x480) at any size."""
    f = 0.96 * width
    return Intrinsics(fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width,
                      height=height)


def _random_pose_error(rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    """A pose whose translation is ``mm`` millimetres and rotation ``deg`` degrees, in seeded
    random directions (the camera mounting error)."""
    t = rng.normal(size=3)
    axis = rng.normal(size=3)
    return pose_from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(deg),
                            t / np.linalg.norm(t) * mm * 1e-3)


def _parse_mount_error(mount_error) -> tuple[float, float]:
    try:
        mm, deg = (float(x) for x in mount_error)
    except (TypeError, ValueError):
        raise ValueError(
            f"mount_error must be (millimetres, degrees), e.g. (2.0, 0.5), got {mount_error!r}"
        ) from None
    if not (math.isfinite(mm) and math.isfinite(deg) and mm >= 0 and deg >= 0):
        raise ValueError(f"mount_error values must be finite and >= 0, got {mount_error!r}")
    return mm, deg


def _calibration_target(kind: str, reach: float) -> textures.Target:
    small = reach < 0.5  # the Cobotta: a board that fits its little workspace
    if kind == "chessboard":
        return textures.chessboard(square=0.02 if small else 0.039)
    if kind == "charuco":
        return textures.charuco(square=0.025 if small else 0.04,
                                marker=0.018 if small else 0.03)
    if kind == "circles":
        return textures.circle_grid(spacing=0.012 if small else 0.02)
    if kind == "aruco":
        return textures.aruco_marker(marker_id=0, size=0.04 if small else 0.1)
    raise ValueError(f"target must be one of {TARGETS}, got {kind!r}")


def _look_at(eye, point, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Optical frame at ``eye`` looking at ``point`` with the image top towards ``up``."""
    eye, point = np.asarray(eye, float), np.asarray(point, float)
    z = point - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


@dataclass(frozen=True)
class Streams:
    """The workcell's independent random streams (``np.random.Generator``), one per knob."""

    scene: np.random.Generator  # target or chess-set placement
    mount: np.random.Generator  # the camera's mounting error
    enc: np.random.Generator  # encoder offsets, then the IK restarts' seed
    cam: np.random.Generator  # main camera's noise
    right: np.random.Generator  # right camera's noise
    chess: np.random.Generator  # a random chess position
    overview: np.random.Generator  # overview camera's noise
    mark: np.random.Generator  # the rectangle mark's placement


@dataclass(frozen=True)
class WorkcellDescription:
    """Everything an engine needs to build the workcell (checked; see ``describe_workcell``).

    Lengths in metres, angles as documented per field; ``intrinsics`` already carries the
    distortion; ``tool`` is resolved ("default" is gone); ``reach`` is ``ARM_REACH[arm]``.
    """

    arm: str
    mount: str
    scene: str
    seed: int
    intrinsics: Intrinsics
    pixel_noise: float
    depth_noise: float
    encoder_noise_deg: float
    mount_mm: float
    mount_deg: float
    lighting: Lighting
    stereo_baseline: float | None
    tool: str | None
    target: str
    chess_position: object
    safety: object
    overview_camera: bool
    flange_target: bool
    depth_model: RealSenseDepthModel | None
    rectangle_mark: bool
    reach: float
    streams: Streams


def describe_workcell(
    arm: str = "panda",
    mount: str = "eye_in_hand",
    scene: str = "calibration",
    seed: int = 0,
    width: int = 640,
    height: int = 480,
    intrinsics: Intrinsics | None = None,
    distortion=None,
    pixel_noise: float = 0.0,
    depth_noise: float = 0.0,
    encoder_noise_deg: float = 0.0,
    mount_error=(0.0, 0.0),
    lighting="default",
    stereo_baseline: float | None = None,
    tool: str | None = "default",
    target: str = "chessboard",
    chess_position: str | dict = "start",
    safety=None,
    overview_camera: bool = False,
    flange_target: bool = True,
    depth_model=None,
    rectangle_mark: bool = False,
) -> WorkcellDescription:
    """Check the options of ``connect("sim", ...)`` (every engine's) and draw the random
    streams from ``seed``; every random choice comes from it.

    arm : one of ``sim_backends.arms.ARM_NAMES`` ("panda", "ur5e", "ur10e", "aubo_i5", "cobotta").
    mount : "eye_in_hand" (camera on the flange) or "eye_to_hand" (camera fixed in the cell).
    scene : "calibration" or "chess" (see ``sim_backends.world``'s module docstring).
    width, height : image size in pixels (default intrinsics scale with it).
    intrinsics : ``robots.interfaces.Intrinsics`` to use instead of the default camera.
    distortion : (k1, k2, p1, p2, k3) applied to the image (overrides ``intrinsics.dist``).
    pixel_noise : Gaussian RGB noise std in 0..255 units. depth_noise : k in sigma_z = k z^2 (1/m).
    encoder_noise_deg : std (degrees) of a constant offset per joint encoder: the robot then
        reports joint angles and flange poses that are slightly off, as a real arm does.
    mount_error : (mm, deg) between the nominal camera mount and the true one, in seeded
        random directions; ``truth`` holds both.
    lighting : preset name ("default", "dim", "side", "overhead") or a ``camera.Lighting``.
    stereo_baseline : metres; adds a right camera at +baseline along the left camera's x.
    tool : "suction", "gripper", "pointer", None, or "default" (none for calibration, suction
        for chess).
    target : calibration target on the table: "chessboard" (9x7 squares of 39 mm),
        "charuco", "circles" or "aruco".
    chess_position : "start", "random" (seeded, 12 pieces) or a dict square -> (kind, colour).
    safety : a ``robots.safety.Safety`` to use instead of the arm's default limits.
    overview_camera : chess scene, eye-in-hand only: also a fixed RGB-D camera
        (``cell.cameras["overview"]``, same intrinsics and noise) on the far side of the board,
        looking down at it, for the coarse stage of the staged approach-to-grasp. It sits
        exactly where ``truth.base_T_overview_cam`` says (its calibration is not the point).
    flange_target : calibration scene: False leaves the flange bare (no marker or board on
        it), so with ``tool=None`` the camera sees the arm's ISO 9409-1 flange face; with a
        fixed camera the arm then starts with the face turned to the camera.
    depth_model : None (exact depth, plus ``depth_noise``), "d435" or a dict of fields or a
        ``sim_backends.depth_noise.RealSenseDepthModel``: every camera's depth as a RealSense
        D4xx streams it (z**2 noise, edge and grazing dropouts, range, 1 mm steps), seeded.
        Not together with ``depth_noise``.
    rectangle_mark : True lays a dark 100 mm x 100 mm square (3 mm thick) on the table beside
        the board, at a seeded position and yaw (``truth.base_T_rectangle``).

    Raises ValueError naming the option, what is wrong and what to give instead.
    """
    if arm not in ARM_NAMES:
        raise ValueError(f"unknown arm {arm!r}; choose one of {ARM_NAMES}")
    if mount not in MOUNTS:
        raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
    if scene not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {scene!r}")
    if tool == "default":
        tool = "suction" if scene == "chess" else None
    if tool not in TOOLS:
        raise ValueError(f"tool must be one of {TOOLS} or 'default', got {tool!r}")
    if target not in TARGETS:
        raise ValueError(f"target must be one of {TARGETS}, got {target!r}")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    mount_mm, mount_deg = _parse_mount_error(mount_error)
    if not (math.isfinite(encoder_noise_deg) and encoder_noise_deg >= 0):
        raise ValueError(f"encoder_noise_deg must be >= 0, got {encoder_noise_deg!r}")
    if stereo_baseline is not None and not (math.isfinite(stereo_baseline) and stereo_baseline > 0):
        raise ValueError("stereo_baseline must be a positive number of metres, got "
                         f"{stereo_baseline!r}")
    if intrinsics is None:
        intrinsics = default_intrinsics(width, height)
    elif not isinstance(intrinsics, Intrinsics):
        raise ValueError("intrinsics must be a robots.interfaces.Intrinsics")
    if distortion is not None:
        i = intrinsics
        intrinsics = Intrinsics(i.fx, i.fy, i.cx, i.cy, i.width, i.height, distortion)
    light = lighting_from(lighting)
    if overview_camera and not (scene == "chess" and mount == "eye_in_hand"):
        raise ValueError("overview_camera=True needs scene='chess' and mount='eye_in_hand' (a "
                         "fixed camera over the board next to the wrist camera)")
    for label, flag in (("flange_target", flange_target), ("rectangle_mark", rectangle_mark)):
        if not isinstance(flag, (bool, np.bool_)):
            raise ValueError(f"{label} must be True or False, got {flag!r}")
    depth_model = depth_model_from(depth_model)
    if depth_model is not None and depth_noise > 0:
        raise ValueError("give depth_noise or depth_model, not both: the RealSense model has its "
                         "own noise")
    if not (chess_position in ("start", "random") or isinstance(chess_position, dict)):
        raise ValueError("chess_position must be 'start', 'random' or a dict "
                         f"square -> (kind, colour), got {chess_position!r}")

    # Independent streams, so turning one knob never reshuffles another's draws.
    # (spawn(8)[:7] equals spawn(7): adding a stream left the others' draws as they were.)
    streams = Streams(*np.random.default_rng(seed).spawn(8))
    return WorkcellDescription(
        arm=arm, mount=mount, scene=scene, seed=int(seed), intrinsics=intrinsics,
        pixel_noise=pixel_noise, depth_noise=depth_noise, encoder_noise_deg=encoder_noise_deg,
        mount_mm=mount_mm, mount_deg=mount_deg, lighting=light, stereo_baseline=stereo_baseline,
        tool=tool, target=target, chess_position=chess_position, safety=safety,
        overview_camera=bool(overview_camera), flange_target=bool(flange_target),
        depth_model=depth_model, rectangle_mark=bool(rectangle_mark), reach=ARM_REACH[arm],
        streams=streams)


# --------------------------------------------------------------------------- layout


def encoder_offsets(d: WorkcellDescription, n_joints: int) -> np.ndarray | None:
    """The constant per-joint encoder offsets (n,) rad, or None without encoder noise."""
    if d.encoder_noise_deg > 0:
        return np.deg2rad(d.streams.enc.normal(0.0, d.encoder_noise_deg, size=n_joints))
    return None


def table_size(reach: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """(size_xy, centre_xy) of the table top in metres, wide enough for the arm's reach."""
    return (2.0 * reach + 0.6, 2.0 * reach + 0.6), (0.3 * reach, 0.0)


def table_target_pose(kind: str, reach: float, rng) -> tuple[textures.Target, np.ndarray]:
    """The calibration target lying on the table at 55 % of the arm's reach in front of it,
    seeded position and yaw. Returns (Target, world_T_board)."""
    board = _calibration_target(kind, reach)
    world_T_centre = board_pose_on_table(rng, (0.55 * reach, 0.0), height=0.003)
    if board.kind == "aruco":  # OpenCV's marker frame: centred, z out of the print
        world_T_board = compose(world_T_centre, make_pose(np.diag([1.0, -1.0, -1.0])))
    else:
        world_T_board = compose(world_T_centre, make_pose(t=-board.centre))
    return board, world_T_board


def fixed_camera_nominal_pose(reach: float) -> np.ndarray:
    """The fixed (eye-to-hand) camera's design pose, world_T_cam: in front of the robot, off to
    its left, looking at the work area."""
    look = np.array([0.5 * reach, 0.0, 0.25 * reach])
    eye = look + np.array([0.75, 0.45, 0.45]) * max(reach, 0.6)
    return _look_at(eye, look)


def rectangle_mark_pose(reach, rng, board, world_T_board, chess) -> np.ndarray:
    """Where the dark rectangle mark lies on the table to the robot's right of the board (or chess
    set; ``chess`` a ChessSet or None), clear of it and of the robot's base, at a seeded
    position and yaw. Returns world_T_rectangle (centre of the top face, z up)."""
    w, h = RECTANGLE_MARK_SIZE
    if chess is not None:
        side = 8 * chess.square + 2 * chess.texture.params["border"]
        centre = transform_points(chess.world_T_chess, [[4 * chess.square] * 2 + [0.0]])[0]
        keep_out = (centre[:2], np.hypot(side, side) / 2)
    elif board is not None:
        centre = transform_points(world_T_board, [board.centre])[0]
        keep_out = (centre[:2], np.hypot(*board.size) / 2)
    else:
        keep_out = (np.zeros(2), 0.0)
    mark_radius = np.hypot(w, h) / 2
    jitter = rng.uniform(-0.01, 0.01, 2)
    yaw = rng.uniform(-np.deg2rad(15), np.deg2rad(15))
    for frac in (0.5, 0.6, 0.7):
        for angle in (-55.0, -70.0, -90.0):
            xy = frac * reach * np.array([np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))])
            xy = xy + jitter
            clear = np.linalg.norm(xy - keep_out[0]) > keep_out[1] + mark_radius + 0.02
            if clear and np.linalg.norm(xy) > 0.12 + mark_radius:  # off the robot's base
                break
        else:
            continue
        break
    world_T_rectangle = make_pose(pose_from_rpy(0, 0, yaw)[:3, :3],
                                  [xy[0], xy[1], RECTANGLE_MARK_THICKNESS])
    return world_T_rectangle


def flange_target(mount: str, reach: float) -> textures.Target:
    """The target on the flange: a small ArUco marker with the camera on the flange (it must
    not block the camera), a small chessboard for a fixed camera to calibrate against."""
    if mount == "eye_in_hand":
        return textures.aruco_marker(marker_id=7, size=0.03 if reach < 0.5 else 0.04)
    square = 0.012 if reach < 0.5 else 0.02
    return textures.chessboard(squares=(7, 6), square=square, margin=square / 2)


def flange_T_marker(target: textures.Target, gap: float) -> np.ndarray:
    """The flange target's pose on tool0: its centre on the tool0 axis, printed face looking
    along flange +z, ``gap`` metres in front of tool0 (the engine measures how far the arm's
    own geometry sticks out there)."""
    if target.kind == "aruco":
        # OpenCV marker frame: z out of the print, so it points along flange +z.
        return make_pose(t=[0.0, 0.0, gap])
    # Chessboard frame: z into the print, i.e. towards the flange.
    flange_T_centre = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, gap])
    return compose(flange_T_centre, make_pose(t=-target.centre))


def teleport_to(arm, base_T_flange) -> bool:
    """Put the arm at an IK solution for a pose (set-up only, no motion). False if unreachable."""
    try:
        q = arm.solve_ik(base_T_flange)
    except UnreachableError:
        return False
    arm.set_joint_positions(q)
    return True


def start_pose(sim_arm, mount, scene, base_T_pybullet, world_T_board, board, flange_T_cam,
                flange_T_marker, flange_target, world_T_cam, reach, intrinsics):
    """Teleport the arm (any engine's ``ArmMotion``) to a pose where the camera sees its
    target (best effort: the arm's own home pose stays if none of the candidates is reachable)."""
    if scene != "calibration":
        return
    candidates = []
    if mount == "eye_in_hand":
        # Camera above the board centre looking straight down with its axes along the
        # board's (z into the board), so the board reads upright in the image; high enough
        # for the whole printed board to fit the image width. Turned half round as a last
        # resort (some wrists cannot reach the upright view).
        world_T_view = compose(world_T_board, make_pose(t=board.centre))
        if board.kind == "aruco":
            world_T_view = compose(world_T_view, make_pose(np.diag([1.0, -1.0, -1.0])))
        intr = intrinsics
        fit = max(board.size[0] * intr.fx / intr.width, board.size[1] * intr.fy / intr.height)
        # Big arms look from higher up, clear of their own bulky wrists.
        heights = [max(1.05 * fit, 0.5 * reach), 1.2 * fit, 1.4 * fit, 0.95 * fit]
        for yaw in (0.0, np.pi):
            for h in heights:
                world_T_cam_goal = compose(make_pose(t=[0, 0, h]), world_T_view,
                                           pose_from_rpy(0, 0, yaw))
                candidates.append(compose(base_T_pybullet, world_T_cam_goal,
                                          invert(flange_T_cam)))
    else:
        # The flange target between the work area and the camera (as close to the camera as
        # the arm allows, for a large image of a small target), facing the camera with its
        # axes along the camera's (its z, into the print, along the optical axis).
        look = np.array([0.5 * reach, 0.0, 0.25 * reach])
        if flange_target is None:  # the bare flange face, its normal (+z) towards the camera
            centre, flange_T_marker = np.zeros(3), make_pose(np.diag([1.0, -1.0, -1.0]))
        else:
            centre = flange_target.centre
        for f in (0.4, 0.3, 0.2, 0.1, 0.0):
            pos = look + f * (world_T_cam[:3, 3] - look)
            world_T_marker = make_pose(world_T_cam[:3, :3], pos - world_T_cam[:3, :3] @ centre)
            candidates.append(compose(base_T_pybullet, world_T_marker, invert(flange_T_marker)))
    for base_T_flange in candidates:
        if teleport_to(sim_arm, base_T_flange):
            return


def chess_pose(reach: float, rng) -> tuple[np.ndarray, float, float]:
    """The chess set in front of the robot, White on the robot's side (a1 to its left):
    (world_T_chess, square m, board thickness m), seeded jitter and yaw."""
    square = 0.03 if reach < 0.5 else 0.05
    thickness = 0.01
    yaw = rng.uniform(-np.deg2rad(3), np.deg2rad(3))
    if reach < 0.5:
        # The Cobotta's suction cup points straight down only between about 0.135 and 0.34 m
        # from its base axis (measured with its IK at piece height near the centre files), less
        # than the 0.24 m board. Centred at 0.24 m (+-1 cm), rank 2 keeps 2-4 cm from the inner
        # edge and rank 7 about 2 cm from the outer one, room for a grasp that a wrong
        # calibration shifts by up to 15 mm (at 0.221 m the pawns on rank 2 stood 0-2 cm inside
        # the edge, and 11 % of picks with a 5 mm / 2 deg calibration error failed there).
        # Ranks 1 and 8 lie at the edges.
        centre = np.array([0.24, 0.0])
    else:
        centre = np.array([0.5 * reach + 0.05, 0.0])
    centre += rng.uniform(-0.01, 0.01, 2)
    # Chess frame: ranks (y) along world +x, files (x) along world -y, z up.
    R = pose_from_rpy(0, 0, yaw)[:3, :3] @ np.array([[0.0, 1.0, 0.0],
                                                      [-1.0, 0.0, 0.0],
                                                      [0.0, 0.0, 1.0]])
    world_T_centre = make_pose(R, [centre[0], centre[1], thickness])
    world_T_chess = compose(world_T_centre, make_pose(t=[-4 * square, -4 * square, 0]))
    return world_T_chess, square, thickness


def overview_camera_pose(world_T_chess: np.ndarray, square: float) -> np.ndarray:
    """A fixed camera beyond the board's far edge (rank 8), high enough that the whole board
    fills about half the image's height, looking down at the board's centre at about 60 deg
    from the horizontal, image top away from the robot: it sees the board past the arm."""
    side = 8 * square
    centre = transform_points(world_T_chess, [[4 * square, 4 * square, 0]])[0]
    away = centre[:2] / np.linalg.norm(centre[:2])  # from the robot base, on the table
    eye = centre + np.r_[0.9 * side * away, 1.6 * side]
    return _look_at(eye, centre, up=np.r_[away, 0.0])


def board_pose_on_table(rng: np.random.Generator, centre_xy, jitter_xy=0.03, jitter_yaw_deg=10,
                        height=0.0) -> np.ndarray:
    """A seeded pose for a board lying printed-face-up on the table around ``centre_xy`` (m).

    Returns the pose of a frame at the board's centre, at ``height`` (m) above the table,
    with the target-frame convention of ``sim_backends.textures`` (z INTO the board, so
    pointing down): x along world -y and y along world -x, turned by up to
    ``jitter_yaw_deg`` about the vertical and shifted by up to ``jitter_xy`` metres. A camera
    looking down from above with its image top away from the robot then sees the board's x
    axis to the right, as in the printed image.
    """
    yaw = np.deg2rad(rng.uniform(-jitter_yaw_deg, jitter_yaw_deg))
    dx, dy = rng.uniform(-jitter_xy, jitter_xy, size=2)
    R0 = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    Rz = pose_from_rpy(0, 0, yaw)[:3, :3]
    return make_pose(Rz @ R0, [centre_xy[0] + dx, centre_xy[1] + dy, height])

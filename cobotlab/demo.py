"""``cobotlab demo``: the whole course chain in the simulator, checked against the truth.

Three parts, each in a fresh PyBullet workcell built from the same seed (so the arm's encoder
errors and the camera's mounting error are the same in all of them):

1. Flange calibration, eye-on-base: a fixed camera watches a small chessboard on the flange;
   the arm visits a few poses around its start pose and ``solutions.registration`` fits
   ``base_T_cam`` from the board centre seen by the camera and the flange poses read back.
2. Eye-in-hand calibration: the wrist camera looks once at the board on the table, the demo
   plans views around where that first look says the board is (with the camera's *design*
   mount, as a user would), captures them with ``robots.capture``, solves ``flange_T_cam``
   with every method of ``solutions.catalog`` (ours and OpenCV's) and saves the default
   result with ``robots.calibration_io``.
3. Pick and place: three chess pieces moved by ``solutions.servoing`` using the saved
   calibration, checked against ``cell.truth.pieces``.

The truth (``cell.truth``) is only read to score the results and to draw them, never to
plan or to solve. The synthetic table of the earlier demo is :func:`run_synthetic`
(``cobotlab demo --synthetic``).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from robots import geometry as geo

ARMS = ("panda", "ur10e", "aubo_i5", "cobotta")

# The chess part's search poses per arm are solutions.servoing.ARM_OPTIONS.

# pixel_noise (RGB standard deviation, 0..255) and encoder_noise_deg (a constant offset per
# joint, standard deviation in degrees) of the simulated cell.
NOISE_LEVELS = {"none": (0.0, 0.0), "low": (2.0, 0.01), "high": (8.0, 0.05)}

# The wrist camera sits this far off its design mount (mm, deg), so the nominal mount is
# visibly wrong and the calibration has something to find.
MOUNT_ERROR = (3.0, 1.5)

MOVES = (("e2", "e4"), ("d2", "d4"), ("b1", "c3"))
# The 342 mm-reach Cobotta cannot point its suction cup straight down over b1-f1, the rank next
# to its base (measured with its IK), so its third move stays on rank 2.
MOVES_BY_ARM = {"cobotta": (("e2", "e4"), ("d2", "d4"), ("c2", "c4"))}
SQUARE_M = 0.05  # the simulator's chess squares on every arm but the Cobotta


def require_solutions(command: str) -> None:
    """Raise ``ModuleNotFoundError`` with one line saying what to install when the reference
    solvers (``solutions``) are missing, as they are in the student install by design."""
    import importlib.util

    if importlib.util.find_spec("solutions") is None:
        raise ModuleNotFoundError(
            f"cobotlab {command} needs the reference solvers (package 'solutions'), which the "
            "student install leaves out: run it where the full cobotlab is installed "
            "(pip install -e . in the repository)", name="solutions")


def chess_square_m(robot: str) -> float:
    """Side (m) of the simulator's chess squares for an arm: 30 mm on the small Cobotta."""
    return 0.03 if robot == "cobotta" else SQUARE_M


@dataclass
class DemoSettings:
    """What ``cobotlab demo`` runs: arm, seed, noise level, output folder, image size and the
    number of capture poses for each calibration."""

    robot: str = "panda"
    seed: int = 0
    noise: str = "low"
    out: Path = Path("out")
    quick: bool = False
    n_flange: int = 12
    n_eye_in_hand: int = 15
    calib_size: tuple[int, int] = (640, 480)
    pick_size: tuple[int, int] = (320, 240)
    progress: bool = True

    @classmethod
    def make(cls, robot="panda", seed=0, noise="low", out="out", quick=False, n_poses=None,
             progress=True) -> DemoSettings:
        """Validated settings; raises ValueError naming the bad option and the choices."""
        if robot not in ARMS:
            raise ValueError(f"unknown robot {robot!r}; choose one of {', '.join(ARMS)}")
        if noise not in NOISE_LEVELS:
            raise ValueError(f"unknown noise level {noise!r}; choose one of "
                             f"{', '.join(NOISE_LEVELS)}")
        if not (isinstance(seed, (int, np.integer)) and seed >= 0):
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        settings = cls(robot=robot, seed=int(seed), noise=noise, out=Path(out), quick=quick,
                       progress=progress)
        if quick:
            # Fewer views, same image size: the fixed camera's flange board is small in view.
            settings.n_flange, settings.n_eye_in_hand = 10, 10
        if n_poses is not None:
            if n_poses < 6:
                raise ValueError(f"n_poses must be at least 6 for the eye-in-hand capture "
                                 f"(some views may fail), got {n_poses}")
            settings.n_eye_in_hand = int(n_poses)
        return settings

    def cell_options(self) -> dict:
        pixel_noise, encoder_noise_deg = NOISE_LEVELS[self.noise]
        return {"arm": self.robot, "seed": self.seed, "pixel_noise": pixel_noise,
                "encoder_noise_deg": encoder_noise_deg, "mount_error": MOUNT_ERROR}


# --------------------------------------------------------------------------- shared helpers


def _sim_cell(**options):
    """The demo's simulated cell, through ``connect("sim")``: the engine (MuJoCo or PyBullet)
    comes from ``COBOTLAB_SIM_ENGINE`` or lab.toml, as for a lab (docs/simulation.md)."""
    from robots import connect

    return connect("sim", **options)


def _board_detector(target):
    """The project's chessboard detector for a simulated printed board (its printed size,
    which a user reads off the print; not a pose)."""
    from robots.capture import chessboard_detector

    cols, rows = target.pattern_size
    square = float(np.linalg.norm(target.object_points[1] - target.object_points[0]))
    return chessboard_detector(cols, rows, square)


def _reachable(robot, base_T_flange) -> bool:
    """True if the pose is inside the safety box and the arm has an IK solution for it."""
    from robots.interfaces import SafetyError, UnreachableError

    try:
        robot.safety.check_cartesian_move(base_T_flange, base_T_flange, 0.1)
        robot.solve_ik(base_T_flange)
    except (SafetyError, UnreachableError):
        return False
    return True


def _progress(settings, iterable=None, **kwargs):
    from tqdm.auto import tqdm

    return tqdm(iterable, disable=not settings.progress, **kwargs)


# --------------------------------------------------------------------------- part 1: flange


@dataclass
class FlangeOutcome:
    """Part 1. ``base_T_cam`` from the offset-aware fit; ``naive`` from the fit that assumes the
    board centre is the flange centre; residuals per kept view (m)."""

    base_T_cam: np.ndarray
    naive_base_T_cam: np.ndarray
    handeye_base_T_cam: np.ndarray
    true_base_T_cam: np.ndarray
    flange_p_marker: np.ndarray
    true_flange_p_marker: np.ndarray
    residuals_m: np.ndarray
    pose_indices: np.ndarray
    n_commanded: int
    marker_base: np.ndarray
    failed: list


def _flange_poses(start, rng, n, safety):
    """Flange poses around the start pose: a 3-D spread of +-6 cm and +-12 degree tilts about
    the board's own axes, so the board stays in view and facing the camera. Positions are kept
    5 cm inside the safety box (a big arm's start pose can sit at its edge)."""
    lo, hi = safety.workspace_min + 0.05, safety.workspace_max - 0.05
    poses = []
    for k in range(n):
        shift = rng.uniform(-0.06, 0.06, 3)
        tilt = np.deg2rad(rng.uniform(-12, 12, 3))
        tilt[2] *= 0.5  # less roll, so the board never looks upside down to the detector
        pose = geo.compose(start, geo.pose_from_rotvec(tilt, np.zeros(3)))
        pose[:3, 3] = np.clip(start[:3, 3] + shift, lo, hi)
        poses.append(pose)
    return poses


def flange_calibration(settings: DemoSettings) -> FlangeOutcome:
    """Part 1: eye-on-base calibration of a fixed camera from a board on the flange."""
    from robots.capture import capture_pose_pairs
    from solutions import handeye, registration

    w, h = settings.calib_size
    with _sim_cell(mount="eye_to_hand", scene="calibration", width=w, height=h,
                         **settings.cell_options()) as cell:
        robot, truth = cell.robot, cell.truth
        target = truth.flange_target
        rng = np.random.default_rng(settings.seed)
        start = robot.flange_pose()
        # Lazily: each unreachable pose costs every IK restart, so stop at the first n_flange.
        reachable = (T for T in _flange_poses(start, rng, 3 * settings.n_flange, robot.safety)
                     if _reachable(robot, T))
        candidates = list(itertools.islice(reachable, settings.n_flange))
        if len(candidates) < 6:
            raise RuntimeError(f"only {len(candidates)} flange poses are reachable on the "
                               f"{settings.robot}; the demo needs 6")
        capture = capture_pose_pairs(robot, cell.camera, candidates, _board_detector(target),
                                     progress=settings.progress, settle_s=0.0, speed=0.25)
        F, C = capture.pose_pairs()
        if len(F) < 5:
            raise RuntimeError(f"the fixed camera saw the flange board in only {len(F)} of "
                               f"{len(candidates)} views; the demo needs 5")
        centre = target.object_points.mean(axis=0)  # the board centre, in the board frame
        cam_points = np.array([geo.transform_points(T, centre) for T in C])
        base_T_cam, p = registration.calibrate_flange_with_offset(cam_points, F)
        naive = registration.calibrate_flange(cam_points, F[:, :3, 3])
        marker_base = np.einsum("nij,j->ni", F[:, :3, :3], p) + F[:, :3, 3]
        residuals = np.linalg.norm(geo.transform_points(base_T_cam, cam_points) - marker_base,
                                   axis=1)
        handeye_X = handeye.calibrate_eye_to_hand(F, C)
        return FlangeOutcome(
            base_T_cam=base_T_cam, naive_base_T_cam=naive, handeye_base_T_cam=handeye_X,
            true_base_T_cam=truth.base_T_cam.copy(), flange_p_marker=p,
            true_flange_p_marker=geo.transform_points(truth.flange_T_marker, centre),
            residuals_m=residuals, pose_indices=capture.pose_indices, n_commanded=len(candidates),
            marker_base=marker_base,
            failed=list(zip(capture.failed_indices.tolist(), capture.failed_reasons)))


# --------------------------------------------------------------------------- part 2: eye in hand


@dataclass
class MethodRow:
    label: str
    X: np.ndarray | None
    rotation_deg: float = np.nan
    translation_mm: float = np.nan
    time_ms: float = np.nan
    error: str = ""


@dataclass
class EyeInHandOutcome:
    """Part 2: every method's result, the default one (saved to ``yaml_path``), residuals per
    view and the poses the robust default flagged."""

    rows: list
    default: MethodRow
    true_flange_T_cam: np.ndarray
    nominal_flange_T_cam: np.ndarray
    base_T_flange: np.ndarray
    cam_T_target: np.ndarray
    true_base_T_board: np.ndarray
    residual_deg: np.ndarray
    residual_mm: np.ndarray
    flagged: tuple
    pose_indices: np.ndarray
    n_commanded: int
    failed: list
    yaml_path: Path
    view_image: np.ndarray | None = None


def _eye_in_hand_views(base_T_board, centre_board, distance, board_x, flange_T_cam_nominal, rng,
                       n):
    """Flange poses putting the camera ``distance`` (+-10 %) from the board centre, tilted 10-30
    degrees at spread azimuths, rolled +-15 degrees, image x roughly along the board's x (the
    chessboard detector needs the board's x within 90 degrees of the image's u).
    ``flange_T_cam_nominal`` is the design mount: planning needs no calibration."""
    centre = geo.transform_points(base_T_board, centre_board)
    poses = []
    azimuths = np.sort(rng.uniform(0, 2 * np.pi, n))  # sorted: neighbours are close views
    for azimuth in azimuths:
        tilt = np.deg2rad(rng.uniform(10, 30))
        d = distance * rng.uniform(0.9, 1.1)
        direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                              np.cos(tilt)])
        eye = centre + d * direction
        z = (centre - eye) / np.linalg.norm(centre - eye)
        x = board_x - (board_x @ z) * z
        x /= np.linalg.norm(x)
        base_T_cam = geo.make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)
        roll = geo.pose_from_rpy(0, 0, np.deg2rad(rng.uniform(-15, 15)))
        poses.append(geo.compose(base_T_cam, roll, geo.invert(flange_T_cam_nominal)))
    return poses


def _sim_problem(capture, F, C, mount, pixel_noise):
    """The fields ``solutions.catalog.hand_eye_methods`` reads, filled from a capture."""
    has_pose = np.all(np.isfinite(capture.cam_T_target), axis=(1, 2))
    pixels = np.array([c for c, ok in zip(capture.corners_px, has_pose) if ok])
    grid = capture.object_points[0]
    return SimpleNamespace(
        base_T_flange=F, cam_T_target=C, mount=mount, pixels=pixels,
        # The catalog only runs the reprojection refinement on noisy pixels; rendered corners
        # always carry some error, so mark them noisy even without added image noise.
        noise=SimpleNamespace(pixel_px=max(pixel_noise, 0.1)),
        board=SimpleNamespace(object_points=lambda: grid),
        camera=SimpleNamespace(K=capture.intrinsics.K, dist=capture.intrinsics.dist))


def eye_in_hand_calibration(settings: DemoSettings) -> EyeInHandOutcome:
    """Part 2: capture views of the table board, solve ``flange_T_cam`` with every method, save
    the default result to ``out/flange_T_cam.yaml``."""
    import cv2

    from robots.calibration_io import save_calibration
    from robots.capture import capture_pose_pairs
    from solutions import handeye
    from solutions.catalog import DEFAULT_METHOD, hand_eye_methods
    from solutions.pipeline import per_pose_residuals

    w, h = settings.calib_size
    with _sim_cell(mount="eye_in_hand", scene="calibration", width=w, height=h,
                         **settings.cell_options()) as cell:
        robot, truth = cell.robot, cell.truth
        detect = _board_detector(truth.board)
        nominal = truth.nominal_flange_T_cam  # the design drawing: what a user knows
        first = detect(cell.camera.capture(), cell.camera.intrinsics)
        if first is None:
            raise RuntimeError(f"the wrist camera does not see the board from the {settings.robot}'s "
                               "start pose")
        base_T_board_guess = geo.compose(robot.flange_pose(), nominal, first.cam_T_target)
        centre = first.object_points.mean(axis=0)
        distance = float(np.linalg.norm(geo.transform_points(first.cam_T_target, centre)))
        rng = np.random.default_rng(settings.seed + 1)
        views = _eye_in_hand_views(base_T_board_guess, centre, min(distance, 0.55),
                                   base_T_board_guess[:3, 0], nominal, rng,
                                   2 * settings.n_eye_in_hand)
        views = [T for T in views if _reachable(robot, T)]
        views = views[:: max(1, len(views) // settings.n_eye_in_hand)][: settings.n_eye_in_hand]
        if len(views) < 6:
            raise RuntimeError(f"only {len(views)} eye-in-hand views are reachable on the "
                               f"{settings.robot}; the demo needs 6")
        capture = capture_pose_pairs(robot, cell.camera, views, detect,
                                     progress=settings.progress, settle_s=0.0, speed=0.25)
        F, C = capture.pose_pairs()
        if len(F) < 5:
            raise RuntimeError(f"the board was detected in only {len(F)} of {len(views)} views")
        true_X = truth.flange_T_cam.copy()
        problem = _sim_problem(capture, F, C, "eye_in_hand", NOISE_LEVELS[settings.noise][0])
        rows = []
        for label, solve in hand_eye_methods(problem):
            start = time.perf_counter()
            try:
                result = solve()
            except Exception as exc:  # noqa: BLE001 -- a method refusing this data is a result to show
                rows.append(MethodRow(label, None, error=str(exc).splitlines()[0]))
                continue
            X = getattr(result, "X", result)
            rows.append(MethodRow(label, X, geo.rotation_error_deg(X, true_X),
                                  geo.translation_error(X, true_X) * 1e3,
                                  (time.perf_counter() - start) * 1e3))
        default = next(r for r in rows if r.label == DEFAULT_METHOD)
        if default.X is None:
            raise RuntimeError(f"the default method {DEFAULT_METHOD!r} failed: {default.error}")
        report = handeye.calibrate_eye_in_hand_report(F, C, method=DEFAULT_METHOD)
        rot, trans = per_pose_residuals(F, C, report.X, "eye_in_hand")
        settings.out.mkdir(parents=True, exist_ok=True)
        yaml_path = settings.out / "flange_T_cam.yaml"
        save_calibration(yaml_path, report.X, "flange", "cam", DEFAULT_METHOD, len(F),
                         {"rotation_residual": report.rotation_residual,
                          "translation_residual_m2": report.translation_residual,
                          "per_pose_rotation_deg": rot, "per_pose_translation_m": trans},
                         robot_id=f"sim/{settings.robot}", camera_id=cell.camera.name)
        view = capture.images[0].copy()
        cv2.drawChessboardCorners(view, tuple(truth.board.pattern_size),
                                  capture.corners_px[0].astype(np.float32).reshape(-1, 1, 2), True)
        return EyeInHandOutcome(
            rows=rows, default=default, true_flange_T_cam=true_X, nominal_flange_T_cam=nominal,
            base_T_flange=F, cam_T_target=C, true_base_T_board=truth.base_T_board.copy(),
            residual_deg=rot, residual_mm=trans * 1e3,
            flagged=tuple(int(capture.pose_indices[i]) for i in report.outlier_pose_indices),
            pose_indices=capture.pose_indices, n_commanded=len(views),
            failed=list(zip(capture.failed_indices.tolist(), capture.failed_reasons)),
            yaml_path=yaml_path, view_image=view)


# --------------------------------------------------------------------------- part 3: chess


@dataclass
class PickRecord:
    """One move: did the piece land on its square, the true grasp and placement errors (mm),
    the true TCP-to-piece error at each servo frame (mm), servo iterations, failure reason."""

    from_square: str
    to_square: str
    kind: str = ""
    placed: bool = False
    grasp_error_mm: float = np.nan
    place_error_mm: float = np.nan
    servo_errors_mm: list = field(default_factory=list)
    iterations: int = 0
    error: str = ""


@dataclass
class PickOutcome:
    picks: list
    before: np.ndarray | None
    after: np.ndarray | None


class _WatchedCamera:
    """The cell's camera, for the controller, that also scores each frame against the truth:
    while the controller servoes over a piece, how far (horizontally) the true TCP is from the
    piece's true axis. It keeps the overview frames the search looks at, for the report."""

    def __init__(self, camera, cell):
        self._camera, self._cell = camera, cell
        self.intrinsics, self.name = camera.intrinsics, camera.name
        self.stage, self.piece_xy, self.errors_mm, self.overview = None, None, [], None

    def capture(self):
        frame = self._camera.capture()
        if self.stage == "search":
            self.overview = frame.rgb
        elif self.stage == "precise" and self.piece_xy is not None:
            self.errors_mm.append(self._tcp_error_mm())
        return frame

    def _tcp_error_mm(self) -> float:
        truth, tool = self._cell.truth, self._cell.robot.tool
        tcp = geo.compose(truth.base_T_flange(), tool.flange_T_tcp)[:3, 3]
        return float(np.linalg.norm(tcp[:2] - self.piece_xy) * 1e3)


def _move_joints_to(robot, base_T_flange, steps: int = 4, speed: float = 0.5) -> None:
    """Joint-space move in ``steps`` waypoints (each inside the safety's joint step): from the
    home pose a straight-line move can cross a singularity on some arms. The IK starts from
    the present joints with the base joint turned towards the target, so an arm that starts
    facing away (the UR10e, folded behind its base) keeps its elbow and wrist configuration
    instead of reaching over backwards."""
    from solutions.servoing import ik_seed_facing

    q0 = robot.joint_positions()
    # Already facing the target within 1 mrad (the Panda): the plain IK, seeded as it stands.
    q1 = robot.solve_ik(base_T_flange, ik_seed_facing(robot, base_T_flange, min_turn_rad=1e-3))
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        robot.move_joints(q0 + s * (q1 - q0), speed=speed)


def pick_pieces(settings: DemoSettings, calibration_path, expected_flange_T_cam) -> PickOutcome:
    """Part 3: move the pieces of ``MOVES`` (``MOVES_BY_ARM`` for some arms) with the IBVS
    staged controller, using the saved calibration; score each move with
    ``cell.truth.pieces``."""
    from robots.calibration_io import load_calibration
    from robots.perception import ServoError, square_centre
    from solutions.servoing import ARM_OPTIONS, StagedPickAndPlace, overview_base_T_cam

    flange_T_cam = load_calibration(calibration_path).pose
    # Where the arm looks for the board, and how high it hovers: the controller's settings
    # for the arm in the simulator's layout.
    options = dict(ARM_OPTIONS[settings.robot])
    square_m = chess_square_m(settings.robot)
    w, h = settings.pick_size
    with _sim_cell(mount="eye_in_hand", scene="chess", width=w, height=h,
                         **settings.cell_options()) as cell:
        truth = cell.truth
        # Same seed, same mount: the camera calibrated in part 2 is this one.
        if geo.translation_error(truth.flange_T_cam, expected_flange_T_cam) > 1e-9:
            raise RuntimeError("the chess cell's camera mount differs from the calibrated one")
        watched = _WatchedCamera(cell.camera, cell)
        x, y = options["search_xy"][0]
        overview = overview_base_T_cam(x, y, options["overview_height_m"],
                                       options.get("view_yaw_rad", 0.0))
        _move_joints_to(cell.robot, geo.compose(overview, geo.invert(flange_T_cam)))
        picks = []
        before = None
        moves = MOVES_BY_ARM.get(settings.robot, MOVES)
        for from_sq, to_sq in _progress(settings, moves, desc="pick", unit="piece"):
            record = PickRecord(from_sq, to_sq)
            start_piece = truth.pieces.get(from_sq)
            record.kind = start_piece.kind if start_piece else "?"
            watched.piece_xy = None if start_piece is None else start_piece.base_T_piece[:2, 3]
            watched.errors_mm = []

            def on_stage(stage, ctl, record=record):
                watched.stage = stage
                if stage == "lift" and watched.piece_xy is not None:
                    record.grasp_error_mm = watched._tcp_error_mm()

            controller = StagedPickAndPlace(cell, flange_T_cam, square_m, "ibvs",
                                            on_stage=on_stage, **options)
            controller.camera = watched
            try:
                result = controller.run(from_sq, to_sq)
                record.iterations = result.iterations
            except (ServoError, ValueError, RuntimeError) as exc:
                cell.robot.stop()
                record.error = f"{type(exc).__name__}: {exc}"
            if before is None:
                before = watched.overview
            record.servo_errors_mm = list(watched.errors_mm)
            after = truth.pieces
            landed = after.get(to_sq)
            record.placed = (not record.error and from_sq not in after and landed is not None
                             and landed.kind == record.kind)
            if landed is not None:
                square = geo.transform_points(truth.base_T_world,
                                              square_centre(to_sq, square_m))
                record.place_error_mm = float(
                    np.linalg.norm(landed.base_T_piece[:2, 3] - square[:2]) * 1e3)
            picks.append(record)
        # One last look from the overview pose, for the "after" picture.
        watched.stage, watched.overview = "search", None
        controller = StagedPickAndPlace(cell, flange_T_cam, square_m, "ibvs", **options)
        controller.camera = watched
        try:
            controller.search()
        except (ServoError, ValueError, RuntimeError):
            pass  # the picture is taken before the board is looked for; it is all we need
        return PickOutcome(picks, before, watched.overview)


# --------------------------------------------------------------------------- the whole demo


@dataclass
class DemoResult:
    settings: DemoSettings
    flange: FlangeOutcome
    eye_in_hand: EyeInHandOutcome
    picks: PickOutcome
    elapsed_s: float
    report: Path

    @property
    def picks_placed(self) -> int:
        return sum(p.placed for p in self.picks.picks)


def _err(X, truth) -> str:
    return (f"{geo.rotation_error_deg(X, truth):8.3f} deg {geo.translation_error(X, truth) * 1e3:8.2f} mm")


def _first_clause(reason: str) -> str:
    return reason.split(";")[0].split(". ")[0][:110]


def _print_flange(f: FlangeOutcome) -> None:
    print(f"  {len(f.residuals_m)} of {f.n_commanded} views used; residual per view (mm): "
          + " ".join(f"{r * 1e3:.2f}" for r in f.residuals_m))
    for label, X in (("calibrate_flange_with_offset", f.base_T_cam),
                     ("calibrate_flange (offset ignored)", f.naive_base_T_cam),
                     ("hand-eye eye_to_hand nonlinear", f.handeye_base_T_cam)):
        print(f"  {label:<36}{_err(X, f.true_base_T_cam)}")
    print(f"  board centre on the flange: found {np.round(f.flange_p_marker * 1e3, 1)} mm, "
          f"true {np.round(f.true_flange_p_marker * 1e3, 1)} mm")
    for index, reason in f.failed:
        print(f"  view {index} skipped: {_first_clause(reason)}")


def _print_eye_in_hand(e: EyeInHandOutcome) -> None:
    print(f"  {len(e.base_T_flange)} of {e.n_commanded} views used; error of flange_T_cam "
          "against the truth:")
    print(f"  {'method':<24}{'rotation (deg)':>15}{'translation (mm)':>18}{'time (ms)':>11}")
    print(f"  {'(design mount)':<24}{geo.rotation_error_deg(e.nominal_flange_T_cam, e.true_flange_T_cam):>15.3f}"
          f"{geo.translation_error(e.nominal_flange_T_cam, e.true_flange_T_cam) * 1e3:>18.2f}")
    for r in e.rows:
        if r.X is None:
            print(f"  {r.label:<24}  failed: {r.error}")
        else:
            print(f"  {r.label:<24}{r.rotation_deg:>15.3f}{r.translation_mm:>18.2f}{r.time_ms:>11.1f}")
    worst = int(np.argmax(e.residual_mm))
    print(f"  residual per view: median {np.median(e.residual_mm):.2f} mm / "
          f"{np.median(e.residual_deg):.3f} deg, worst view {e.pose_indices[worst]} "
          f"{e.residual_mm[worst]:.2f} mm; flagged: {list(e.flagged) or 'none'}")
    for index, reason in e.failed:
        print(f"  view {index} skipped: {_first_clause(reason)}")
    print(f"  saved {e.default.label} result to {e.yaml_path}")


def _print_picks(p: PickOutcome) -> None:
    print(f"  {'move':<10}{'piece':<8}{'placed':<8}{'grasp err (mm)':>15}{'place err (mm)':>15}"
          f"{'servo its':>10}")
    for r in p.picks:
        print(f"  {r.from_square}-{r.to_square:<7}{r.kind:<8}{'yes' if r.placed else 'NO':<8}"
              f"{r.grasp_error_mm:>15.2f}{r.place_error_mm:>15.2f}{r.iterations:>10}")
        if r.error:
            print(f"    failed: {r.error}")


def run_demo(robot: str = "panda", seed: int = 0, noise: str = "low", out="out",
             quick: bool = False, n_poses: int | None = None, progress: bool = True) -> DemoResult:
    """Run the three parts in the simulator, print their errors against the truth and write
    ``out/report.html`` (figures as PNG files beside it). Returns the numbers as a
    :class:`DemoResult`. Bad options raise ValueError before anything runs."""
    require_solutions("demo")
    from cobotlab.report import write_report

    settings = DemoSettings.make(robot, seed, noise, out, quick, n_poses, progress)
    t0 = time.perf_counter()
    pixel_noise, encoder_deg = NOISE_LEVELS[noise]
    print(f"cobotlab demo: {robot}, seed {seed}, noise {noise!r} (image noise {pixel_noise:g}/255, "
          f"encoder offsets {encoder_deg:g} deg per joint), camera mounted {MOUNT_ERROR[0]:g} mm / "
          f"{MOUNT_ERROR[1]:g} deg off its design pose{', quick' if quick else ''}")

    print("\n[1/3] flange calibration, eye-on-base: error of base_T_cam against the truth")
    flange = flange_calibration(settings)
    _print_flange(flange)

    print("\n[2/3] eye-in-hand calibration with every method")
    eye = eye_in_hand_calibration(settings)
    _print_eye_in_hand(eye)

    print(f"\n[3/3] pick and place with the saved calibration ({eye.yaml_path})")
    picks = pick_pieces(settings, eye.yaml_path, eye.true_flange_T_cam)
    _print_picks(picks)

    elapsed = time.perf_counter() - t0
    report = write_report(settings, flange, eye, picks, elapsed)
    result = DemoResult(settings, flange, eye, picks, elapsed, report)
    print("\nsummary: errors against the truth")
    print(f"  flange calibration   base_T_cam    {_err(flange.base_T_cam, flange.true_base_T_cam)}")
    print(f"  eye-in-hand ({eye.default.label}) flange_T_cam {_err(eye.default.X, eye.true_flange_T_cam)}")
    placed = [r for r in picks.picks if r.placed]
    worst = max((r.place_error_mm for r in placed), default=np.nan)
    print(f"  pick and place       {len(placed)}/{len(picks.picks)} pieces placed, worst "
          f"placement {worst:.1f} mm from the square centre")
    print(f"report: {report}")
    print(f"elapsed: {elapsed:.1f} s")
    if len(placed) < len(picks.picks):
        raise RuntimeError(f"{len(picks.picks) - len(placed)} of {len(picks.picks)} picks failed; "
                           f"see {report}")
    return result


# --------------------------------------------------------------------------- synthetic table


def run_synthetic(seed: int = 0, n_poses: int = 15, pixel_px: float = 0.3,
                  robot_rot_deg: float = 0.05, robot_trans_mm: float = 0.2) -> None:
    """``cobotlab demo --synthetic``: every hand-eye method on one seeded synthetic problem per
    mount (board corners projected with pixel noise, poses from ``cv2.solvePnP``, robot poses
    with encoder-level noise). Prints the rotation (deg) and translation (mm) error of X."""
    require_solutions("demo --synthetic")
    from autograder.synthetic import NoiseModel, make_hand_eye
    from solutions.catalog import DEFAULT_METHOD, hand_eye_methods

    noise = NoiseModel(pixel_px=pixel_px, robot_rot_deg=robot_rot_deg, robot_trans_mm=robot_trans_mm)
    print(f"cobotlab demo --synthetic: seed {seed}, {n_poses} poses, pixel noise {pixel_px} px, "
          f"robot noise {robot_rot_deg} deg / {robot_trans_mm} mm per axis")
    for mount in ("eye_in_hand", "eye_to_hand"):
        problem = make_hand_eye(seed, mount, n_poses=n_poses, noise=noise)
        unknown = "flange_T_cam" if mount == "eye_in_hand" else "base_T_cam"
        print(f"\n{mount}: error of {unknown} against the truth")
        print(f"  {'method':<22}{'rotation (deg)':>15}{'translation (mm)':>18}{'time (ms)':>11}")
        for label, solve in hand_eye_methods(problem):
            start = time.perf_counter()
            try:
                result = solve()
            except Exception as exc:  # noqa: BLE001 -- a method refusing this data is a result to show
                print(f"  {label:<22}  failed: {exc}")
                continue
            ms = (time.perf_counter() - start) * 1000
            X = getattr(result, "X", result)
            print(f"  {label:<22}{geo.rotation_error_deg(X, problem.X_true):>15.4f}"
                  f"{geo.translation_error(X, problem.X_true) * 1000:>18.3f}{ms:>11.1f}")
    print(f"\nThe default method is '{DEFAULT_METHOD}'; 'refine_reprojection' also uses the raw corners.")

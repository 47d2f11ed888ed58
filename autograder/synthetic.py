"""Seeded calibration problems with known ground truth.

Students practise on public seeds and the autograder grades on a secret seed with the very same
generators, so a solver that is right on practice problems is right on the hidden ones and no
answer can be hard-coded.

Every generator takes ``seed``: an int or a ``numpy.random.Generator``, and returns a small
dataclass with the inputs a solver sees (``base_T_flange``, ``cam_T_target``, ...) and the truth
(``X_true``, ``Y_true``, ...). Frames and units follow the project conventions: (4, 4) float64
poses, ``a_T_b`` maps b-coordinates to a-coordinates, metres and radians. Noise levels are
standard deviations *per axis* in the units their names say (deg, mm, px).

Noise model for a measured pose ``T = [R t]``: rotation noise is a rotation vector with i.i.d.
N(0, sigma) components applied in the parent frame (``R' = exp([w]x) R``), translation noise
is i.i.d. N(0, sigma) per axis added to ``t``. This is how OpenCV's own hand-eye test perturbs
its poses (it adds the noise to the Rodrigues vector).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from robots import geometry as geo

__all__ = [
    "NoiseModel",
    "Board",
    "CameraModel",
    "HandEyeProblem",
    "FlangeProblem",
    "ThreePointProblem",
    "as_generator",
    "perturb_pose",
    "make_hand_eye",
    "make_opencv_scenario",
    "make_flange",
    "make_three_point",
    "make_real_like_hand_eye",
]

MOUNTS = ("eye_in_hand", "eye_to_hand")


def as_generator(seed) -> np.random.Generator:
    """A numpy Generator from an int seed (or the Generator itself, passed through)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or isinstance(seed, (bool, float)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(
            f"seed must be an int or numpy.random.Generator, got {seed!r}; "
            "pass e.g. seed=0 so the problem can be reproduced"
        )
    return np.random.default_rng(int(seed))


@dataclass(frozen=True)
class NoiseModel:
    """Measurement noise, standard deviations per axis.

    ``robot_*`` perturbs ``base_T_flange`` (what the controller reports), ``cam_*`` perturbs
    ``cam_T_target`` (what the camera estimates), ``pixel_px`` perturbs the projected board
    corners (then ``cam_T_target`` is re-estimated from them with ``cv2.solvePnP``).
    ``n_outliers`` views get a gross error of ``outlier_rot_deg`` about a random axis and
    ``outlier_trans_mm`` in a random direction on the camera side: a mis-detected board.
    """

    robot_rot_deg: float = 0.0
    robot_trans_mm: float = 0.0
    cam_rot_deg: float = 0.0
    cam_trans_mm: float = 0.0
    pixel_px: float = 0.0
    n_outliers: int = 0
    outlier_rot_deg: float = 5.0
    outlier_trans_mm: float = 50.0

    def __post_init__(self):
        for name in ("robot_rot_deg", "robot_trans_mm", "cam_rot_deg", "cam_trans_mm",
                     "pixel_px", "outlier_rot_deg", "outlier_trans_mm"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"NoiseModel.{name} must be a finite value >= 0, got {value}")
        if self.n_outliers < 0:
            raise ValueError(f"NoiseModel.n_outliers must be >= 0, got {self.n_outliers}")


@dataclass(frozen=True)
class Board:
    """A chessboard's inner-corner grid: ``cols`` x ``rows`` corners, ``square_m`` apart.

    Object points lie in the target frame's z = 0 plane with the origin on the first corner,
    x along a row and y along a column (OpenCV's ``findChessboardCorners`` order). The default
    is the 9 x 7-square board of 39 mm used in the labs (8 x 6 inner corners).
    """

    cols: int = 8
    rows: int = 6
    square_m: float = 0.039

    def object_points(self) -> np.ndarray:
        """(cols*rows, 3) corner positions in the target frame, metres, row-major."""
        xs, ys = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
        return pts * self.square_m

    @property
    def centre(self) -> np.ndarray:
        """Centre of the corner grid in the target frame, metres."""
        return np.array([(self.cols - 1) / 2, (self.rows - 1) / 2, 0.0]) * self.square_m


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with OpenCV's (k1, k2, p1, p2, k3) distortion; K in pixels."""

    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int

    @staticmethod
    def default() -> CameraModel:
        """640 x 480 with a 600 px focal length (about a RealSense D435 colour stream)."""
        K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
        return CameraModel(K=K, dist=np.zeros(5), width=640, height=480)

    def project(self, cam_T_target: np.ndarray, points_target: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of target-frame points seen from a camera at ``cam_T_target``."""
        import cv2

        rvec, _ = cv2.Rodrigues(cam_T_target[:3, :3])
        px, _ = cv2.projectPoints(points_target, rvec, cam_T_target[:3, 3], self.K, self.dist)
        return px.reshape(-1, 2)


@dataclass
class HandEyeProblem:
    """A hand-eye problem: measured robot and camera poses, and the truth.

    eye_in_hand: X = flange_T_cam, Y = base_T_target, and
        ``base_T_flange[i] @ X @ cam_T_target[i] == Y``.
    eye_to_hand: X = base_T_cam, Y = flange_T_target, and
        ``base_T_flange[i] @ Y == X @ cam_T_target[i]``.
    """

    mount: str
    base_T_flange: np.ndarray
    cam_T_target: np.ndarray
    X_true: np.ndarray
    Y_true: np.ndarray
    true_base_T_flange: np.ndarray
    true_cam_T_target: np.ndarray
    noise: NoiseModel
    board: Board | None = None
    camera: CameraModel | None = None
    pixels: np.ndarray | None = None
    outlier_indices: tuple[int, ...] = ()

    @property
    def n_poses(self) -> int:
        return len(self.base_T_flange)

    def as_ax_yb(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, X, Y) with ``A[i] @ X == Y @ B[i]`` (robot-world-hand-eye form).

        eye_in_hand: A = base_T_flange, B = target_T_cam = inv(cam_T_target),
        X = flange_T_cam, Y = base_T_target.
        eye_to_hand: A = base_T_flange, B = cam_T_target, X = flange_T_target, Y = base_T_cam.
        """
        if self.mount == "eye_in_hand":
            return self.base_T_flange, geo.invert(self.cam_T_target), self.X_true, self.Y_true
        return self.base_T_flange, self.cam_T_target, self.Y_true, self.X_true


@dataclass
class FlangeProblem:
    """Eye-on-base flange calibration: a fixed camera sees a marker on the flange.

    ``cam_points[i]`` is the marker centre measured in the camera frame (m),
    ``base_points[i]`` the flange centre (tool0 origin) in the base frame (m), and
    ``base_T_flange[i]`` the full flange pose. Truth: ``base_T_cam_true`` and the marker
    centre in the flange frame ``flange_p_marker_true`` (zeros when the marker is centred).
    """

    cam_points: np.ndarray
    base_points: np.ndarray
    base_T_flange: np.ndarray
    base_T_cam_true: np.ndarray
    flange_p_marker_true: np.ndarray
    noise_mm: float
    depth_noise_mm: float
    outlier_indices: tuple[int, ...] = ()


@dataclass
class ThreePointProblem:
    """Single-shot hand-to-eye calibration from three board points (lab 4).

    The world frame is the board's: origin on a corner, x along one edge, the board in the xy
    plane. ``cam_points``/``base_points`` are (3, 3): origin, a point on +x, a point in the xy
    plane, measured by the stereo camera and by the robot's pointer. ``check_cam`` /
    ``check_base`` are (12, 3) further board points for the per-axis RMSE.
    """

    cam_points: np.ndarray
    base_points: np.ndarray
    check_cam: np.ndarray
    check_base: np.ndarray
    base_T_cam_true: np.ndarray
    base_T_world_true: np.ndarray
    cam_T_world_true: np.ndarray
    camera_noise_mm: float
    pointer_noise_mm: float


# --------------------------------------------------------------------------- noise


def perturb_pose(T: np.ndarray, rot_std_rad: float, trans_std_m: float,
                 rng: np.random.Generator) -> np.ndarray:
    """A noisy copy of pose ``T`` (see the module docstring for the noise model)."""
    out = np.array(T, dtype=float, copy=True)
    if rot_std_rad > 0:
        out[:3, :3] = geo.rotation_from_rotvec(rng.normal(0.0, rot_std_rad, 3)) @ out[:3, :3]
    if trans_std_m > 0:
        out[:3, 3] += rng.normal(0.0, trans_std_m, 3)
    return out


def _gross_error(T: np.ndarray, rot_deg: float, trans_mm: float, rng) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    out = T.copy()
    out[:3, :3] = geo.rotation_from_rotvec(np.radians(rot_deg) * axis) @ T[:3, :3]
    out[:3, 3] += direction * trans_mm / 1000.0
    return out


def _random_rotation(rng, max_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return geo.rotation_from_rotvec(np.radians(rng.uniform(0, max_deg)) * axis)


# --------------------------------------------------------------------------- hand-eye


def _sample_view(rng, board: Board, camera: CameraModel, depth_m=(0.35, 0.7),
                 tilt_deg: float = 40.0, roll_deg: float = 60.0) -> np.ndarray | None:
    """A cam_T_target with the whole board in the image and facing the camera, or None."""
    # Start fronto-parallel (target z along the optical axis, looking at the board's front),
    # then tilt about an in-plane axis and roll about the optical axis, as a student would.
    tilt_axis = np.r_[rng.normal(size=2), 0.0]
    tilt_axis /= np.linalg.norm(tilt_axis)
    roll = geo.rotation_from_rotvec(np.radians(rng.uniform(-roll_deg, roll_deg)) * np.array([0, 0, 1.0]))
    R = roll @ geo.rotation_from_rotvec(np.radians(rng.uniform(0, tilt_deg)) * tilt_axis)
    depth = rng.uniform(*depth_m)
    half_w = 0.35 * depth * camera.width / camera.K[0, 0]
    half_h = 0.35 * depth * camera.height / camera.K[1, 1]
    centre_cam = np.array([rng.uniform(-half_w, half_w), rng.uniform(-half_h, half_h), depth])
    cam_T_target = geo.make_pose(R, centre_cam - R @ board.centre)
    px = camera.project(cam_T_target, board.object_points())
    margin = 10.0
    inside = ((px[:, 0] > margin) & (px[:, 0] < camera.width - margin)
              & (px[:, 1] > margin) & (px[:, 1] < camera.height - margin))
    return cam_T_target if inside.all() else None


def _nudge_view(rng, view, board: Board, camera: CameraModel, motion_deg) -> np.ndarray | None:
    """``view`` turned by ``motion_deg`` about a random axis through the board centre, or None
    if the board then leaves the image or turns more than 50 deg away from the camera."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    turn = geo.rotation_from_rotvec(np.radians(rng.uniform(*motion_deg)) * axis)
    R = turn @ view[:3, :3]
    if R[2, 2] < np.cos(np.radians(50.0)):
        return None
    centre_cam = geo.transform_points(view, board.centre) + rng.normal(0.0, 0.01, 3)
    candidate = geo.make_pose(R, centre_cam - R @ board.centre)
    px = camera.project(candidate, board.object_points())
    inside = ((px[:, 0] > 10) & (px[:, 0] < camera.width - 10)
              & (px[:, 1] > 10) & (px[:, 1] < camera.height - 10))
    return candidate if inside.all() and 0.3 < candidate[2, 3] < 0.8 else None


def _sample_views(rng, n_poses, board, camera, motion_deg) -> np.ndarray:
    """n views whose consecutive relative rotations lie within ``motion_deg`` (degrees).

    Each next view is first drawn afresh (varied views, as a careful student takes them); when
    the requested motions are too small for a fresh draw to land in range, it is the previous
    view turned about the board centre instead.
    """
    lo, hi = motion_deg
    views = []
    for _ in range(20000):
        fresh = rng.uniform() < 0.5 or not views
        view = (_sample_view(rng, board, camera) if fresh
                else _nudge_view(rng, views[-1], board, camera, motion_deg))
        if view is None:
            continue
        if views:
            angle = geo.rotation_error_deg(views[-1], view)
            if not lo <= angle <= hi:
                continue
        views.append(view)
        if len(views) == n_poses:
            return np.array(views)
    raise RuntimeError(
        f"could not sample {n_poses} views with {lo}-{hi} degree motions keeping the board in "
        "view; widen motion_deg or use a smaller board"
    )


def _true_flange_T_cam(rng) -> np.ndarray:
    """A wrist camera a few centimetres off the flange axis, looking roughly along it."""
    R = _random_rotation(rng, 30.0) @ Rotation.from_euler("z", rng.uniform(-180, 180), degrees=True).as_matrix()
    t = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), rng.uniform(0.02, 0.10)])
    return geo.make_pose(R, t)


def _true_base_T_target(rng) -> np.ndarray:
    """A board lying face up on the table in front of the robot, rotated about the vertical.

    OpenCV's board frame has z pointing into the board, away from a camera that sees its
    front; for a face-up board that is straight down in the base frame.
    """
    R = (Rotation.from_euler("z", rng.uniform(-180, 180), degrees=True)
         * Rotation.from_euler("x", 180, degrees=True)).as_matrix()
    t = np.array([rng.uniform(0.35, 0.6), rng.uniform(-0.2, 0.2), rng.uniform(0.0, 0.05)])
    return geo.make_pose(R, t)


def _true_base_T_cam_fixed(rng) -> np.ndarray:
    """A fixed camera about 1 m from the base, looking back at the workspace."""
    eye = np.array([rng.uniform(0.9, 1.2), rng.uniform(-0.3, 0.3), rng.uniform(0.5, 0.9)])
    look_at = np.array([0.45, 0.0, 0.3])
    z = look_at - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ Rotation.from_euler("z", rng.uniform(-10, 10), degrees=True).as_matrix()
    return geo.make_pose(geo.project_to_so3(R), eye)


def _true_flange_T_target(rng, board: Board) -> np.ndarray:
    """A board held by the flange, a few centimetres beyond it, centred near the axis."""
    R = _random_rotation(rng, 20.0)
    centre = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.02, 0.08)])
    return geo.make_pose(R, centre - R @ board.centre)


def make_hand_eye(seed, mount: str = "eye_in_hand", n_poses: int = 10,
                  noise: NoiseModel | None = None, motion_deg=(15.0, 45.0),
                  board: Board | None = None, camera: CameraModel | None = None) -> HandEyeProblem:
    """A hand-eye problem sampled the way a careful student would capture one.

    Views keep the whole board in the image (depth 0.35-0.7 m, tilt <= 40 deg, roll <= 60 deg)
    and consecutive motions rotate by ``motion_deg`` degrees about varied axes. With
    ``noise.pixel_px > 0`` the measured ``cam_T_target`` comes from ``cv2.solvePnP`` on noisy
    corner pixels (``problem.pixels``); camera pose noise, if also set, is added on top.
    """
    if mount not in MOUNTS:
        raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
    if n_poses < 3:
        raise ValueError(f"n_poses must be >= 3 for a hand-eye problem, got {n_poses}")
    rng = as_generator(seed)
    noise = noise or NoiseModel()
    board = board or Board()
    camera = camera or CameraModel.default()
    if noise.n_outliers > n_poses:
        raise ValueError(f"n_outliers ({noise.n_outliers}) > n_poses ({n_poses})")

    cam_T_target = _sample_views(rng, n_poses, board, camera, motion_deg)
    if mount == "eye_in_hand":
        X, Y = _true_flange_T_cam(rng), _true_base_T_target(rng)
        # base_T_flange @ X @ cam_T_target == Y
        base_T_flange = Y @ geo.invert(cam_T_target) @ geo.invert(X)
    else:
        X, Y = _true_base_T_cam_fixed(rng), _true_flange_T_target(rng, board)
        # base_T_flange @ Y == X @ cam_T_target
        base_T_flange = X @ cam_T_target @ geo.invert(Y)

    outliers = tuple(sorted(rng.choice(n_poses, size=noise.n_outliers, replace=False).tolist()))
    seen_T_target = cam_T_target.copy()
    for i in outliers:
        seen_T_target[i] = _gross_error(cam_T_target[i], noise.outlier_rot_deg, noise.outlier_trans_mm, rng)

    object_points = board.object_points()
    pixels = np.stack([camera.project(T, object_points) for T in seen_T_target])
    measured_cam = seen_T_target.copy()
    if noise.pixel_px > 0:
        import cv2

        pixels = pixels + rng.normal(0.0, noise.pixel_px, pixels.shape)
        for i, (T, px) in enumerate(zip(seen_T_target, pixels)):
            rvec0, _ = cv2.Rodrigues(T[:3, :3])
            ok, rvec, tvec = cv2.solvePnP(object_points, px, camera.K, camera.dist,
                                          rvec=rvec0.copy(), tvec=T[:3, 3].copy(),
                                          useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
            if not ok:
                raise RuntimeError(f"solvePnP failed on synthetic view {i}")
            measured_cam[i] = geo.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
    measured_cam = np.stack([
        perturb_pose(T, np.radians(noise.cam_rot_deg), noise.cam_trans_mm / 1000.0, rng)
        for T in measured_cam
    ])
    measured_robot = np.stack([
        perturb_pose(T, np.radians(noise.robot_rot_deg), noise.robot_trans_mm / 1000.0, rng)
        for T in base_T_flange
    ])
    return HandEyeProblem(
        mount=mount, base_T_flange=measured_robot, cam_T_target=measured_cam, X_true=X, Y_true=Y,
        true_base_T_flange=base_T_flange, true_cam_T_target=cam_T_target, noise=noise,
        board=board, camera=camera, pixels=pixels, outlier_indices=outliers,
    )


def _opencv_style_pose(rng, theta_range, t_range) -> np.ndarray:
    """OpenCV's test pose: rotation vector theta * a with a ~ U[-1, 1]^3 (not normalised)
    and theta ~ U(theta_range) with a random sign; each translation component ~ U(t_range)
    with a random sign."""
    axis = rng.uniform(-1.0, 1.0, 3)
    theta = rng.uniform(*np.radians(theta_range)) * rng.choice([-1.0, 1.0])
    t = rng.uniform(*t_range, 3) * rng.choice([-1.0, 1.0], 3)
    return geo.make_pose(geo.rotation_from_rotvec(theta * axis), t)


def make_opencv_scenario(seed, mount: str = "eye_in_hand", n_poses: int = 10,
                         noise: bool = True) -> HandEyeProblem:
    """The scenario of OpenCV's own ``calibrateHandEye`` accuracy test, re-implemented.

    cam2gripper: 10-50 deg, translations 0.05-0.5 m per axis; target2base: 5-85 deg,
    0.5-3.5 m; gripper2base: 5-45 deg, 0.5-1.5 m. Noise: N(0, 0.002 rad) on each Rodrigues
    component and N(0, 5 mm) per axis on target2cam; N(0, 0.001 rad) and N(0, 1 mm) on
    gripper2base. For eye_to_hand the same numbers describe the mirrored problem, with the
    robot poses inverted as OpenCV's documentation prescribes (base2gripper in place of
    gripper2base): X = base_T_cam, Y = flange_T_target.
    """
    if mount not in MOUNTS:
        raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
    rng = as_generator(seed)
    cam2gripper = _opencv_style_pose(rng, (10, 50), (0.05, 0.5))
    target2base = _opencv_style_pose(rng, (5, 85), (0.5, 3.5))
    gripper2base = np.stack([_opencv_style_pose(rng, (5, 45), (0.5, 1.5)) for _ in range(n_poses)])
    target2cam = geo.invert(cam2gripper) @ geo.invert(gripper2base) @ target2base
    if mount == "eye_in_hand":
        robot_true, X, Y = gripper2base, cam2gripper, target2base
    else:
        # Mirror: the "gripper" of OpenCV's generator is our base; its "base" is our flange.
        robot_true, X, Y = geo.invert(gripper2base), cam2gripper, target2base
    model = NoiseModel(robot_rot_deg=np.degrees(0.001), robot_trans_mm=1.0,
                       cam_rot_deg=np.degrees(0.002), cam_trans_mm=5.0) if noise else NoiseModel()
    measured_cam = np.stack([perturb_pose(T, np.radians(model.cam_rot_deg), model.cam_trans_mm / 1000, rng)
                             for T in target2cam])
    measured_robot = np.stack([perturb_pose(T, np.radians(model.robot_rot_deg), model.robot_trans_mm / 1000, rng)
                               for T in robot_true])
    return HandEyeProblem(
        mount=mount, base_T_flange=measured_robot, cam_T_target=measured_cam, X_true=X, Y_true=Y,
        true_base_T_flange=robot_true, true_cam_T_target=target2cam, noise=model,
    )


# --------------------------------------------------------------------------- flange (lab 1)


def make_flange(seed, n_points: int = 12, noise_mm: float = 0.0, depth_noise_mm: float = 0.0,
                fixed_orientation: bool = True, marker_offset_m=None,
                n_outliers: int = 0, outlier_mm: float = 12.0) -> FlangeProblem:
    """Eye-on-base flange calibration data (lab 1) with known ``base_T_cam``.

    The flange visits ``n_points`` positions in a 0.3 x 0.3 x 0.2 m box in front of a fixed
    camera, at one orientation (``fixed_orientation=True``, as in the real Aubo capture) or at
    orientations varied by up to 30 deg. The marker sits at ``marker_offset_m`` in the flange
    frame (default: centred). ``noise_mm`` is isotropic per-axis noise on the camera points;
    ``depth_noise_mm`` is extra noise along the camera's z (depth) axis, as with a RealSense.
    """
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    rng = as_generator(seed)
    base_T_cam = _true_base_T_cam_fixed(rng)
    p_marker = np.zeros(3) if marker_offset_m is None else np.asarray(marker_offset_m, float).reshape(3)
    R_down = Rotation.from_euler("x", 180, degrees=True).as_matrix()  # tool pointing down
    poses = []
    for _ in range(n_points):
        R = R_down if fixed_orientation else _random_rotation(rng, 30.0) @ R_down
        t = np.array([rng.uniform(0.3, 0.6), rng.uniform(-0.15, 0.15), rng.uniform(0.2, 0.4)])
        poses.append(geo.make_pose(R, t))
    base_T_flange = np.array(poses)
    marker_base = np.einsum("nij,j->ni", base_T_flange[:, :3, :3], p_marker) + base_T_flange[:, :3, 3]
    cam_points = geo.transform_points(geo.invert(base_T_cam), marker_base)
    cam_points += rng.normal(0.0, noise_mm / 1000.0, cam_points.shape)
    cam_points[:, 2] += rng.normal(0.0, depth_noise_mm / 1000.0, n_points)
    outliers = tuple(sorted(rng.choice(n_points, size=n_outliers, replace=False).tolist()))
    for i in outliers:
        direction = rng.normal(size=3)
        cam_points[i] += direction / np.linalg.norm(direction) * outlier_mm / 1000.0
    return FlangeProblem(
        cam_points=cam_points, base_points=base_T_flange[:, :3, 3].copy(),
        base_T_flange=base_T_flange, base_T_cam_true=base_T_cam, flange_p_marker_true=p_marker,
        noise_mm=noise_mm, depth_noise_mm=depth_noise_mm, outlier_indices=outliers,
    )


# --------------------------------------------------------------------------- three points (lab 4)


def make_three_point(seed, camera_noise_mm: float = 0.0, pointer_noise_mm: float = 0.0,
                     board: Board | None = None, inclined: bool = False) -> ThreePointProblem:
    """Single-shot hand-to-eye calibration from three board corners (lab 4).

    The board lies on the table (or, with ``inclined``, tilted 20-35 deg); the world frame is
    the board's corner frame. The three measured points are the origin corner, the far corner
    along x, and the far corner along y; 12 check points are spread over the board.
    """
    rng = as_generator(seed)
    board = board or Board()
    base_T_cam = _true_base_T_cam_fixed(rng)
    base_T_world = _true_base_T_target(rng)
    if inclined:
        tilt = Rotation.from_euler("x", rng.uniform(20, 35), degrees=True).as_matrix()
        base_T_world[:3, :3] = base_T_world[:3, :3] @ tilt
    cam_T_world = geo.invert(base_T_cam) @ base_T_world
    corners = board.object_points()
    three = np.array([corners[0], corners[board.cols - 1], corners[-board.cols]])
    check_idx = rng.choice(len(corners), size=12, replace=False)
    check = corners[check_idx]

    def measure(T, pts, sigma_mm):
        return geo.transform_points(T, pts) + rng.normal(0.0, sigma_mm / 1000.0, pts.shape)

    return ThreePointProblem(
        cam_points=measure(cam_T_world, three, camera_noise_mm),
        base_points=measure(base_T_world, three, pointer_noise_mm),
        check_cam=measure(cam_T_world, check, camera_noise_mm),
        check_base=measure(base_T_world, check, pointer_noise_mm),
        base_T_cam_true=base_T_cam, base_T_world_true=base_T_world, cam_T_world_true=cam_T_world,
        camera_noise_mm=camera_noise_mm, pointer_noise_mm=pointer_noise_mm,
    )


# --------------------------------------------------------------------------- real-like captures


def make_real_like_hand_eye(seed, n_poses: int = 28, robot_rot_deg: float = 0.03,
                            robot_trans_mm: float = 0.25, robot_gain: float = 0.001,
                            board_scale: float = 0.98, pixel_px: float = 0.07,
                            motion_deg=(15.0, 45.0)) -> HandEyeProblem:
    """An eye-in-hand capture with the errors real ones have (modelled on the KUKA kuka_2 set).

    What the other generators leave out and real captures show: robot pose error as large as
    the camera's (``robot_rot_deg`` / ``robot_trans_mm`` per axis, drawn afresh per view), a
    part of it that repeats with the arm's configuration (``robot_gain``: the controller
    reports every translation from the base and every rotation angle away from the first
    view's orientation ``1 + robot_gain`` times too large, as a slightly miscalibrated arm
    does), and a board printed at ``board_scale`` times its stated square size. Corners get
    ``pixel_px`` of noise per axis; ``cam_T_target`` is solvePnP on the *stated* board, so its
    distances are off by the scale error, as on a real rig.

    The camera is 1920 x 1200 with a 1056 px focal length and the board 24 x 17 inner corners
    of 15 mm (stated), like kuka_2. Returns a ``HandEyeProblem`` whose ``board`` is the stated
    board, ``pixels`` the noisy corners, ``true_base_T_flange`` the poses without robot error.
    """
    import cv2

    rng = as_generator(seed)
    if not 0.5 < board_scale < 2.0:
        raise ValueError(f"board_scale must be a factor near 1 (0.5-2), got {board_scale}")
    stated = Board(cols=24, rows=17, square_m=0.015)
    true_board = Board(cols=24, rows=17, square_m=0.015 * board_scale)
    K = np.array([[1056.0, 0.0, 959.5], [0.0, 1056.0, 599.5], [0.0, 0.0, 1.0]])
    camera = CameraModel(K=K, dist=np.zeros(5), width=1920, height=1200)
    cam_T_target = _sample_views(rng, n_poses, true_board, camera, motion_deg)
    X, Y = _true_flange_T_cam(rng), _true_base_T_target(rng)
    base_T_flange = Y @ geo.invert(cam_T_target) @ geo.invert(X)

    reported = base_T_flange.copy()
    reference = base_T_flange[0, :3, :3]
    for i, T in enumerate(base_T_flange):
        turn = geo.rotvec_from_rotation(T[:3, :3] @ reference.T)
        reported[i, :3, :3] = geo.rotation_from_rotvec((1.0 + robot_gain) * turn) @ reference
        reported[i, :3, 3] = (1.0 + robot_gain) * T[:3, 3]
    reported = np.stack([perturb_pose(T, np.radians(robot_rot_deg), robot_trans_mm / 1000.0, rng)
                         for T in reported])

    object_points = stated.object_points()
    pixels = np.stack([camera.project(T, true_board.object_points()) for T in cam_T_target])
    pixels = pixels + rng.normal(0.0, pixel_px, pixels.shape)
    measured = np.empty_like(cam_T_target)
    for i, px in enumerate(pixels):
        ok, rvec, tvec = cv2.solvePnP(object_points, px, K, camera.dist)
        if not ok:
            raise RuntimeError(f"solvePnP failed on synthetic view {i}")
        measured[i] = geo.make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
    noise = NoiseModel(robot_rot_deg=robot_rot_deg, robot_trans_mm=robot_trans_mm, pixel_px=pixel_px)
    return HandEyeProblem(
        mount="eye_in_hand", base_T_flange=reported, cam_T_target=measured, X_true=X, Y_true=Y,
        true_base_T_flange=base_T_flange, true_cam_T_target=cam_T_target, noise=noise,
        board=stated, camera=camera, pixels=pixels,
    )

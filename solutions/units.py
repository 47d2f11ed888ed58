"""Unit plausibility checks shared by the solvers: millimetres among metres, degrees passed as
radians, normalised image coordinates passed as pixels.

Why these checks exist: every hand-eye and robot-world solver takes robot poses and camera
poses and ties their translations together through the unknown offsets. When one side is in
millimetres and the other in metres (the classic first day on an Aubo or a Cobotta, whose
controllers speak millimetres), no equation fails: the rotation comes out right and the
translation hundreds of metres off, without a word. The checks here are made once, at the
public entry of a solver, and judged from the data themselves (no absolute size is assumed,
so data consistently in millimetres pass; the result is then in millimetres too).

The central check, ``translation_scale``: with the rotations fitted first (units do not affect
them), the translation equations of ``A_i X = Y B_i`` (or of ``A_k X = X B_k`` for motions) are
linear in the unknown translations, so one more unknown, a factor k on the camera side's
translations, costs one more column of the least-squares system:

    R_Ai t_X - t_Y + t_Ai = k R_Y t_Bi             (poses)
    (R_Ak - I) t_X + t_Ak = k R_X t_Bk             (motions)

Consistent data give k = 1 up to noise (the scaled hand-eye calibration of Andreff et al. 2001
estimates the same k for structure-from-motion cameras, whose scale is unknown); a robot in
millimetres and a camera in metres give k = 1000, the reverse 1/1000. k is fitted twice, with
the robot's and with the camera's translations as the response: noise on the side taken as
known biases its fit towards 0 (errors in variables), and the two fits bracket the truth, so a
unit mix is named only when both agree, each beyond the threshold by two of its standard
errors. Data that cannot tell k (a camera turning about its own centre, whose translations are
all noise; very few noisy poses) conclude nothing.

Thresholds (``UNIT_RATIO``, ``SCALE_Z``, ``MAX_SCALE_SE``). Physically, a rigid rig leaves no
room for k far from 1 once the lever arms t_X, t_Y are fitted: a robot's reach is under ~2 m,
a board is 0.05-3 m from the camera, and nothing consistent makes one side's translations 30
times the other's. Measured: on the 62 scenario rows of benchmarks/handeye_accuracy.py (30
seeds each, 1860 correct problems, 5 poses with 1 deg / 5 mm of noise to 40 exact ones, both
mounts, OpenCV's generator with its 0.5-3.5 m boards) the pose form's k stayed within a
factor 8.8 of 1; the motion form's (2480 problems x all pairs / consecutive pairs) went beyond
30 only on 5-pose rows with 1 deg of noise, with a standard error of log k of 3.6 or more,
never within 2 standard errors of the threshold. The three real KUKA captures give
0.96-1.001. A factor of 30 (the geometric middle between 1 and 1000, below centimetres' 100)
is therefore unambiguous. With it, a robot in millimetres was named on 1859 of those 1860
problems in pose form (the miss: 5 poses, 1 deg / 5 mm) and on 1851 of 930 x 2 motion sets
(the misses: 5-10 poses at 1 deg / 5 mm, and consecutive pairs of 10 poses with a 5 deg / 50
mm outlier), where k is too uncertain to call.
"""

from __future__ import annotations

import math

import numpy as np

from robots import geometry as geo

__all__ = [
    "MAX_SCALE_SE",
    "MIN_BOARD_SPREAD_PX",
    "SCALE_Z",
    "UNIT_RATIO",
    "ScaleFit",
    "board_distance_ratio",
    "check_board_distance",
    "check_board_scale",
    "check_motion_units",
    "check_normalised_pixels",
    "check_pose_units",
    "check_radians",
    "describe_scale",
    "motion_translation_scale",
    "translation_scale",
]

#: Two length scales (robot vs camera translations, board vs image) further apart than this
#: factor are not one unit: consistent data stay within a factor 9 (see the module docstring),
#: millimetres against metres give 1000, centimetres 100.
UNIT_RATIO = 30.0
#: The scale is judged only when its relative standard error (that of log k) is below this:
#: with fewer, noisier poses the data cannot tell the scale.
MAX_SCALE_SE = 1.0
#: ... and k must lie beyond ``UNIT_RATIO`` by this many standard errors of log k.
SCALE_Z = 2.0
#: A chessboard's corners spread (RMS about their middle) over fewer pixels than this cannot
#: have been detected in an image: OpenCV's detectors need squares of several pixels. Corners
#: that small are normalised image coordinates (x/z, y/z, of order 0.1-1) passed as pixels.
MIN_BOARD_SPREAD_PX = 3.0
#: ... when the camera matrix is a pixel one (focal length above this, in pixels); with
#: K = identity normalised coordinates are the right input.
_PIXEL_FOCAL_PX = 50.0

# Named units, as factors of a metre: the band in which a scale is attributed to each.
_UNIT_BANDS = ((300.0, 3000.0, "millimetres", 1000), (30.0, 300.0, "centimetres", 100))


def describe_scale(scale: float) -> tuple[str, int] | None:
    """(unit, factor) when ``scale`` (how many times larger one side's lengths are) looks like
    that unit against metres: 300-3000 -> millimetres, 30-300 -> centimetres; else None."""
    for lo, hi, unit, factor in _UNIT_BANDS:
        if lo <= scale < hi:
            return unit, factor
    return None


def _as_translation_name(name: str) -> str:
    return name if name.endswith("]") else f"{name}[:, :3, 3]"


def _unit_message(k: float, se: float, robot_name: str, camera_name: str, robot_scale: float,
                  camera_scale: float, what: str, camera_fix: str | None) -> str:
    """The message for a scale k = robot translations / camera translations far from 1."""
    big, small = (robot_name, camera_name) if k > 1 else (camera_name, robot_name)
    named = describe_scale(k if k > 1 else 1.0 / k)
    numbers = (f"{what} {robot_name} moves {robot_scale:.4g} and {camera_name} {camera_scale:.4g} "
               f"(medians), and the translation equations fit only with {robot_name}'s "
               f"translations {k:.4g} times {camera_name}'s (+-{100 * se:.2g} %), where a "
               "rigid rig needs 1")
    if named is None:
        return (f"{robot_name} and {camera_name} are in different units: {numbers}. Convert "
                "both to metres (cobotlab works in metres and radians)")
    unit, n = named
    if big == camera_name and camera_fix is not None:
        fix = camera_fix.format(n=n)
    else:
        fix = f"divide {_as_translation_name(big)} by {n}"
    return (f"{big} translations look like {unit} and {small} translations like metres: "
            f"{numbers}. {fix[0].upper()}{fix[1:]} (cobotlab works in metres)")


class ScaleFit:
    """The fitted robot-to-camera translation scale, from both regressions (see
    ``mismatched``), with the median translation sizes for messages.

    ``k``: robot translations / camera translations with the robot side as the response
    (camera translations scaled by k); ``k_reverse``: the same ratio with the camera side as the
    response (robot translations scaled by 1/k_reverse); ``se``, ``se_reverse``: their relative
    standard errors (of log k). Each is None when the data cannot determine it.
    """

    __slots__ = ("k", "se", "k_reverse", "se_reverse", "_sizes")

    def __init__(self, k, se, k_reverse, se_reverse, sizes):
        self.k, self.se, self.k_reverse, self.se_reverse = k, se, k_reverse, se_reverse
        self._sizes = sizes  # computed for messages only

    @property
    def robot_scale(self) -> float:
        """Median size of the robot side's translations (motions between views), as given."""
        return self._sizes()[0]

    @property
    def camera_scale(self) -> float:
        """Median size of the camera side's translations (motions between views), as given."""
        return self._sizes()[1]

    @property
    def mismatched(self) -> bool:
        """Whether both regressions put the scale beyond ``UNIT_RATIO`` on the same side, by
        more than ``SCALE_Z`` of their standard errors, each determined within
        ``MAX_SCALE_SE``.

        Noise sits on both sides, and least squares blames the response alone: when one side's
        translations carry nothing but noise (a camera turning about its own centre) the fit
        with the robot as response explains it without the camera (k -> 0, with a tiny
        error) and the reverse fit without the robot (k -> inf). The two regressions bracket
        the true ratio (the errors-in-variables bound), so a unit mix is named only when they
        agree.
        """
        limit = math.log(UNIT_RATIO)
        signs = []
        for k, se in ((self.k, self.se), (self.k_reverse, self.se_reverse)):
            if k is None or not se < MAX_SCALE_SE or abs(math.log(k)) - limit <= SCALE_Z * se:
                return False
            signs.append(k > 1)
        return signs[0] == signs[1]


def _solve_scale(D: np.ndarray, rhs: np.ndarray) -> tuple[float, float] | tuple[None, None]:
    """Least squares D x = rhs with the scale k last; (k, relative standard error of k), or
    (None, None) when k is not determined (zero column, rank deficiency, k <= 0)."""
    norms = np.sqrt(np.einsum("ij,ij->j", D, D))
    if not np.all(np.isfinite(D)) or norms[-1] == 0.0 or not np.any(rhs) or (
            len(rhs) <= D.shape[1]):
        return None, None
    Ds = D / np.where(norms > 0, norms, 1.0)  # columns in metres and in millimetres alike
    G = Ds.T @ Ds  # unit-diagonal: its condition number is that of the scaled system
    if np.linalg.cond(G) > 1e12:
        return None, None
    G_inv = np.linalg.inv(G)
    sol = G_inv @ (Ds.T @ rhs)
    k = sol[-1] / norms[-1]
    if not k > 0:
        return None, None
    r = Ds @ sol - rhs
    var = G_inv[-1, -1] * float(r @ r) / (len(rhs) - D.shape[1])
    return float(k), float(np.sqrt(max(var, 0.0)) / norms[-1] / k)


def _both_ways(lever: np.ndarray, robot: np.ndarray, camera: np.ndarray):
    """(k, se, k_reverse, se_reverse) from ``lever @ t + robot = k camera`` (stacked rows):
    once with the robot translations as the response, once with the camera's."""
    n_rows, n_lever = lever.shape
    D = np.empty((n_rows, n_lever + 1))
    D[:, :n_lever] = lever
    D[:, n_lever] = -camera
    k, se = _solve_scale(D, -robot)
    D[:, n_lever] = robot           # camera = lever t' / k + robot / k: scale 1 / k
    m, se_m = _solve_scale(D, camera)
    return k, se, (None if m is None else 1.0 / m), se_m


def _park_rotation(rvA: np.ndarray, rvB: np.ndarray) -> np.ndarray:
    """R_X with alpha = R_X beta for rotation vectors alpha (robot), beta (camera)."""
    U, _, Vt = np.linalg.svd((rvB.T @ rvA).T)
    if np.linalg.det(U @ Vt) < 0:
        U = U * [1.0, 1.0, -1.0]
    return U @ Vt


def translation_scale(A: np.ndarray, B: np.ndarray, rvA=None, rvB=None) -> ScaleFit:
    """Fit k in ``R_Ai t_X - t_Y + t_Ai = k R_Y t_Bi`` for validated (N, 4, 4) poses of
    ``A_i X = Y B_i`` (A: robot side, B: camera side), both ways; see the module docstring.

    rvA, rvB: optional rotation vectors of motions ``inv(A_i) A_j``, ``inv(B_i) B_j``
    between views (e.g. ``solutions.diagnostics.pose_pair_rotvecs``) for the rotation R_X;
    by default those between consecutive views (n - 1 of them are plenty for a rotation whose
    only use is to bring the camera's translations into the robot's axes).
    """
    if rvA is None or rvB is None:
        i, j = np.arange(len(A) - 1), np.arange(1, len(A))
        rvA = geo.rotvecs_from_rotations(np.swapaxes(A[i, :3, :3], 1, 2) @ A[j, :3, :3])
        rvB = geo.rotvecs_from_rotations(np.swapaxes(B[i, :3, :3], 1, 2) @ B[j, :3, :3])
    RX = _park_rotation(rvA, rvB)
    U, _, Vt = np.linalg.svd(np.sum(A[:, :3, :3] @ RX @ np.swapaxes(B[:, :3, :3], 1, 2), axis=0))
    RY = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0]) @ Vt
    n = len(A)
    lever = np.zeros((n, 3, 6))
    lever[:, :, :3] = A[:, :3, :3]
    lever[:, :, 3:6] = -np.eye(3)
    fits = _both_ways(lever.reshape(-1, 6), A[:, :3, 3].reshape(-1),
                      (B[:, :3, 3] @ RY.T).reshape(-1))
    def sizes():
        # How far the robot's flange and the camera side's pose move between consecutive
        # views (medians), in the units given.
        return tuple(float(np.median(np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)))
                     for T in (A, B))

    return ScaleFit(*fits, sizes)


def motion_translation_scale(A: np.ndarray, B: np.ndarray, rvA: np.ndarray,
                             rvB: np.ndarray) -> ScaleFit:
    """Fit k in ``(R_Ak - I) t_X + t_Ak = k R_X t_Bk`` for validated (M, 4, 4) motions of
    ``A_k X = X B_k`` with rotation vectors rvA, rvB, both ways; see the module docstring."""
    RX = _park_rotation(rvA, rvB)
    fits = _both_ways((A[:, :3, :3] - np.eye(3)).reshape(-1, 3), A[:, :3, 3].reshape(-1),
                      (B[:, :3, 3] @ RX.T).reshape(-1))
    def sizes():
        return tuple(float(np.median(np.linalg.norm(T[:, :3, 3], axis=1))) for T in (A, B))

    return ScaleFit(*fits, sizes)


def check_pose_units(A: np.ndarray, B: np.ndarray, robot_name: str = "base_T_flange",
                     camera_name: str = "cam_T_target", camera_fix: str | None = None,
                     rvA=None, rvB=None) -> ScaleFit:
    """Raise ``ValueError`` naming the likely unit and the fix when the robot poses A and the
    camera poses B of ``A_i X = Y B_i`` (validated, (N, 4, 4)) are in different length units.

    ``camera_fix``: the fix to print when the camera side is the one in millimetres, with
    ``{n}`` for the factor (e.g. "divide board_points by {n}" when B came from solvePnP).
    """
    fit = translation_scale(A, B, rvA, rvB)
    if fit.mismatched:
        raise ValueError(_unit_message(fit.k, fit.se, robot_name, camera_name, fit.robot_scale,
                                       fit.camera_scale, "between consecutive views",
                                       camera_fix))
    return fit


def check_motion_units(A: np.ndarray, B: np.ndarray, rvA: np.ndarray, rvB: np.ndarray,
                       robot_name: str = "A", camera_name: str = "B") -> ScaleFit:
    """``check_pose_units`` for motions A_k, B_k of ``A_k X = X B_k`` (validated)."""
    fit = motion_translation_scale(A, B, rvA, rvB)
    if fit.mismatched:
        raise ValueError(_unit_message(fit.k, fit.se, robot_name, camera_name, fit.robot_scale,
                                       fit.camera_scale, "in a motion", None))
    return fit


def check_radians(value: float, name: str) -> float:
    """``value`` (an angle or an angular noise level in radians) as a float; ``ValueError`` when
    it exceeds pi, which no angle in radians needs: it was given in degrees; NaN raises too."""
    if math.isnan(value):
        raise ValueError(f"{name} is NaN; give an angle in radians")
    if value > math.pi:
        raise ValueError(
            f"{name} = {value:g} rad is more than pi: it looks like degrees; pass "
            f"np.radians({value:g}) = {math.radians(value):.4g} (cobotlab works in radians)")
    return value


def _view_spreads(points: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """RMS distance of each view's valid rows of ``points`` (n, N, d) from their mean (n,)."""
    w = valid[..., None].astype(float)
    count = np.maximum(valid.sum(axis=1), 1)[:, None]
    mean = np.sum(np.where(w > 0, points, 0.0), axis=1) / count
    d2 = np.sum(np.where(w > 0, points - mean[:, None, :], 0.0) ** 2, axis=(1, 2))
    return np.sqrt(d2 / count[:, 0])


def check_normalised_pixels(pixels: np.ndarray, valid: np.ndarray, K: np.ndarray,
                            name: str = "pixels") -> np.ndarray:
    """Each view's corner spread in pixels (n,); ``ValueError`` when the corners are
    normalised image coordinates (x/z, y/z) passed with a pixel camera matrix K.

    ``pixels`` (n, N, 2) with ``valid`` (n, N) marking the corners seen (at least 4 per
    view that counts). A board whose corners spread over fewer than ``MIN_BOARD_SPREAD_PX``
    pixels cannot have been detected, while normalised coordinates spread over 0.05-1.
    """
    spread = _view_spreads(pixels, valid)
    views = valid.sum(axis=1) >= 4
    focal = math.sqrt(abs(K[0, 0] * K[1, 1]))
    if views.any() and focal > _PIXEL_FOCAL_PX:
        median = float(np.median(spread[views]))
        if median < MIN_BOARD_SPREAD_PX:
            raise ValueError(
                f"{name} look like normalised image coordinates (x/z, y/z), not pixels: the "
                f"corners of a view spread over {median:.3g} px (median RMS about their middle), "
                f"far too small to have been detected, while K has a focal length of "
                f"{focal:.4g} px. Pass the detected pixel coordinates, or convert normalised "
                "ones with pixels = (K @ [x, y, 1])[:2] (cv2.projectPoints); or pass K = "
                "np.eye(3) and dist = None to work in normalised coordinates")
    return spread


def board_distance_ratio(board_points: np.ndarray, pixels: np.ndarray, valid: np.ndarray,
                         K: np.ndarray, cam_T_target_predicted: np.ndarray):
    """(median ratio, median predicted distance, median imaged distance) of the camera-to-board
    distance the poses predict over the one the board's apparent size gives (see
    ``check_board_distance``), over the views with at least 4 corners; None without any."""
    views = np.flatnonzero(valid.sum(axis=1) >= 4)
    if len(views) == 0:
        return None
    px_spread = _view_spreads(pixels[views], valid[views])
    board = np.broadcast_to(board_points, (len(views),) + board_points.shape)
    board_spread = _view_spreads(board, valid[views])
    ok = (px_spread > 0) & (board_spread > 0)
    if not ok.any():
        return None
    # The board's origin, not its middle: where the middle lies is in the board's units,
    # which are the ones in question. The origin is a corner of the board, within about a
    # board's width (at most ~1.5 viewing distances, for the board to fit in the image) of the
    # corners seen, so the two distances differ by a factor of at most ~3.
    predicted = np.linalg.norm(cam_T_target_predicted[views][ok][:, :3, 3], axis=1)
    imaged = math.sqrt(abs(K[0, 0] * K[1, 1])) * board_spread[ok] / px_spread[ok]
    return (float(np.median(predicted / imaged)), float(np.median(predicted)),
            float(np.median(imaged)))


def check_board_distance(board_points: np.ndarray, pixels: np.ndarray, valid: np.ndarray,
                         K: np.ndarray, cam_T_target_predicted: np.ndarray,
                         board_name: str = "board_points",
                         pose_names: str = "base_T_flange, X0 and Y0") -> None:
    """Raise ``ValueError`` when the board's size and its distance from the camera are in
    different units.

    The corners' spread in the image gives each view's distance in the board's units:
    ``f * spread_board / spread_px`` (pinhole; a tilted board looks smaller, by at most a
    factor of about 1.4 over its two axes up to 80 degrees of tilt). The poses predict the
    distance of the board's origin in their units (``cam_T_target_predicted`` (n, 4, 4)), a
    corner within a factor ~3 of the corners seen. The two agree within a few times on any
    consistent capture with a rough start (1.02-1.35 on the three real KUKA captures, from the
    refined start or with X0 = identity; 0.85-1.08 on synthetic ones), so a median ratio beyond
    ``UNIT_RATIO`` is a unit mix: 1000 when the robot poses (or the start) are in millimetres,
    1/1000 when the board is.
    """
    found = board_distance_ratio(board_points, pixels, valid, K, cam_T_target_predicted)
    if found is None:
        return
    ratio, predicted, imaged = found
    if not (ratio > 0 and math.isfinite(ratio)) or abs(math.log(ratio)) <= math.log(UNIT_RATIO):
        return
    numbers = (f"the poses put the board {predicted:.4g} from the camera (median), but its "
               f"size in {board_name} and in the image say {imaged:.4g}: a factor {ratio:.4g}")
    named = describe_scale(ratio if ratio > 1 else 1.0 / ratio)
    if named is None:
        raise ValueError(f"{board_name} and {pose_names} are in different units: {numbers}. "
                         "Convert both to metres (or check that X0 and Y0 belong to these poses)")
    unit, n = named
    if ratio > 1:
        raise ValueError(
            f"{pose_names} translations look like {unit} and {board_name} like metres: "
            f"{numbers}. Divide base_T_flange[:, :3, 3] (and X0, Y0 translations) by {n} "
            "(cobotlab works in metres)")
    raise ValueError(
        f"{board_name} look like {unit} and {pose_names} like metres: {numbers}. Divide "
        f"{board_name} by {n} (cobotlab works in metres)")


def check_board_scale(scale: float, board_name: str = "board_points") -> None:
    """Raise ``ValueError`` when a fitted board scale (the factor on the stated corner
    positions that fits the images and the robot best) is further than ``UNIT_RATIO`` from 1:
    a printed board is off by a few per cent (a printer's scaling, at most a factor ~1.4 for
    A3 printed on A4), never by 30 times; 1/1000 is a board given in millimetres."""
    if scale > 0 and abs(math.log(scale)) <= math.log(UNIT_RATIO):
        return
    named = describe_scale(1.0 / scale) if scale > 0 else None
    if named is None:
        raise ValueError(
            f"the board's fitted scale is {scale:.4g}, where a printed board is within a few per "
            f"cent of 1: {board_name} are not in the units of the robot poses (metres), or do "
            "not describe this board")
    unit, n = named
    raise ValueError(
        f"{board_name} look like {unit}: the board's fitted scale is {scale:.4g} (a printed "
        f"board is within a few per cent of 1). Divide {board_name} by {n} (cobotlab works in "
        "metres)")

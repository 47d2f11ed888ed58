"""Checks that hand-eye data mean what a solver assumes, shared by every solver and the CLI.

Two kinds of check live here, both judged from the data themselves:

* motion size and variety (``screen_motions``): motions that rotate by less than
  ``MIN_MOTION_DEG`` have axes made of noise, and motions all about one axis leave the rotation
  about it unobservable. ``solutions.handeye`` applies it to its motions and
  ``solutions.robot_world`` to the motions between its poses, so both refuse the same data.
* conventions and pairing (``diagnose_ax_yb``, ``check_hand_eye_poses``, ``check_ax_yb``): the
  commonest user errors -- robot poses inverted (OpenCV's base2gripper passed as
  ``base_T_flange``), camera poses inverted (cam2target passed as ``cam_T_target``), the wrong
  mount, or the two lists not paired view by view -- give a wrong X with large residuals, not
  an error, in every solver. They are told apart by two invariants of ``A_i X = Y B_i``:

  1. the robot motion between views i and j (``inv(A_i) A_j``) and the camera motion
     (``inv(B_i) B_j``) are conjugate, so they rotate by the same angle whatever X, Y and
     whichever side is inverted (inverting poses conjugates the motion: same angle). The
     median mismatch of these angles over all pairs of views measures the rotation noise, and
     a mismatch of many degrees means the views are not paired;
  2. with the right convention the best rotation-only fit leaves per-view residuals of the
     same size as that noise (about 1.6 times the median angle mismatch for isotropic noise;
     see ``INCONSISTENT_RATIO`` for the range measured at the benchmark noise levels).
     Inverting one side gives residuals of tens to hundreds of times the noise.

  Inverting the robot poses, inverting the camera poses and switching the mount are one and
  the same change of the equations (``inv(A) X = Y B`` is ``A Y' = X' B`` rearranged), so the
  data cannot say which of the three happened; the message lists them, with a hint from the
  camera poses (a board in front of the camera has z > 0 in ``cam_T_target``).

A third, small kind: the argument checks every solver module shares (``check_choice``,
``check_flag``, ``check_number``, ``as_array``, ``describe``), so that a refused argument is
named with what was expected and what came (None, a string, a shape and dtype), in the same
words everywhere.

Frames and names follow the project conventions (``a_T_b`` maps b-coordinates into a;
metres, radians inside, degrees in messages). This module imports only ``robots.geometry`` and
``solutions.units``, so every solver module can use it without an import circle.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from robots import geometry as geo
from solutions import units

__all__ = [
    "INCONSISTENT_RATIO",
    "WARN_RATIO",
    "MAX_PAIRING_MISMATCH_DEG",
    "MIN_AXIS_SPREAD_DEG",
    "MIN_MOTION_DEG",
    "PairingDiagnosis",
    "as_array",
    "axis_spread_deg",
    "check_ax_yb",
    "check_choice",
    "check_flag",
    "check_hand_eye_poses",
    "check_motion_pairing",
    "check_motion_residuals",
    "check_number",
    "describe",
    "diagnose_ax_yb",
    "diagnose_hand_eye",
    "mounts_indistinguishable",
    "pose_pair_rotvecs",
    "screen_motions",
]

#: Motions rotating less than this (degrees) have rotation axes dominated by noise.
MIN_MOTION_DEG = 1.0
#: The motions' rotation axes must spread over at least this angle (degrees), else the rotation
#: of X about their common axis (and its translation along it) cannot be observed.
MIN_AXIS_SPREAD_DEG = 2.0
#: A fit is inconsistent with the data's own noise when its median per-view rotation residual
#: exceeds this many times the median robot/camera motion-angle mismatch. On the synthetic rows
#: of benchmarks/handeye_accuracy.py (5-40 views, 1600 correct problems) correct data stay
#: below 4, except 5 views with a 5 deg outlier (up to 17, where the inverted convention fits
#: far worse, so nothing is named); an inverted side named as such gives 6-2000, median 98.
INCONSISTENT_RATIO = 6.0
#: Without a convention that fits better, the data are only reported as inconsistent (a
#: warning) beyond this ratio, above the 17 of correct data.
WARN_RATIO = 25.0
#: ... and the other convention is named only when it fits at least this many times better.
BETTER_FACTOR = 4.0
#: Motion-level version of WARN_RATIO (per-motion residual over the median |angle(A_k) -
#: angle(B_k)|): correct motions give at most 33 (5 poses with a 5 deg outlier, non-robust
#: Park), motions built from inverted poses 2-250, typically 20-200. Motions alone cannot show
#: which convention would fit, so this only warns.
MOTION_WARN_RATIO = 40.0
#: Robot and camera motions between the same two views that differ in angle by more than this
#: (degrees, median over all pairs of views) cannot come from one capture: the lists are not
#: paired. Correct data at 1 deg of camera noise per axis give at most 2 deg.
MAX_PAIRING_MISMATCH_DEG = 5.0
# Noise below this (degrees) is rounding: a floor for the ratios on exact data.
_NOISE_FLOOR_DEG = 0.01
# The search for a better pairing runs only when the motion angles disagree by more than this
# (degrees, median): shuffled or shifted synthetic captures show 1.7 deg and more, and correct
# captures with pose noise under about 0.3 deg never need the search's few milliseconds
# (it runs too when the fit is inconsistent: a partly shuffled capture of precise poses).
_PAIRING_SEARCH_DEG = 0.3


# --------------------------------------------------------------------------- arguments
# Shared by the solver modules so that every refused argument is named with what was expected
# and what came, in the same words; validation happens once, at the public entry.


def describe(value) -> str:
    """A short account of what a caller passed, for error messages: None, a string, an array's
    shape and dtype, a list's length, or the type."""
    if value is None:
        return "None"
    if isinstance(value, (str, bytes)):
        text = repr(value)
        return f"the string {text if len(text) <= 40 else text[:37] + '...'}"
    if isinstance(value, (bool, np.bool_)):
        return f"the boolean {bool(value)}"
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    if isinstance(value, numbers.Number):
        return f"the number {value!r}"
    if isinstance(value, (list, tuple)):
        return f"a {type(value).__name__} of {len(value)} item{'s' if len(value) != 1 else ''}"
    kind = type(value)
    if kind.__module__ == "builtins":
        return f"{'an' if kind.__name__[0] in 'aeiou' else 'a'} {kind.__name__}"
    return f"a {kind.__module__}.{kind.__qualname__} object"


def check_choice(value, name: str, choices, label: str | None = None):
    """``value`` if it is one of ``choices`` (strings, or None), else ``ValueError`` naming
    ``name``, the choices and what came (``label`` names an unknown string, e.g. "unknown
    hand-eye method 'horaud'")."""
    for choice in choices:
        if value is choice or (isinstance(value, str) and isinstance(choice, str)
                               and value == choice):
            return value
    if isinstance(value, str) and label:
        raise ValueError(f"unknown {label} {value!r}: {name} must be one of {tuple(choices)}")
    raise ValueError(f"{name} must be one of {tuple(choices)}, got {describe(value)}")


def check_flag(value, name: str, allow_none: bool = False):
    """``value`` as a bool (True, False, numpy booleans, 0 or 1; also None if ``allow_none``),
    else ``ValueError``: a string such as "no" would otherwise count as True."""
    if value is None and allow_none:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and value in (0, 1):
        return bool(value)
    expected = "True, False or None" if allow_none else "True or False"
    raise ValueError(f"{name} must be {expected}, got {describe(value)}")


def check_number(value, name: str, *, minimum: float | None = None, above: float | None = None,
                 integer: bool = False, unit: str = "", allow_none: bool = False):
    """``value`` as a finite float (an int if ``integer``), at least ``minimum`` or strictly
    above ``above``; ``ValueError`` naming ``name``, the expectation and what came otherwise.
    Numpy scalars and 0-d arrays count as numbers; booleans and strings do not."""
    if value is None and allow_none:
        return None
    what = "an integer" if integer else "a finite number"
    bound = ""
    if minimum is not None:
        bound = f" >= {minimum:g}"
    elif above is not None:
        bound = f" > {above:g}"
    expected = f"{name} must be {what}{bound}{' (' + unit + ')' if unit else ''}"
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{expected}, got {describe(value)}")
    if integer:
        if not (isinstance(value, numbers.Integral) or float(value).is_integer()):
            raise ValueError(f"{expected}, got {describe(value)}")
        out = int(value)
    else:
        out = float(value)
    if not np.isfinite(out) or (minimum is not None and out < minimum) or (
            above is not None and not out > above):
        raise ValueError(f"{expected}, got {value!r}")
    return out


def as_array(value, name: str, expected: str) -> np.ndarray:
    """``value`` as a float64 array (lists, tuples and integer arrays welcome); ``ValueError``
    naming ``name``, ``expected`` (e.g. "an (N, 3) array of points in metres") and what came
    for None, strings, dicts and other non-numeric input."""
    if value is None or isinstance(value, (str, bytes, dict)):
        raise ValueError(f"{name} must be {expected}, got {describe(value)}")
    try:
        return geo.as_real_array(value, name)
    except ValueError as err:
        if "complex" in str(err):
            raise
        raise ValueError(f"{name} must be {expected}, got {describe(value)} that is not "
                         "numeric (or whose rows differ in length)") from None


# --------------------------------------------------------------------------- motion screening


def axis_spread_deg(rotvecs: np.ndarray) -> float:
    """How far rotation axes spread from a common line, degrees (0 when all parallel).

    Uses the angle-weighted axes (rotation vectors): for two equally weighted axes at angle
    phi, the ratio s2/s1 of their stack's singular values is tan(phi/2); the signs of the axes
    do not matter to singular values.
    """
    if len(rotvecs) < 2:
        return 0.0
    s = np.linalg.svd(rotvecs, compute_uv=False)
    return float(np.degrees(2.0 * np.arctan2(s[1], s[0])))


def _labels(ks, pairs, limit: int = 8) -> str:
    ks = list(ks)

    def one(k):
        return f"{k} (poses {pairs[k][0]}->{pairs[k][1]})" if pairs is not None else str(k)

    text = ", ".join(one(k) for k in ks[:limit])
    return text + (f", ... ({len(ks)} in all)" if len(ks) > limit else "")


def screen_motions(rvA: np.ndarray, rvB: np.ndarray, pairs=None, *, what: str = "motions",
                   warn_dropped: bool = True) -> np.ndarray:
    """Indices of the motions a solver can use; ``ValueError`` when too few remain.

    rvA, rvB: (M, 3) rotation vectors (rad) of the robot-side and camera-side motions.
    pairs: optional (M, 2) pose indices of each motion, to name them in messages. Motions
    rotating less than ``MIN_MOTION_DEG`` on either side are dropped (with a warning when
    ``warn_dropped``); at least 2 must remain, and the remaining axes must spread over
    ``MIN_AXIS_SPREAD_DEG`` on both sides.
    """
    M = len(rvA)
    angle_deg = np.degrees(np.minimum(np.linalg.norm(rvA, axis=1), np.linalg.norm(rvB, axis=1)))
    small = np.flatnonzero(angle_deg < MIN_MOTION_DEG)
    keep = np.flatnonzero(angle_deg >= MIN_MOTION_DEG)
    if len(keep) < 2:
        raise ValueError(
            f"{len(small)} of {M} {what} rotate less than {MIN_MOTION_DEG} deg "
            f"(largest {angle_deg.max():.3g} deg): {what} {_labels(small, pairs)}. Pure "
            "translations or near-identical orientations cannot determine the rotation of X; "
            "capture poses that rotate the flange 15-45 degrees about different axes"
        )
    if len(small) and warn_dropped:
        geo.warn_caller(
            f"dropped {len(small)} of {M} {what} that rotate less than "
            f"{MIN_MOTION_DEG} deg (their rotation axes are noise): {what} "
            f"{_labels(small, pairs)}"
        )
    for side, rv in (("robot (A)", rvA[keep]), ("camera (B)", rvB[keep])):
        spread_deg = axis_spread_deg(rv)
        if spread_deg < MIN_AXIS_SPREAD_DEG:
            axis = np.linalg.svd(rv)[2][0]
            raise ValueError(
                f"all rotation axes are parallel: the {side} {what} all turn about "
                f"{np.round(axis, 3)} (axes spread {spread_deg:.2g} deg < "
                f"{MIN_AXIS_SPREAD_DEG} deg), so the rotation of X about that axis and its "
                "translation along it are unobservable; rotate the flange about at least two "
                "different axes"
            )
    return keep


def _log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad) of a stack of rotations: the angle by atan2 of the
    antisymmetric part and the trace (accurate at every angle), the axis from the
    antisymmetric part (loses precision only near 180 degrees, harmless for these checks)."""
    v = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0],
                        R[:, 1, 0] - R[:, 0, 1]], axis=1)
    sin = np.linalg.norm(v, axis=1)
    angle = np.arctan2(sin, 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0))
    return v * (angle / np.maximum(sin, 1e-300))[:, None]


def pose_pair_rotvecs(A: np.ndarray, B: np.ndarray):
    """Rotation vectors (rad) of the robot motions ``inv(A_i) A_j`` and camera motions
    ``inv(B_i) B_j`` over all pairs i < j of (N, 4, 4) poses, and the (M, 2) pairs."""
    i, j = np.triu_indices(len(A), k=1)
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    rvA = _log_so3(np.swapaxes(RA[i], 1, 2) @ RA[j])
    rvB = _log_so3(np.swapaxes(RB[i], 1, 2) @ RB[j])
    return rvA, rvB, np.stack([i, j], axis=1)


# --------------------------------------------------------------------------- conventions


@dataclass(frozen=True)
class PairingDiagnosis:
    """How well poses ``A_i``, ``B_i`` fit ``A_i X = Y B_i``, as given and with B inverted.

    angle_mismatch_deg: median over pairs of views of |angle(inv(A_i) A_j) -
    angle(inv(B_i) B_j)|, the rotation noise the data show (invariant to X, Y and to
    inverting either side). residual_deg / flipped_residual_deg: median per-view residual of
    the best rotation-only fit, as given and with every B_i inverted. ratio / flipped_ratio:
    those residuals over the angle mismatch (floored at 0.01 deg). reorder: when the angles say
    the lists are not paired, the order of B that pairs them best (B[reorder[i]] goes with
    A[i]) and reordered_mismatch_deg its angle mismatch, else None. verdict: "ok", "flipped"
    (B inverted fits far better), "pairing" (not paired view by view) or "inconsistent"
    (neither fits; cause unknown).
    """

    angle_mismatch_deg: float
    residual_deg: float
    flipped_residual_deg: float
    ratio: float
    flipped_ratio: float
    reorder: np.ndarray | None
    reordered_mismatch_deg: float | None
    verdict: str


def _rotation_fit(RA: np.ndarray, RB: np.ndarray, rvA: np.ndarray, rvB: np.ndarray):
    """Per-view residual angles (deg) of the best rotations R_X, R_Y in R_Ai R_X = R_Y R_Bi.

    Starts from Park and Martin's closed form on the motions (alpha = R_X beta for their
    rotation vectors), then alternates chordal means for R_Y and R_X, twice, the second time
    with Cauchy weights at 3 x the median residual, so one bad view (a mis-detected board)
    cannot inflate them all.
    """
    RX = _nearest_rotation((rvB.T @ rvA).T)
    RAt, RBt = np.swapaxes(RA, 1, 2), np.swapaxes(RB, 1, 2)
    w = np.ones(len(RA))
    for _ in range(2):
        RY = _nearest_rotation(np.einsum("n,nij->ij", w, RA @ RX @ RBt))
        RX = _nearest_rotation(np.einsum("n,nij->ij", w, RAt @ RY @ RB))
        RY = _nearest_rotation(np.einsum("n,nij->ij", w, RA @ RX @ RBt))
        res = np.degrees(np.linalg.norm(_log_so3(RY.T @ RA @ RX @ RBt), axis=1))
        w = 1.0 / (1.0 + (res / (3.0 * max(float(np.median(res)), 1e-12))) ** 2)
    return res


def _nearest_rotation(M: np.ndarray) -> np.ndarray:
    """``geo.project_to_so3`` without its input checks, for the inner loop of
    ``_rotation_fit`` (its inputs are sums of rotations, finite by construction)."""
    U, _, Vt = np.linalg.svd(M)
    if np.linalg.det(U @ Vt) < 0:
        U = U * [1.0, 1.0, -1.0]
    return U @ Vt


def _pairing_order(rvA: np.ndarray, rvB: np.ndarray, n: int) -> np.ndarray:
    """The order of B's views that best matches A's by the angles between views.

    Each view's signature is the sorted list of its rotation angles to all other views (the
    same for a robot pose and its camera pose, whatever X and the pairing); the Hungarian
    algorithm pairs the signatures.
    """
    i, j = np.triu_indices(n, k=1)
    angA = np.zeros((n, n))
    angB = np.zeros((n, n))
    angA[i, j] = angA[j, i] = np.linalg.norm(rvA, axis=1)
    angB[i, j] = angB[j, i] = np.linalg.norm(rvB, axis=1)
    sigA, sigB = np.sort(angA, axis=1), np.sort(angB, axis=1)
    cost = np.abs(sigA[:, None, :] - sigB[None, :, :]).sum(axis=2)
    _, order = linear_sum_assignment(cost)
    return order


def _mismatch_deg(A: np.ndarray, B: np.ndarray) -> float:
    rvA, rvB, _ = pose_pair_rotvecs(A, B)
    return float(np.degrees(np.median(np.abs(np.linalg.norm(rvA, axis=1)
                                             - np.linalg.norm(rvB, axis=1)))))


def diagnose_ax_yb(A: np.ndarray, B: np.ndarray, full: bool = False) -> PairingDiagnosis:
    """Diagnose validated (N, 4, 4) poses of ``A_i X = Y B_i`` (see the module docstring).

    Costs a rotation-only fit (a few 3x3 SVDs) and, on data that fit, nothing more: the fit
    with B inverted is made only when the data as given do not fit, or when ``full`` (then
    ``flipped_residual_deg`` is always filled in, else it may be NaN); the search for a
    better pairing only when the motion angles disagree.
    """
    rvA, rvB, _ = pose_pair_rotvecs(A, B)
    mismatch = float(np.degrees(np.median(np.abs(np.linalg.norm(rvA, axis=1)
                                                 - np.linalg.norm(rvB, axis=1)))))
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    residual = float(np.median(_rotation_fit(RA, RB, rvA, rvB)))
    floor = max(mismatch, _NOISE_FLOOR_DEG)
    ratio = residual / floor
    flipped = np.nan
    if full or ratio > INCONSISTENT_RATIO:
        _, rvBi, _ = pose_pair_rotvecs(A, geo.invert(B))
        flipped = float(np.median(_rotation_fit(RA, np.swapaxes(RB, 1, 2), rvA, rvBi)))

    reorder, reordered = None, None
    if (mismatch > _PAIRING_SEARCH_DEG or ratio > INCONSISTENT_RATIO) and len(A) >= 4:
        order = _pairing_order(rvA, rvB, len(A))
        if np.any(order != np.arange(len(A))):
            reordered = _mismatch_deg(A, B[order])
            if reordered * BETTER_FACTOR < mismatch:
                reorder = order
            else:
                reordered = None

    if reorder is not None or mismatch > MAX_PAIRING_MISMATCH_DEG:
        verdict = "pairing"
    elif ratio > INCONSISTENT_RATIO and flipped * BETTER_FACTOR < residual:
        verdict = "flipped"
    elif ratio > WARN_RATIO:
        verdict = "inconsistent"
    else:
        verdict = "ok"
    return PairingDiagnosis(mismatch, residual, flipped, ratio, flipped / floor, reorder,
                            reordered, verdict)


def _to_ax_yb(F: np.ndarray, C: np.ndarray, mount: str):
    """Hand-eye poses in the ``A_i X = Y B_i`` form: A = base_T_flange and B = target_T_cam
    (eye_in_hand) or cam_T_target (eye_to_hand)."""
    check_choice(mount, "mount", ("eye_in_hand", "eye_to_hand"))
    return F, (geo.invert(C) if mount == "eye_in_hand" else C)


def diagnose_hand_eye(base_T_flange, cam_T_target, mount: str = "eye_in_hand",
                      full: bool = False) -> PairingDiagnosis:
    """``diagnose_ax_yb`` for hand-eye poses (OpenCV's gripper2base and target2cam) and a
    mount; "flipped" then means the poses fit the other mount, or one side inverted."""
    F = geo.as_poses(base_T_flange, "base_T_flange")
    C = geo.as_poses(cam_T_target, "cam_T_target")
    full = check_flag(full, "full")
    if len(F) != len(C) or len(F) < 3:
        raise ValueError(f"need the same number (>= 3) of base_T_flange and cam_T_target "
                         f"poses, got {len(F)} and {len(C)}")
    return diagnose_ax_yb(*_to_ax_yb(F, C, mount), full=full)


def mounts_indistinguishable(d: PairingDiagnosis) -> bool:
    """True when the poses fit the other mount (equivalently: one side inverted) about as well
    as the given one, from a ``diagnose_*(..., full=True)`` diagnosis.

    Views that only tilt the camera about axes in the board's plane (a cone of views aimed at
    one point, no roll about the viewing axis) fit both mounts exactly: for any rotation R
    about an axis in that plane, R Rz(180 deg) R = Rz(180 deg), so a board-flipped solution of
    the other mount explains them too, and the result rests on the mount being right.
    """
    return d.flipped_residual_deg < 2.0 * max(d.residual_deg, _NOISE_FLOOR_DEG)


def _order_text(order: np.ndarray, a_name: str, b_name: str) -> str:
    n = len(order)
    for k in range(1, n):
        if np.array_equal(order, np.roll(np.arange(n), -k)):
            shift = k if k <= n // 2 else k - n
            return (f"shifted by {abs(shift)} view{'s' if abs(shift) > 1 else ''}: "
                    f"{a_name}[i] goes with {b_name}[i {'+' if shift > 0 else '-'} {abs(shift)}] "
                    "(one list has an extra or a missing view at its start or end)")
    moved = np.flatnonzero(order != np.arange(n))
    return f"reordered ({len(moved)} of {n} entries are out of place)"


def _pairing_message(d: PairingDiagnosis, a_name: str, b_name: str) -> str:
    head = (f"{a_name}[i] and {b_name}[i] do not come from the same view: the robot and camera "
            "motions between two views must rotate by the same angle, but here they differ by "
            f"{d.angle_mismatch_deg:.3g} deg (median over all pairs of views; measurement "
            "noise gives well under 2 deg). ")
    if d.reorder is not None:
        head += (f"Pairing {a_name}[i] with {b_name}[order[i]] for order = "
                 f"{d.reorder.tolist()} makes them agree to {d.reordered_mismatch_deg:.3g} deg: "
                 f"{b_name} looks {_order_text(d.reorder, a_name, b_name)}. ")
    return head + ("Check how the images were sorted (e.g. 'img10' before 'img2'), and that a "
                   "view whose board was not found was dropped from both lists")


def _flip_hint(C: np.ndarray | None) -> str:
    """Which inversion the camera poses point at: a board in front of the camera has z > 0."""
    if C is None:
        return ""
    z_given, z_inv = C[:, 2, 3], geo.invert(C)[:, 2, 3]
    if np.all(z_given > 0) and not np.all(z_inv > 0):
        return (" Every cam_T_target puts the board in front of the camera (z > 0), so the "
                "camera poses are probably right: look at the robot poses or the mount first.")
    if np.all(z_inv > 0) and not np.all(z_given > 0):
        return (" cam_T_target puts the board behind the camera (z < 0) in some views, and its "
                "inverse in front in all: the camera poses are most likely inverted.")
    return ""


def _numbers(d: PairingDiagnosis) -> str:
    return (f"the best rotation leaves {d.residual_deg:.3g} deg per view (median), "
            f"{d.ratio:.0f} times what the noise in these poses explains (robot and camera "
            f"motion angles agree to {d.angle_mismatch_deg:.3g} deg)")


def check_hand_eye_poses(F: np.ndarray, C: np.ndarray, mount: str,
                         camera_name: str = "cam_T_target",
                         camera_fix: str | None = None) -> PairingDiagnosis:
    """Raise ``ValueError`` (or warn) when validated robot and camera poses do not fit
    ``mount`` (see the module docstring), or are in different length units
    (``solutions.units.check_pose_units``, which ``camera_name`` and ``camera_fix`` go to);
    returns the diagnosis for reports."""
    d = diagnose_ax_yb(*_to_ax_yb(F, C, mount))
    other = "eye_to_hand" if mount == "eye_in_hand" else "eye_in_hand"
    where = ("the camera is fixed in the cell and the board rides on the flange"
             if other == "eye_to_hand" else "the camera rides on the flange")
    if d.verdict == "pairing":
        raise ValueError(_pairing_message(d, "base_T_flange", "cam_T_target"))
    if d.verdict == "flipped":
        raise ValueError(
            f"base_T_flange and cam_T_target do not fit an {mount} calibration: {_numbers(d)}. "
            f"With one side inverted they fit to {d.flipped_residual_deg:.3g} deg. Three "
            "mistakes give exactly this and the data cannot tell them apart: (1) robot poses "
            "given as flange_T_base (OpenCV's base2gripper): pass "
            "robots.geometry.invert(base_T_flange); (2) camera poses given as target_T_cam "
            "(cam2target): pass invert(cam_T_target); (3) the wrong mount: if "
            f"{where}, call calibrate_{other}.{_flip_hint(C)}")
    # Millimetres among metres leave the rotations (all the checks above look at) intact and
    # the translations hundreds of metres off: the scale of the two sides' translations.
    units.check_pose_units(*_to_ax_yb(F, C, mount), "base_T_flange", camera_name, camera_fix)
    if d.verdict == "inconsistent":
        geo.warn_caller(
            f"base_T_flange and cam_T_target fit an {mount} calibration poorly: {_numbers(d)}. "
            "Inverting either side does not help. Check for many bad views, a board that moved "
            "during the capture, or robot and camera readings taken at different moments")
    return d


def check_ax_yb(A: np.ndarray, B: np.ndarray, a_name: str = "A",
                b_name: str = "B") -> PairingDiagnosis:
    """``check_hand_eye_poses`` for the ``A_i X = Y B_i`` form of ``solutions.robot_world``."""
    d = diagnose_ax_yb(A, B)
    if d.verdict == "pairing":
        raise ValueError(_pairing_message(d, a_name, b_name))
    if d.verdict == "flipped":
        raise ValueError(
            f"{a_name} and {b_name} do not fit A_i X = Y B_i: {_numbers(d)}. With {b_name} "
            f"inverted they fit to {d.flipped_residual_deg:.3g} deg. For eye-in-hand data "
            f"{a_name} = base_T_flange and {b_name} = target_T_cam = invert(cam_T_target) "
            "(the inverse of what solvePnP gives); for eye-to-hand {b_name} = cam_T_target. "
            f"Inverting {a_name} instead (flange_T_base given) has the same effect: invert "
            "whichever of the two is in the wrong convention")
    units.check_pose_units(A, B, a_name, b_name)
    if d.verdict == "inconsistent":
        geo.warn_caller(
            f"{a_name} and {b_name} fit A_i X = Y B_i poorly: {_numbers(d)}; inverting either "
            "side does not help. Check for many bad views or poses recorded at different "
            "moments")
    return d


def check_motion_pairing(rvA: np.ndarray, rvB: np.ndarray, pairs=None) -> None:
    """Raise ``ValueError`` when motions A[k] and B[k] rotate by clearly different angles:
    they cannot be the same motion seen by the robot and by the camera."""
    diff = np.degrees(np.abs(np.linalg.norm(rvA, axis=1) - np.linalg.norm(rvB, axis=1)))
    if len(diff) and float(np.median(diff)) > MAX_PAIRING_MISMATCH_DEG:
        worst = np.argsort(diff)[::-1][:5]
        raise ValueError(
            f"A[k] and B[k] are not the same motion: a robot motion and the camera motion it "
            f"causes rotate by the same angle, but these differ by {np.median(diff):.3g} deg "
            f"(median; largest at motions {_labels(worst, pairs)}). Build both from poses "
            "recorded at the same views, in the same order (solutions.handeye.hand_eye_motions)")


def check_motion_residuals(RA: np.ndarray, RB: np.ndarray, X: np.ndarray) -> float:
    """Warn when X leaves motion residuals far beyond the noise the motions show.

    RA, RB: (M, 3, 3) rotations of the motions with ``A_k X = X B_k``; X: the solution (4, 4).
    Returns the ratio of the median residual angle of ``R_A R_X = R_X R_B`` to the median
    mismatch |angle(A_k) - angle(B_k)| (floored at 0.01 deg).
    """
    angle = np.linalg.norm
    R = X[:3, :3]
    mismatch = np.degrees(np.abs(angle(_log_so3(RA), axis=1) - angle(_log_so3(RB), axis=1)))
    residual = np.degrees(angle(_log_so3(RA @ R @ np.swapaxes(RB, 1, 2) @ R.T), axis=1))
    ratio = float(np.median(residual)) / max(float(np.median(mismatch)), _NOISE_FLOOR_DEG)
    if ratio > MOTION_WARN_RATIO:
        geo.warn_caller(
            f"X leaves motion residuals of {np.median(residual):.3g} deg (median), {ratio:.0f} "
            "times what the noise in these motions explains (robot and camera motion angles "
            f"agree to {np.median(mismatch):.3g} deg): A and B are probably built from poses in "
            "the wrong convention (robot poses as flange_T_base, camera poses as target_T_cam) "
            "or for the wrong mount. Build them with solutions.handeye.hand_eye_motions from "
            "base_T_flange and cam_T_target, or call calibrate_eye_in_hand / "
            "calibrate_eye_to_hand, which say which convention fits")
    return ratio

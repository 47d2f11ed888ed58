"""The import stage of ``solutions.pipeline``: a capture made by another tool -> a ``Capture``.

Robot poses (``robots.pose_files.read_poses``), the board's corners (images + a board, or a
corners file), the camera's intrinsics (given, or calibrated from the corners). A pose file
often leaves its conventions unsaid; each one not given is decided from the data, and each
decision comes back as a ``Decision`` with its evidence:

- the rotation vector's unit (rad or deg): the robot's motion between two views and the
  camera's must rotate by the same angle, whatever X is, so the wrong reading shows as a large
  median angle mismatch (``diagnostics.diagnose_hand_eye``'s ``angle_mismatch_deg``);
- the quaternion's order (xyzw or wxyz): the angles cannot tell it (a permutation of the four
  numbers keeps every relative angle), nor the rotations alone when the direction is unknown
  (the wrong order reads like the inverted direction); the screw pitches below can, since only
  the right rotations give every robot motion the camera motion's pitch;
- the direction (``base_T_flange`` or its inverse): for the stated mount, only one direction
  lets a single X rotate every robot motion's axis onto the camera motion's
  (``residual_deg`` against ``flipped_residual_deg``). Inverting the poses and switching the
  mount give the same equations, so this needs the mount to be stated (``--mount``);
- the length unit (m or mm): a motion's translation along its rotation axis (its screw pitch)
  is the same for the robot and the camera whatever X is, and the camera's is in metres (the
  board's stated size); the flange's distance from the base (a few metres at most) is shown
  beside it.

Where the data cannot tell, ``ValueError`` asks for the flag that names the choices.

The target in the images is a ``Target`` (a ``robots.targets`` detector: chessboard, ChArUco,
ArUco/AprilTag markers, circle grids). A chessboard or a symmetric circle grid may be listed
half a turn round; once the rotations are read (and before the direction, which a turned view
would mislead), each view's corner order is chosen from the robot's motion
(``robots.half_turn``) and reported as a ``Decision`` too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from robots import geometry as geo
from robots import targets
from robots.capture import Capture, capture_from_views, read_views
from robots.half_turn import resolve_capture_half_turns
from robots.interfaces import Intrinsics
from robots.pose_files import PoseConvention, PoseTable, read_poses, to_base_T_flange
from solutions import diagnostics

#: The wrong reading of a rotation must mismatch the motion angles this many times more than
#: the right one (and by ANGLE_MARGIN_DEG at least) for the data to decide.
ANGLE_RATIO = 5.0
ANGLE_MARGIN_DEG = 1.0
#: The direction: the other direction's rotation residual must be this many times larger.
DIRECTION_RATIO = 3.0
#: Motions whose rotation is below this carry no usable axis for the screw pitch.
PITCH_MIN_ANGLE_DEG = 10.0


@dataclass(frozen=True)
class Decision:
    """One convention of the pose file: ``what`` (e.g. ``length unit``), ``value`` (``mm``),
    ``how`` (``given``, ``named in the file`` or ``from the data``) and ``evidence`` (the
    numbers that decided it, "" when given)."""

    what: str
    value: str
    how: str
    evidence: str = ""

    def __str__(self) -> str:
        tail = f": {self.evidence}" if self.evidence else ""
        return f"{self.what}: {self.value} ({self.how}){tail}"


#: ``Target.kind`` values, for the command line's ``--target``.
TARGET_KINDS = ("chessboard", "charuco", "aruco", "apriltag", "circles")


@dataclass(frozen=True)
class Target:
    """The calibration target of a capture's images: ``kind`` (one of ``TARGET_KINDS``),
    ``detect(frame, intrinsics) -> Detection`` (``robots.targets``), ``half_turn_ambiguous``
    (True for a plain chessboard or a symmetric circle grid, whose corner order is then
    resolved from the robot's motion) and ``description`` (for messages)."""

    kind: str
    detect: object
    half_turn_ambiguous: bool
    description: str


def chessboard_target(cols: int, rows: int, square_m: float) -> Target:
    """A plain chessboard of ``cols`` x ``rows`` inner corners, squares ``square_m`` metres."""
    return Target("chessboard", targets.chessboard_with_reasons(cols, rows, square_m), True,
                  f"{cols} x {rows} chessboard, {square_m * 1000:g} mm squares")


def circle_grid_target(cols: int, rows: int, spacing_m: float, asymmetric: bool) -> Target:
    """A circle grid (``targets.circle_grid_detector``); only a symmetric one can flip."""
    return Target("circles", targets.circle_grid_detector(cols, rows, spacing_m, asymmetric),
                  not asymmetric, f"{cols} x {rows} {'asymmetric ' if asymmetric else ''}"
                                  f"circle grid, {spacing_m * 1000:g} mm spacing")


def charuco_target(squares_x: int, squares_y: int, square_m: float, marker_m: float,
                   dictionary: str, legacy: bool = False) -> Target:
    """A ChArUco board (``targets.charuco_detector``): its markers fix the corner order."""
    return Target("charuco", targets.charuco_detector(squares_x, squares_y, square_m, marker_m,
                                                      dictionary, legacy), False,
                  f"{squares_x} x {squares_y} ChArUco board ({dictionary}), "
                  f"{square_m * 1000:g} mm squares, {marker_m * 1000:g} mm markers")


def marker_target(kind: str, dictionary: str, marker_m: float, marker_id=None, grid=None,
                  separation_m=None) -> Target:
    """ArUco or AprilTag markers (``targets.aruco_detector``): one (``marker_id`` or any) or a
    ``grid`` = (columns, rows) with ``separation_m`` between markers."""
    ids = None if marker_id is None else (marker_id,)
    shape = "one marker" if grid is None else f"{grid[0]} x {grid[1]} grid of markers"
    return Target(kind, targets.aruco_detector(dictionary, marker_m, ids, grid, separation_m),
                  False, f"{shape} ({dictionary}), {marker_m * 1000:g} mm"
                         + ("" if marker_id is None else f", id {marker_id}"))


@dataclass(frozen=True)
class ImportedCapture:
    """``capture`` (a ``robots.capture.Capture``, base_T_flange in metres), the
    ``convention`` its pose file was read with, the ``decisions`` (one per convention) and
    ``intrinsics_source`` (where K and the distortion came from). ``half_turns``: the
    ``robots.half_turn.PoseChoice`` of a target that can be read half a turn round (which
    views were turned, with the evidence), else None."""

    capture: Capture
    convention: PoseConvention
    decisions: tuple
    intrinsics_source: str
    half_turns: object = None


def _mismatch(table, convention, C, mount) -> tuple[float, float, float]:
    """(angle mismatch deg, rotation residual deg, flipped residual deg) of a reading."""
    F = to_base_T_flange(table, convention)
    d = diagnostics.diagnose_hand_eye(F, C, mount, full=True)
    return d.angle_mismatch_deg, d.residual_deg, d.flipped_residual_deg


def _pick_angle_unit(table, convention, C, mount):
    """Rotation vectors in rad or deg, from the data: the unit changes each motion's rotation
    angle, which must be the camera motion's."""
    scores = {unit: _mismatch(table, replace(convention, angle_unit=unit), C, mount)[0]
              for unit in ("rad", "deg")}
    best, other = sorted(scores, key=scores.get)
    evidence = ("median |angle(robot motion) - angle(camera motion)| over pairs of views: "
                + ", ".join(f"{unit} {score:.3g} deg" for unit, score in scores.items()))
    if not (scores[other] > ANGLE_RATIO * scores[best]
            and scores[other] - scores[best] > ANGLE_MARGIN_DEG):
        raise ValueError(f"the data cannot tell the angle unit ({evidence}); pass --angle-unit "
                         "rad or deg")
    return (replace(convention, angle_unit=best),
            Decision("angle unit", best, "from the data", evidence))


def _pick_direction(table, convention, C, mount, mount_given: bool):
    _, residual, flipped = _mismatch(table, convention, C, mount)
    other_mount = "eye_to_hand" if mount == "eye_in_hand" else "eye_in_hand"
    evidence = (f"with --mount {mount}, the median per-view rotation residual of the best X is "
                f"{residual:.3g} deg reading the poses as base_T_flange and {flipped:.3g} deg "
                "as flange_T_base")
    if flipped > DIRECTION_RATIO * max(residual, 1e-3):
        value = "base_T_flange"
    elif residual > DIRECTION_RATIO * max(flipped, 1e-3):
        value = "flange_T_base"
        if not mount_given:
            raise ValueError(
                f"{evidence}: either the file holds flange_T_base (the inverse), or the camera "
                f"is {other_mount}; inverting the poses and switching the mount give the same "
                "equations, so say which: pass --mount eye_in_hand or eye_to_hand (then the "
                "direction follows), or --pose-direction base_T_flange or flange_T_base")
    else:
        raise ValueError(f"the data cannot tell the pose direction ({evidence}; the views "
                         "rotate too little about the camera's viewing axis to tell); pass "
                         "--pose-direction base_T_flange or flange_T_base")
    return replace(convention, direction=value), Decision("pose direction", value,
                                                          "from the data", evidence)


def _screw_pitches(T: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """(rotation angle rad, translation along the rotation axis) of inv(T_i) @ T_j per pair."""
    i, j = np.array(pairs).T
    M = geo.invert(T[i]) @ T[j]
    rotvecs = geo.rotvecs_from_rotations(M[:, :3, :3])
    angles = np.linalg.norm(rotvecs, axis=1)
    pitches = np.einsum("ij,ij->i", rotvecs, M[:, :3, 3]) / np.maximum(angles, 1e-12)
    return angles, pitches


def _pitch_ratios(F, C, mount: str):
    """(median robot/camera screw-pitch ratio or None, spread of log10 |ratio| about its
    median, motions used) over every pair of views.

    Motions as the hand-eye equations pair them (eye-in-hand inv(F_i) F_j with C_i inv(C_j);
    eye-to-hand F_i inv(F_j) with the same camera motion) are conjugate, and conjugate motions
    have the same translation along their rotation axis, whatever X is: the ratio is the
    robot's length unit over the camera's (metres), the same for every pair when the rotations
    are read right. Inverting every pose keeps each pitch, so this cannot tell the direction."""
    robot = F if mount == "eye_in_hand" else geo.invert(F)
    pairs = [(i, j) for i in range(len(F)) for j in range(i + 1, len(F))]
    angles, robot_pitch = _screw_pitches(robot, pairs)
    _, camera_pitch = _screw_pitches(geo.invert(C), pairs)
    use = (angles > np.radians(PITCH_MIN_ANGLE_DEG)) & (np.abs(camera_pitch) > 0.005)
    if use.sum() < 3:
        return None, float("nan"), int(use.sum())
    ratios = robot_pitch[use] / camera_pitch[use]
    logs = np.log10(np.maximum(np.abs(ratios), 1e-12))
    spread = float(np.median(np.abs(logs - np.median(logs))))
    if np.mean(ratios > 0) < 0.9:  # pitches of both signs: no common ratio at all
        spread = max(spread, 1.0)
    return float(np.median(ratios)), spread, int(use.sum())


def _pick_length(table, convention, C, mount):
    """m or mm: the robot's screw pitches against the camera's (metres), with the reach."""
    F = to_base_T_flange(table, replace(convention, length_unit="m"))
    reach = float(np.max(np.linalg.norm(table.translations, axis=1)))
    ratio, _, used = _pitch_ratios(F, C, mount)
    evidence = (f"the flange is up to {reach:.4g} file units from the base"
                + (f"; the robot's screw pitch is {ratio:.4g} times the camera's (metres) over "
                   f"{used} motions" if ratio is not None else
                   "; too few motions with a screw pitch to compare with the camera's"))
    by_pitch = None
    if ratio is not None and ratio > 0:
        scale = np.log10(ratio)
        by_pitch = "m" if abs(scale) < 0.5 else "mm" if abs(scale - 3) < 0.5 else None
    by_reach = "m" if reach < 5.0 else "mm" if reach > 50.0 else None
    # The pitch, when measured, must agree with one unit; the reach alone decides only when
    # the motions carry no pitch to compare.
    value = by_pitch if ratio is not None else by_reach
    if value is None or (by_reach is not None and by_reach != value):
        raise ValueError(f"the data cannot tell the length unit ({evidence}); pass "
                         "--length-unit m or mm")
    return replace(convention, length_unit=value), Decision("length unit", value,
                                                            "from the data", evidence)


def _pick_quat_order(table, convention, C, mount, direction_given: bool, mount_given: bool):
    """The quaternion order, and the direction with it when not given.

    The angles cannot tell the order (a permutation of the four numbers keeps every 4-d dot
    product, hence every relative angle), and the rotations alone cannot either when the
    direction is unknown: an odd permutation is q -> a q* b, which makes each motion the
    inverted direction's, turned by a constant. The translations can: only the right
    rotations give every motion the camera's screw pitch (``_pitch_ratios``)."""
    directions = (convention.direction,) if direction_given else ("base_T_flange",
                                                                  "flange_T_base")
    readings = [replace(convention, quat_order=o, direction=d)
                for o in ("xyzw", "wxyz") for d in directions]
    residual = {r: _mismatch(table, r, C, mount)[1] for r in readings}

    def name(r):
        return f"{r.quat_order} as {r.direction}"

    evidence = ("median per-view rotation residual of the best X: "
                + ", ".join(f"{name(r)} {residual[r]:.3g} deg" for r in readings))
    # each order at its best direction; then the rotations, or the pitches, tell the orders apart
    fits = [min((r for r in readings if r.quat_order == o), key=lambda r: residual[r])
            for o in ("xyzw", "wxyz")]
    fits.sort(key=lambda r: residual[r])
    if residual[fits[1]] < DIRECTION_RATIO * max(residual[fits[0]], 1e-3):
        spreads = {}
        for r in fits:
            F = to_base_T_flange(table, replace(r, length_unit="m"))
            spreads[r] = _pitch_ratios(F, C, mount)[1]
        fits.sort(key=lambda r: spreads[r])
        evidence += ("; spread of the robot/camera screw-pitch ratio over the motions "
                     "(log10): " + ", ".join(f"{name(r)} {spreads[r]:.3g}" for r in fits))
        best, runner = spreads[fits[0]], spreads[fits[1]]
        if not (runner > 3 * best and runner - best > 0.05):
            raise ValueError(f"the data cannot tell the quaternion order ({evidence}); pass "
                             "--quat-order xyzw or wxyz")
    chosen = fits[0]
    if not direction_given:
        other = replace(chosen, direction=next(d for d in directions if d != chosen.direction))
        if residual[other] < DIRECTION_RATIO * max(residual[chosen], 1e-3):
            raise ValueError(f"the data cannot tell the pose direction ({evidence}; the views "
                             "rotate too little about the camera's viewing axis to tell); pass "
                             "--pose-direction base_T_flange or flange_T_base")
    decisions = [Decision("quat order", chosen.quat_order, "from the data", evidence)]
    if not direction_given:
        if chosen.direction == "flange_T_base" and not mount_given:
            raise ValueError(
                f"{evidence}: the poses read as {name(chosen)}; either the file holds "
                "flange_T_base, or the camera is mounted the other way; inverting the poses "
                "and switching the mount give the same equations, so say which: pass --mount "
                "eye_in_hand or eye_to_hand (then the direction follows), or --pose-direction")
        decisions.append(Decision("pose direction", chosen.direction, "from the data",
                                  "with the quaternion order, above"))
    return chosen, decisions


def check_pairing(table: PoseTable, convention: PoseConvention, C, mount: str) -> None:
    """``ValueError`` when the poses and the views are not paired one to one (a file sorted
    otherwise than the images, a view missing from one list): their motions then rotate by
    different angles, whatever the conventions (``diagnostics.diagnose_hand_eye``)."""
    d = diagnostics.diagnose_hand_eye(to_base_T_flange(table, convention), C, mount, full=True)
    if d.verdict != "pairing":
        return
    message = (f"the robot poses and the views are not paired one to one: between two views "
               f"the robot and the camera must rotate by the same angle, but here they differ "
               f"by {d.angle_mismatch_deg:.3g} deg (median over pairs of views; noise gives "
               "well under 2 deg). Check that the images sort in the order of the poses "
               "(numbered names), one pose per image, none missing from either")
    if d.reorder is not None:
        message += (f"; another pairing of the same poses and views fits "
                    f"({d.reordered_mismatch_deg:.3g} deg)")
    raise ValueError(message)


def decide_convention(table: PoseTable, cam_T_target, mount: str, given: dict,
                      mount_given: bool = True, reread=None):
    """The ``PoseConvention`` of ``table`` (the kept views' rows) against the camera's board
    poses ``cam_T_target`` (same views, metres): each field in ``given`` (field -> value) is
    taken as given, the quaternion order a header named is taken, the rest are decided from
    the data. ``reread(convention) -> (cam_T_target, decision)``, when given, is called once
    the rotations are read (quaternion order, angle unit) and before the direction is
    decided, which a view read half a turn round would mislead. Returns (convention,
    decisions)."""
    convention = PoseConvention(**{k: v for k, v in given.items() if v is not None})
    labels = {"length_unit": "length unit", "angle_unit": "angle unit",
              "quat_order": "quat order", "direction": "pose direction"}
    decisions = [Decision(labels[k], v, "given") for k, v in given.items() if v is not None]
    C = geo.as_poses(cam_T_target, "cam_T_target")
    if table.layout != "rotvec" or given.get("angle_unit") is not None:
        # nothing else decided here changes a motion's angle: check the pairing first
        check_pairing(table, convention, C, mount)
    if table.layout == "quat" and given.get("quat_order") is None:
        if table.quat_order is not None:
            convention = replace(convention, quat_order=table.quat_order)
            decisions.append(Decision("quat order", table.quat_order, "named in the file"))
        else:
            convention, found = _pick_quat_order(table, convention, C, mount,
                                                 given.get("direction") is not None, mount_given)
            decisions += found
    if table.layout == "rotvec" and given.get("angle_unit") is None:
        convention, d = _pick_angle_unit(table, convention, C, mount)
        decisions.append(d)
    if reread is not None:
        cam_T_target, decision = reread(convention)
        C = geo.as_poses(cam_T_target, "cam_T_target")
        decisions.append(decision)
    if given.get("direction") is None and not any(d.what == "pose direction"
                                                   for d in decisions):
        convention, d = _pick_direction(table, convention, C, mount, mount_given)
        decisions.append(d)
    if given.get("length_unit") is None:
        convention, d = _pick_length(table, convention, C, mount)
        decisions.append(d)
    check_pairing(table, convention, C, mount)
    return convention, tuple(decisions)


def _rows(table: PoseTable, keep) -> PoseTable:
    return replace(table, translations=table.translations[keep], rotations=table.rotations[keep],
                   names=tuple(table.names[i] for i in keep))


def _resolve_half_turns(capture: Capture):
    """The capture with every view's corner order the one the robot's motion agrees with, the
    ``PoseChoice`` and its ``Decision`` (views named by the capture's view numbers)."""
    capture, choice = resolve_capture_half_turns(capture)
    number = [int(v) for v in capture.pose_indices]
    turned = [number[k] for k in choice.changed]
    if turned:
        value = f"views {turned} turned half a turn"
        evidence = ("with the detected order they disagree with the robot's motion by a median "
                    + ", ".join(f"{choice.alternative_deg[k]:.1f}" for k in choice.changed)
                    + " deg, turned by "
                    + ", ".join(f"{choice.mismatch_deg[k]:.2f}" for k in choice.changed)
                    + " deg (the angle the flange turns between two views against the one the "
                      "camera sees the board turn)")
    else:
        value = "as detected"
        evidence = (f"every view agrees with the robot's motion as detected (median mismatch at "
                    f"most {np.max(choice.mismatch_deg):.2f} deg)")
    if choice.unclear:
        evidence += (f"; views {[number[k] for k in choice.unclear]} are not decided by the "
                     "motion (distrust them)")
    return capture, choice, Decision("corner order", value, "from the robot's motion", evidence)


def import_capture(poses, *, images=None, corners=None, board=None, target: Target | None = None,
                   intrinsics: Intrinsics | None = None, mount: str = "eye_in_hand",
                   mount_given: bool = True, length_unit=None, angle_unit=None,
                   quat_order=None, direction=None, robot_name: str = "",
                   camera_name: str = "") -> ImportedCapture:
    """Import a capture made elsewhere.

    ``poses``: a pose file or folder (``robots.pose_files.read_poses``). ``images`` (a folder,
    one image per pose, in name order with numbers as numbers) with ``target`` (a ``Target``:
    ``chessboard_target``, ``charuco_target``, ``marker_target``, ``circle_grid_target``) or
    ``board`` = (inner columns, inner rows, square m) for a chessboard, or ``corners`` (an .npz, ``robots.capture.corners_from_file``). ``intrinsics``: the
    camera's own calibration, used as given; None: calibrated from the corners. ``mount``:
    eye_in_hand or eye_to_hand (``mount_given`` False when it is only the default, so a pose
    direction that rests on it is asked for rather than assumed). ``length_unit`` (m, mm),
    ``angle_unit`` (rad, deg), ``quat_order`` (xyzw, wxyz), ``direction`` (base_T_flange,
    flange_T_base): given, or decided from the data (module docstring).
    """
    from robots import pose_files

    for name, value, choices in (("length_unit", length_unit, pose_files.LENGTH_UNITS),
                                 ("angle_unit", angle_unit, pose_files.ANGLE_UNITS),
                                 ("quat_order", quat_order, pose_files.QUAT_ORDERS),
                                 ("direction", direction, pose_files.DIRECTIONS),
                                 ("mount", mount, ("eye_in_hand", "eye_to_hand"))):
        if value is not None and value not in choices:
            raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    table = read_poses(poses)
    if images is not None and target is None and board is not None:
        target = chessboard_target(*board)
    views = read_views(len(table), corners, images, detect=target and target.detect,
                       intrinsics=intrinsics) if images is not None else \
        read_views(len(table), corners)
    # The board poses first (robot poses are not needed for them): the conventions are
    # decided against them.
    placeholder = np.tile(np.eye(4), (len(table), 1, 1))
    capture = capture_from_views(placeholder, views, intrinsics, robot_name, camera_name)
    given = {"length_unit": length_unit, "angle_unit": angle_unit, "quat_order": quat_order,
             "direction": direction}
    kept = _rows(table, capture.pose_indices)
    resolved = {}

    def reread(convention):
        # A motion's rotation angle is the same whichever the direction and the length unit,
        # so the robot poses read so far tell each view's corner order (robots.half_turn).
        capture.base_T_flange = to_base_T_flange(kept, convention)
        resolved["capture"], resolved["choice"], decision = _resolve_half_turns(capture)
        return resolved["capture"].cam_T_target, decision

    ambiguous = target is not None and target.half_turn_ambiguous
    convention, decisions = decide_convention(kept, capture.cam_T_target, mount, given,
                                              mount_given, reread if ambiguous else None)
    capture = resolved.get("capture", capture)
    F = to_base_T_flange(table, convention)
    capture.commanded_base_T_flange = F
    capture.base_T_flange = F[capture.pose_indices]
    choice = resolved.get("choice")
    source = ("given" if intrinsics is not None else
              f"calibrated from the corners of {len(capture)} views (cv2.calibrateCamera)")
    return ImportedCapture(capture, convention, decisions, source, choice)

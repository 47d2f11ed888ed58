"""Robot-world-hand-eye calibration: solve ``A_i @ X = Y @ B_i`` for two unknown poses.

The form used throughout this module (and by ``solutions.mle``)::

    A_i @ X == Y @ B_i            for every pose i = 0 .. n-1

Eye-in-hand reading (camera on the flange, board fixed in the cell):

* ``A_i = base_T_flange_i``                    what the robot controller reports,
* ``B_i = target_T_cam_i = inv(cam_T_target_i)``  the inverse of what solvePnP returns,
* ``X   = flange_T_cam``                       the hand-eye transform,
* ``Y   = base_T_target``                      where the board lies.

Eye-to-hand (fixed camera, board on the flange) fits the same form with
``A_i = base_T_flange_i``, ``B_i = cam_T_target_i``, ``X = flange_T_target``, ``Y = base_T_cam``.

Relation to OpenCV. ``cv2.calibrateRobotWorldHandEye(R_world2cam, t_world2cam,
R_base2gripper, t_base2gripper, method)`` returns ``(R_base2world, t_base2world,
R_gripper2cam, t_gripper2cam)``. OpenCV's "a2b" maps a-coordinates into b, so in the
eye-in-hand reading:

* world2cam   = ``cam_T_target``            = inv(B_i)   (passed as is),
* base2gripper = ``flange_T_base``           = inv(A_i)   (the robot pose INVERTED),
* base2world  = ``target_T_base``           = inv(Y),
* gripper2cam = ``cam_T_flange``            = inv(X).

So OpenCV's outputs are the inverses of this module's X and Y (``tests/test_robot_world.py``
checks the mapping against OpenCV itself).

Methods of ``solve_ax_yb``:

* ``"shah"``  Shah (2013): rotations from the null space of the Kronecker system
  ``(R_B ⊗ R_A) vec(R_X) = vec(R_Y)``, each projected to SO(3), then translations by linear
  least squares.
* ``"li"``    Li, Wang & Wu (2010): one linear least-squares system in vec(R_X), vec(R_Y), t_X,
  t_Y; the rotations are projected to SO(3) and the translations re-solved with them fixed.
* ``"nonlinear"``  joint Levenberg-Marquardt refinement over SO(3)^2 x R^6 of the rotation
  (rad) and translation (m) residuals of each B_i against inv(Y) A_i X, each divided by its
  noise level estimated from the data, optionally with a robust loss, started from whichever
  closed form fits better (it is ``solutions.mle.refine_hand_eye`` in its eye-to-hand form).

Residual metrics are the course's: mean rotational error ``(1/n) sum ||R_A R_X - R_Y R_B||_F^2``
(dimensionless) and mean translational error ``(1/n) sum ||R_A t_X + t_A - R_Y t_B - t_Y||^2``
(m^2); see ``ax_yb_residuals``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robots import geometry as geo
from solutions import diagnostics
from solutions.ax_yb_closed_forms import (
    LOSSES,
    MIN_MOTION_DEG,
    check_rotation_variety,
    li_closed_form,
    loss_weights,
    shah_closed_form,
    validate_ax_yb,
)
from solutions.mle import refine_hand_eye

__all__ = [
    "LOSSES",
    "METHODS",
    "MIN_MOTION_DEG",
    "AxYbResiduals",
    "ax_yb_residuals",
    "check_rotation_variety",
    "li_closed_form",
    "loss_weights",
    "shah_closed_form",
    "solve_ax_yb",
    "validate_ax_yb",
]

METHODS = ("shah", "li", "nonlinear")


# --------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class AxYbResiduals:
    """Per-pose and mean residuals of ``A_i X = Y B_i`` as the course defines them.

    ``rotation_per_pose[i] = ||R_Ai R_X - R_Y R_Bi||_F^2`` (dimensionless),
    ``translation_per_pose_m2[i] = ||R_Ai t_X + t_Ai - R_Y t_Bi - t_Y||^2`` (m^2); the means
    are over the poses.
    """

    rotation_per_pose: np.ndarray
    translation_per_pose_m2: np.ndarray

    @property
    def mean_rotation(self) -> float:
        return float(self.rotation_per_pose.mean())

    @property
    def mean_translation_m2(self) -> float:
        return float(self.translation_per_pose_m2.mean())


def ax_yb_residuals(A, B, X, Y) -> AxYbResiduals:
    """The course's rotational and translational residuals of ``A_i X = Y B_i`` (see above)."""
    A = geo.as_poses(A, "A")
    B = geo.as_poses(B, "B")
    if len(A) != len(B):
        raise ValueError(f"A has {len(A)} poses but B has {len(B)}; pass one B per A")
    X = geo.as_pose(X, "X")
    Y = geo.as_pose(Y, "Y")
    rot = A[:, :3, :3] @ X[:3, :3] - Y[:3, :3] @ B[:, :3, :3]
    trans = (A[:, :3, :3] @ X[:3, 3] + A[:, :3, 3]) - (B[:, :3, 3] @ Y[:3, :3].T + Y[:3, 3])
    return AxYbResiduals(np.einsum("nij,nij->n", rot, rot), np.einsum("ni,ni->n", trans, trans))


# --------------------------------------------------------------------------- entry point


def solve_ax_yb(A, B, method: str = "li", loss: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``A_i @ X = Y @ B_i`` for X and Y, both (4, 4) poses in metres.

    Eye-in-hand: ``A = base_T_flange``, ``B = target_T_cam = inv(cam_T_target)``, giving
    ``X = flange_T_cam`` and ``Y = base_T_target``. OpenCV's ``calibrateRobotWorldHandEye``
    takes (cam_T_target, inv(base_T_flange)) and returns (inv(Y), inv(X)); see the module
    docstring.

    ``method`` is ``"shah"``, ``"li"`` or ``"nonlinear"``; ``loss`` (``None``, ``"huber"``,
    ``"soft_l1"``, ``"cauchy"``) applies to ``"nonlinear"`` only and down-weights poses whose
    residual is many noise levels out. At least 3 poses with rotations about two or more
    axes are required (``ValueError`` otherwise, saying what to capture).
    """
    diagnostics.check_choice(method, "method", METHODS, "AX = YB method")
    diagnostics.check_choice(loss, "loss", LOSSES, "robust loss")
    A, B = validate_ax_yb(A, B)
    # The motion-size screen of the AX = XB calibrations, on the motions between every two
    # poses: both refuse the same captures. Then refuse inverted or mis-paired poses, and
    # robot and camera translations in different units, which every method would turn into a
    # wrong X and Y without an error.
    rvA, rvB, pairs = diagnostics.pose_pair_rotvecs(A, B)
    diagnostics.screen_motions(rvA, rvB, pairs, what="pose pairs", warn_dropped=False)
    diagnostics.check_ax_yb(A, B)
    if method == "shah":
        return shah_closed_form(A, B)
    if method == "li":
        return li_closed_form(A, B)
    # Start from the closed form that fits better in the course's rotational metric plus the
    # translational one scaled to metres^2 (both near zero at a good start).
    starts = [shah_closed_form(A, B), li_closed_form(A, B)]
    costs = []
    for X, Y in starts:
        res = ax_yb_residuals(A, B, X, Y)
        costs.append(res.mean_rotation + res.mean_translation_m2)
    X0, Y0 = starts[int(np.argmin(costs))]
    # A_i X = Y B_i is the eye-to-hand equation base_T_flange_i Y' = X' cam_T_target_i with
    # X' = Y and Y' = X, so the maximum-likelihood refinement of solutions.mle serves here: B_i
    # is compared with its prediction inv(Y) A_i X, rotation and translation weighted by noise
    # levels estimated from the data.
    res = refine_hand_eye(A, B, "eye_to_hand", X0=Y0, Y0=X0, robust=loss is not None,
                          loss=loss or "cauchy")
    return res.Y, res.X

"""Not orthonormalised: a pose answer whose rotation block is not a rotation, but whose
nearest rotation is the right one.

Applies to a pose answer (and to a rotation-matrix answer). A rotation built by hand can
miss the step that makes it one: a frame whose axes are never normalised, a block never
projected onto SO(3). Which matrix comes out depends on the data, so, as the reflection
family, this one names it from the answer itself (:func:`nearest_rotation_is_right`): the
block's ``R^T R`` is off the identity by more than rounding, and the rotation nearest to
it (its polar factor, ``U V^T`` of its SVD) lands within the noise of the truth. Only then
is the cause known: the missing step, which undoes the mistake.

A block that is no rotation and whose nearest rotation is wrong too (Rodrigues' formula
with a term left out, a linear least-squares map) has no one cause to name: a term of the
formula, an unnormalised axis, a fit that is no rotation fit all give one. The grader says
the symptom then (:data:`NOT_A_ROTATION`, a line of the problem's errors, not a named
mistake) and names nothing: naming several causes at once to hit one is no name.
Its predictions (the truth's rotation block scaled) only show where it applies.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import (
    OUTPUT,
    Family,
    Prediction,
    Problem,
    as_array,
    is_pose,
    is_rotation,
)
from robots import geometry as geo

NOT_ORTHONORMAL = ("its rotation block is not a rotation (R^T R is not the identity), but "
                   "the rotation nearest to it is the right one: the step that makes it "
                   "orthonormal is missing (normalise each axis, or project the block onto "
                   "SO(3): U V^T of its SVD, with det +1)")

# What the grader says of a block that is no rotation when no cause is known (a problem's
# error line, not a named mistake): the symptom, and what a rotation must be.
NOT_A_ROTATION = ("its rotation block is not a rotation (R^T R is not the identity, so it has "
                  "no angle to measure): whatever builds it must give orthonormal axes with "
                  "det +1")

# R^T R this far from I is no float rounding (float32 arithmetic lands near 1e-7) and
# beyond what geometry's own validation re-orthonormalises silently (DESIGN.md: 1e-6).
GRAM_TOL = 1e-5


def _block(value, truth) -> np.ndarray | None:
    """The 3x3 block a student's ``value`` gives for the truth's rotation, or None."""
    v = as_array(value)
    if v is None:
        return None
    if is_pose(truth) and v.shape == (4, 4):
        return v[:3, :3]
    if is_rotation(truth) and v.shape == (3, 3):
        return v
    return None


def not_orthonormal(value, truth) -> bool:
    """True when ``value`` answers a pose (or rotation) ``truth`` with a block whose
    ``R^T R`` is off the identity by more than :data:`GRAM_TOL`."""
    R = _block(value, truth)
    if R is None:
        return False
    return bool(np.abs(R.T @ R - np.eye(3)).max() > GRAM_TOL)


def nearest_rotation_is_right(value, truth, distance) -> bool:
    """True when ``value`` answers a pose (or rotation) ``truth`` with a block that is not
    orthonormal (:func:`not_orthonormal`) and ``value`` with that block replaced by its
    nearest rotation lies within the noise of ``truth``: ``distance(a, b)`` measures answer
    ``a`` against ``b`` taken as the truth, in noise units (at most 1 is within)."""
    if not not_orthonormal(value, truth):
        return False
    fixed = np.array(as_array(value), dtype=float)
    # a block with det <= 0 is a mirror's (the reflection family's), not one left unscaled
    if not np.all(np.isfinite(fixed)) or np.linalg.det(fixed[:3, :3]) <= 0:
        return False
    try:
        fixed[:3, :3] = geo.project_to_so3(fixed[:3, :3])
        return float(distance(fixed, truth)) <= 1.0
    except Exception:  # noqa: BLE001 - what the measure cannot take is not within it
        return False


def _scaled_block(problem: Problem) -> list[Prediction]:
    t = as_array(problem.truth)
    if t is None or not (is_pose(t) or is_rotation(t)):
        return []
    out = np.array(t)
    out[:3, :3] *= 1.1
    return [Prediction(out)]


NOT_ROTATION = Family("not a rotation", NOT_ORTHONORMAL, OUTPUT, _scaled_block, "not a rotation")
FAMILIES = (NOT_ROTATION,)

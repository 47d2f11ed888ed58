"""Not a rotation: a pose answer whose rotation block is not orthonormal.

Applies to a pose answer (and to a rotation-matrix answer). A rotation built by hand can
miss the step that makes it one: a matrix fitted by least squares and never projected onto
SO(3), Rodrigues' formula with a term missing or an axis left unnormalised, a frame whose
axes are not made orthogonal. Which matrix comes out depends on the data, so, as the
reflection family, this one names it from the answer itself (:func:`not_orthonormal`): a
block with ``R^T R`` off the identity by more than rounding is no rotation, whatever else
is wrong. Its predictions (the truth's rotation block scaled) only show where it applies.
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

NOT_ORTHONORMAL = ("its rotation block is not a rotation (R^T R is not the identity): "
                   "project it onto SO(3) with an SVD (U V^T, with det +1), or check the "
                   "formula that builds it (Rodrigues' needs a unit axis and all three terms)")

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


def _scaled_block(problem: Problem) -> list[Prediction]:
    t = as_array(problem.truth)
    if t is None or not (is_pose(t) or is_rotation(t)):
        return []
    out = np.array(t)
    out[:3, :3] *= 1.1
    return [Prediction(out)]


NOT_ROTATION = Family("not a rotation", NOT_ORTHONORMAL, OUTPUT, _scaled_block, "not a rotation")
FAMILIES = (NOT_ROTATION,)

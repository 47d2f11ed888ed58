"""A reflection left in a rotation: an orthonormal block with determinant -1.

Applies to a pose answer. An SVD fit without the reflection fix, or a frame built with one
cross product the wrong way round, returns a mirror image; which axis is mirrored depends on
the data, so the family names it from the answer itself (:func:`mirrored`): a rotation
block that is orthonormal with determinant -1 is a reflection, whatever its axis. Its
predictions (the truth with one axis mirrored) only show where it applies.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import OUTPUT, Family, Prediction, Problem, as_array, is_pose

MIRRORED = ("its rotation has determinant -1: a mirror image, not a rotation (in an SVD fit, "
            "flip the sign of the last column of V when det(V U^T) < 0)")


def _mirrored_axes(problem: Problem) -> list[Prediction]:
    if not is_pose(problem.truth):
        return []
    out = []
    for axis in range(3):
        T = np.array(problem.truth, dtype=float)
        T[:3, axis] *= -1.0
        out.append(Prediction(T))
    return out


def mirrored(value, truth) -> bool:
    """True when ``value`` is a (4, 4) pose-shaped array whose rotation block is orthonormal
    with determinant -1 and ``truth`` a pose."""
    v = as_array(value)
    if v is None or v.shape != (4, 4) or not is_pose(truth):
        return False
    R = v[:3, :3]
    return bool(np.linalg.det(R) < 0 and np.allclose(R.T @ R, np.eye(3), atol=1e-3))


REFLECTION = Family("reflection", MIRRORED, OUTPUT, _mirrored_axes, "reflection")
FAMILIES = (REFLECTION,)

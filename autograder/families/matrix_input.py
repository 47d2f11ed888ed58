"""A matrix input read wrong: used transposed, or a camera matrix's principal point left out.

* Transposed: numpy indexes ``[row, column]``; reading ``K[2, 0]`` for ``K[0, 2]`` (or
  building the matrix from rows where columns were meant) reads the input transposed.
  Applies to an input that is a square matrix (2x2 and up), neither a pose (an inverted
  pose is :mod:`.reversed_stack`'s) nor symmetric (its transpose is itself).
* Principal point left out: a pinhole projection or back-projection written ``u / fx``
  where ``(u - cx) / fx`` is meant. Applies to an input of the kind of a camera matrix
  (3x3, upper triangular, last row [0, 0, 1], positive focal lengths, a principal point
  off zero).

* One entry for its twin: ``fx`` used where ``fy`` belongs, or ``cx`` where ``cy`` does: the
  x line of a pinhole formula copied for y with one letter left unchanged. Applies to a
  camera matrix whose two entries differ (where they are equal the slip changes nothing
  and is not named). Only the x-for-y direction: x is written first, and each prediction
  is a whole answer stored in practice data (lab 5's are point clouds).

Input side: the private reference called on the input changed so. The words name the input
by the function's parameter name (:func:`.chain.one_input_changed`).
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem, as_array, is_pose
from autograder.families.chain import one_input_changed

TRANSPOSED_INPUT = ("the input {name} was read transposed ([column, row] where [row, column] "
                    "was meant, e.g. {name}[2, 0] for {name}[0, 2]): numpy indexes a matrix "
                    "[row, column]")
NO_PRINCIPAL_POINT = ("the principal point (cx, cy) of {name} was left out: a pixel's offset "
                      "from the optical axis is (u - cx, v - cy), not (u, v)")


def _square(a) -> np.ndarray | None:
    """``a`` as a square non-symmetric matrix that is no pose, or None."""
    if isinstance(a, (int, float, str, bytes, dict)) or is_pose(a):
        return None
    m = as_array(a)
    if m is None or m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] < 2 \
            or np.allclose(m, m.T):
        return None
    return m


def is_camera_matrix(a) -> bool:
    """A pinhole camera matrix K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]], fx, fy > 0, its
    principal point off zero."""
    m = _square(a)
    return m is not None and m.shape == (3, 3) and np.allclose(m[2], [0.0, 0.0, 1.0]) \
        and m[1, 0] == 0.0 and m[0, 0] > 0 and m[1, 1] > 0 and bool(np.any(m[:2, 2] != 0))


def _without_principal_point(K) -> np.ndarray:
    out = np.array(K, dtype=float)
    out[:2, 2] = 0.0
    return out


ENTRY_FOR_TWIN = ("{name}'s {used} was used where its {meant} belongs ({name}[{i}, {j}] read "
                  "for {name}[{k}, {l}]): x pixels go with fx and cx, y pixels with fy and cy")

# (used, its index, meant, its index): an entry of K read where its twin of the y axis belongs
_TWINS = (("fx", (0, 0), "fy", (1, 1)), ("cx", (0, 2), "cy", (1, 2)))


def _entry_over_twin(K, at: tuple, to: tuple) -> np.ndarray:
    """``K`` with its entry ``at`` copied over its entry ``to``."""
    out = np.array(K, dtype=float)
    out[to] = out[at]
    return out


def _twins_differ(a, at: tuple, to: tuple) -> bool:
    return is_camera_matrix(a) and bool(np.asarray(a)[at] != np.asarray(a)[to])


def _entry_for_twin(problem: Problem) -> list[Prediction]:
    """The reference with one entry of a camera-matrix input copied over its twin (fx over
    fy, ...), one prediction per twin pair whose entries differ."""
    out = []
    for used, at, meant, to in _TWINS:
        # every field but the input's name, which one_input_changed fills in
        words = ENTRY_FOR_TWIN.format(name="{name}", used=used, meant=meant,
                                      i=at[0], j=at[1], k=to[0], l=to[1])
        out += one_input_changed(lambda a, at=at, to=to: _twins_differ(a, at, to),
                                 lambda K, at=at, to=to: _entry_over_twin(K, at, to),
                                 words)(problem)
    return out


# The principal point first: a formula that reads K's entries one by one gets from K.T
# exactly what it gets without (cx, cy) (K.T[0, 2] = K[2, 0] = 0), and where two families
# give one answer the first speaks for both: leaving (cx, cy) out is the common slip.
FAMILIES = (
    Family("missing part", NO_PRINCIPAL_POINT.format(name="K"), INPUT,
           one_input_changed(is_camera_matrix, _without_principal_point, NO_PRINCIPAL_POINT),
           "no principal point"),
    Family("inverse/transpose", TRANSPOSED_INPUT.format(name="a matrix input"), INPUT,
           one_input_changed(lambda a: _square(a) is not None,
                             lambda a: np.asarray(a, float).T, TRANSPOSED_INPUT),
           "input transposed"),
    Family("input used twice", ENTRY_FOR_TWIN.format(name="K", used="fx", meant="fy", i=0, j=0,
                                                     k=1, l=1), INPUT, _entry_for_twin,
           "entry for its twin"),
)

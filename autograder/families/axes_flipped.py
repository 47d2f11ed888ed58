"""Two axes flipped: a frame built right but for two of its axes, which point the wrong way.

A frame built from points or vectors with cross products (z = x cross v, y = z cross x)
flips two axes at once when one cross product takes its operands in the wrong order
(v cross x = -(x cross v)): z comes out negated and y, built from it, too. Two axes
flipped is still a rotation (det +1, so not the reflection family's mirror image): the
right frame turned a half turn about its own third axis, ``R @ diag(1, -1, -1)`` for x
kept. Applies to a pose or a rotation answer; the translation is kept. Output side; the
flip is its own undo.
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

AXES_FLIPPED = ("its {a} and {b} axes point the wrong way (the right frame turned a half turn "
                "about its own {kept} axis): a cross product with its operands in the wrong "
                "order (b x a = -(a x b)) flips the axis it builds and the axes built from it")

# (the axis kept, the two flipped): each a half turn about one of the frame's own axes
_FLIPS = (("x", "y", "z"), ("y", "x", "z"), ("z", "x", "y"))


def _flipped(value, kept: int) -> np.ndarray:
    """``value`` (a pose or a rotation) with the two columns of its rotation block other than
    ``kept`` negated."""
    out = np.array(value, dtype=float)
    signs = -np.ones(3)
    signs[kept] = 1.0
    out[:3, :3] = out[:3, :3] * signs
    return out


def _axes_flipped(problem: Problem) -> list[Prediction]:
    t = as_array(problem.truth)
    if t is None or not (is_pose(t) or is_rotation(t)):
        return []
    return [Prediction(_flipped(t, k), lambda v, k=k: _flipped(v, k), t,
                       words=AXES_FLIPPED.format(kept=kept, a=a, b=b))
            for k, (kept, a, b) in enumerate(_FLIPS)]


FAMILIES = (Family("sign", AXES_FLIPPED.format(kept="x", a="y", b="z"), OUTPUT, _axes_flipped,
                   "two axes flipped"),)

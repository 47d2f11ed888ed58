"""A corpus of classic student mistakes in labs 0, 1, 2 and 4, kept out of the grader.

Each entry is a student's graded function with ONE classic bug in an otherwise correct body,
written by hand from what students get wrong (issue 52, Required 4), with:

* ``words``: the mistake in a student's words (what they would say once they found it);
* ``family``: the general family a rule over the answer's shape would name it by (one of
  :data:`FAMILIES`), or ``"none"`` where no general family describes it (an aliasing bug,
  a row taken for a column, a median for a mean);
* ``also``: other families that describe the *answer* exactly as well (swapping the two
  point sets of a hand-to-eye fit returns exactly the inverse pose: "the inverse" is a
  right name for it too);
* ``names``: for a mistake of no family, a regular expression a right name must match
  (None: no name is right, any name is a misnaming).

The corpus is the test set of the mistake families (issue 52, Required 1-3), so it is built
without looking at any family's implementation, and nothing under ``autograder/`` may import
it. ``benchmarks/mistake_naming.py`` scores every entry with ``autograder.checks.evaluate``
(what ``check()`` shows a student) and counts named / misnamed / unnamed per lab.

The corpus modules import only numpy, scipy and ``robots.geometry``, as a lab notebook does:
the grader's forbidden-call scan reads their globals as it reads a notebook's. They hold
near-copies of the labs' answers: instructors' material, never released to students.

Two bugs first written for it are no mistakes, and are left out: a Tsai-Lenz whose modified
Rodrigues vectors are 2 sin(theta) a (or theta a, or in degrees) instead of 2 sin(theta/2) a
(A's and B's scale alike, and skew(P_A + P_B) P' = P_B - P_A is homogeneous in that scale,
so only the weighting of the motions changes), and a hand-to-eye fit that gives
frame_from_three_points its points as (origin, xy, x) on both sides (the same wrong world
frame on both sides cancels in base_T_world @ inv(cam_T_world)). A name for either would be
a misnaming of correct code.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["FAMILIES", "LABS", "Mistake", "load", "pose", "register"]

FAMILIES = ("inverse/transpose", "reflection", "units m/mm", "units rad/deg", "sign",
            "swapped arguments", "reversed stack/order", "first/last for mean", "sum for mean",
            "root or not", "absolute for squared", "uncentred", "none")

# lab -> the graded functions a mistake may be written for (the labs' scoring entries)
LABS = {
    "lab0_frames": ("invert_pose", "compose_chain", "pose_from_rotvec"),
    "lab1_flange": ("fit_rigid", "per_point_residuals", "per_axis_rmse"),
    "lab2_handeye": ("motions", "tsai_lenz", "axes_ls", "rotation_residual",
                     "translation_residual"),
    "lab4_stereo": ("frame_from_three_points", "reproject", "hand_to_eye_from_three_points",
                    "per_axis_rmse"),
}


@dataclass(frozen=True)
class Mistake:
    """One student's function with one classic bug (see the module docstring)."""

    id: str
    lab: str
    function: str
    words: str
    family: str
    func: Callable
    also: tuple[str, ...] = ()
    names: str | None = None

    @property
    def accepted(self) -> tuple[str, ...]:
        """The families whose name is a right name for this mistake."""
        return tuple(f for f in (self.family, *self.also) if f != "none")


_REGISTRY: dict[str, Mistake] = {}


def pose(R, t):
    """The (4, 4) array [[R, t], [0, 0, 0, 1]] as a student builds it: ``R`` is taken as
    given, so a mistake that makes no rotation returns it as the student's code would."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def register(lab: str):
    """A decorator factory for one lab's module: ``@mistake(function, family, words, ...)``
    registers the decorated function, under its own name as the id, and returns it
    unchanged (so the grader's source scan reads the student's function as written)."""
    if lab not in LABS:
        raise ValueError(f"lab {lab!r} is not in the corpus; use one of {sorted(LABS)}")

    def mistake(function: str, family: str, words: str, also: tuple[str, ...] = (),
                names: str | None = None):
        if function not in LABS[lab]:
            raise ValueError(f"{lab} grades no function {function!r}; use one of "
                             f"{LABS[lab]}")
        for f in (family, *also):
            if f not in FAMILIES:
                raise ValueError(f"family {f!r} is not one of {FAMILIES}")

        def add(func: Callable) -> Callable:
            if func.__name__ in _REGISTRY:
                raise ValueError(f"two corpus mistakes are called {func.__name__}")
            _REGISTRY[func.__name__] = Mistake(func.__name__, lab, function, words, family,
                                               func, tuple(also), names)
            return func

        return add

    return mistake


def load(labs=None) -> list[Mistake]:
    """Every corpus mistake of ``labs`` (default: all four), in the order written."""
    wanted = tuple(LABS) if labs is None else tuple(labs)
    unknown = [lab for lab in wanted if lab not in LABS]
    if unknown:
        raise ValueError(f"no corpus for {unknown}; the corpus covers {sorted(LABS)}")
    for lab in wanted:
        importlib.import_module(f"{__name__}.{lab}")
    return [m for m in _REGISTRY.values() if m.lab in wanted]

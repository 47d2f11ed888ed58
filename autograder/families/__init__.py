"""Mistake families: classic mistakes tried on every graded function whose types they fit.

A lab's code mistakes (``FunctionSpec.code_mistakes``) name only what its author foresaw. A
family names a classic mistake on any function, the built-in labs' and an instructor's
alike, deciding from the *kinds* of the function's answer and inputs (a pose, a rotation,
an (N, 3) point set, a stack of poses, a pair of same-typed inputs, a scalar error), never
from a lab's title or a function's name, whether it applies; and it predicts the answer
that mistake gives on a problem. One module per act:

* output side, a transform of the truth (public: computed where ``check()`` runs):
  :mod:`.inverse` (inverse pose, transposed rotation or matrix), :mod:`.units_length`
  (x1000, /1000; per part of a tuple answer), :mod:`.units_angle` (180/pi, pi/180),
  :mod:`.sign`, :mod:`.root` (RMS vs mean square), :mod:`.sum_for_mean`,
  :mod:`.reflection` (a determinant -1 rotation, read from the answer itself),
  :mod:`.axes_flipped` (two axes of a frame pointing the wrong way: a cross product's
  operands swapped),
  :mod:`.pose_parts` (a pose part by part: its rotation right and its translation
  negated, zero or rotated the wrong way; its angle halved or doubled; its rotation
  transposed whatever its translation), :mod:`.stack_items` (each pose of a stack
  answer inverted or transposed), :mod:`.not_rotation` (a rotation block that is not
  orthonormal, read from the answer itself);
* input side, the function's private reference (``FunctionSpec.reference``) called on
  transformed inputs (precomputed into practice data, as code mistakes are, so a student's
  install holds no answer code): :mod:`.swapped` (A for B), :mod:`.reversed_stack` (a
  stack last to first, its poses inverted, an input pose inverted), :mod:`.first_last`
  (a stack's first or last item for the mean over it), :mod:`.absolute` (a mean of
  absolute errors for an RMS), :mod:`.units_input` (one input's lengths
  in millimetres), :mod:`.product_order` (the factors of each product in reverse
  order), :mod:`.chain` (a pose input, or a stack's poses, left out of the chain as the
  identity; one input used in place of another of its kind), :mod:`.matrix_input` (a
  square matrix input read transposed; a camera matrix's principal point left out).
* over stacks and reductions (:mod:`.stacks` reads which inputs are stacks and how the
  reference's answer is reduced over their items): :mod:`.off_by_one` (a stack's first or
  last item left out or taken twice), :mod:`.statistic` (median, max, n - 1, mean for sum;
  n - 1 also read from the answer), :mod:`.wrong_axis` (one value over every axis or per
  item), input side; :mod:`.precision` (float32 where that alone loses credit) and
  :mod:`.uncentred` (a rigid fit of raw points, or its translation from before the
  reflection fix), output side.

The public surface, stable for ``labs verify`` and the grader:

* :data:`FAMILIES`: every :class:`Family` (``.name`` the family, ``.words`` what the
  student is told with the fix, ``.side`` "output" or "input", ``.key`` a short id);
* :func:`applicable(spec, trial) <applicable>` -> the families that predict an answer on
  that problem; ``family.predict(spec, trial)`` -> that answer, or None;
* :func:`predictions(spec, trial, truth, sides) <predictions>` -> ``[(MistakeName,
  Prediction)]``, the candidates the grader's ``nearest`` rule weighs;
* :func:`undoing(distance)`: the distance that compares an answer with a prediction that
  can be undone (the answer mapped back, against the truth) and with any other plainly;
* :class:`MistakeName`: a named mistake as a typed value, ``family`` None for a lab's
  code mistake.

A family is named only by ``autograder.mistakes.nearest``: within the problem's noise and
clearly nearer than every other candidate (the truth, the reference's answer, trivial
answers, code mistakes), and never two at once.
"""

from __future__ import annotations

import math

import numpy as np

from autograder.families import (
    absolute,
    axes_flipped,
    chain,
    first_last,
    inverse,
    matrix_input,
    not_rotation,
    off_by_one,
    pose_parts,
    precision,
    product_order,
    reflection,
    reversed_stack,
    root,
    sign,
    stack_items,
    statistic,
    sum_for_mean,
    swapped,
    uncentred,
    units_angle,
    units_input,
    units_length,
    wrong_axis,
)
from autograder.families.base import (
    INPUT,
    OUTPUT,
    Family,
    MistakeName,
    Prediction,
    Problem,
    answer_truth,
    is_pose,
    same_answer,
)
from autograder.spec_types import FunctionSpec, Trial

__all__ = ["FAMILIES", "INPUT", "OUTPUT", "Family", "MistakeName", "Prediction", "applicable",
           "mirrored_name", "not_rotation_name", "nulls", "predictions", "transforms",
           "transposed_for_inverse_name", "undoing"]

FAMILIES: tuple[Family, ...] = (
    *inverse.FAMILIES, *units_length.FAMILIES, *units_angle.FAMILIES, *sign.FAMILIES,
    *root.FAMILIES, *sum_for_mean.FAMILIES, *reflection.FAMILIES,
    *swapped.FAMILIES, *reversed_stack.FAMILIES, *first_last.FAMILIES, *absolute.FAMILIES,
    *units_input.FAMILIES,
    *pose_parts.FAMILIES, *stack_items.FAMILIES, *not_rotation.FAMILIES,
    *axes_flipped.FAMILIES,
    *product_order.FAMILIES,
    # stacks and reductions (issue 52): each a walk over the inputs gone wrong
    *off_by_one.FAMILIES, *statistic.FAMILIES, *wrong_axis.FAMILIES, *precision.FAMILIES,
    *uncentred.FAMILIES,
    # a chain of frames gone wrong at one input (issue 52): a factor left out, one used twice;
    # a matrix input read transposed, a camera matrix's principal point left out
    *chain.FAMILIES, *matrix_input.FAMILIES,
)


def applicable(spec: FunctionSpec, trial: Trial, truth=None) -> list[Family]:
    """The families that predict an answer on ``trial`` (the input side only where
    ``spec`` has a reference). A closed loop's function (``spec.drive``) has none: its
    answer is the loop's measured errors."""
    if spec.drive is not None or trial.raises is not None:
        return []
    return [f for f in FAMILIES if f.applies(spec, trial, truth)]


def predictions(spec: FunctionSpec, trial: Trial, truth=None,
                sides=(OUTPUT, INPUT)) -> list[tuple[MistakeName, Prediction]]:
    """``[(name, prediction)]`` of every family on ``trial`` whose side is in ``sides``,
    in :data:`FAMILIES`' order; ``truth`` the part of the truth an answer is compared with
    (default: from ``trial.truth``). [] for a closed loop or a degenerate problem."""
    if spec.drive is not None or trial.raises is not None:
        return []
    problem = Problem(spec, trial, answer_truth(trial, truth))
    seen: list = []
    found = [(f.label(p), p) for f in FAMILIES if f.side in sides
             for p in (f.predictions(problem) if f.side == OUTPUT
                       else _distinct(f.predictions(problem), seen))]
    if INPUT not in sides:
        return found
    # an input-side mistake that changes nothing here (K times 1000 leaves every ray as it
    # was) predicts the right answer: no mistake to name
    right = problem.right_answer()
    return [(name, p) for name, p in found
            if p.undo is not None or right is None or not same_answer(p.answer, right)]


def _identical(a, b) -> bool:
    """True when ``a`` and ``b`` are the same answer bit for bit (NaN where NaN is: a depth
    image's holes), a tuple part by part."""
    if isinstance(a, tuple) or isinstance(b, tuple):
        return isinstance(a, tuple) and isinstance(b, tuple) and len(a) == len(b) \
            and all(_identical(x, y) for x, y in zip(a, b))
    try:
        x, y = np.asarray(a), np.asarray(b)
        return x.shape == y.shape and x.dtype.kind in "fiub" and y.dtype.kind in "fiub" \
            and bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f" == y.dtype.kind))
    except (TypeError, ValueError):
        return False


def _distinct(found: list[Prediction], seen: list) -> list[Prediction]:
    """``found`` less the plain input-side predictions whose answer an earlier one gave bit
    for bit (K.T read entry by entry gives what K without (cx, cy) gives): the nearest rule
    keeps the earlier one for both anyway, and practice data then holds each answer once.
    ``seen`` collects the answers kept, across families."""
    kept = []
    for p in found:
        plain = p.undo is None and not (p.loose or p.wraps or p.resolved) and p.null is None
        if plain and any(_identical(p.answer, q) for q in seen):
            continue
        if plain:
            seen.append(p.answer)
        kept.append(p)
    return kept


def nulls(found: list[tuple[MistakeName, Prediction]]) -> list:
    """The answers that compute nothing of what each prediction scales (the truth's rotation
    with no translation, a tuple with one part zeroed): an answer as near one of them as to
    a mistake's is not told apart from computing nothing there, and gets no name."""
    return [p.null for _, p in found if p.null is not None]


def transforms(truth) -> list[tuple[MistakeName, Prediction]]:
    """The output-side families' predictions on ``truth`` alone (no function, no inputs:
    the families that read the inputs, as sum for mean, give none)."""
    problem = Problem(None, Trial(args=(), truth=truth, tol={}), truth)
    return [(f.label(p), p) for f in FAMILIES if f.side == OUTPUT
            for p in f.predictions(problem) if p.undo is not None]


# Undoing a mistake tells it apart only where zeroing what it scales costs more than this many
# noise units (see Prediction.null).
RESOLVED = 4.0


def undoing(distance):
    """``distance(a, b)`` extended to :class:`Prediction` candidates: an answer against a
    prediction with an ``undo`` is the answer mapped back, measured against the truth (so
    an estimate in millimetres is named on a noisy problem, where the truth in millimetres
    is far from it); two predictions, or one without ``undo``, compare their answers.
    Made for one problem: what depends on one candidate alone (is it a pose, is its mistake
    resolved) is computed once per candidate, not once per comparison."""
    known: dict = {}

    def once(tag: str, of, compute):
        # keyed by identity, holding ``of`` so that its id is not reused while cached
        hit = known.get((tag, id(of)))
        if hit is None or hit[0] is not of:
            hit = known[(tag, id(of))] = (of, compute())
        return hit[1]

    def resolved(b: Prediction) -> bool:
        return b.null is not None and distance(b.null, b.base) <= RESOLVED

    def measure(a, b) -> float:
        if isinstance(b, Prediction) and not isinstance(a, Prediction) \
                and once("pose", b, lambda: is_pose(b.answer)) \
                and not once("pose", a, lambda: is_pose(a)):
            # every pose mistake keeps the rotation block a rotation: one that is none
            # (an axis not normalised) is no such mistake, however near in numbers
            return math.inf
        if isinstance(b, Prediction):
            if isinstance(a, Prediction) or b.undo is None:
                a = a.answer if isinstance(a, Prediction) else a
                return distance(a, b.answer)
            with np.errstate(all="ignore"):  # an answer's square root may be NaN: far
                if once("resolved", b, lambda: resolved(b)):
                    return distance(a, b.answer)
                return distance(b.undo(a), b.base)
        return distance(a.answer if isinstance(a, Prediction) else a, b)
    return measure


def mirrored_name(value, truth) -> MistakeName | None:
    """The reflection family's name when ``value`` is a mirror image of a pose (see
    :func:`autograder.families.reflection.mirrored`), else None."""
    return reflection.REFLECTION.label() if reflection.mirrored(value, truth) else None


def transposed_for_inverse_name(value, truth, distance) -> MistakeName | None:
    """The inverse family's name for T.T returned where T^-1 was asked (see
    :func:`autograder.families.inverse.transposed_for_inverse`), else None."""
    return inverse.FOR_INVERSE.label() \
        if inverse.transposed_for_inverse(value, truth, distance) else None


def not_rotation_name(value, truth, distance) -> MistakeName | None:
    """The not-a-rotation family's name when ``value``'s rotation block is not orthonormal
    and its nearest rotation is the truth's to the noise (``distance`` in noise units; see
    :func:`autograder.families.not_rotation.nearest_rotation_is_right`), else None."""
    return not_rotation.NOT_ROTATION.label() \
        if not_rotation.nearest_rotation_is_right(value, truth, distance) else None

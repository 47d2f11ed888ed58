"""A chain of frames gone wrong at one input: a factor left out, or one input used twice.

* A factor left out: the student's product of frames skips one transform (the residual of
  a fit computed on the points as given, without applying ``dst_T_src``; a point carried
  through ``a_T_b`` but not ``b_T_c``). Applies to a function with a pose among its inputs,
  or a stack of poses: the private reference is called with that pose (every pose of that
  stack) replaced by the identity, which is what leaving the factor out of each product
  computes.
* An input used in place of another of the same kind: two inputs of one shape (two point
  sets, two stacks of poses, two poses) and the first given for both, or the second
  (``src`` where ``dst`` belongs); the swap of the pair is :mod:`.swapped`'s.

Input side (the reference on transformed inputs, precomputed into practice data). The words
name the input by the function's parameter name (``FunctionSpec.parameters``), so a student
reads which variable to look at. A prediction that gives the right answer, the identity or
zeros on a problem (a pose used twice in ``inv(a_T_b) @ a_T_c``) is never named: the
nearest-candidate rule keeps the trivial answers ahead of it.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import INPUT, Family, Prediction, Problem, is_pose, is_stack
from autograder.families.swapped import same_kind_pairs
from autograder.spec_types import declared_parameters

LEFT_OUT = ("the transform {name} was left out of the chain (computed as if it were the "
            "identity): apply {name} in the product, in its place in the chain of frames")
USED_TWICE = ("{used} was used where {meant} belongs (one input taken twice): use each "
              "input for its own parameter")


def parameter_names(spec, n: int) -> list[str]:
    """The names of the first ``n`` parameters of ``spec``'s function, from
    ``spec.parameters`` ("src, dst, iterations=500") or else ``spec.signature``, defaults
    and annotations left out; "input k" (1-based) where the spec does not say."""
    names = declared_parameters(spec)
    if not names:
        # the signature's own list ("f(a_T_b (4, 4), b_T_c)": no Python), its shapes and
        # annotations left out
        signature = getattr(spec, "signature", None) or ""
        text = signature[signature.find("(") + 1:] if "(" in signature else ""
        names = [p.split("=")[0].split(":")[0].strip() for p in _top_level(text)]
        names = [p for p in names if p.isidentifier()]
    return [names[k] if k < len(names) else f"input {k + 1}" for k in range(n)]


def _top_level(text: str) -> list[str]:
    """``text`` split at its commas outside brackets, up to the bracket closing it."""
    out, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            if depth == 0:
                return out + [text[start:i]]
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(text[start:i])
            start = i + 1
    return out + [text[start:]]


def _identity_for(value):
    """The identity in place of a pose, or of every pose of a stack (in its container)."""
    if is_pose(value):
        return np.eye(4)
    eyes = [np.eye(4) for _ in range(len(value))]
    return list(eyes) if isinstance(value, list) else \
        tuple(eyes) if isinstance(value, tuple) else np.stack(eyes)


def one_input_changed(test, change, words: str):
    """A family's predictions: for each input ``a`` that passes ``test(a)``, the reference on
    the inputs with that one replaced by ``change(a)``, named by ``words`` formatted with the
    input's parameter ``name``."""
    def make(problem: Problem) -> list[Prediction]:
        args = tuple(problem.trial.args)
        names = parameter_names(problem.spec, len(args))
        out = []
        for i, a in enumerate(args):
            if not test(a):
                continue
            changed = tuple(change(a) if k == i else x for k, x in enumerate(args))
            answer = problem.reference(*changed)
            if answer is not None:
                out.append(Prediction(answer, words=words.format(name=names[i])))
        return out
    return make


def _pose_or_stack(a) -> bool:
    return not isinstance(a, (int, float, str)) and (is_pose(a) or is_stack(a))


def _used_twice(problem: Problem) -> list[Prediction]:
    args = tuple(problem.trial.args)
    names = parameter_names(problem.spec, len(args))
    out = []
    for i, j in same_kind_pairs(args):
        for used, meant in ((i, j), (j, i)):
            changed = list(args)
            changed[meant] = args[used]
            answer = problem.reference(*changed)
            if answer is not None:
                out.append(Prediction(answer, words=USED_TWICE.format(used=names[used],
                                                                      meant=names[meant])))
    return out


FAMILIES = (
    Family("factor left out", LEFT_OUT.format(name="one input pose"), INPUT,
           one_input_changed(_pose_or_stack, _identity_for, LEFT_OUT), "factor left out"),
    Family("input used twice", USED_TWICE.format(used="one input", meant="another"), INPUT,
           _used_twice, "input used twice"),
)

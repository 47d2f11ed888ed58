"""The types a lab's spec is written in, and the output checks the specs share.

A graded function has two halves. Its public scoring (``autograder/scoring/<lab>.py``):
points, checks, ``measure``, ``drive``, signature, limits; a :class:`FunctionSpec` with
``make_trial=None``, shipped to students. Its private generation (``autograder/specs/<lab>.py``,
instructors only): the generator that computes the truth, the answer functions, the code
mistakes, which completes the same :class:`FunctionSpec` with ``dataclasses.replace``.
Imports go one way: specs -> scoring -> spec_types, and checks -> scoring, spec_types (checks
reaches specs only when the grader asks for them).
"""

from __future__ import annotations

import ast
import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from robots import geometry as geo


class OutputError(ValueError):
    """A student's return value that cannot be scored (wrong type, shape, NaN)."""


@dataclass(frozen=True)
class Check:
    """One measured aspect of an answer.

    ``bands`` are ``(multiple_of_tolerance, credit)`` pairs, tightest first: an error within
    ``multiple * tol`` earns ``credit``. ``unit`` names the error's unit for feedback.

    ``requires`` names other checks of the same function that must earn some credit (any
    band) on a problem for this one to earn any there: a part of the answer that a trivial
    rule gets right on its own (a pose's translation copied from an input while its rotation
    is the identity, a centre without its normal) is worth nothing unless the rest of the
    answer is right. Its credit is then voided on that problem (``CheckResult.n_voided``),
    and the feedback says the check was within its tolerance but another one failed.
    ``describe`` says what the check measures, in words that hold whatever the mistake was:
    it is shown beside every failure of the check, so it must never point one way (a
    stacking error is not "the sign of the gain").
    """

    name: str
    unit: str
    weight: float
    bands: tuple[tuple[float, float], ...]
    describe: str = ""
    requires: tuple[str, ...] = ()

    def credit(self, error: float, tol: float) -> float:
        if not math.isfinite(error):
            return 0.0
        for multiple, credit in self.bands:
            if error <= multiple * tol:
                return credit
        return 0.0

    @property
    def reach(self) -> float:
        """The widest multiple of the tolerance that still earns credit: the scale of "within
        the noise" when an answer is compared with a mistake's (autograder.mistakes)."""
        return max((m for m, credit in self.bands if credit > 0), default=1.0)


@dataclass
class Trial:
    """One problem: the inputs the student's function gets, and what only the grader keeps."""

    args: tuple
    truth: Any
    tol: dict[str, float]
    label: str = ""
    # Edge cases earn credit only when the whole answer is right, so a trivial output (the
    # identity for a zero rotation) cannot collect partial credit on them; and only when the
    # same function is fully right on at least one ordinary problem of the run (neither
    # all_or_nothing nor ``raises``), so the identity for a zero rotation, the one pose of a
    # one-pose chain echoed back or a ValueError raised on every input earns nothing there
    # unless the method itself works (autograder.checks.score_function).
    all_or_nothing: bool = False
    # A degenerate problem (collinear points, too few of them): the right answer is raising
    # this exception (by class name, e.g. "ValueError"), which earns full credit (an edge
    # case: only when an ordinary problem is right, as above); a returned value earns none,
    # whatever it is.
    raises: str | None = None
    # Precomputed by the private side for practice data (autograder.practice), where the
    # spec's ``code_mistakes``, ``reference`` and ``substitutes`` are not shipped: this
    # problem's [(words, predicted answer, family)] of its code mistakes (family None) and
    # its input-side mistake families (autograder.families), and the stand-in tables for a call with ``args``
    # (functions without a ``drive`` only). None: ask the spec.
    mistakes: list | None = None
    substitutes: dict | None = None


@dataclass(frozen=True)
class FunctionSpec:
    """How to grade one student function, found in the notebook by ``name``."""

    name: str
    points: float
    n_trials: int   # hidden problems per student
    # The generator (private: autograder/specs); None in the public scoring entry.
    make_trial: Callable[[np.random.Generator, int], Trial] | None
    measure: Callable[[Any, Trial], dict[str, float]]
    checks: tuple[Check, ...]
    signature: str
    time_limit_s: float = 10.0
    # The notebook's ``def`` parameter list as Python source ("points, inlier_m,
    # iterations=500, seed=0"): names, order and defaults, which `cobotlab labs verify`
    # compares with the notebook (``signature`` is the human-readable form for feedback).
    parameters: str | None = None
    # Closed-loop grading (a control law): ``drive(call, trial)`` calls the student's function
    # as often as it needs, ``call(*args)`` returning its value or raising StudentCallError,
    # and returns what ``measure`` scores. None: one call with ``trial.args``.
    # ``time_limit_s`` then bounds the whole loop of one trial.
    drive: Callable | None = None
    # Dotted names of routines this function must not call (the library routine that does
    # what the lab teaches): a use earns zero for the function (autograder.forbidden).
    forbidden: tuple[str, ...] = ()
    # One bug costs once: ``substitutes(args)`` gives, for one call with ``args``, the true
    # answers of the other graded functions it relies on, {name: [(their args, value), ...]}.
    # While the call runs, the notebook's function of that name answers those arguments with
    # the true value (anything else still goes to the student's own), so a sign error in
    # interaction_matrix is not charged again in ibvs_velocity. Values only, never code.
    substitutes: Callable[[tuple], dict[str, list[tuple[tuple, Any]]]] | None = None
    # Practice problems per public seed (None: n_trials). check() shows len(PUBLIC_SEEDS)
    # seeds' worth, and the hidden grade must draw at least as many, so that a bug check()
    # reveals cannot pass the grader by luck.
    practice_trials: int | None = None
    # The classic wrong versions of this function (private: autograder/specs). Each loses
    # credit on at least 99 % of hidden draws (benchmarks/grading_fairness.py and
    # `cobotlab labs verify` measure it), and an answer equal to one's answer on the same
    # problem is named by check() and the feedback (autograder.mistakes names those seen
    # from the truth alone: inverse pose, millimetres, ...).
    code_mistakes: tuple[CodeMistake, ...] = ()
    # The right answer as code (private: autograder/specs, or an instructor's spec):
    # ``reference(*trial.args)`` returns what a right function returns on those inputs.
    # The input-side mistake families (autograder.families: swapped arguments, a reversed
    # stack, a stack's first item) call it on transformed inputs to predict a mistake's
    # answer; None: those families are not tried on this function.
    reference: Callable | None = None


@dataclass(frozen=True)
class MistakeName:
    """A named mistake, as the grader carries it to check(), the feedback and the class
    report: ``words`` what the student is told (the diagnosis, then the fix after a
    colon); ``family`` the mistake family that named it (autograder.families, e.g.
    "units m/mm"), None for one of a lab's own code mistakes."""

    family: str | None
    words: str

    def __str__(self) -> str:
        return self.words


@dataclass(frozen=True)
class CodeMistake:
    """A classic wrong version of a graded function, as code: ``func`` takes the graded
    function's arguments and returns what that mistake returns; ``label`` is the words the
    feedback shows when a student's answer equals it ("the translation is in millimetres:
    the course works in metres")."""

    label: str
    func: Callable


def copied(value):
    """A deep copy of inputs or answers (arrays, tuples and lists of them, numbers), arrays
    copied directly: ``copy.deepcopy``'s bookkeeping cost more than the arrays where the
    mistake families call a reference on every problem. Anything else is deep-copied."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if type(value) in (tuple, list):
        return type(value)(copied(v) for v in value)
    if value is None or isinstance(value, (bool, int, float, str, np.generic)):
        return value
    return copy.deepcopy(value)


def declared_parameters(spec: FunctionSpec) -> list[str]:
    """The names of ``spec``'s positional parameters, read from ``spec.parameters`` (the
    notebook's ``def`` list, e.g. "points, inlier_m, iterations=500"); [] where it gives
    none or does not parse."""
    if not spec.parameters:
        return []
    try:
        args = ast.parse(f"def f({spec.parameters}):\n    pass").body[0].args
    except SyntaxError:
        return []
    return [a.arg for a in args.posonlyargs + args.args]


def mistake_answers(spec: FunctionSpec, trial: Trial) -> list[tuple[str, Any]]:
    """[(label, answer)] of ``spec``'s code mistakes on ``trial``: one call with its inputs,
    or the spec's closed loop (``drive``) around the mistake, whose answer is the loop's
    measured errors. A mistake that raises, or whose answer is within every tolerance of
    this problem, gives no answer: an answer that passes must not be named as a mistake (a
    float32 composition is exact enough on some problems, a slightly biased fit on others)."""
    answers = []
    with np.errstate(all="ignore"):  # a mistake may divide by zero: that is its bug
        for mistake in spec.code_mistakes:
            try:
                if spec.drive is None:
                    # a copy: a mistake that writes into its inputs must not change the problem
                    args = copy.deepcopy(trial.args)
                    answer = mistake.func(*args)
                else:
                    answer = spec.drive(mistake.func, trial)
            except Exception:  # noqa: BLE001 - a mistake may well raise on some inputs
                continue
            if trial.raises is None and _within_tolerance(spec, trial, answer):
                continue
            answers.append((mistake.label, answer))
    return answers


def _within_tolerance(spec: FunctionSpec, trial: Trial, answer) -> bool:
    try:
        measured = spec.measure(answer, trial)
    except Exception:  # noqa: BLE001 - an answer the scoring rejects is not within tolerance
        return False
    return all(float(measured[c.name]) <= trial.tol[c.name] for c in spec.checks)


# --------------------------------------------------------------------------- output validation


def as_output_pose(value) -> np.ndarray:
    """The student's return value as a finite (4, 4) float array, or OutputError saying why."""
    if isinstance(value, (list, tuple)):
        try:
            value = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise OutputError("returned a list that is not a 4x4 array of numbers") from None
    if not isinstance(value, np.ndarray):
        raise OutputError(f"returned {type(value).__name__}, expected a (4, 4) numpy array")
    if value.shape != (4, 4):
        raise OutputError(f"returned shape {value.shape}, expected (4, 4)")
    value = value.astype(float)
    if not np.all(np.isfinite(value)):
        raise OutputError("returned NaN or inf")
    if np.abs(value[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise OutputError(f"returned a last row {value[3]}, a pose's is [0, 0, 0, 1]")
    return value


def pose_errors(T: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """rotation (deg) and translation (mm) errors of a returned pose; inf if R is no rotation."""
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) <= 0:
        rot = math.inf  # not a rotation: no angle to speak of
    else:
        nearest = geo.project_to_so3(R)
        rot = float(geo.rotation_error_deg(nearest, truth[:3, :3]))
        # project_to_so3 forgives a slightly non-orthonormal block; charge what it removed.
        rot += float(np.degrees(np.abs(R - nearest).max()))
    return {
        "rotation": rot,
        "translation": float(np.linalg.norm(T[:3, 3] - truth[:3, 3]) * 1000.0),
    }


def measure_pose(value, trial: Trial) -> dict[str, float]:
    return pose_errors(as_output_pose(value), trial.truth)


# Exact-arithmetic problems: any correct float64 formula lands within 1e-6 deg / 1e-6 mm
# (about 1e7 times float64 rounding on metre-scale poses); float32 arithmetic lands near
# 1e-4, which earns half; a wrong formula is off by degrees and millimetres.
EXACT_TOL = {"rotation": 1e-6, "translation": 1e-6}
EXACT_BANDS = ((1.0, 1.0), (1e3, 0.5))


def pose_checks(what: str) -> tuple[Check, ...]:
    return (
        Check("rotation", "deg", 0.5, EXACT_BANDS, f"the rotation block of {what}"),
        Check("translation", "mm", 0.5, EXACT_BANDS, f"the translation column of {what}",
              requires=("rotation",)),
    )


def random_pose(rng: np.random.Generator, max_trans_m: float = 1.0) -> np.ndarray:
    R = geo.rotation_from_rotvec(random_rotvec(rng))
    return geo.make_pose(R, rng.uniform(-max_trans_m, max_trans_m, 3))


def random_rotvec(rng: np.random.Generator, angle=None) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return axis * (rng.uniform(0.05, np.pi - 0.05) if angle is None else angle)

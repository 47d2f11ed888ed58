"""Graded-function specifications, scoring, and the student-facing ``check``.

A lab's graded functions are pure (arrays in, arrays out), so each is graded the same way: draw
problems with a seeded generator, call the function on the inputs, and measure the output
against the truth in physical units (degrees, millimetres). Each function has a few named
checks ("rotation", "translation", ...); each check awards credit by accuracy band, as a
multiple of a per-problem tolerance:

* noise-free problems (lab 0): the tolerance is a small multiple of float64 rounding, so any
  correct formula earns full credit, sloppy arithmetic (float32) half, a wrong formula none;
* noisy problems (lab 1 on): the tolerance comes from the noise level and the number of
  measurements (what a least-squares estimator achieves), so a correct method earns full
  credit with overwhelming probability and a wrong one, off by far more, cannot.

The same code scores three ways: :func:`check` on public seeds in the student's notebook
(prints the score and why), :func:`hidden_test` inside nbgrader's kernel (only a cross-check:
that kernel runs student code and can be tampered with), and :mod:`autograder.pipeline.score`, which
scores outputs from an isolated worker against truth it never lets out of its own process.

What a student's copy holds is the public half: the scoring of every graded function
(:mod:`autograder.scoring`) and the practice problems as data (:mod:`autograder.practice`),
so :func:`check` and :func:`hidden_test` score on those in every install. The generators
and answer functions (:mod:`autograder.specs`) are the instructor's: :data:`SPECS`,
:func:`make_trials` and :func:`public_trials` on a generator need them, and this module
imports them only when asked for.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from autograder import families, forbidden, mistakes, practice, registry
from autograder.errors import ErrorGroup, ProblemError, error_groups, error_lines
from autograder.families import not_rotation, pieces, units_angle
from autograder.inside import standin
from autograder.mistakes import Weighing
from autograder.outcomes import Failed, Failure, TrialOutcome, raised

# Re-exported where callers reach them as checks.<name> (tests, benchmarks, grading).
from autograder.spec_types import (  # noqa: F401
    EXACT_TOL,
    Check,
    CodeMistake,
    FunctionSpec,
    MistakeName,
    OutputError,
    Trial,
    measure_pose,
    mistake_answers,
)
from robots import geometry as geo

__all__ = [
    "Check",
    "Trial",
    "FunctionSpec",
    "TrialOutcome",
    "Failure",
    "Failed",
    "raised",
    "CheckResult",
    "FunctionResult",
    "SCORING",
    "PUBLIC_SEEDS",
    "spec_for",
    "make_trials",
    "score_function",
    "evaluate",
    "check",
    "hidden_test",
    "run_trial",
    "StudentCallError",
    "forbidden_result",
    "InstructorOnly",
]

# The public seeds of check() and the kernel seeds of hidden_test() are the practice data's
# (autograder.practice), re-exported here where notebooks and the grader reach them.
PUBLIC_SEEDS, KERNEL_SEEDS = practice.PUBLIC_SEEDS, practice.KERNEL_SEEDS


class InstructorOnly(ImportError):
    """What needs the private generators (a lab's private spec), absent from a student install."""


class _Labs(Mapping):
    """{assignment: specs} over every lab of :mod:`autograder.registry`, each loaded when first
    asked for, so a lab whose files are broken breaks only itself. ``in`` asks whether the
    lab exists, without loading it."""

    def __init__(self, load):
        self._load = load

    def __getitem__(self, name):
        if not isinstance(name, str) or name not in registry.all_labs():
            raise KeyError(name)
        return self._load(name)

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in registry.all_labs()

    def __iter__(self):
        return iter(registry.lab_names())

    def __len__(self) -> int:
        return len(registry.all_labs())


def _private(name: str) -> tuple[FunctionSpec, ...]:
    """The full specs (generators included) of ``name``; InstructorOnly without them."""
    if not registry.private_available(name):
        raise InstructorOnly(
            f"the hidden-problem generators of {name} are only in the instructor's install or "
            "course repository, not in a student's copy; check() and hidden_test() score on "
            "the practice data shipped with each lab instead")
    return registry.specs(name)


SCORING: Mapping[str, tuple[FunctionSpec, ...]] = _Labs(registry.scoring)
"""{assignment: public scoring entries}: what :func:`check` scores with, in every install."""

SPECS: Mapping[str, tuple[FunctionSpec, ...]] = _Labs(_private)
"""{assignment: full specs}: the grader's, the course tools' and the benchmarks'. Importing
this module never imports a private spec; indexing one lab imports that lab's only."""


# A time limit counts CPU seconds of the student's code (the same on a quiet laptop and on a
# loaded grading machine); the wall clock only backs it up, at this multiple of the limit,
# against code that sleeps or blocks.
WALL_BACKSTOP_FACTOR = 4.0


@dataclass
class CheckResult:
    name: str
    unit: str
    credit: float               # 0..1, mean over problems
    n_full: int
    n_trials: int
    worst_error: float
    median_error: float
    tolerance: float            # the full-credit threshold on the worst problem, in ``unit``
    describe: str = ""
    # Problems this check passed but which count as failed because of another check: one it
    # ``requires`` failed there, another check failed on an all-or-nothing edge case, or the
    # edge case counts only with an ordinary problem right (so "worst error 0 mm" beside a
    # failure is no contradiction).
    n_voided: int = 0


def voided_sentence(c: CheckResult, more: bool = True) -> str:
    """Why ``c`` counts as failed on problems where it was within its tolerance (its
    ``n_voided``), in words for the feedback; never "outside the tolerance". ``more``: the
    sentence follows a count of problems outside the tolerance."""
    n, s = c.n_voided, "s" if c.n_voided != 1 else ""
    head = f"{n} more problem{s} within the tolerance but" if more else f"{n} problem{s}"
    return (f"{head} counted as failed: another check failed there (a part of the answer "
            "counts only when the rest is right), or it is an edge case, which counts only "
            "when the whole answer is right on it and on an ordinary problem")


@dataclass
class FunctionResult:
    """The score of one function and the reasons, in words a student can act on."""

    name: str
    points: float
    max_points: float
    checks: list[CheckResult] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    # For feedback: problems run and problems not fully right, and the forbidden routines used.
    n_problems: int = 0
    n_failed: int = 0
    forbidden: tuple[str, ...] = ()
    # What went wrong on each problem that erred, in the order the scoring met them
    # (``errors`` is their first lines); the feedback's counts and groups derive from it.
    problem_errors: tuple[ProblemError, ...] = ()
    # The classic mistakes the answers looked like (each a typed name: a mistake family's
    # or a code mistake's, once each, in the order first met): what the class report counts.
    mistakes: tuple[MistakeName, ...] = ()

    @property
    def fraction(self) -> float:
        return self.points / self.max_points if self.max_points else 0.0

    @property
    def error_groups(self) -> list[ErrorGroup]:
        """Each distinct message once with its count, typed failure and labels (see
        :func:`autograder.errors.error_groups`); a verdict written without
        problems (a forbidden routine's) is its ``errors``, on no problem."""
        if not self.problem_errors:
            return [ErrorGroup(e, 0, None) for e in dict.fromkeys(self.errors)]
        return error_groups(self.problem_errors)

    @property
    def error_counts(self) -> dict[str, int]:
        """{message: problems it was said on}, from :attr:`problem_errors`."""
        return {g.message: g.count for g in error_groups(self.problem_errors)}

    @property
    def lost_to_time(self) -> bool:
        """Some problem was lost to a time limit (see :attr:`Failure.lost_to_time`)."""
        return any(g.failure is not None and g.failure.lost_to_time
                   for g in error_groups(self.problem_errors))

    @property
    def failed_checks(self) -> list[str]:
        return [c.name for c in self.checks if c.credit < 1.0]

    def summary(self) -> str:
        lines = [f"{self.name}: {self.points:g} / {self.max_points:g} points"]
        for c in self.checks:
            status = "ok  " if c.credit >= 1.0 else ("part" if c.credit > 0 else "FAIL")
            unit = f" {c.unit}" if c.unit else ""
            worst = ("none (no usable answer on some problems)" if not math.isfinite(c.worst_error)
                     else f"{c.worst_error:.3g}{unit}")
            voided = f"; {voided_sentence(c)}" if c.n_voided else ""
            lines.append(f"  [{status}] {c.name}: {c.n_full}/{c.n_trials} problems within "
                         f"{c.tolerance:.3g}{unit}; worst error {worst}{voided}"
                         + (f"  ({c.describe})" if c.describe and c.credit < 1 and not voided
                            else ""))
        for e in self.errors:
            lines.append(f"  ! {e}")
        return "\n".join(lines)


def _current_assignment() -> str | None:
    """The lab whose folder this process runs in, if any.

    A notebook's kernel starts in the notebook's folder, which is named after the assignment
    in labs/, in an nbgrader course (source/, release/, autograded/<student>/) and in a
    student's download, so two labs may grade functions of the same name.
    """
    import os

    name = os.path.basename(os.getcwd())
    return name if name in SCORING else None


def _locate(name: str, assignment: str | None = None) -> tuple[str, int]:
    """(assignment, index in its SPECS) of graded function ``name`` (see :func:`spec_for`)."""
    if assignment is not None and assignment not in SCORING:
        raise ValueError(f"unknown assignment {assignment!r}; assignments are {sorted(SCORING)}")
    here = assignment or _current_assignment()
    if here is not None:
        for i, spec in enumerate(SCORING[here]):
            if spec.name == name:
                return here, i
        if assignment is not None:
            known = sorted(s.name for s in SCORING[assignment])
            raise ValueError(f"{assignment} grades no function named {name!r}; it grades {known}")
    matches = [(lab, i) for lab, group in _usable_labs() for i, spec in enumerate(group)
               if spec.name == name]
    if len(matches) == 1:
        return matches[0]
    if matches:
        labs = ", ".join(lab for lab, _ in matches)
        raise ValueError(f"{name!r} is graded in several labs ({labs}); pass assignment=")
    known = sorted(s.name for _, g in _usable_labs() for s in g)
    raise ValueError(f"no graded function named {name!r}; graded functions are {known}")


def _usable_labs():
    """(lab, public entries) of every lab that loads: one lab's broken files must not stop
    check() in another (the broken lab says what is wrong when it is itself asked for)."""
    for lab in registry.lab_names():
        try:
            yield lab, SCORING[lab]
        except registry.LabError:
            continue


def spec_for(name: str, assignment: str | None = None) -> FunctionSpec:
    """The spec of graded function ``name`` in ``assignment``: the full one (with its
    generator) in an instructor's install, the public scoring entry in a student's.

    Without ``assignment``: the lab of the current folder if it grades ``name``, else the one
    lab that does; a name graded by several labs then needs ``assignment=``.
    """
    lab, index = _locate(name, assignment)
    if registry.private_available(lab):
        return SPECS[lab][index]
    return SCORING[lab][index]


def _assignment_of(spec: FunctionSpec) -> str:
    """The assignment whose spec (public or full) ``spec`` is."""
    for lab, group in _usable_labs():
        if any(s is spec for s in group):
            return lab
    for lab, group in registry.loaded_specs().items():
        if any(s is spec for s in group):
            return lab
    return _locate(spec.name)[0]


# --------------------------------------------------------------------------- scoring


def make_trials(spec: FunctionSpec, rng: np.random.Generator, n: int | None = None) -> list[Trial]:
    """``n`` (default ``spec.n_trials``) problems drawn from ``rng`` by the spec's generator
    (a full spec of :data:`SPECS`: the public scoring entries have none)."""
    if spec.make_trial is None:
        raise InstructorOnly(f"{spec.name}: drawing new problems needs the instructor's "
                             "generators (checks.SPECS); a public scoring entry has none")
    return [spec.make_trial(rng, i) for i in range(spec.n_trials if n is None else n)]


def public_trials(spec: FunctionSpec, seed: int) -> list[Trial]:
    """The practice problems of a public seed (the same generator as the hidden ones).

    A full spec draws them; a public scoring entry reads them from the practice data
    (:mod:`autograder.practice`), with their mistakes and stand-in tables precomputed.
    """
    if spec.make_trial is None:
        return practice.practice_trials(_assignment_of(spec), spec.name, [seed])
    return make_trials(spec, practice.practice_rng(seed), spec.practice_trials or spec.n_trials)


# How a named mistake begins its message to the student (the mistake itself is also in
# FunctionResult.mistakes, which is what the class report counts).
MISTAKE_NOTE = "this answer looks like a classic mistake: "


def problem_errors(spec: FunctionSpec, trials: list[Trial],
                   outcomes: list[TrialOutcome]) -> list[dict[str, tuple[float, float]]]:
    """Each problem's ``{check: (error, tolerance)}`` as :func:`score_function` measures
    them, in the check's unit (error inf: no usable answer); the degenerate inputs that must
    raise are left out (their error is no distance)."""
    out = []
    for trial, outcome in zip(trials, outcomes):
        if trial.raises is not None:
            continue
        measured = _measured(spec, outcome.value, trial)[0] if outcome.error is None else None
        out.append({name: (row[0], row[1]) for name, row in
                    _problem_rows(spec, trial, measured).items()})
    return out


def score_function(spec: FunctionSpec, trials: list[Trial],
                   outcomes: list[TrialOutcome], *, hints: bool = True) -> FunctionResult:
    """Score a function's outcomes on ``trials``; a failed call earns nothing on that problem.

    ``hints=False`` leaves out the "looks like a classic mistake" notes, which never change a
    score: the fairness statistics of ``labs verify`` score thousands of draws and only count
    points, and naming a mistake costs more than scoring it (every failed problem is compared
    with each of the spec's mistakes and the mistake families of autograder.families).
    """
    if len(trials) != len(outcomes):
        raise ValueError(f"{len(trials)} trials but {len(outcomes)} outcomes")
    found: list[ProblemError] = []
    mistakes: dict[MistakeName, None] = {}
    # First pass: each problem's rows {check: (error, tol, credit, voided)} on its own.
    table = []
    for trial, outcome in zip(trials, outcomes):
        measured, error = _measured_or_error(spec, trial, outcome)
        found += [error] if error is not None else []
        table.append((measured, _problem_rows(spec, trial, measured)))
    # An edge case (all-or-nothing, or a degenerate input that must raise) earns credit only
    # when the method is right on at least one ordinary problem: the identity for a zero
    # rotation, a one-pose chain echoed back, or a ValueError raised on every input is no
    # method (see Trial.all_or_nothing).
    ordinary = [rows for t, (_, rows) in zip(trials, table)
                if not (t.all_or_nothing or t.raises is not None)]
    method_right = any(rows and min(r[2] for r in rows.values()) >= 1.0 for rows in ordinary)
    per_check = {c.name: [] for c in spec.checks}
    answered_wrong: list[tuple[Trial, object]] = []
    n_failed = 0
    gated = 0
    for trial, outcome, (measured, rows) in zip(trials, outcomes, table):
        edge = trial.all_or_nothing or trial.raises is not None
        if edge and ordinary and not method_right and rows \
                and min(r[2] for r in rows.values()) > 0.0:
            rows = {k: (r[0], r[1], 0.0, r[3] or r[2] >= 1.0) for k, r in rows.items()}
            gated += 1
        failed = bool(rows) and min(r[2] for r in rows.values()) < 1.0
        n_failed += failed
        if failed and outcome.error is None and trial.raises is None:
            answered_wrong.append((trial, outcome.value))
        for name, row in rows.items():
            per_check[name].append(row)
    found += _named_lines(spec, answered_wrong, mistakes, hints)
    if gated:   # leads: why right answers earned nothing, past the cap of five lines
        found.append(ProblemError(
            next(t.label for t in trials if t.all_or_nothing or t.raises is not None),
            f"answered right, but {gated} edge case(s) like this count only when the answer "
            "is right on at least one ordinary problem too, and it is right on none",
            leads=True))
    results = [_check_result(c, per_check[c.name]) for c in spec.checks]
    total = sum(c.weight * r.credit for c, r in zip(spec.checks, results))
    points = round(spec.points * total / sum(c.weight for c in spec.checks), 2)
    return FunctionResult(spec.name, points, spec.points, results, error_lines(found),
                          n_problems=len(trials), n_failed=n_failed,
                          problem_errors=tuple(found), mistakes=tuple(mistakes))


def _named_lines(spec: FunctionSpec, answered_wrong: list, named: dict,
                 hints: bool = True) -> list[ProblemError]:
    """The lines of what each failed answer ``(trial, value)`` looks like, in their order:
    the classic mistake it is nearest to (added to ``named``), else, for a rotation block
    that is no rotation, that symptom. A mistake is named only where no failed problem rules
    it out: one slip gives the same answer on every problem, so a name that fits some
    problems (an edge case where two causes give one answer: a symmetric rotation block is
    its own transpose) but lies beyond the noise on another failed one is not the cause.
    ``hints=False`` names nothing (a hint never changes a score)."""
    weighed = [_weighed_hint(spec, value, trial) if hints else Weighing(None)
               for trial, value in answered_wrong]
    given = {w.label for w in weighed} - {None}
    ruled_out: set = set()
    for (trial, value), w in zip(answered_wrong, weighed):
        doubted = (w.far & given) - {w.label} - ruled_out
        if doubted:
            ruled_out |= doubted - _near_on_a_piece(spec, value, trial, doubted)
    lines = []
    for (trial, value), w in zip(answered_wrong, weighed):
        if w.label is not None and w.label not in ruled_out:
            named.setdefault(w.label)
            lines.append(ProblemError(trial.label, f"{MISTAKE_NOTE}{w.label.words}", leads=True))
        elif _no_rotation(value, trial):
            # the symptom, where no cause is known: "inf deg" alone says nothing of why
            lines.append(ProblemError(trial.label, not_rotation.NOT_A_ROTATION, leads=True))
    return lines


def _near_on_a_piece(spec: FunctionSpec, value, trial: Trial, labels: set) -> set:
    """Those of ``labels`` (mistakes ``value`` lies beyond the noise of as a whole on
    ``trial``) that one piece of ``value`` lies within the noise of: a translation in
    millimetres beside a rotation wrong for another reason is still that mistake there."""
    try:
        truth = _answer_truth(trial, value)
        _, predicted, distance = _weighing_terms(spec, trial, truth)
        predicted = [p for p in predicted if p[0] in labels]
        return set().union(*(w.near for w in _piece_weighings(value, truth, predicted, distance)))
    except Exception:  # noqa: BLE001 - what cannot be weighed rules nothing out
        return set(labels)


def _no_rotation(value, trial: Trial) -> bool:
    """True when ``value`` answers a pose or rotation with a block that is not orthonormal
    (:func:`autograder.families.not_rotation.not_orthonormal`); never raises."""
    try:
        return not_rotation.not_orthonormal(value, _answer_truth(trial, value))
    except Exception:  # noqa: BLE001 - a value this odd has other lines to say why
        return False


def _measured_or_error(spec: FunctionSpec, trial: Trial,
                       outcome: TrialOutcome) -> tuple[dict | None, ProblemError | None]:
    """One problem's ``{check: error}`` (None: nothing to measure) and what went wrong on
    it, if anything: the call's failure, an answer that cannot be measured, or a degenerate
    input that did not raise as it must."""
    if trial.raises is not None:
        if outcome.has_raised(trial.raises):
            return {c.name: 0.0 for c in spec.checks}, None
        # the message is the scoring's, whatever the call did: no failure behind it, but
        # the line the call raised at, where it raised, is the student's to see
        return None, ProblemError(trial.label, f"expected {trial.raises} on this degenerate "
                                  f"input, got {outcome.error or 'a return value'}",
                                  place=outcome.failure.place if outcome.failure else None)
    if outcome.error is not None:
        return None, ProblemError(trial.label, outcome.error, outcome.failure)
    measured, message = _measured(spec, outcome.value, trial)
    return measured, (None if message is None
                      else ProblemError(trial.label, message, outcome.failure))


def _check_result(c, rows: list[tuple]) -> CheckResult:
    """One check's result from its problems' rows ``(error, tol, credit, voided)``."""
    errs = np.array([r[0] for r in rows])
    credit = float(np.mean([r[2] for r in rows])) if rows else 0.0
    # The worst problem is the one furthest past its own tolerance (tolerances differ per
    # problem), so the tolerance printed is the one that problem failed.
    ratios = np.array([r[0] / r[1] if r[1] > 0 else (0.0 if r[0] == 0 else math.inf)
                       for r in rows])
    worst = int(np.argmax(np.nan_to_num(ratios, nan=math.inf))) if rows else 0
    return CheckResult(
        name=c.name, unit=c.unit, credit=credit,
        n_full=sum(1 for r in rows if r[2] >= 1.0), n_trials=len(rows),
        worst_error=float(errs[worst]) if rows else math.inf,
        median_error=float(np.median(errs)) if rows else math.inf,
        tolerance=float(rows[worst][1]) if rows else math.nan, describe=c.describe,
        n_voided=sum(1 for r in rows if r[3]))


def _problem_rows(spec: FunctionSpec, trial: Trial, measured: dict | None) -> dict:
    """{check: (error, tol, credit, voided)} of one problem: each check's band credit, then
    a check whose ``requires`` earned nothing voided, then, on an all-or-nothing problem,
    every check voided unless all are fully right. ``voided``: the check was within its
    tolerance but counts as failed because of another check."""
    rows = {}
    for c in spec.checks:
        err = math.inf if measured is None else measured[c.name]
        rows[c.name] = (err, trial.tol[c.name], c.credit(err, trial.tol[c.name]), False)
    raw = dict(rows)
    for c in spec.checks:
        if any(raw[name][2] <= 0.0 for name in c.requires):
            err, tol, credit, _ = rows[c.name]
            rows[c.name] = (err, tol, 0.0, credit >= 1.0)
    if trial.all_or_nothing and rows and min(r[2] for r in rows.values()) < 1.0:
        rows = {k: (r[0], r[1], 0.0, r[3] or r[2] >= 1.0) for k, r in rows.items()}
    return rows


def _measured(spec: FunctionSpec, value, trial: Trial) -> tuple[dict | None, str | None]:
    """({check: error as a float}, None) for the answer ``value`` to ``trial``, or (None,
    why it cannot be measured). Never raises: the value is the student's, and whatever it
    is (an integer of 400 digits, an object array, a string where a pose belongs) it costs
    that problem, not the grade of the whole submission."""
    try:
        measured = spec.measure(value, trial)
        return {c.name: float(measured[c.name]) for c in spec.checks}, None
    except OutputError as exc:
        return None, str(exc)
    except Exception as exc:  # noqa: BLE001 - any value the measure cannot use fails here
        detail = str(exc)[:200]
        return None, (f"returned a value that cannot be measured ({type(exc).__name__}"
                      + (f": {detail})" if detail else ")"))


def _mistake_hint(spec: FunctionSpec, value, trial: Trial) -> MistakeName | None:
    """The name of the one classic mistake ``value`` is clearly nearest to on ``trial`` (the
    spec's code mistakes and the input-side families' predictions, both precomputed with
    practice data, and the output-side families of :mod:`autograder.families`), or None.
    None when nothing is near, when two are about as near, or when comparing cannot be done
    on a value this odd."""
    return _weighed_hint(spec, value, trial).label


def _weighed_hint(spec: FunctionSpec, value, trial: Trial) -> Weighing:
    """:func:`_mistake_hint`'s name, with the names ``value`` lies beyond the noise of on
    ``trial`` (:class:`autograder.mistakes.Weighing`)."""
    try:
        return _matching_mistake(spec, value, trial)
    except Exception:  # noqa: BLE001 - a hint is a courtesy: no hint, never a failed grade
        return Weighing(None)


def _answer_truth(trial: Trial, value):
    """The part of ``trial.truth`` an answer is compared with: the truth itself, or its first
    part when the truth carries what the measure needs beside it (fit_rigid's (pose, points))
    and the answer is no pair."""
    truth = trial.truth
    if isinstance(truth, (tuple, list)) and truth and not isinstance(value, (tuple, list)):
        return truth[0]
    return truth


def _as_truth(trial: Trial, answer):
    """``answer`` in the form of ``trial.truth``, so the spec's measure can take it as one."""
    truth = trial.truth
    if isinstance(truth, (tuple, list)) and truth and not isinstance(answer, (tuple, list)):
        return (answer, *truth[1:])
    return answer


def _noise_distance(spec: FunctionSpec, trial: Trial):
    """distance(a, b): answer ``a`` measured against ``b`` taken as the truth, by the spec's
    own measure, each check's error over its tolerance times its widest credited band (so 1
    is the edge of "within the noise", the scale the problem's own noise sets), the largest
    over the checks. A closed loop's measured errors (a dict), or answers the measure cannot
    take as a truth or measure at all, are compared entry by entry relative to their size (2 %,
    as :func:`autograder.mistakes.matches`) or to the check's tolerance, whichever is larger."""
    reach = {c.name: c.reach * trial.tol[c.name] for c in spec.checks}

    def relative(a, b) -> float:
        if isinstance(a, dict) or isinstance(b, dict):
            if not (isinstance(a, dict) and isinstance(b, dict)) or a.keys() != b.keys():
                return math.inf
            return max((relative(a[k], b[k]) if k not in reach else
                        abs(float(a[k]) - float(b[k]))
                        / max(reach[k], 0.02 * abs(float(b[k])), 1e-300)
                        for k in a), default=0.0)
        return mistakes.relative_distance(a, b)

    def distance(a, b) -> float:
        if spec.drive is not None:
            return relative(a, b)
        try:
            with np.errstate(all="ignore"):
                measured = spec.measure(a, Trial(args=trial.args, truth=_as_truth(trial, b),
                                                 tol=trial.tol, label=trial.label))
            d = max(float(measured[name]) / scale if scale > 0 else
                    (0.0 if float(measured[name]) == 0 else math.inf)
                    for name, scale in reach.items())
        except Exception:  # noqa: BLE001 - b is no truth the measure takes: compare as arrays
            return relative(a, b)
        # inf: the measure has no number for ``a`` (a rotation block that is no rotation, as a
        # frame whose y axis was copied), whatever it is compared with: compare as arrays
        return d if math.isfinite(d) else relative(a, b)

    return distance


def _predicted(spec: FunctionSpec, trial: Trial, truth) -> list:
    """[(MistakeName, answer or Prediction)]: the code mistakes, then the families, in that
    order so that where a family predicts what a code mistake does, the lab's own words
    (written for that function) speak for both. Practice data carries the code mistakes and
    the input-side families precomputed (a student's install has no reference to call)."""
    if trial.mistakes is not None:
        listed = [(_as_name(m), _precomputed(_as_name(m), m[1], truth)) for m in trial.mistakes]
        sides = (families.OUTPUT,)
    else:
        listed = [(MistakeName(None, words), answer)
                  for words, answer in mistake_answers(spec, trial)]
        sides = (families.OUTPUT, families.INPUT)
    return listed + families.predictions(spec, trial, truth, sides)


def _precomputed(name: MistakeName, answer, truth):
    """A practice problem's precomputed answer as the grader weighs it live: practice data
    holds answers only, so the one input-side family whose prediction wraps (the
    reference's pose estimate with its angle times 180/pi) gets its rule back."""
    if name.family == units_angle.FAMILIES[0].name and families.is_pose(truth) \
            and families.is_pose(answer):
        return families.Prediction(answer, wraps=True)
    return answer


def _as_name(entry) -> MistakeName:
    """A practice problem's precomputed mistake ``(words, answer[, family])`` as its name."""
    if isinstance(entry[0], MistakeName):
        return entry[0]
    return MistakeName(entry[2] if len(entry) > 2 else None, str(entry[0]))


def _matching_mistake(spec: FunctionSpec, value, trial: Trial) -> Weighing:
    if spec.drive is not None:
        # the closed loop's measured errors; the truth's are none at all
        predicted = trial.mistakes if trial.mistakes is not None else \
            mistake_answers(spec, trial)
        listed = [(None, {c.name: 0.0 for c in spec.checks}),
                  *((_as_name(m) if trial.mistakes is not None else MistakeName(None, m[0]),
                     m[1]) for m in predicted)]
        return mistakes.weigh(value, listed, _noise_distance(spec, trial))
    truth = _answer_truth(trial, value)
    noise, predicted, distance = _weighing_terms(spec, trial, truth)
    whole = _whole_answer_weighing(value, truth, predicted, distance)
    hint = whole.label
    if hint is None and not _measurable(spec, value, trial):
        # T.T for T^-1, then a piece's mistake, before what is read from the answer itself:
        # a translation in millimetres is named beside a rotation block that is no rotation
        hint = families.transposed_for_inverse_name(value, truth, noise) \
            or _piece_name(_piece_weighings(value, truth, _invertible(predicted), distance))
    hint = hint or families.mirrored_name(value, truth) \
        or families.not_rotation_name(value, truth, noise)
    return Weighing(hint, whole.far)


def _weighing_terms(spec: FunctionSpec, trial: Trial, truth) -> tuple:
    """What the nearest rule weighs an answer on ``trial`` with: the problem's noise distance,
    the candidates (code mistakes and families, less those the noise does not resolve) and
    the distance that undoes a mistake and bounds a scaled angle's radius."""
    noise = _noise_distance(spec, trial)
    predicted = _resolved(_predicted(spec, trial, truth), noise, truth)
    distance = _wrapping(families.undoing(noise), lambda: _wrap_radius(noise, truth))
    return noise, predicted, distance


def _whole_answer_weighing(value, truth, predicted: list, distance) -> Weighing:
    """The nearest rule on ``value`` as a whole against ``predicted`` (see
    :func:`_matching_mistake`): the exact candidates, then the loose ones."""
    exact = [p for p in predicted if not _loose(p[1])]
    nothing = [(None, truth), *_no_mistakes(truth, exact)]
    weighed = mistakes.weigh(value, nothing + exact, distance)
    loose = [p for p in predicted if _loose(p[1])]
    if weighed.label is None and loose:
        # a mistake in one part whatever the rest: only where no whole answer names it;
        # before the whole-answer candidates: where one gives the same answer on this
        # problem, it was not near in the first pass, so the loose one speaks for both
        weighed = mistakes.weigh(value, nothing + loose + exact, distance)
    return weighed


def _measurable(spec: FunctionSpec, value, trial: Trial) -> bool:
    """True when the spec's measure gives every check a finite error on ``value``."""
    measured, _ = _measured(spec, value, trial)
    return measured is not None and all(math.isfinite(e) for e in measured.values())


def _invertible(predicted: list) -> list:
    """The mistakes that map a right piece to the answer's and back (``undo``: x1000,
    degrees, an inverse): the only ones named from a piece of an answer that cannot be
    measured as a whole. Undoing one gives the truth's piece, while a piece that merely
    looks like a part left out (a translation near zero) says nothing of why, beside another
    piece that is wrong for a reason no candidate knows."""
    return [p for p in predicted
            if isinstance(p[1], families.Prediction) and p[1].undo is not None]


def _piece_weighings(value, truth, predicted: list, distance) -> list[Weighing]:
    """Each piece of ``value`` (:func:`autograder.families.pieces.spliced`: a pose's
    rotation block, its translation; each part of a tuple) spliced into the truth and
    weighed on its own against ``predicted``."""
    return [_whole_answer_weighing(piece, truth, predicted, distance)
            for piece in pieces.spliced(value, truth)]


def _piece_name(by_piece: list[Weighing]) -> MistakeName | None:
    """The one name the pieces' weighings give (:func:`_piece_weighings`), or None when
    they give none or two different ones (never two names at once)."""
    names = {w.label for w in by_piece} - {None}
    return names.pop() if len(names) == 1 else None


# A pose's angle scaled (times 180/pi, halved, doubled) is named only where a wrong angle
# about the right axis (another scaling, an axis left unnormalised) lands that near it by
# chance at most this often (its noise band against a full turn): on a problem whose noise
# spans degrees only an answer that is the mistake to rounding is named.
WRAP_CHANCE = 1e-4


def _wrap_radius(distance, truth) -> float:
    """The radius, in noise units (at most 1), within which an answer is named as a pose
    whose angle was scaled: a wrong angle about the right axis (an axis left unnormalised,
    another factor; times 180/pi wraps around the turn) lands within a band of the
    prediction by chance; the band is kept to :data:`WRAP_CHANCE` of the turn."""
    T = np.array(truth, dtype=float)
    axis = geo.rotvec_from_rotation(T[:3, :3])
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-9 else np.eye(3)[2]
    turned = np.array(T)
    turned[:3, :3] = T[:3, :3] @ geo.rotation_from_rotvec(np.radians(1.0) * axis)
    per_degree = float(distance(turned, T))      # noise units per degree about the axis
    return min(1.0, WRAP_CHANCE * 180.0 * per_degree)


def _wrapping(distance, radius):
    """``distance`` with an answer's distance to a ``wraps`` prediction over ``radius()``
    (computed once, when first needed)."""
    found: list[float] = []

    def measure(a, b) -> float:
        d = distance(a, b)
        if isinstance(b, families.Prediction) and b.wraps and \
                not isinstance(a, families.Prediction):
            if not found:
                found.append(radius())
            return d / found[0] if found[0] > 0 else math.inf
        return d
    return measure


def _resolved(predicted: list, distance, truth) -> list:
    """``predicted`` less the predictions marked ``resolved`` that lie within
    ``families.RESOLVED`` noise units of the truth: there the mistake moves the answer too
    little to be told (a half turn is its own transpose; an angle halved under noise that
    spans degrees)."""
    def kept(candidate) -> bool:
        return not (isinstance(candidate, families.Prediction) and candidate.resolved) \
            or distance(candidate.answer, truth) > families.RESOLVED
    return [p for p in predicted if kept(p[1])]


def _loose(candidate) -> bool:
    return isinstance(candidate, families.Prediction) and candidate.loose


def _no_mistakes(truth, predicted: list) -> list:
    """(None, answer) of the answers that compute nothing: the trivial ones and the
    predictions' nulls, less those a family names as its mistake (a translation left out
    is the zero translation)."""
    # only an answer compared as it is can be a null (one with an undo is a transform of the
    # truth); the families' nulls are mostly one answer ([R | 0]): each compared once
    answers = [p[1].answer if isinstance(p[1], families.Prediction) else p[1]
               for p in predicted
               if not (isinstance(p[1], families.Prediction) and p[1].undo is not None)]
    nulls: list = []
    for t in families.nulls([p for p in predicted if isinstance(p[1], families.Prediction)]):
        if not any(families.same_answer(t, u) for u in nulls):
            nulls.append(t)
    nulls = [t for t in nulls if not any(families.same_answer(t, a) for a in answers)]
    return [(None, t) for t in mistakes.trivial_answers(truth) + nulls]


class StudentCallError(Exception):
    """A call of the student's function inside a closed-loop ``drive`` failed (``failure``:
    how, when the grader knows)."""

    def __init__(self, message: str, failure: Failure | None = None):
        super().__init__(message)
        self.failure = failure


class _CallerFailed(BaseException):
    """Carries an exception of ``call_once`` itself (not of the student's function) out
    of a closed loop, past any ``except Exception`` in the loop and past the net that
    charges the loop's other failures to the student's values."""

    def __init__(self, cause: Exception):
        super().__init__(cause)
        self.cause = cause


def run_trial(spec: FunctionSpec, trial: Trial, call_once, time_limit_s: float,
              wall_factor: float = WALL_BACKSTOP_FACTOR) -> TrialOutcome:
    """One trial: a single ``call_once(args, cpu_limit_s) -> TrialOutcome``, or the spec's
    closed loop of them (``spec.drive``) within ``time_limit_s`` CPU seconds of the student's
    code in all (wall clock: ``wall_factor`` times that)."""
    if spec.drive is None:
        return call_once(trial.args, time_limit_s)
    started = time.perf_counter()
    cpu_used = 0.0

    def call(*args):
        nonlocal cpu_used
        left = time_limit_s - cpu_used
        if left <= 0 or time.perf_counter() - started > wall_factor * time_limit_s:
            raise StudentCallError(f"timed out: the closed loop took over {time_limit_s:g} s",
                                   Failure(Failed.TIMED_OUT, limit_s=time_limit_s))
        try:
            outcome = call_once(args, left)
        except Exception as exc:  # noqa: BLE001 - the caller's failure (a worker that died)
            raise _CallerFailed(exc) from None
        cpu_used += outcome.cpu_seconds
        if outcome.error is not None:
            raise StudentCallError(outcome.error, outcome.failure)
        return outcome.value

    def done(**kwargs) -> TrialOutcome:
        return TrialOutcome(seconds=time.perf_counter() - started, cpu_seconds=cpu_used, **kwargs)

    try:
        value = spec.drive(call, trial)
    except _CallerFailed as failed:
        raise failed.cause from None
    except StudentCallError as exc:
        return done(error=str(exc), failure=exc.failure or raised(""))
    except OutputError as exc:
        return done(error=f"returned an unusable value in the loop: {exc}",
                    failure=Failure(Failed.UNUSABLE))
    except Exception as exc:  # noqa: BLE001 - the loop ran on the student's values
        return done(error=f"returned a value the closed loop cannot use "
                          f"({type(exc).__name__}: {str(exc)[:200]})",
                    failure=Failure(Failed.UNUSABLE))
    return done(value=value)


def _call_in_process(func, trial: Trial, spec: FunctionSpec | None = None) -> TrialOutcome:
    def once(args, timeout_s):
        # Fresh copies: a function that writes into its input must not corrupt the next check.
        args = tuple(standin.copy_value(a) for a in args)
        if spec is not None and spec.drive is None and trial.substitutes is not None:
            tables = trial.substitutes  # practice data: precomputed for trial.args
        else:
            tables = spec.substitutes(args) if spec is not None and spec.substitutes else None
        started, cpu_started = time.perf_counter(), time.process_time()

        def outcome(**kwargs) -> TrialOutcome:
            return TrialOutcome(seconds=time.perf_counter() - started,
                                cpu_seconds=time.process_time() - cpu_started, **kwargs)

        try:
            with standin.substituted(getattr(func, "__globals__", {}), tables):
                value = func(*args)
        except Exception as exc:  # noqa: BLE001 - report any error as the student's
            return outcome(error=f"{type(exc).__name__}: {exc}",
                           failure=raised(type(exc).__name__))
        return outcome(value=value)

    if spec is None:
        return once(trial.args, math.inf)
    return run_trial(spec, trial, once, spec.time_limit_s)


def forbidden_result(spec: FunctionSpec, names) -> FunctionResult:
    """Zero for ``spec``: it uses the forbidden routines ``names``; the reason says which."""
    listed = ", ".join(sorted(names))
    return FunctionResult(spec.name, 0.0, spec.points, [], [
        f"uses {listed}, which {spec.name} must not call: this lab asks you to write that "
        "computation yourself (score 0 for this function)"], forbidden=tuple(sorted(names)))


def _static_forbidden(func, spec: FunctionSpec, always=forbidden.ALWAYS_FORBIDDEN) -> list[str]:
    """Forbidden names in ``func``'s own source, its aliases resolved in its globals."""
    import inspect
    import textwrap

    try:
        source = textwrap.dedent(inspect.getsource(func))
    except (OSError, TypeError):
        return []
    header = []
    for alias, value in getattr(func, "__globals__", {}).items():
        target = getattr(value, "__name__", None) if inspect.ismodule(value) else None
        if target is None and callable(value) and getattr(value, "__module__", None):
            target = f"{value.__module__}.{getattr(value, '__name__', alias)}"
        if target and alias.isidentifier() and target.replace(".", "").replace("_", "").isalnum():
            header.append(f"import {target} as {alias}" if inspect.ismodule(value)
                          else f"from {target.rsplit('.', 1)[0]} import "
                               f"{target.rsplit('.', 1)[1]} as {alias}")
    # a lambda's source is the line that binds it: scanned under the graded name it is bound to
    name = func.__name__ if func.__name__.isidentifier() else spec.name
    return forbidden.static_hits(header + [source], name, spec.forbidden, always)


def evaluate(func, name: str | None = None, seeds=PUBLIC_SEEDS,
             assignment: str | None = None, reference: bool = False) -> FunctionResult:
    """Score ``func`` in this process on the problems of the given public ``seeds``.

    The rule of the grader applies: a call of one of the spec's forbidden routines (seen in
    the function's code or caught while it runs) scores zero, and the result says why.
    ``reference=True`` is the instructor's self-check of a reference solver (or a thin adapter
    around one): the reference solvers may then be called, the spec's own forbidden routines
    still may not. A function defined in ``solutions`` itself is taken as a reference.
    """
    lab, index = _locate(name or getattr(func, "__name__", ""), assignment)
    spec = SCORING[lab][index]  # public scoring on practice data, whatever the install
    trials = practice.practice_trials(lab, spec.name, seeds)
    reference = reference or forbidden.is_reference_solver(func)
    always = () if reference else forbidden.ALWAYS_FORBIDDEN
    with forbidden.Tripwire(spec.forbidden, always) as tripwire:
        outcomes = [_call_in_process(func, t, spec) for t in trials]
    used = set(tripwire.hits) | set(_static_forbidden(func, spec, always))
    if used:
        return forbidden_result(spec, used)
    return score_function(spec, trials, outcomes)


def check(func, name: str | None = None, seeds=PUBLIC_SEEDS,
          assignment: str | None = None) -> None:
    """Score your function on practice problems and show the score it would get, and why
    (a table in Jupyter, text elsewhere; ``evaluate`` returns the result instead).

    The hidden grade uses the same problem generator and the same scoring on fresh problems,
    so a function that gets full marks here for the right reasons gets them there.

    Args:
        func: your function, e.g. ``check(invert_pose)``.
        name: the graded function's name if ``func`` is called differently.
        seeds: public practice seeds (ints).
        assignment: the lab, e.g. "lab1_flange"; found from the notebook's folder otherwise.
    """
    result = evaluate(func, name, seeds, assignment)
    _show(result)


def _html_report(result: FunctionResult) -> str:
    import html

    esc = html.escape
    colour = "#1a7f37" if result.fraction >= 1 else ("#9a6700" if result.points > 0 else "#cf222e")
    rows = []
    for c in result.checks:
        unit = f" {c.unit}" if c.unit else ""
        verdict = "passed" if c.credit >= 1 else ("partly" if c.credit > 0 else "failed")
        worst = f"{c.worst_error:.3g}{unit}" if math.isfinite(c.worst_error) else "no answer"
        hint = "" if c.credit >= 1 else (
            voided_sentence(c, more=False) if c.n_voided and c.n_full + c.n_voided == c.n_trials
            else c.describe)
        rows.append(f"<tr><td>{esc(c.name)}</td><td>{verdict}</td>"
                    f"<td>{c.n_full}/{c.n_trials}</td><td>{esc(worst)}</td>"
                    f"<td>{c.tolerance:.3g}{esc(unit)}</td><td>{esc(hint)}</td></tr>")
    problems = "".join(f"<li>{esc(e)}</li>" for e in result.errors)
    return (f"<div><b style='color:{colour}'>{esc(result.name)}: {result.points:g} / "
            f"{result.max_points:g} points</b>"
            "<table><tr><th>check</th><th>result</th><th>problems within</th>"
            "<th>worst error</th><th>tolerance</th><th>hint</th></tr>" + "".join(rows)
            + "</table>" + (f"<ul>{problems}</ul>" if problems else "") + "</div>")


def _show(result: FunctionResult) -> None:
    """The report as a table under a Jupyter kernel (with the text as its plain form), and
    printed text anywhere else."""
    shell = None
    try:
        from IPython import get_ipython

        shell = get_ipython()
    except ImportError:
        pass
    if shell is not None and getattr(shell, "kernel", None) is not None:
        from IPython.display import display

        display({"text/plain": result.summary(), "text/html": _html_report(result)}, raw=True)
    else:
        print(result.summary())


def hidden_test(func, name: str | None = None, assignment: str | None = None) -> None:
    """nbgrader's hidden test: assert full marks on the kernel seeds (a cross-check only)."""
    result = evaluate(func, name, KERNEL_SEEDS, assignment)
    assert result.fraction >= 1.0, result.summary()


"""Monte Carlo over hidden draws: does correct code keep full credit, does each mistake lose it?

One draw is one student's hidden problem set of one graded function, drawn as the grader
draws it (``checks.make_trials`` with the grader's problem generator for that student id).
:func:`score_draws` scores several callables side by side on the same draws with the
grader's own scoring (``checks.score_function``) and counts, per callable, the draws that
scored below full points; :func:`clopper_pearson` bounds the rate behind such a count and
:func:`draws_for_rate` says how many clean draws it takes to show a rate below a target.

How a callable is called is pluggable (a :data:`Caller`): :func:`in_process` calls it in
this process as ``check()`` does; a sandboxed caller changes where code runs, not what it
scores. Used by ``benchmarks/grading_fairness.py`` (correct variants against the specs' code
mistakes, 10,000 draws per function).

The other side of fairness is that nothing earns credit for nothing: :class:`TrivialGate`
scores the trivial answers of :mod:`autograder.trivial` (zeros, the identity, a constant
normal, the inputs echoed back, ...) on the same draws with the same scoring, and gives
each one's mean share of the function's points with a 95 % interval.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from autograder import checks
from autograder.checks import TrialOutcome
from autograder.outcomes import raised
from autograder.spec_types import FunctionSpec, OutputError, Trial

__all__ = ["Caller", "DrawStats", "Loss", "TrivialGate", "TrivialScore", "TRIVIAL_LIMIT",
           "clopper_pearson", "draws_for_rate", "in_process", "margin", "mean_interval",
           "score_draws", "student_id", "trivial_gate"]

Caller = Callable[[FunctionSpec, Trial], TrialOutcome]
"""Runs the function under test on one problem: ``caller(spec, trial) -> TrialOutcome``. A
caller may also have ``many(spec, trials) -> list[TrialOutcome]``, a draw's problems at once
(a sandboxed caller's one round trip): :func:`score_draws` then uses it."""


def _outcomes(caller: Caller, spec: FunctionSpec, trials: list[Trial]) -> list[TrialOutcome]:
    many = getattr(caller, "many", None)
    return many(spec, trials) if many is not None else [caller(spec, t) for t in trials]


def in_process(func) -> Caller:
    """A :data:`Caller` running ``func`` in this process, as ``check()`` does (fresh copies of
    the inputs, the spec's stand-ins, its closed loop and time limit)."""
    def call(spec: FunctionSpec, trial: Trial) -> TrialOutcome:
        return checks._call_in_process(func, trial, spec)
    return call


def student_id(k: int) -> str:
    """The student id of draw ``k`` (``student000123``)."""
    return f"student{k:06d}"


# --------------------------------------------------------------------------- statistics


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided interval for the rate behind k successes in n
    trials."""
    from scipy.stats import beta  # ~0.3 s to import: only where an interval is asked for

    a = (1 - level) / 2
    low = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    high = 1.0 if k >= n else float(beta.ppf(1 - a, k + 1, n - k))
    return low, high


def mean_interval(total: float, n: int, level: float = 0.95) -> tuple[float, float]:
    """An interval for the mean of n values in [0, 1] that sum to ``total``: the
    Clopper-Pearson interval with a fractional count. A value in [0, 1] spreads less than a
    0/1 value of the same mean (Bernoulli(x) has mean x), so the binomial interval is the
    conservative one; with all values 0 it is [0, 3.7 / n] as for a count of 0."""
    if n <= 0:
        return 0.0, 1.0
    return clopper_pearson(min(max(total, 0.0), n), n, level)


def draws_for_rate(rate: float = 1e-3, level: float = 0.95) -> int:
    """The fewest draws n whose Clopper-Pearson upper bound with 0 losses is below ``rate``
    (3,688 for 1e-3 at 95 %: with no loss seen, n draws show a rate below about 3.7 / n)."""
    if not 0 < rate < 1:
        raise ValueError(f"rate must be in (0, 1), got {rate}")
    # With k = 0 the upper bound is 1 - (alpha/2)^(1/n): start from its closed form and let
    # the interval itself settle the last draw either way of rounding.
    n = max(1, math.ceil(math.log((1 - level) / 2) / math.log1p(-rate)))
    while n > 1 and clopper_pearson(0, n - 1, level)[1] < rate:
        n -= 1
    while clopper_pearson(0, n, level)[1] >= rate:
        n += 1
    return n


# --------------------------------------------------------------------------- one problem


@dataclass(frozen=True)
class _Worst:
    """A problem's check furthest past its full-credit tolerance (ratio: error / tolerance;
    inf with ``reason`` when the call gave no usable answer)."""

    ratio: float
    check: str | None = None
    error: float = math.nan
    tolerance: float = math.nan
    unit: str = ""
    reason: str | None = None


def _worst_check(spec: FunctionSpec, trial: Trial, outcome: TrialOutcome) -> _Worst:
    if trial.raises is not None:
        if outcome.has_raised(trial.raises):
            return _Worst(0.0)
        return _Worst(math.inf, reason=f"expected {trial.raises}, got "
                                       f"{outcome.error or 'a return value'}")
    if outcome.error is not None:
        return _Worst(math.inf, reason=outcome.error)
    try:
        measured = spec.measure(outcome.value, trial)
    except OutputError as exc:
        return _Worst(math.inf, reason=str(exc))
    worst = _Worst(-math.inf)
    for c in spec.checks:
        error, tol = float(measured[c.name]), trial.tol[c.name]
        ratio = error / tol if tol > 0 else (0.0 if error == 0 else math.inf)
        if math.isnan(ratio):
            ratio = math.inf
        if ratio > worst.ratio:
            worst = _Worst(ratio, c.name, error, tol, c.unit)
    return worst


def margin(spec: FunctionSpec, trial: Trial, outcome: TrialOutcome) -> float:
    """Largest error / full-credit tolerance over the checks of one problem (inf: no usable
    answer; for a problem that must raise, 0 when it did)."""
    return _worst_check(spec, trial, outcome).ratio


# --------------------------------------------------------------------------- many draws


@dataclass(frozen=True)
class Loss:
    """The first draw on which a caller lost credit, and the worst problem of that draw."""

    draw: int
    student: str
    points: float
    max_points: float
    trial: str                 # the problem's label
    check: str | None          # None: the call gave no usable answer (see ``reason``)
    error: float
    tolerance: float
    unit: str
    reason: str | None = None
    problem: int | None = None   # the problem's index among the draw's problems
    ratio: float = math.nan      # error / tolerance (inf: no usable answer)

    def describe(self) -> str:
        """One line: "draw student000123 (1.5/3): check rotation 0.8 deg > tol 0.5 deg on a
        'planar set of 6 points' problem"."""
        unit = f" {self.unit}" if self.unit else ""
        what = self.reason if self.check is None else \
            f"check {self.check} {self.error:.3g}{unit} > tol {self.tolerance:.3g}{unit}"
        return (f"draw {self.student} ({self.points:g}/{self.max_points:g}): {what} on a "
                f"'{self.trial}' problem")


@dataclass(frozen=True)
class DrawStats:
    """One caller over some draws: draws scored (``seen``), draws below full points
    (``lost``), the problems of those draws (``problems``) and those below full credit
    (``problems_lost``: a mistake that loses every draw may still lose few problems), the
    points summed over them, the largest :func:`margin` (correct callers only, NaN for the
    others) with its problem (``worst``), and the first losing draw."""

    correct: bool
    seen: int = 0
    lost: int = 0
    points: float = 0.0
    margin: float = math.nan
    first_loss: Loss | None = None
    seconds: float = 0.0
    problems: int = 0
    problems_lost: int = 0
    worst: Loss | None = None

    def merged(self, other: DrawStats) -> DrawStats:
        """These draws and ``other``'s (disjoint ranges) together."""
        losses = [x for x in (self.first_loss, other.first_loss) if x is not None]
        worst = [x for x in (self.worst, other.worst) if x is not None]
        return replace(self, seen=self.seen + other.seen, lost=self.lost + other.lost,
                       points=self.points + other.points,
                       margin=max(self.margin, other.margin) if self.correct else math.nan,
                       first_loss=min(losses, key=lambda x: x.draw) if losses else None,
                       seconds=self.seconds + other.seconds,
                       problems=self.problems + other.problems,
                       problems_lost=self.problems_lost + other.problems_lost,
                       worst=max(worst, key=lambda x: (x.ratio, -x.draw)) if worst else None)


def score_draws(spec: FunctionSpec, assignment: str, draws: range,
                callers: Mapping[str, Caller], rng_of: Callable[[str], np.random.Generator],
                correct: Collection[str] = (), mistakes_stop: int | None = None,
                on_draw: Callable[[int, list[Trial]], None] | None = None
                ) -> dict[str, DrawStats]:
    """Score every caller on the hidden problems of ``spec`` (a full spec of ``assignment``)
    for each draw k in ``draws``: the problems of student :func:`student_id` (k), drawn from
    ``rng_of(student)`` (the grader's problem generator for that student and function).

    Callers named in ``correct`` are correct code: their :func:`margin` is tracked. The
    others (mistakes) are scored only on draws below ``mistakes_stop`` (None: all): 1,000
    draws without a miss already bound a mistake's catch rate above 99.6 %, it is correct
    code that needs the long run. ``on_draw(k, trials)``, if given, sees each draw's
    problems after they are scored (a :class:`TrivialGate` scores its answers on them, the
    tolerances are read off them). Returns {caller name: :class:`DrawStats`}.
    """
    if not any(s is spec for s in checks.SPECS[assignment]):
        raise ValueError(f"{spec.name}: not a full spec of {assignment} (checks.SPECS)")
    unknown = set(correct) - set(callers)
    if unknown:
        raise ValueError(f"correct callers {sorted(unknown)} are not among the callers")
    stats = {name: DrawStats(correct=name in correct, margin=0.0 if name in correct else math.nan)
             for name in callers}
    spent = dict.fromkeys(callers, 0.0)
    with np.errstate(all="ignore"):  # the mistakes divide by zero on purpose
        for k in draws:
            student = student_id(k)
            trials = checks.make_trials(spec, rng_of(student))
            for name, caller in callers.items():
                s = stats[name]
                if not s.correct and mistakes_stop is not None and k >= mistakes_stop:
                    continue
                started = time.perf_counter()
                outcomes = _outcomes(caller, spec, trials)
                result = checks.score_function(spec, trials, outcomes, hints=False)
                lost = result.points < spec.points
                worst = [_worst_check(spec, t, o) for t, o in zip(trials, outcomes)] \
                    if s.correct or (lost and s.first_loss is None) else []
                spent[name] += time.perf_counter() - started
                first, worst_problem = s.first_loss, s.worst
                if worst and ((lost and first is None) or s.correct):
                    i = max(range(len(worst)), key=lambda j: worst[j].ratio)
                    w, trial = worst[i], trials[i]
                    here = Loss(k, student, result.points, spec.points, trial.label, w.check,
                                w.error, w.tolerance, w.unit, w.reason, problem=i,
                                ratio=w.ratio)
                    first = here if lost and first is None else first
                    if s.correct and (worst_problem is None or w.ratio > worst_problem.ratio):
                        worst_problem = here
                stats[name] = replace(
                    s, seen=s.seen + 1, lost=s.lost + lost, points=s.points + result.points,
                    first_loss=first, worst=worst_problem,
                    problems=s.problems + result.n_problems,
                    problems_lost=s.problems_lost + result.n_failed,
                    margin=max(s.margin, *(w.ratio for w in worst)) if s.correct else math.nan)
            if on_draw is not None:
                on_draw(k, trials)
    return {name: replace(s, seconds=spent[name]) for name, s in stats.items()}


# --------------------------------------------------------------------------- trivial answers

TRIVIAL_LIMIT = 0.05
"""A trivial answer may earn at most this share of a function's points on average."""


@dataclass
class TrivialScore:
    """One trivial answer (:mod:`autograder.trivial`) over the draws a :class:`TrivialGate`
    saw: the share of the function's points it earned, summed over draws (``points``) and
    split by the check that gave it (``by_check``), and per check the problems whose error
    was within that check's full-credit tolerance (``within``, of ``problems``)."""

    answer: str
    draws: int = 0
    points: float = 0.0
    by_check: dict[str, float] = field(default_factory=dict)
    within: dict[str, int] = field(default_factory=dict)
    problems: int = 0
    raises: bool = False         # the answer raises on every problem (it has no error)
    # per check, the median error of each draw's problems (inf: no usable answer)
    median_errors: dict[str, list[float]] = field(default_factory=dict)

    @property
    def mean(self) -> float:
        """Mean share of the function's points per draw (0..1)."""
        return self.points / self.draws if self.draws else 0.0

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        return mean_interval(self.points, self.draws, level)

    def typical_error(self, check: str) -> float:
        """The median over draws of the median error on ``check`` (inf: none usable)."""
        errors = self.median_errors.get(check)
        typical = float(np.median(errors)) if errors else math.inf
        return math.inf if math.isnan(typical) else typical

    @property
    def check(self) -> str | None:
        """The check that gave the most of its credit, or None when none gave any."""
        best = max(self.by_check.items(), key=lambda kv: kv[1], default=(None, 0.0))
        return best[0] if best[1] > 0 else None


class TrivialGate:
    """The trivial answers of one graded function, scored on draw after draw of its hidden
    problems in this process with the grader's scoring (no student code runs: a trivial
    answer is a value, or for a closed loop a law of the spec's own loop)."""

    def __init__(self, spec: FunctionSpec):
        self.spec = spec
        self._loop_spec = replace(spec, substitutes=None)
        self.draws = 0
        self.scores: dict[str, TrivialScore] = {}
        self.seconds = 0.0

    def add(self, trials: list[Trial]) -> None:
        """Score every trivial answer on one draw's problems (a student's problem set)."""
        from autograder import trivial

        started = time.perf_counter()
        spec = self.spec
        per_trial = []
        for i, trial in enumerate(trials):
            others = trials[i + 1:] + trials[:i]
            per_trial.append({a.name: a for a in trivial.trivial_answers(spec, trial, others)})
        names = list(dict.fromkeys(n for answers in per_trial for n in answers))
        weight_sum = sum(c.weight for c in spec.checks) or 1.0
        with np.errstate(all="ignore"):
            for name in names:
                outcomes = [self._outcome(answers.get(name), trial)
                            for answers, trial in zip(per_trial, trials)]
                result = checks.score_function(spec, trials, outcomes, hints=False)
                score = self.scores.setdefault(name, TrivialScore(name, draws=self.draws))
                score.raises = any(a[name].raises is not None for a in per_trial if name in a)
                score.points += result.points / spec.points if spec.points else 0.0
                for c, r in zip(spec.checks, result.checks):
                    score.by_check[c.name] = score.by_check.get(c.name, 0.0) + \
                        c.weight * r.credit / weight_sum
                    score.within[c.name] = score.within.get(c.name, 0) + r.n_full + r.n_voided
                    score.median_errors.setdefault(c.name, []).append(r.median_error)
                score.problems += len(trials)
        self.draws += 1
        for score in self.scores.values():
            score.draws = self.draws     # an answer absent from a draw earned nothing there
        self.seconds += time.perf_counter() - started

    def _outcome(self, answer, trial: Trial) -> TrialOutcome:
        if answer is None:
            return TrialOutcome(error="the trivial answer does not apply to this problem")
        if answer.raises is not None:
            return TrialOutcome(error=f"{answer.raises}: raised on every problem",
                                failure=raised(answer.raises))
        if self.spec.drive is not None:
            # A trivial law calls no other graded function: no stand-in tables to build.
            return checks._call_in_process(answer.value, trial, self._loop_spec)
        return TrialOutcome(value=answer.value)

    def ranked(self) -> list[TrivialScore]:
        """The answers, the highest mean share of points first."""
        return sorted(self.scores.values(), key=lambda s: (-s.mean, s.answer))

    def failing(self, limit: float = TRIVIAL_LIMIT) -> list[TrivialScore]:
        """The answers whose mean share of the function's points is above ``limit``."""
        return [s for s in self.ranked() if s.mean > limit]


def trivial_gate(spec: FunctionSpec, draws: range,
                 rng_of: Callable[[str], np.random.Generator]) -> TrivialGate:
    """:class:`TrivialGate` of ``spec`` over the problems of students :func:`student_id` (k)
    for k in ``draws``, each drawn from ``rng_of(student)``."""
    gate = TrivialGate(spec)
    for k in draws:
        gate.add(checks.make_trials(spec, rng_of(student_id(k))))
    return gate

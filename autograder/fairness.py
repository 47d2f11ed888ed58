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
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, replace

import numpy as np

from autograder import checks
from autograder.checks import TrialOutcome
from autograder.spec_types import FunctionSpec, OutputError, Trial

__all__ = ["Caller", "DrawStats", "Loss", "clopper_pearson", "draws_for_rate", "in_process",
           "margin", "score_draws", "student_id"]

Caller = Callable[[FunctionSpec, Trial], TrialOutcome]
"""Runs the function under test on one problem: ``caller(spec, trial) -> TrialOutcome``."""


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
    high = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return low, high


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
        if outcome.error is not None and outcome.error.split(":", 1)[0] == trial.raises:
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
    (``lost``), the points summed over them, the largest :func:`margin` (correct callers
    only, NaN for the others) and the first losing draw."""

    correct: bool
    seen: int = 0
    lost: int = 0
    points: float = 0.0
    margin: float = math.nan
    first_loss: Loss | None = None
    seconds: float = 0.0

    def merged(self, other: DrawStats) -> DrawStats:
        """These draws and ``other``'s (disjoint ranges) together."""
        losses = [x for x in (self.first_loss, other.first_loss) if x is not None]
        return replace(self, seen=self.seen + other.seen, lost=self.lost + other.lost,
                       points=self.points + other.points,
                       margin=max(self.margin, other.margin) if self.correct else math.nan,
                       first_loss=min(losses, key=lambda x: x.draw) if losses else None,
                       seconds=self.seconds + other.seconds)


def score_draws(spec: FunctionSpec, assignment: str, draws: range,
                callers: Mapping[str, Caller], rng_of: Callable[[str], np.random.Generator],
                correct: Collection[str] = (), mistakes_stop: int | None = None
                ) -> dict[str, DrawStats]:
    """Score every caller on the hidden problems of ``spec`` (a full spec of ``assignment``)
    for each draw k in ``draws``: the problems of student :func:`student_id` (k), drawn from
    ``rng_of(student)`` (the grader's problem generator for that student and function).

    Callers named in ``correct`` are correct code: their :func:`margin` is tracked. The
    others (mistakes) are scored only on draws below ``mistakes_stop`` (None: all): 1,000
    draws without a miss already bound a mistake's catch rate above 99.6 %, it is correct
    code that needs the long run. Returns {caller name: :class:`DrawStats`}.
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
            for trial in trials:
                # A hint never changes a score: without this, every failed problem of every
                # mistake would run all the spec's mistakes again to name one.
                if trial.mistakes is None:
                    trial.mistakes = []
            for name, caller in callers.items():
                s = stats[name]
                if not s.correct and mistakes_stop is not None and k >= mistakes_stop:
                    continue
                started = time.perf_counter()
                outcomes = [caller(spec, t) for t in trials]
                result = checks.score_function(spec, trials, outcomes)
                lost = result.points < spec.points
                worst = [_worst_check(spec, t, o) for t, o in zip(trials, outcomes)] \
                    if s.correct or (lost and s.first_loss is None) else []
                spent[name] += time.perf_counter() - started
                first = s.first_loss
                if lost and first is None:
                    w, trial = max(zip(worst, trials), key=lambda p: p[0].ratio)
                    first = Loss(k, student, result.points, spec.points, trial.label, w.check,
                                 w.error, w.tolerance, w.unit, w.reason)
                stats[name] = replace(
                    s, seen=s.seen + 1, lost=s.lost + lost, points=s.points + result.points,
                    first_loss=first,
                    margin=max(s.margin, *(w.ratio for w in worst)) if s.correct else math.nan)
    return {name: replace(s, seconds=spent[name]) for name, s in stats.items()}

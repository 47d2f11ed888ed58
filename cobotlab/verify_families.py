"""``labs verify``'s family table: per graded function, which mistake families
(:mod:`autograder.families`) apply to it, and how often each family's answer loses credit.

A family applies to a function by the kinds of its answer and inputs (a pose, a stack, a pair
of same-shaped inputs, ...); where it applies it predicts the answer a student making only
that mistake returns. :class:`FamilyGate` scores that answer on the hidden draws with the
grader's own scoring, on the problems of each draw where the family applies, and counts the
draws on which it loses credit. A family that applies but keeps full credit on many draws is
a hole in the lab's tolerances (its mistake cannot be told from a right answer there); a
family that applies nowhere is listed as such, so an author sees what the families cover.
Input-side families call the spec's private reference (``FunctionSpec.reference``): a spec
without one is listed as giving them none to call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from autograder import checks, fairness, families
from autograder.families.base import Problem, answer_truth
from autograder.outcomes import TrialOutcome
from autograder.spec_types import FunctionSpec, Trial

__all__ = ["FamilyGate", "FamilyScore", "APPLIES", "NOT_APPLICABLE", "NO_REFERENCE"]

APPLIES, NOT_APPLICABLE, NO_REFERENCE = "applies", "does not apply", "no reference"


@dataclass
class FamilyScore:
    """One family's mistake on one function over the draws a :class:`FamilyGate` saw:
    ``problems`` on which it applied, ``draws`` with at least one such problem, ``lost`` of
    those draws on which its answer scored below full points."""

    family: str          # the family's name ("units m/mm")
    mistake: str         # the mistake within it ("x1000"): its key, or its name
    side: str            # "output" or "input"
    problems: int = 0
    draws: int = 0
    lost: int = 0

    @property
    def share(self) -> float:
        """Share of the draws it applied to on which its answer lost credit (0..1)."""
        return self.lost / self.draws if self.draws else 0.0

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        return fairness.clopper_pearson(self.lost, self.draws, level)


class FamilyGate:
    """Every family of :data:`autograder.families.FAMILIES`, scored draw after draw on one
    function's hidden problems in this process (no student code runs: a family's answer is
    a value the family predicts from the problem)."""

    def __init__(self, spec: FunctionSpec):
        self.spec = spec
        self.draws = 0
        self.seconds = 0.0
        self.scores = [FamilyScore(f.name, f.key or f.name, f.side) for f in families.FAMILIES]

    def add(self, trials: list[Trial]) -> None:
        """Score each family's answer on one draw's problems (where it applies)."""
        started = time.perf_counter()
        # one Problem per trial, shared by every family: the reference's answers on it (a
        # stack's items alone, a call each) are computed once, not once per family
        problems = [self._problem(trial) for trial in trials]
        for family, score in zip(families.FAMILIES, self.scores):
            kept, outcomes = [], []
            for trial, problem in zip(trials, problems):
                answer = family.answer_on(problem) if problem is not None else None
                if answer is not None:
                    kept.append(trial)
                    outcomes.append(TrialOutcome(value=answer))
            if not kept:
                continue
            result = checks.score_function(self.spec, kept, outcomes, hints=False)
            score.problems += len(kept)
            score.draws += 1
            score.lost += result.points < result.max_points
        self.draws += 1
        self.seconds += time.perf_counter() - started

    def _problem(self, trial: Trial) -> Problem | None:
        if self.spec.drive is not None or trial.raises is not None:
            return None   # a closed loop's answer is its loop; a degenerate input must raise
        return Problem(self.spec, trial, answer_truth(trial))

    def status(self, score: FamilyScore) -> str:
        """:data:`APPLIES`, :data:`NOT_APPLICABLE`, or :data:`NO_REFERENCE` (an input-side
        family on a spec without ``reference``: nothing to call on swapped inputs)."""
        if score.draws:
            return APPLIES
        if score.side == families.INPUT and self.spec.reference is None:
            return NO_REFERENCE
        return NOT_APPLICABLE

    def rows(self) -> list[dict]:
        """One row per family mistake: the ones that apply first, the least often losing
        credit first (the holes an author should look at)."""
        rows = []
        for score in self.scores:
            low, high = score.interval() if score.draws else (0.0, 1.0)
            rows.append({"family": score.family, "mistake": score.mistake, "side": score.side,
                         "status": self.status(score), "problems": score.problems,
                         "draws": score.draws, "lost": score.lost, "share": score.share,
                         "low": low, "high": high})
        return sorted(rows, key=lambda r: (r["status"] != APPLIES, r["share"], r["family"],
                                           r["mistake"]))

"""docs/authoring.md's "Scoring rules" examples run as written, and say what the scoring does."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from autograder import checks
from autograder.spec_types import Check, FunctionSpec, Trial

DOC = Path(__file__).resolve().parent.parent / "docs" / "authoring.md"


def _section(title: str) -> str:
    text = DOC.read_text()
    start = text.index(f"## {title}")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def test_every_example_of_the_scoring_rules_runs():
    import autograder.spec_types as spec_types
    from robots import geometry as geo

    blocks = re.findall(r"```python\n(.*?)```", _section("Scoring rules"), re.S)
    assert len(blocks) >= 5
    for block in blocks:
        # what the examples take as given: a problem's inputs
        namespace = {"np": np, "geo": geo, **vars(spec_types),
                     "src": np.random.default_rng(0).normal(size=(5, 3)),
                     "dst": np.random.default_rng(1).normal(size=(5, 3)), "t": np.ones(3)}
        exec(compile(block, str(DOC), "exec"), namespace)


def test_a_check_that_requires_another_earns_nothing_without_it():
    """The doc's plane checks: a point on the plane with a wrong normal earns nothing."""
    block = next(b for b in re.findall(r"```python\n(.*?)```", _section("Scoring rules"), re.S)
                 if "requires=" in b)
    namespace = {"Check": Check}
    exec(block, namespace)
    spec = FunctionSpec(name="plane", points=2.0, n_trials=2, make_trial=None,
                        measure=lambda value, trial: value, checks=namespace["checks"],
                        signature="plane()")
    trials = [Trial(args=(), truth=None, tol={"normal": 1.0, "offset": 1.0}) for _ in range(2)]
    right_point = checks.TrialOutcome(value={"normal": 30.0, "offset": 0.0})
    result = checks.score_function(spec, trials, [right_point, right_point])
    assert result.points == 0.0
    assert [c.n_voided for c in result.checks] == [0, 2]
    whole = checks.TrialOutcome(value={"normal": 0.5, "offset": 0.5})
    assert checks.score_function(spec, trials, [whole, right_point]).points == 1.0

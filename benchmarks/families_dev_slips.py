"""Naming on the development set of algorithmic slips (issue 52): named / misnamed / unnamed.

Usage: python benchmarks/families_dev_slips.py [--draws 10] [--seed 0]

The slips are tests/test_families_slips.py's (a formula written wrong, not a unit or a
sign: labs 3, 4 and 5 and an instructor's ``project(K, p_cam)``), each scored on
``--draws`` fresh draws of its function's problems through the path check() uses
(``checks._mistake_hint``), side by side with the baseline: the same grader without the
families this work added for them (:mod:`autograder.families.matrix_input`). A slip a
family describes is named when its family (or the lab's own code mistake) names it; a slip
no family describes must stay unnamed, any name on it is a misname. Shares carry 95 %
bootstrap intervals over the problems. This is the development set: the held-out corpus is
benchmarks/mistake_naming.py's.
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import test_families_poses as harness  # noqa: E402
import test_families_slips as dev  # noqa: E402

from autograder import checks, families  # noqa: E402
from autograder.families import matrix_input  # noqa: E402
from autograder.outcomes import TrialOutcome  # noqa: E402

NEW = {id(f) for f in matrix_input.FAMILIES}
BOOTSTRAP = 2000


@contextmanager
def baseline():
    """The grader without the matrix families."""
    kept = families.FAMILIES
    families.FAMILIES = tuple(f for f in kept if id(f) not in NEW)
    try:
        yield
    finally:
        families.FAMILIES = kept


def outcomes(draws: int, seed: int) -> list[tuple[str, bool, str]]:
    """(slip, described by a family, verdict) per problem."""
    out = []
    for k, (lab, name, func, family) in enumerate(dev.DEV):
        spec = dev.spec_of(lab, name)
        for t in harness._trials(spec, seed + 1000 * k, draws):
            n = checks._mistake_hint(spec, func(*t.args), t)
            out.append((func.__name__, family is not None, dev.verdict(n, family)))
    return out


def lost(draws: int, seed: int) -> dict[str, int]:
    """Per slip, the problems on which it loses credit (a name matters only there)."""
    found = {}
    for k, (lab, name, func, _) in enumerate(dev.DEV):
        spec = dev.spec_of(lab, name)
        trials = harness._trials(spec, seed + 1000 * k, draws)
        found[func.__name__] = sum(
            checks.score_function(spec, [t], [TrialOutcome(value=func(*t.args))],
                                  hints=False).fraction < 1.0 for t in trials)
    return found


def _share(flags: np.ndarray, rng) -> str:
    if flags.size == 0:
        return "   -"
    boots = rng.choice(flags, (BOOTSTRAP, len(flags))).mean(axis=1)
    low, high = np.percentile(boots, [2.5, 97.5])
    return f"{flags.mean():6.1%} [{low:.2f}, {high:.2f}]"


def _counts(found, slip) -> str:
    v = [x for m, _, x in found if m == slip]
    return f"{v.count('named')}/{v.count('misnamed')}/{v.count('unnamed')}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    started = time.process_time()
    new = outcomes(args.draws, args.seed)
    with baseline():
        old = outcomes(args.draws, args.seed)
    families_of = {f.__name__: fam for _, _, f, fam in dev.DEV}
    losses = lost(args.draws, args.seed)
    print(f"{'slip':34} {'described by':20} {'baseline n/m/u':>15} {'families n/m/u':>15}"
          f" {'lost':>5}")
    for slip in dict.fromkeys(m for m, _, _ in new):
        print(f"{slip:34} {str(families_of[slip]):20} {_counts(old, slip):>15} "
              f"{_counts(new, slip):>15} {losses[slip]:>5}")
    for label, found in (("baseline", old), ("families", new)):
        for described, part in ((True, "described"), (False, "no family")):
            verdicts = np.array([x for _, d, x in found if d == described])
            print(f"{label:9} {part:10} problems {len(verdicts):4}"
                  f"  named {_share(verdicts == 'named', rng)}"
                  f"  misnamed {_share(verdicts == 'misnamed', rng)}"
                  f"  unnamed {_share(verdicts == 'unnamed', rng)}")
    print(f"CPU {time.process_time() - started:.0f} s")


if __name__ == "__main__":
    main()

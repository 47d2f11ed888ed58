"""Naming on the development set of the pose families (issue 52): named / misnamed / unnamed.

Usage: python benchmarks/families_dev_poses.py [--draws 10] [--seed 0]

The dev mistakes are tests/test_families_poses.py's (one classic bug each, labs 0-5 and an
instructor's ``relative_pose``), each scored on ``--draws`` fresh draws of its function's
problems through the path check() uses (``checks._mistake_hint``), side by side with the
baseline: the same grader without the families this work added (a pose part by part, a
stack item by item, the order of a product, no rotation). A name is right when its family
is the dev mistake's (or the lab's own code mistake, family None, where the lab wrote one
for it); any other name is a misname. Shares carry 95 % bootstrap intervals over the
problems. This is the development set: the held-out corpus is benchmarks/mistake_naming.py's.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import test_families_poses as dev  # noqa: E402

from autograder import checks, families  # noqa: E402
from autograder.families import not_rotation, pose_parts, product_order, stack_items  # noqa: E402

NEW = {id(f) for m in (pose_parts, stack_items, not_rotation, product_order)
       for f in m.FAMILIES}
BOOTSTRAP = 2000


@contextmanager
def baseline():
    """The grader without the new families (the registry and the name from the answer)."""
    kept, name = families.FAMILIES, families.not_rotation_name
    families.FAMILIES = tuple(f for f in kept if id(f) not in NEW)
    families.not_rotation_name = lambda value, truth, distance: None
    try:
        yield
    finally:
        families.FAMILIES, families.not_rotation_name = kept, name


def outcomes(draws: int, seed: int) -> list[tuple[str, str]]:
    """(dev mistake, "named" / "misnamed" / "unnamed") per problem."""
    out = []
    for k, (lab, name, func, family) in enumerate(dev.DEV):
        spec = dev._spec(lab, name)
        for t in dev._trials(spec, seed + 1000 * k, draws):
            n = checks._mistake_hint(spec, func(*t.args), t)
            verdict = "unnamed" if n is None else \
                "named" if n.family in (family, None) else "misnamed"
            out.append((func.__name__, verdict))
    return out


def _share(flags: np.ndarray, rng) -> str:
    boots = rng.choice(flags, (BOOTSTRAP, len(flags))).mean(axis=1)
    low, high = np.percentile(boots, [2.5, 97.5])
    return f"{flags.mean():6.1%} [{low:.2f}, {high:.2f}]"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    new = outcomes(args.draws, args.seed)
    with baseline():
        old = outcomes(args.draws, args.seed)
    print(f"{'dev mistake':32} {'baseline n/m/u':>16} {'families n/m/u':>16}")
    for mistake in dict.fromkeys(m for m, _ in new):
        row = []
        for found in (old, new):
            v = [x for m, x in found if m == mistake]
            row.append(f"{v.count('named')}/{v.count('misnamed')}/{v.count('unnamed')}")
        print(f"{mistake:32} {row[0]:>16} {row[1]:>16}")
    for label, found in (("baseline", old), ("families", new)):
        verdicts = np.array([x for _, x in found])
        print(f"{label:9} problems {len(verdicts):4}  named {_share(verdicts == 'named', rng)}"
              f"  misnamed {_share(verdicts == 'misnamed', rng)}"
              f"  unnamed {_share(verdicts == 'unnamed', rng)}")


if __name__ == "__main__":
    main()

"""The private side of grading, one module per assignment (``autograder/specs/<assignment>.py``).

Each module completes its lab's public scoring entries (:mod:`autograder.scoring`) with what
computes an answer: the problem generators and their truths, the answer functions they use,
the mistakes predictors and the stand-in tables computed from a call's arguments, as
``SPECS`` (full :class:`autograder.spec_types.FunctionSpec` objects, made with
``dataclasses.replace``). ``ANSWERS`` lists its functions that compute a graded quantity, for
the test that no student copy holds them (tests/test_answer_free.py).

Instructors only: this package is not in the student wheel, and nothing a student notebook
imports (autograder.checks, autograder.scoring, autograder.practice when it finds its data
file) imports it. Modules are found by name, so adding a lab adds a file here and one in
autograder/scoring/.
"""

from __future__ import annotations

import importlib
import pkgutil


def collect_specs() -> dict:
    """{assignment name: tuple of full FunctionSpec} for every module in this package."""
    specs = {}
    for module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        specs[module.name] = importlib.import_module(f"{__name__}.{module.name}").SPECS
    return specs

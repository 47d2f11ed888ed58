"""The private side of grading, one module per assignment (``autograder/specs/<assignment>.py``).

Each module completes its lab's public scoring entries (:mod:`autograder.scoring`) with what
computes an answer: the problem generators and their truths, the answer functions they use,
the code mistakes (``FunctionSpec.code_mistakes``: the classic wrong versions, which the
feedback names and the fairness benchmark scores) and the stand-in tables computed from a
call's arguments, as
``SPECS`` (full :class:`autograder.spec_types.FunctionSpec` objects, made with
``dataclasses.replace``). ``ANSWERS`` lists its functions that compute a graded quantity, for
the test that no student copy holds them (tests/test_answer_free.py).

Instructors only: this package is not in the student wheel, and nothing a student notebook
imports (autograder.checks, autograder.scoring, autograder.practice when it finds its data
file) imports it. The lab registry (:mod:`autograder.registry`) loads a module when its lab
is first graded, and loads an instructor's own lab's private spec the same way from the
course's ``.cobotlab/specs/`` (docs/authoring.md).
"""

from __future__ import annotations

"""The options of one grade run, as one frozen value that every stage reads and none changes.

``cobotlab grade``'s flags and :func:`autograder.pipeline.pipeline.grade_course`'s keywords
land here once; a stage takes the :class:`GradeOptions` (not a dozen loose arguments), so what a run
was asked to do is written in one place and cannot drift between stages.
"""

from __future__ import annotations

from dataclasses import dataclass

from autograder import freeze
from autograder.pipeline.worker import Limits


@dataclass(frozen=True)
class GradeOptions:
    """What one grade run was asked to do (see :func:`autograder.pipeline.pipeline.grade_course` for
    each field's meaning). Times are seconds of wall clock; ``students`` None: everyone."""

    workers: int = 1
    run_nbgrader: bool = False
    nbgrader_kernel: bool = False
    nbgrader_cell_timeout_s: int | None = None
    nbgrader_timeout_s: float = 300
    limits: Limits = Limits()
    caps: freeze.Caps = freeze.Caps()
    fresh: bool = False
    nonce: str | None = None
    quiet: bool = False
    students: tuple[str, ...] | None = None
    template: bool = True
    rescore: bool = False

    def __post_init__(self):
        # a list of ids handed in stays the caller's: the run keeps its own, immutable copy
        if self.students is not None and not isinstance(self.students, tuple):
            if isinstance(self.students, str):
                raise ValueError("students must be a list of student ids, not one string "
                                 f"({self.students!r}): pass [{self.students!r}]")
            object.__setattr__(self, "students", tuple(self.students))

"""What one submission's code did, nothing scored: the execute stage's values.

An :class:`Execution` holds per graded function a :class:`FunctionRun` (one
:class:`~autograder.outcomes.TrialOutcome` per problem), what each cell did when it was first
loaded (:class:`CellRun`), the notes and flags of the run. :mod:`autograder.executions` is its
wire form (the cluster's replies, the kept executions, a shard job's returns).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from autograder import (
    checks,
)
from autograder.outcomes import Note, Place
from autograder.pipeline.cells import CellOrigin


@dataclass(frozen=True)
class CellRun:
    """One notebook cell as the worker first ran it: ``origin`` says where it sits; ``error``
    is empty when it ran through; ``timed_out`` when its limit stopped it; ``stdout`` and
    ``stderr`` are the first few KB it wrote to each. A cell that raised also has the
    ``exception``'s type name, its ``message`` (``str(exc)``, capped) and the ``place`` of
    the student's line it stopped at (None when no line of the notebook was on the stack)."""

    origin: CellOrigin
    error: str = ""
    stdout: str = ""
    stderr: str = ""
    timed_out: bool = False
    exception: str = ""
    message: str = ""
    place: Place | None = None


@dataclass
class FunctionRun:
    """What one graded function did on its problems: an outcome per problem (a value, or a
    typed failure), in order; ``forbidden``: the forbidden routines it reached (the static
    scan's, then no problem was run, or the tripwire's), which make it score zero."""

    name: str
    outcomes: list[checks.TrialOutcome] = field(default_factory=list)
    forbidden: tuple[str, ...] = ()


@dataclass
class Execution:
    """What one submission's code did, and nothing scored: per graded function a
    :class:`FunctionRun` on its hidden problems; per ``hidden_test(f)`` of nbgrader's test
    cells (``run_tests``: ``kernel_tests`` names them in order), one on the kernel seeds'
    public problems (none for a function forbidden or unknown); what each cell did on
    the first load; the flags of the static scan and of the sandbox; the notes for the
    instructor; the time it took (``profile``: see :class:`SubmissionGrade`)."""

    student_id: str
    assignment: str
    functions: list[FunctionRun] = field(default_factory=list)
    kernel_tests: list[str] = field(default_factory=list)
    kernel_runs: dict[str, FunctionRun] = field(default_factory=dict)
    suspicious: list[str] = field(default_factory=list)
    sandbox_flags: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    cell_origins: list[CellOrigin] = field(default_factory=list)
    cell_runs: list[CellRun] = field(default_factory=list)
    seconds: float = 0.0
    profile: dict = field(default_factory=lambda: {
        "start_s": 0.0, "shared_s": 0.0, "cells_s": 0.0, "hidden_s": 0.0, "peak_mb": None})


def cell_error_note(error: str, place: Place | None = None) -> Note:
    """The note of a notebook cell that failed while loading: ``error``'s words, and the
    ``place`` it stopped at (a line, or the whole cell when it hung), which the run log and
    the feedback write in, each in its reader's numbering; the student reads it too."""
    return Note(f"  cell error: {error}", for_student=error, place=place)

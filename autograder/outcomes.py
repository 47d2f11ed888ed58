"""The grader's typed values between its stages: what one call of a student's function
came to (a value, or a typed failure), and the flags and notes a grade carries.

A failure carries its kind as a value (:class:`Failed`), never as the first words of its
message: the grader decides what follows a time-out (the rest of the function's problems
skipped, a ``timed_out:<function>`` flag, the feedback's "Timed out" line) from
``failure.kind``, so rewording a message changes what students read and nothing else.
``error`` stays the text the feedback shows. In the same way a :class:`Flag` says which
graded function it is about, a :class:`Note` whether a student may read it, and a
:class:`Place` which line of the student's code a failure or a note is about: no message
holds it in words; each renderer writes it in at the end (:func:`placed`), the feedback as
the student's ``In [n]``, the run log as the grader's cell index.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

__all__ = ["Failed", "Cause", "Place", "Failure", "raised", "TrialOutcome", "Flag", "Note",
           "placed", "grader_cell", "student_words", "note_place", "instructor_words"]


class Failed(str, enum.Enum):
    """Why a call gave no value."""

    RAISED = "raised"                    # the function raised (``exception``: the type's name)
    TIMED_OUT = "timed_out"              # a time limit stopped it
    NOT_FOUND = "not_found"              # the notebook defines no function of that name
    UNUSABLE = "unusable"                # it returned a value that cannot be sent or used
    WORKER_STOPPED = "worker_stopped"    # the worker died or broke the protocol (``cause``)
    SKIPPED = "skipped"                  # not run, because of ``cause``


class Cause(str, enum.Enum):
    """What stopped the worker, or what a skipped problem was skipped after."""

    TIMED_OUT = "timed_out"              # skipped: an earlier problem timed out
    WORKER_STOPPED = "worker_stopped"    # skipped: an earlier problem stopped the worker
    DEADLINE = "deadline"                # skipped: the submission's wall clock was used up
    CPU_LIMIT = "cpu_limit"              # the worker's lifetime CPU limit (RLIMIT_CPU) hit
    LOAD_TIME = "load_time"              # the notebook did not load within its CPU budget
    OTHER = "other"                      # killed, crashed, a malformed or oversized reply


# Bounds of a place a worker or a kept execution may claim: an execution holds at most this
# many cells (see autograder.executions), and no cell of a lab notebook is this long.
MAX_CELLS = 20000
MAX_LINE = 10**6


@dataclass(frozen=True)
class Place:
    """A line of the student's code as the grader ran it: ``cell``, the grader's index of
    the code cell (0-based, the order of ``Execution.cell_origins``, not the student's
    ``In [n]``); ``line``, 1-based within that cell, or None for the cell as a whole (one
    that hung: no line is known)."""

    cell: int
    line: int | None = None

    def __post_init__(self):
        for name, low, high in (("cell", 0, MAX_CELLS - 1), ("line", 1, MAX_LINE)):
            value = getattr(self, name)
            if name == "line" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ValueError(f"Place.{name} = {value!r} is not an integer within "
                                 f"{low}..{high}; give the cell's index and the line's number")

    @classmethod
    def claimed(cls, value) -> Place | None:
        """The place a worker's reply claims (``[cell, line]``), or None when it claims none
        or one that is no place: the worker is untrusted, and a wrong place costs only the
        submission's own feedback its line number."""
        if not isinstance(value, (list, tuple)) or len(value) != 2 or value[1] is None:
            return None
        try:
            return cls(*value)
        except ValueError:
            return None

    @classmethod
    def whole_cell(cls, index: int) -> Place | None:
        """The whole of code cell ``index`` (one that hung), or None past the bounds (a
        notebook of more cells than a place can name loses only that note's cell)."""
        return cls(index) if 0 <= index < MAX_CELLS else None

    def to_wire(self) -> list:
        """The place as the worker's reply and a kept execution carry it: ``[cell, line]``
        (``line`` null for a whole cell)."""
        return [self.cell, self.line]


def grader_cell(index: int) -> str:
    """The grader's own name of code cell ``index`` ("cell 4"), as the instructor's log and
    ``labs verify`` show it; the student's feedback names it ``In [n]`` instead
    (:func:`autograder.feedback.line_name`)."""
    return f"cell {index}"


def placed(words: str, place: Place | None, cell_name=grader_cell) -> str:
    """``words`` with ``place`` written in, its cell named by ``cell_name`` (an index ->
    words): "words (cell 4, line 7)" for a line, "cell 4: words" for a whole cell, the words
    alone without a place. The one place where a place becomes text: every renderer (the
    feedback page, the run log, ``labs verify``) composes it here, at the end."""
    if place is None:
        return words
    if place.line is None:
        return f"{cell_name(place.cell)}: {words}"
    return f"{words} ({cell_name(place.cell)}, line {place.line})"


@dataclass(frozen=True)
class Failure:
    """A typed failure. ``exception``: the raised exception's type name (RAISED); ``cause``
    (SKIPPED, WORKER_STOPPED); ``limit_s``: the CPU limit in seconds that an earlier
    problem's time-out or a closed loop ran into, when it is known; ``place``: the
    student's line it stopped at, when known."""

    kind: Failed
    exception: str = ""
    cause: Cause | None = None
    limit_s: float | None = None
    place: Place | None = None

    @property
    def is_time_out(self) -> bool:
        """A time-out, or a problem skipped after one (what the feedback says in words)."""
        return self.kind is Failed.TIMED_OUT or (
            self.kind is Failed.SKIPPED and self.cause is Cause.TIMED_OUT)

    @property
    def lost_to_time(self) -> bool:
        """A problem lost to a time limit of any kind: a time-out, a problem skipped after
        one or after the submission's deadline, a worker stopped by its CPU limit or a
        notebook that did not load in time (the ``timed_out:<function>`` flag)."""
        return self.is_time_out or (self.kind is Failed.SKIPPED and self.cause is Cause.DEADLINE) \
            or (self.kind is Failed.WORKER_STOPPED
                and self.cause in (Cause.CPU_LIMIT, Cause.LOAD_TIME))

    @property
    def skipped_after_earlier(self) -> bool:
        """Not run because an earlier problem timed out or stopped the worker."""
        return self.kind is Failed.SKIPPED and self.cause in (Cause.TIMED_OUT,
                                                              Cause.WORKER_STOPPED)


def raised(exception: str) -> Failure:
    """The failure of a call that raised an exception of type name ``exception``."""
    return Failure(Failed.RAISED, exception=exception)


@dataclass
class TrialOutcome:
    """What a call returned (``value``) or why it failed (``error``: the words; ``failure``:
    the kind); ``seconds`` of wall clock and ``cpu_seconds`` of the student's process it
    took. An ``error`` given without a ``failure`` is taken as raised, by an exception of
    no known type (so it matches no ``Trial.raises``)."""

    value: Any = None
    error: str | None = None
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    failure: Failure | None = None

    def __post_init__(self):
        if self.error is not None and self.failure is None:
            self.failure = Failure(Failed.RAISED)

    def has_raised(self, exception: str) -> bool:
        """The call raised an exception whose type is named ``exception`` (a
        :attr:`Trial.raises <autograder.spec_types.Trial.raises>`)."""
        return self.failure is not None and self.failure.kind is Failed.RAISED \
            and self.failure.exception == exception


class Flag(str):
    """A finding for the instructor, written ``kind`` or ``kind:detail`` (as grades.csv has
    it); ``function``: the graded function it is about, None for the whole submission."""

    kind: str
    function: str | None

    def __new__(cls, kind: str, detail: str = "", function: str | None = None):
        self = super().__new__(cls, f"{kind}:{detail}" if detail else kind)
        self.kind, self.function = kind, function
        return self


def about_function(flag: str) -> str | None:
    """The graded function ``flag`` is about (a plain string is about the whole submission)."""
    return flag.function if isinstance(flag, Flag) else None


class Note(str):
    """A note on a grade, for the instructor's run log; ``for_student``: the words a student
    reads in their feedback (about running their own notebook), None when it is the
    instructor's only (the grader's retries, its sandbox, nbgrader's cross-check);
    ``place``: the student's cell or line it is about, which neither text holds (each
    renderer writes it in with :func:`placed`, in its reader's numbering)."""

    for_student: str | None
    place: Place | None

    def __new__(cls, text: str, for_student: str | None = None, place: Place | None = None):
        self = super().__new__(cls, text)
        self.for_student, self.place = for_student, place
        return self


def student_words(note: str) -> str | None:
    """What a student reads of ``note`` (None: nothing; a plain string is the instructor's)."""
    return note.for_student if isinstance(note, Note) else None


def note_place(note: str) -> Place | None:
    """The place ``note`` is about (None: none; a plain string is about no place)."""
    return note.place if isinstance(note, Note) else None


def instructor_words(note: str) -> str:
    """``note`` as the instructor's run log shows it: its text, its place written in with the
    grader's cell numbers."""
    return placed(str(note), note_place(note))

"""What went wrong on each problem of a graded function, typed: a :class:`ProblemError` per
problem that erred, and what the feedback and the summary are made of, derived from them.

The scoring (:func:`autograder.checks.score_function`) records one :class:`ProblemError` per
problem in the order it meets them; nothing joins counts, failures and labels by the words
of a message afterwards. :func:`error_groups` gives each distinct message once, with the
number of problems it was said on, the typed failure behind it and the labels of the
problems it is among the first lines of; :func:`error_lines` gives the first few lines a
student reads ("on a <label> problem: <message>"). A message is one error only because
its words and its place are the same: "each distinct error once" is about what the student
reads, and the same words said at two lines of the notebook are two lines of feedback. The
place is the failure's typed :class:`~autograder.outcomes.Place`, never in the message's
words; the lines and the feedback write it in with :func:`autograder.outcomes.placed`.
"""

from __future__ import annotations

from dataclasses import dataclass

from autograder.outcomes import Failure, Place, placed

__all__ = ["ProblemError", "ErrorGroup", "MAX_GROUPS", "MAX_LINES", "error_groups",
           "error_lines", "line_words"]

MAX_GROUPS = 20   # distinct messages counted: a submission can make every message distinct
MAX_LINES = 5     # lines of FunctionResult.errors


@dataclass(frozen=True)
class ProblemError:
    """What went wrong on one problem. ``label``: the problem's (e.g. "chain of 3");
    ``message``: the words a student reads; ``failure``: the call's typed failure when the
    call gave no value, None when the scoring wrote the message (an unusable answer, a
    degenerate input that did not raise, a classic mistake); ``leads``: put before the
    other lines (the classic mistake an answer looks like, why right answers earned
    nothing); ``place``: the student's line the call stopped at, never in ``message``'s
    words (given: the scoring's words about a call that raised elsewhere than it must, e.g.
    on a degenerate input; else the failure's)."""

    label: str
    message: str
    failure: Failure | None = None
    leads: bool = False
    place: Place | None = None

    def __post_init__(self):
        if self.place is None and self.failure is not None:
            object.__setattr__(self, "place", self.failure.place)


@dataclass(frozen=True)
class ErrorGroup:
    """One distinct message at one place: the ``count`` of problems it was said on (0 for
    a verdict written without problems, e.g. a forbidden routine's), the first typed
    failure behind it (None: the scoring's words), the ``labels`` of the problems whose
    lines carry it among the first :data:`MAX_LINES` (in their order, each once, empty
    ones left out), and the ``place`` it was said at (None: no line of the notebook)."""

    message: str
    count: int
    failure: Failure | None
    labels: tuple[str, ...] = ()
    place: Place | None = None


def line_words(label: str, message: str, place: Place | None = None) -> str:
    """The line for ``message`` said on a problem labelled ``label`` at ``place`` (written
    in with the grader's cell numbers: :attr:`FunctionResult.errors
    <autograder.checks.FunctionResult.errors>` is what ``labs verify`` and the instructor
    read; the feedback page renumbers from the groups' typed places)."""
    return f"on a {label} problem: {placed(message, place)}"


def _first_lines(errors) -> list[ProblemError]:
    """Each distinct line once, leading ones first (a later leading line before an earlier
    one), then the rest in the order met; the first :data:`MAX_LINES` of them. A leading
    line (a named mistake) is given once whatever problems it was met on: the same name on
    five problems would fill every line and hide what else went wrong."""
    seen: set = set()
    lines: list[ProblemError] = []
    for e in errors:
        words = (e.message, e.place) if e.leads else line_words(e.label, e.message, e.place)
        if words not in seen:
            seen.add(words)
            lines.insert(0 if e.leads else len(lines), e)
    return lines[:MAX_LINES]


def error_lines(errors) -> list[str]:
    """The lines of ``errors`` (:class:`ProblemError`) a student reads, at most
    :data:`MAX_LINES`."""
    return [line_words(e.label, e.message, e.place) for e in _first_lines(errors)]


def error_groups(errors) -> list[ErrorGroup]:
    """Each distinct (message, place) of ``errors`` once, in the order first met, with its
    count, first typed failure and labels (see :class:`ErrorGroup`); past
    :data:`MAX_GROUPS` distinct ones the others are not counted."""
    counts: dict[tuple[str, Place | None], int] = {}
    failures: dict[tuple[str, Place | None], Failure] = {}
    for e in errors:
        key = (e.message, e.place)
        if key in counts or len(counts) < MAX_GROUPS:
            counts[key] = counts.get(key, 0) + 1
            if e.failure is not None:
                failures.setdefault(key, e.failure)
    labels: dict[tuple[str, Place | None], list[str]] = {}
    # a named mistake is one line, but the group lists the problems it was met on, as
    # many as lines would have shown
    shown = [*_first_lines(errors), *(e for e in errors if e.leads)]
    for e in shown:
        said = labels.setdefault((e.message, e.place), [])
        if e.label and e.label not in said and len(said) < MAX_LINES:
            said.append(e.label)
    return [ErrorGroup(message, n, failures.get((message, place)),
                       tuple(labels.get((message, place), ())), place)
            for (message, place), n in counts.items()]

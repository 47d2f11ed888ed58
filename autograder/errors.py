"""What went wrong on each problem of a graded function, typed: a :class:`ProblemError` per
problem that erred, and what the feedback and the summary are made of, derived from them.

The scoring (:func:`autograder.checks.score_function`) records one :class:`ProblemError` per
problem in the order it meets them; nothing joins counts, failures and labels by the words
of a message afterwards. :func:`error_groups` gives each distinct message once, with the
number of problems it was said on, the typed failure behind it and the labels of the
problems it is among the first lines of; :func:`error_lines` gives the first few lines a
student reads ("on a <label> problem: <message>"). A message is one error only because
its words are the same: "each distinct error once" is about what the student reads.
"""

from __future__ import annotations

from dataclasses import dataclass

from autograder.outcomes import Failure

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
    nothing)."""

    label: str
    message: str
    failure: Failure | None = None
    leads: bool = False


@dataclass(frozen=True)
class ErrorGroup:
    """One distinct message: the ``count`` of problems it was said on (0 for a verdict
    written without problems, e.g. a forbidden routine's), the first typed failure behind
    it (None: the scoring's words), and the ``labels`` of the problems whose lines carry
    it among the first :data:`MAX_LINES` (in their order, each once, empty ones left
    out)."""

    message: str
    count: int
    failure: Failure | None
    labels: tuple[str, ...] = ()


def line_words(label: str, message: str) -> str:
    """The line a student reads for ``message`` said on a problem labelled ``label``."""
    return f"on a {label} problem: {message}"


def _first_lines(errors) -> list[ProblemError]:
    """Each distinct line once, leading ones first (a later leading line before an earlier
    one), then the rest in the order met; the first :data:`MAX_LINES` of them."""
    seen: set[str] = set()
    lines: list[ProblemError] = []
    for e in errors:
        words = line_words(e.label, e.message)
        if words not in seen:
            seen.add(words)
            lines.insert(0 if e.leads else len(lines), e)
    return lines[:MAX_LINES]


def error_lines(errors) -> list[str]:
    """The lines of ``errors`` (:class:`ProblemError`) a student reads, at most
    :data:`MAX_LINES`."""
    return [line_words(e.label, e.message) for e in _first_lines(errors)]


def error_groups(errors) -> list[ErrorGroup]:
    """Each distinct message of ``errors`` once, in the order first met, with its count,
    first typed failure and labels (see :class:`ErrorGroup`); past :data:`MAX_GROUPS`
    distinct messages the others are not counted."""
    counts: dict[str, int] = {}
    failures: dict[str, Failure] = {}
    for e in errors:
        if e.message in counts or len(counts) < MAX_GROUPS:
            counts[e.message] = counts.get(e.message, 0) + 1
            if e.failure is not None:
                failures.setdefault(e.message, e.failure)
    labels: dict[str, list[str]] = {}
    for e in _first_lines(errors):
        said = labels.setdefault(e.message, [])
        if e.label and e.label not in said:
            said.append(e.label)
    return [ErrorGroup(m, n, failures.get(m), tuple(labels.get(m, ()))) for m, n in
            counts.items()]

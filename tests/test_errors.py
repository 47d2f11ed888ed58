"""FunctionResult's errors are typed per problem (ProblemError); the lines a student reads,
the counts and the feedback's groups are derived from them, never joined by message text."""

from __future__ import annotations

from autograder import errors as pe
from autograder.errors import ErrorGroup, ProblemError, error_groups, error_lines
from autograder.outcomes import Cause, Failed, Failure, Place, raised

BOOM = raised("ValueError")
HUNG = Failure(Failed.TIMED_OUT, place=Place(2, 5))
SKIP = Failure(Failed.SKIPPED, cause=Cause.TIMED_OUT, limit_s=3.0)


def test_lines_put_leading_errors_first_each_line_once_and_cap_them():
    errors = [ProblemError("a", "ValueError: x", BOOM), ProblemError("b", "ValueError: x", BOOM),
              ProblemError("a", "ValueError: x", BOOM),            # the same line again
              ProblemError("c", "looks like mistake 1", leads=True),
              ProblemError("d", "looks like mistake 2", leads=True),
              ProblemError("b", "looks like mistake 2", leads=True)]   # the same name again
    # a named mistake once, on the first problem it was met on; the other lines stay
    assert error_lines(errors) == [
        "on a d problem: looks like mistake 2", "on a c problem: looks like mistake 1",
        "on a a problem: ValueError: x", "on a b problem: ValueError: x"]
    # five problems with one name leave room for what else went wrong
    named = [ProblemError(str(i), "looks like mistake 1", leads=True) for i in range(5)]
    assert error_lines([*named, ProblemError("z", "not a proper rotation")]) == [
        "on a 0 problem: looks like mistake 1", "on a z problem: not a proper rotation"]
    assert error_groups([*named, ProblemError("z", "not a proper rotation")])[0].labels == \
        ("0", "1", "2", "3", "4")
    many = [ProblemError(str(i), "m") for i in range(3 * pe.MAX_LINES)]
    assert len(error_lines(many)) == pe.MAX_LINES


def test_groups_count_each_message_with_its_first_failure_and_its_shown_labels():
    errors = [ProblemError("e1", "returned NaN"),                  # the scoring's words
              ProblemError("e1", "timed out", HUNG),
              *[ProblemError(f"p{i}", "skipped", SKIP) for i in range(6)],
              ProblemError("e2", "returned NaN", BOOM)]            # a failure met later
    groups = error_groups(errors)
    assert [g.message for g in groups] == ["returned NaN", "timed out", "skipped"]
    assert groups[0] == ErrorGroup("returned NaN", 2, BOOM, ("e1",))
    assert groups[1] == ErrorGroup("timed out", 1, HUNG, ("e1",), Place(2, 5))
    # only the problems of the first lines are named: p0..p2 made lines 3-5, e2 none
    assert groups[2] == ErrorGroup("skipped", 6, SKIP, ("p0", "p1", "p2"))


def test_past_the_cap_a_new_message_is_not_counted_but_old_ones_still_are():
    errors = [ProblemError("x", f"distinct {i}", BOOM) for i in range(pe.MAX_GROUPS + 5)]
    errors.append(ProblemError("x", "distinct 0"))
    groups = error_groups(errors)
    assert len(groups) == pe.MAX_GROUPS and groups[0].count == 2


def test_the_same_words_at_two_places_are_two_groups_and_two_lines_each_placed():
    """The place is typed: the groups split by it, and only the lines write it in (with the
    grader's cell numbers, as ``labs verify`` shows them)."""
    at = [Failure(Failed.RAISED, exception="KeyError", place=Place(3, line))
          for line in (4, 9)]
    errors = [ProblemError("a", "KeyError: 'x'", at[0]), ProblemError("b", "KeyError: 'x'", at[0]),
              ProblemError("c", "KeyError: 'x'", at[1]),
              ProblemError("d", "KeyError: 'x'", raised("KeyError"))]     # no place known
    groups = error_groups(errors)
    assert [(g.message, g.place, g.count) for g in groups] == [
        ("KeyError: 'x'", Place(3, 4), 2), ("KeyError: 'x'", Place(3, 9), 1),
        ("KeyError: 'x'", None, 1)]
    assert [g.labels for g in groups] == [("a", "b"), ("c",), ("d",)]
    assert error_lines(errors) == [
        "on a a problem: KeyError: 'x' (cell 3, line 4)",
        "on a b problem: KeyError: 'x' (cell 3, line 4)",
        "on a c problem: KeyError: 'x' (cell 3, line 9)", "on a d problem: KeyError: 'x'"]


def test_the_scorings_words_about_a_call_that_stopped_at_a_line_keep_its_place():
    """A degenerate input that raised the wrong exception is the scoring's verdict (no
    failure behind it, so it counts as no raise of the student's), said at the call's line."""
    said = ProblemError("collinear", "expected ValueError on this degenerate input, got "
                        "NotImplementedError", place=Place(6, 4))
    assert said.failure is None and said.place == Place(6, 4)
    [group] = error_groups([said, said])
    assert (group.count, group.failure, group.place) == (2, None, Place(6, 4))
    assert error_lines([said]) == ["on a collinear problem: expected ValueError on this "
                                   "degenerate input, got NotImplementedError (cell 6, line 4)"]
    # a failure's own place is the default; a given one stands
    assert ProblemError("a", "x", HUNG).place == Place(2, 5)
    assert ProblemError("a", "x", HUNG, place=Place(0, 1)).place == Place(0, 1)


def test_a_degenerate_input_answered_with_the_wrong_exception_is_placed_at_its_raise():
    """checks writes the verdict's words itself, and takes the place from the call's typed
    failure: the student sees the line that raised the wrong exception."""
    from autograder import checks
    from autograder.outcomes import Failed, Failure, TrialOutcome
    from autograder.spec_types import Trial

    trial = Trial(args=(), truth=None, tol={}, label="collinear", raises="ValueError")
    raised = TrialOutcome(error="NotImplementedError",
                          failure=Failure(Failed.RAISED, "NotImplementedError",
                                          place=Place(7, 4)))
    _, said = checks._measured_or_error(None, trial, raised)
    assert said.failure is None and said.place == Place(7, 4)
    _, returned = checks._measured_or_error(None, trial, TrialOutcome(value=1.0))
    assert returned.place is None and returned.message.endswith("got a return value")

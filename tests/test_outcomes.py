"""A place (autograder.outcomes.Place) travels typed from the worker to whoever writes the
words: the one composition (placed) for a line and for a whole cell, a note's place kept
apart from its two texts, and the bounds of what an untrusted worker may claim."""

from __future__ import annotations

import pytest

from autograder.outcomes import (
    MAX_CELLS,
    Note,
    Place,
    instructor_words,
    note_place,
    placed,
    student_words,
)
from autograder.pipeline.execution import cell_error_note


def test_placed_writes_a_line_after_the_words_and_a_whole_cell_before_them():
    assert placed("KeyError: 'x'", Place(4, 7)) == "KeyError: 'x' (cell 4, line 7)"
    assert placed("timed out", Place(4)) == "cell 4: timed out"
    assert placed("timed out", None) == "timed out"
    assert placed("x", Place(2, 3), lambda i: f"In [{i + 10}]") == "x (In [12], line 3)"


def test_a_note_keeps_its_place_apart_from_both_texts():
    note = cell_error_note("NameError: name 'K' is not defined", Place(3, 17))
    assert "cell 3" not in note and "cell 3" not in student_words(note)
    assert note_place(note) == Place(3, 17)
    assert instructor_words(note) == "  cell error: NameError: name 'K' is not defined " \
        "(cell 3, line 17)"
    # a plain string is the instructor's words about no place
    assert note_place("notebook loaded") is None
    assert instructor_words("notebook loaded") == "notebook loaded"
    assert instructor_words(Note("no place", "no place")) == "no place"


@pytest.mark.parametrize("claim", [None, "cell 3, line 7", [3], [3, 7, 1], [3, None],
                                   [-1, 2], [3, 0], [True, 2], [MAX_CELLS, 1], [1.0, 2]])
def test_a_worker_claims_no_place_it_cannot_have(claim):
    assert Place.claimed(claim) is None


def test_places_are_bounded_and_a_whole_cell_past_the_bounds_is_no_place():
    assert Place.claimed([3, 7]) == Place(3, 7)
    assert Place.whole_cell(5) == Place(5) and Place(5).line is None
    assert Place.whole_cell(MAX_CELLS) is None
    with pytest.raises(ValueError, match="Place.line"):
        Place(1, 0)
    with pytest.raises(ValueError, match="Place.cell"):
        Place(-1)

"""The grade run's options are one frozen value, and its problems are drawn whole before any
code runs and cannot be changed after (issue 51): no course, no sandbox needed."""

from __future__ import annotations

import dataclasses

import pytest

from autograder.grade_options import GradeOptions
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import draw_all, draw_problems

SECRET = "a-secret-of-16-chars-or-more"


def test_the_options_are_frozen_and_keep_their_own_student_list():
    wanted = ["ada", "bo"]
    options = GradeOptions(workers=2, students=wanted)
    wanted.append("cy")
    assert options.students == ("ada", "bo")
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.workers = 3


def test_one_student_id_as_a_string_is_refused_by_name():
    with pytest.raises(ValueError, match="students must be a list"):
        GradeOptions(students="ada")


def test_grade_course_takes_options_or_keywords_not_both(tmp_path):
    # refused before the course is looked at: the folder need not exist
    with pytest.raises(TypeError, match="options= or keyword settings"):
        grade_course(tmp_path / "none", "lab0_frames", options=GradeOptions(), quiet=True)
    with pytest.raises(TypeError, match="colour"):
        grade_course(tmp_path / "none", "lab0_frames", colour=True)


def test_every_student_is_drawn_at_once_as_draw_problems_draws_them():
    drawn = draw_all("lab0_frames", SECRET, None, ["ada", "bo", "ada"])
    for sid in ("ada", "bo"):
        one = draw_problems("lab0_frames", sid, SECRET, None)
        mine = drawn.of(sid)
        assert mine.student_id == sid and mine.trials.keys() == one.trials.keys()
        for name in one.trials:
            assert [t.label for t in mine.trials[name]] == [t.label for t in one.trials[name]]
            assert repr([t.args for t in mine.trials[name]]) == repr(
                [t.args for t in one.trials[name]])
    with pytest.raises(KeyError, match="cy"):
        drawn.of("cy")   # nothing is drawn late: a student not in the run has none
    assert not hasattr(drawn, "keep")
    with pytest.raises(TypeError):
        drawn._by_student["cy"] = drawn.of("ada")

"""The cross-check with nbgrader's own cell results is part of scoring (issue 51): the score
stage flags from the :class:`NbgraderCells` its ``Executed`` carries, and the cell results of
this run's nbgrader run are clamped by the gradebook's one helper. Pure: no sandbox, no
course, no nbgrader run (tests/test_grading_record.py grades a course end to end)."""

from __future__ import annotations

import time
from pathlib import Path

from autograder import checks, gradebook
from autograder.freeze import Frozen
from autograder.gradebook import CellScore
from autograder.pipeline.begin import GradeRun
from autograder.pipeline.execute import Executed
from autograder.pipeline.execution import Execution, FunctionRun
from autograder.pipeline.nbgrader_results import NbgraderCells
from autograder.pipeline.problems import draw_problems
from autograder.pipeline.score import score_submission
from autograder.pipeline.worker import Limits

LAB, WHO = "lab0_frames", "ada"
RUN = GradeRun(Path("/nonexistent"), Path("/nonexistent"), LAB, "s" * 40, None, "fixed",
               Limits(), [], time.monotonic())
SUB = Frozen(WHO, notebooks=[Path("lab0_frames.ipynb")])


def _executed(wrong: str | None, cells: NbgraderCells | None) -> Executed:
    """Every function right except ``wrong`` (a value that fails every check)."""
    problems = draw_problems(LAB, WHO, RUN.secret, None)
    runs = [FunctionRun(s.name, [checks.TrialOutcome(value=None if s.name == wrong else t.truth)
                                 for t in problems.trials[s.name]])
            for s in checks.SPECS[LAB]]
    return Executed(execution=Execution(WHO, LAB, functions=runs), problems=problems,
                    nbgrader_cells=cells)


def _flags(done: Executed) -> list[tuple[str, str | None]]:
    return [(str(f).split(":")[0], f.function) for f in score_submission(RUN, SUB, done).flags]


FUNCTIONS = {"test_invert_pose": "invert_pose", "test_compose_chain": "compose_chain"}


def test_nbgrader_passed_where_the_grader_failed_is_flagged_in_score():
    passed = NbgraderCells({"test_invert_pose": (2.0, 2.0), "test_compose_chain": (2.0, 2.0)},
                           FUNCTIONS)
    done = _executed("invert_pose", passed)
    assert _flags(done) == [("nbgrader_passed_but_grader_failed", "invert_pose")]
    assert _flags(_executed(None, passed)) == []            # both agree: nothing to say
    assert done.nbgrader_cells is passed                     # score reads, never changes


def test_a_missing_cell_or_no_result_is_flagged_and_no_cells_means_no_cross_check():
    missing = NbgraderCells({"test_compose_chain": (0.0, 2.0)}, FUNCTIONS)
    assert _flags(_executed(None, missing)) == [("nbgrader_missing_cell", "invert_pose")]
    assert _flags(_executed(None, NbgraderCells({}, FUNCTIONS))) == [
        ("nbgrader_no_result", None)]
    assert _flags(_executed("invert_pose", None)) == []     # no nbgrader view: no cross-check


def test_this_runs_cells_are_clamped_as_the_gradebook_holds_them():
    cells = [CellScore("lab0_frames", "test_invert_pose", 5.0, 2.0),
             CellScore("lab0_frames", "test_compose_chain", -1.0, 2.0),
             CellScore("other", "test_other", 1.0, 1.0)]
    assert gradebook.nbgrader_cell_results(cells, {"lab0_frames"}) == {
        "test_invert_pose": (2.0, 2.0), "test_compose_chain": (0.0, 2.0),
        "test_other": (0.0, 1.0)}   # a cell of a notebook not handed in scores 0

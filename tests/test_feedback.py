"""The student's feedback page (autograder.feedback): dedupe, counts, wording, cell numbers,
escaping; from constructed results and from one real grading run of a lab 0 notebook.

The real run takes a few seconds (one sandboxed worker); the rest is pure rendering.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from autograder import checks
from autograder.checks import CheckResult, FunctionResult
from autograder.errors import ProblemError
from autograder.feedback import error_lines, feedback_html, function_verdict
from autograder.outcomes import (
    Cause,
    Failed,
    Failure,
    Place,
    instructor_words,
    note_place,
    raised,
    student_words,
)
from autograder.pipeline.cells import CellOrigin, extract_code
from autograder.pipeline.execution import cell_error_note
from autograder.pipeline.run_submission import grade_notebook
from autograder.pipeline.score import SubmissionGrade
from autograder.pipeline.worker import Limits

SECRET = "feedback-secret-" + "x" * 24
LIMITS = Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=30)
LAB0 = Path(__file__).resolve().parent.parent / "labs" / "lab0_frames" / "lab0_frames.ipynb"


def _check(name="rotation", unit="deg", n_full=6, n=6, worst=1e-9, tol=1e-6,
           describe="the rotation block"):
    credit = n_full / n
    return CheckResult(name, unit, credit, n_full, n, worst, worst, tol, describe)


def _grade(*functions, notes=(), origins=()):
    return SubmissionGrade("alice", "lab0_frames", list(functions), [], list(notes),
                           cell_origins=list(origins))


def _origins(*prompts):
    return [CellOrigin("lab0_frames.ipynb", 2 * p, p) for p in prompts]


def _section(page: str, name: str) -> str:
    start = page.index(f"<a id='{name}'></a>")
    end = page.find("<a id=", start + 1)
    return page[start:end if end > 0 else len(page)]


# --------------------------------------------------------------------------- constructed


def test_one_line_per_distinct_error_with_its_count_and_cell_as_the_student_sees_it():
    message = "ZeroDivisionError: division by zero"
    at = Failure(Failed.RAISED, exception="ZeroDivisionError", place=Place(2, 5))
    f = FunctionResult(
        "pose_from_rotvec", 2.0, 4.0,
        [_check(n_full=5, n=8, worst=float("inf"), describe="the rotation block of the pose")],
        errors=[f"on a {label} problem: {message} (cell 2, line 5)"
                for label in ("zero rotation", "tiny rotation", "half turn")],
        n_problems=8, n_failed=3,
        problem_errors=tuple(ProblemError(label, message, at) for label in (
            "zero rotation", "tiny rotation", "half turn")))
    # the grader's cell 2 is the student's In [7] (magic and hidden cells were dropped)
    page = feedback_html(_grade(f, origins=_origins(1, 4, 7)))
    section = _section(page, "pose_from_rotvec")
    assert section.count("ZeroDivisionError") == 1
    assert "(cell In [7], line 5)" in section and "cell 2," not in section
    assert "on 3 of 8 problems: zero rotation, tiny rotation, half turn" in section
    assert "Failed on 3 of 8 problems" in section and "failed on 3 of 8" in page
    assert "partly passed" in section and "no usable answer" in section


def test_notebook_notes_are_deduplicated_with_a_count():
    notes = ["notebook loaded: 9 code cells, 3 raised"] + \
        [cell_error_note("NotImplementedError", Place(3, 4))] * 3 + \
        [cell_error_note("timed out after 22 s (skipped from then on)", Place(5)),
         cell_error_note("KeyError: 'x'"),
         "nbgrader's scratch gradebook is unreadable (hidden_test cells)"]
    page = feedback_html(_grade(notes=notes, origins=_origins(1, 2, 3, 5, 6, 8)))
    assert page.count("NotImplementedError") == 1
    assert "NotImplementedError (cell In [5], line 4) (in 3 cells)" in page
    assert "cell In [8]: timed out" in page
    assert "KeyError: 'x'" in page.replace("&#x27;", "'") and "()" not in page
    assert "hidden_test" not in page  # nbgrader's notes are the instructor's, not the student's


def test_a_place_is_written_in_from_its_type_never_read_out_of_the_words():
    """Renumbering comes from the typed place: words that look like a place (the student
    wrote them) are shown as written, and the same words at two lines are two lines."""
    forged = "ValueError: see (cell 0, line 1)"
    at = [Failure(Failed.RAISED, exception="ValueError", place=Place(1, line)) for line in (2, 6)]
    f = FunctionResult("invert_pose", 0.0, 3.0, [_check(n_full=0, worst=float("inf"))],
                       n_problems=6, n_failed=6, problem_errors=(
                           *[ProblemError("a", forged, at[0])] * 4,
                           *[ProblemError("b", forged, at[1])] * 2))
    lines = error_lines(f, _origins(3, 8))
    assert lines == ["ValueError: see (cell 0, line 1) (cell In [8], line 2) (on 4 of 6 "
                     "problems: a)",
                     "ValueError: see (cell 0, line 1) (cell In [8], line 6) (on 2 of 6 "
                     "problems: b)"]
    hung = [cell_error_note("cell 0: timed out", Place(1)), cell_error_note("(cell 1, line 1)")]
    page = feedback_html(_grade(notes=hung, origins=_origins(3, 8)))
    assert "cell In [8]: cell 0: timed out" in page and "(cell 1, line 1)" in page
    assert "In [3]" not in page


def test_an_unwritten_function_is_not_implemented_not_a_method_hint():
    stub = "NotImplementedError (cell 1, line 3)"
    f = FunctionResult(
        "compose_chain", 0.0, 3.0,
        [_check(n_full=0, worst=float("inf"), describe="HINT: multiply left to right")],
        errors=[f"on a chain of {k} problem: {stub}" for k in range(1, 6)],
        n_problems=6, n_failed=6,
        problem_errors=tuple(ProblemError(f"chain of {k}", stub, Failure(
            Failed.RAISED, exception="NotImplementedError", place=Place(1, 3)))
            for k in range(1, 7)))
    assert function_verdict(f) == "not_implemented"
    section = _section(feedback_html(_grade(f, origins=_origins(2, 4))), "compose_chain")
    assert "not implemented" in section and "Not implemented yet" in section
    assert "cell In [4], line 3" in section
    assert "HINT" not in section and "FAILED" not in section and "within tolerance" not in section
    # raising NotImplementedError on some problems only is an error like any other
    partial = FunctionResult("compose_chain", 1.0, 3.0, [_check(n_full=4)], n_problems=6,
                             n_failed=2, problem_errors=(
                                 ProblemError("a", stub, raised("NotImplementedError")),) * 2)
    assert function_verdict(partial) == "partial"


def test_missing_function_forbidden_routine_and_time_out_are_said_plainly():
    missing = FunctionResult("invert_pose", 0.0, 3.0, [_check(n_full=0)], n_problems=6,
                             n_failed=6,
                             problem_errors=(ProblemError(
                                 "a", "no function named invert_pose is defined",
                                 Failure(Failed.NOT_FOUND)),) * 6)
    spec = checks.spec_for("pose_from_rotvec", "lab0_frames")
    banned = checks.forbidden_result(spec, ["scipy.spatial.transform.Rotation.from_rotvec"])
    hung = FunctionResult(
        "compose_chain", 0.0, 3.0, [_check(n_full=0, worst=float("inf"))], n_problems=6,
        n_failed=6, problem_errors=(
            ProblemError("a", "timed out (cell 1, line 4)",
                         Failure(Failed.TIMED_OUT, place=Place(1, 4))),
            *[ProblemError("a", "skipped: an earlier problem timed out after 3 s",
                           Failure(Failed.SKIPPED, cause=Cause.TIMED_OUT, limit_s=3.0))] * 5))
    assert [function_verdict(f) for f in (missing, banned, hung)] == \
        ["not_found", "forbidden", "timed_out"]
    page = feedback_html(_grade(missing, banned, hung))
    assert "defines no function named <code>invert_pose</code>" in page
    section = _section(page, "pose_from_rotvec")
    assert "Rotation.from_rotvec" in section and "yourself" in section and "Score 0" in section
    [line] = [x for x in error_lines(hung, []) if x.startswith("Timed out")]
    assert "within its time limit of 3 s of CPU time on 1 of 6 problem" in line
    assert "the other 5 problem(s) were then not run" in line
    assert "skipped:" not in page and "timed out" in _section(page, "compose_chain")
    # a submission with no notebook to run (course.grade_course's zero grade)
    nothing = checks.score_function(spec, [], [])
    assert function_verdict(nothing) == "not_graded"
    assert "Not graded" in feedback_html(_grade(nothing)) and "nan" not in feedback_html(
        _grade(nothing))


def test_student_text_is_escaped_and_capped():
    hostile = "<script>alert('x')</script>" + "A" * 20_000
    f = FunctionResult("invert_pose", 0.0, 3.0, [_check(n_full=0, worst=float("inf"))],
                       errors=[f"on a random problem: {hostile}"], n_problems=6, n_failed=6,
                       problem_errors=tuple(ProblemError("random", f"{i} {hostile}")
                                            for i in range(20)))
    notes = [cell_error_note(hostile, Place(0, 1)),
             cell_error_note("\x1b[31m</code>")]
    grade = SubmissionGrade("<b>bob</b>", "lab0_frames", [f], [], notes)
    page = feedback_html(grade)
    assert "<script" not in page and "&lt;script&gt;" in page
    assert "<b>bob" not in page and "</code>\n" not in page and "\x1b" not in page
    assert len(page) < 20_000, len(page)  # 20 distinct 20-KB errors, a few lines shown
    assert "other distinct errors" in page


# --------------------------------------------------------------------------- the grader


def test_extract_code_maps_each_kept_cell_to_the_students_numbering(tmp_path):
    cells = [("markdown", "# title"), ("code", "import numpy as np"), ("code", "   "),
             ("code", "%%capture\nx = 1"), ("markdown", "text"),
             ("code", "y = 2\n### BEGIN HIDDEN TESTS\nz = 3"), ("code", "def f():\n    pass")]
    nb = {"cells": [{"cell_type": t, "metadata": {}, "source": s} for t, s in cells],
          "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "nb.ipynb"
    path.write_text(json.dumps(nb))
    code, origins, notes = extract_code(path, with_origins=True)
    assert code == ["import numpy as np", "def f():\n    pass"] and notes == []
    # In [1] imports, empty cell not counted, In [2] the cell magic, In [3] the hidden test
    assert origins == [CellOrigin("nb.ipynb", 2, 1), CellOrigin("nb.ipynb", 7, 4)]
    assert extract_code(path) == (code, notes)


def test_score_function_counts_failed_problems_and_each_error():
    spec = checks.spec_for("invert_pose", "lab0_frames")
    trials = checks.public_trials(spec, 0)
    assert len(trials) >= 4
    outcomes = [checks.TrialOutcome(value=np.linalg.inv(t.args[0])) for t in trials]
    outcomes[0] = checks.TrialOutcome(error="ValueError: boom")
    outcomes[1] = checks.TrialOutcome(error="ValueError: boom")
    outcomes[2] = checks.TrialOutcome(value=np.full((4, 4), np.nan))
    result = checks.score_function(spec, trials, outcomes)
    assert result.n_problems == len(trials) and result.n_failed == 3
    assert result.error_counts == {"ValueError: boom": 2, "returned NaN or inf": 1}


def _student_lab0(tmp_path) -> tuple[Path, int, int]:
    """The lab 0 notebook as released (stubs, no hidden tests) with a cell magic added after
    the imports and a wrong invert_pose (forgets to rotate the translation). Returns the
    path and the In [n] of the compose_chain and pose_from_rotvec cells."""
    nb = json.loads(LAB0.read_text())
    for cell in nb["cells"]:
        source = "".join(cell["source"])
        source = re.sub(r"### BEGIN SOLUTION\n.*?### END SOLUTION",
                        "# YOUR CODE HERE\n    raise NotImplementedError()", source, flags=re.S)
        cell["source"] = re.sub(r"### BEGIN HIDDEN TESTS\n.*?### END HIDDEN TESTS\n?", "",
                                source, flags=re.S)
        if cell["metadata"].get("nbgrader", {}).get("grade_id") == "invert_pose":
            cell["source"] = cell["source"].replace(
                "# YOUR CODE HERE\n    raise NotImplementedError()",
                "out = np.eye(4)\n    out[:3, :3] = a_T_b[:3, :3].T\n"
                "    out[:3, 3] = -a_T_b[:3, 3]\n    return out")
    at = 1 + next(i for i, c in enumerate(nb["cells"])
                  if c["metadata"].get("nbgrader", {}).get("grade_id") == "imports")
    nb["cells"].insert(at, {"cell_type": "code", "metadata": {}, "outputs": [],
                            "execution_count": None, "source": "%%capture\nprint('hi')"})
    prompts, n = {}, 0
    for cell in nb["cells"]:
        if cell["cell_type"] == "code" and "".join(cell["source"]).strip():
            n += 1
            prompts[cell["metadata"].get("nbgrader", {}).get("grade_id")] = n
    path = tmp_path / "lab0_frames.ipynb"
    path.write_text(json.dumps(nb))
    return path, prompts["compose_chain"], prompts["pose_from_rotvec"]


def test_page_of_a_real_graded_lab0_notebook(tmp_path):
    path, chain_prompt, rotvec_prompt = _student_lab0(tmp_path)
    grade = grade_notebook([path], "lab0_frames", "alice", SECRET, "nonce", LIMITS)
    by_name = {f.name: f for f in grade.functions}
    assert grade.score == 1.5, grade  # the rotation half of invert_pose
    assert [function_verdict(by_name[n]) for n in ("invert_pose", "compose_chain",
                                                  "pose_from_rotvec")] == \
        ["partial", "not_implemented", "not_implemented"]
    page = feedback_html(grade)
    n = by_name["invert_pose"].n_problems
    assert n == checks.spec_for("invert_pose", "lab0_frames").n_trials
    # -t for the translation is one of the spec's code mistakes: the page names it.
    assert "classic mistake: its translation is -t, not -R^T t" in page
    assert f"on {n} of {n} problems" in page
    assert " mm" in page and "rotation: passed" not in page  # only what failed is explained
    chain = _section(page, "compose_chain")
    assert f"cell In [{chain_prompt}], line 4" in chain, chain
    assert f"cell In [{rotvec_prompt}], line 4" in _section(page, "pose_from_rotvec")
    assert "FAILED" not in chain and by_name["compose_chain"].checks[0].describe not in chain
    # each distinct load error once; the stubs raised from the test cells that call them
    notes = page[page.index("While running your notebook"):]
    assert notes.count(f"NotImplementedError (cell In [{rotvec_prompt}], line 4)") == 1
    for needle in (SECRET, "nonce", "hidden_test", "HIDDEN", "BEGIN SOLUTION"):
        assert needle not in page, needle


def test_page_of_a_real_hang_a_forbidden_routine_and_a_hostile_message(tmp_path):
    cells = ["import numpy as np\nimport cv2",
             "def invert_pose(T):\n    while True:\n        pass",
             "def compose_chain(poses):\n    raise ValueError('<img src=x onerror=alert(1)>')",
             "def pose_from_rotvec(r, t):\n    T = np.eye(4)\n    T[:3, :3] = cv2.Rodrigues(r)[0]"
             "\n    T[:3, 3] = t\n    return T"]
    nb = {"cells": [{"cell_type": "code", "metadata": {}, "outputs": [], "source": c}
                    for c in cells], "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "lab0_frames.ipynb"
    path.write_text(json.dumps(nb))
    limits = Limits(cell_timeout_s=5, call_timeout_s=2, load_timeout_s=30)
    grade = grade_notebook([path], "lab0_frames", "bob", SECRET, None, limits)
    assert grade.score == 0.0
    assert [function_verdict(f) for f in grade.functions] == ["timed_out", "failed", "forbidden"]
    page = feedback_html(grade)
    hang = _section(page, "invert_pose")
    n = grade.functions[0].n_problems
    # stopped on the loop's line 2 or 3, wherever the CPU timer caught it
    assert re.search(rf"within its time limit of 2 s of CPU time on 1 of {n} problem\(s\) "
                     rf"\(stopped at cell In \[2\], line [23]\); the other {n - 1} "
                     r"problem\(s\) were then not run", hang), hang
    crash = _section(page, "compose_chain")
    assert "<img" not in page and "ValueError: &lt;img src=x" in crash
    assert f"(cell In [3], line 2) (on {n} of {n} problems" in crash
    # the place came typed from the worker: the message holds the words only, the instructor's
    # lines write it in with the grader's cell index (compose_chain is cell 2 of 4)
    [group] = grade.functions[1].error_groups
    assert "(cell" not in group.message and group.place == Place(2, 2)
    assert grade.functions[1].errors[0].endswith("(cell 2, line 2)")
    assert "this check measures" not in crash  # every problem raised: the error is the story
    assert "cv2.Rodrigues" in _section(page, "pose_from_rotvec")


def test_a_cell_that_hangs_past_its_backstop_is_named_from_its_typed_cell(tmp_path):
    """A cell that blocks the worker's own timers is killed by the grader's backstop
    (:class:`CellHang`): its note carries the cell as a place, not in its words, and the
    page names the student's ``In [n]`` before them (the run log the grader's index)."""
    cells = ["x = 1",
             "import signal, time\nsignal.pthread_sigmask(signal.SIG_BLOCK, "
             "{signal.SIGALRM, signal.SIGPROF})\ntime.sleep(60)",
             "y = 2"]
    nb = {"cells": [{"cell_type": "code", "metadata": {}, "outputs": [], "source": c}
                    for c in cells], "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / "lab0_frames.ipynb"
    path.write_text(json.dumps(nb))
    limits = Limits(cell_timeout_s=0.5, call_timeout_s=1, load_timeout_s=30, wall_factor=1)
    grade = grade_notebook([path], "lab0_frames", "cy", SECRET, None, limits)
    [hung] = [n for n in grade.notes if note_place(n) is not None]
    assert note_place(hung) == Place(1) and "cell" not in student_words(hung)
    assert instructor_words(hung).startswith("cell 1: ")
    page = feedback_html(grade)
    assert re.search(r"cell In \[2\]: timed out after [\d.]+ s \(skipped from then on\)", page)

"""A graded class, once, and what leaves it (issue 40, parts 4 and 5): the grades as Canvas,
Moodle and a plain CSV import them (`cobotlab export`), and the class at a glance
(`cobotlab report`), opened in Chromium.

The class (lab 0, graded for real in the sandbox): the reference; two students with the same
code of their own, renamed and reformatted; one with a classic mistake, whom a TA then gives
a manual score in the gradebook; one late, under a course rule that a late submission scores
zero; one who handed in the released notebook blank.
"""

from __future__ import annotations

import ast
import csv
import io
import json
from datetime import datetime

import course_kit as kit
import pytest
from test_browser_lab import browser  # noqa: F401 - the Chromium fixture, shared

from autograder import gradebook, registry
from autograder.pipeline.pipeline import grade_course
from cobotlab.class_report import canonical, normalised_functions, notebook_functions, similar_pairs
from cobotlab.cli import main

pytestmark = pytest.mark.slow   # a class graded in the sandbox, and Chromium
LAB = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
DUE = datetime(2026, 11, 21)            # everyone's timestamp is 2026-11-20 10:00 UTC ...
LATE_STAMP = "2026-11-22 09:00:00.000000 UTC"   # ... but the late student's
MANUAL = 1.5                             # the TA's score of the mistaken invert_pose cell

TWIN_A = {
    "invert_pose": '''def invert_pose(a_T_b):
    """Mine."""
    rot = a_T_b[:3, :3].T
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = -rot @ a_T_b[:3, 3]   # the origin, seen the other way
    return out
''',
    "compose_chain": '''def compose_chain(poses):
    acc = np.eye(4)
    i = 0
    while i < len(poses):
        acc = acc @ poses[i]
        i += 1
    return acc
''',
    "pose_from_rotvec": '''def pose_from_rotvec(rvec, t):
    r = np.asarray(rvec, dtype=float).reshape(3)
    ang = np.linalg.norm(r)
    M = np.eye(4)
    if ang > 1e-12:
        k = r / ang
        S = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        M[:3, :3] = np.eye(3) + np.sin(ang) * S + (1.0 - np.cos(ang)) * (S @ S)
    M[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return M
''',
}
# the same code: other names, other layout, comments and docstrings of its own
TWIN_B = {
    "invert_pose": '''def invert_pose(pose):
    # transpose the rotation
    Rt = pose[:3, :3].T
    result = np.eye(4)
    result[:3, :3] = Rt
    result[:3, 3] = -Rt @ pose[:3, 3]
    return result
''',
    "compose_chain": '''def compose_chain(poses):
    """Left to right."""
    total = np.eye(4)
    n = 0
    while n < len(poses):
        total = total @ poses[n]
        n += 1
    return total
''',
    "pose_from_rotvec": '''def pose_from_rotvec(v, trans):
    vec = np.asarray(v, dtype=float).reshape(3)
    angle = np.linalg.norm(vec)
    T = np.eye(4)
    if angle > 1e-12:
        axis = vec / angle
        K = np.array([[0.0, -axis[2], axis[1]],
                      [axis[2], 0.0, -axis[0]],
                      [-axis[1], axis[0], 0.0]])
        T[:3, :3] = (np.eye(3) + np.sin(angle) * K
                     + (1.0 - np.cos(angle)) * (K @ K))
    T[:3, 3] = np.asarray(trans, dtype=float).reshape(3)
    return T
''',
}
# lab 0's first code mistake: the rotation block kept as R (compose and rotvec left blank)
MISTAKE = {"invert_pose": '''def invert_pose(a_T_b):
    R = a_T_b[:3, :3]
    t = a_T_b[:3, 3]
    b_T_a = np.eye(4)
    b_T_a[:3, :3] = R
    b_T_a[:3, 3] = -R @ t
    return b_T_a
'''}
MISTAKE_LABEL = "its rotation block is R, not R^T"
LATE = {"invert_pose": '''def invert_pose(T):
    out = np.zeros((4, 4))
    out[3, 3] = 1.0
    out[:3, :3] = T[:3, :3].transpose()
    out[:3, 3] = -(T[:3, :3].transpose().dot(T[:3, 3]))
    return out
'''}
STUDENTS = ("ref", "twin_a", "twin_b", "mistake", "late", "blank")


def _set_up(course) -> None:
    """Due date, the course's late rule and a name for one student (nbgrader's API)."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        gb.update_or_create_assignment(LAB, duedate=DUE)
        gb.update_or_create_student("ref", first_name="Ada", last_name="Ref",
                                    email="ada@example.edu")
    config = course / "nbgrader_config.py"
    config.write_text(config.read_text() + '\nc.LateSubmissionPlugin.penalty_method = "zero"\n')


def _manual_score(course) -> str:
    """The TA's manual score of the mistake student's invert_pose test cell (formgrader's
    write), and that cell's grade id."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        sub = gb.find_submission(LAB, "mistake")
        cell = next(g for nb in sub.notebooks for g in nb.grades if "invert" in g.name)
        cell.manual_score = MANUAL
        gb.db.commit()
        return cell.name


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """The class above, graded once for both halves of this file."""
    course = kit.released_course(tmp_path_factory.mktemp("class"), LAB)
    _set_up(course)
    reference = kit.solution_sources(LAB, FUNCTIONS)
    for student, cells in (("ref", reference), ("twin_a", TWIN_A), ("twin_b", TWIN_B),
                           ("mistake", MISTAKE), ("late", LATE), ("blank", None)):
        kit.submit(course, LAB, student, replace=cells)
    (course / "submitted" / "late" / LAB / "timestamp.txt").write_text(LATE_STAMP)
    rows = {r["student_id"]: r for r in grade_course(course, LAB, workers=2, quiet=True)}
    cell = _manual_score(course)
    yield course, rows, cell
    registry.use_course(None)


# --------------------------------------------------------------------------- export


def _roster(tmp_path, rows, header) -> str:
    path = tmp_path / "roster.csv"
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(header)
    writer.writerows(rows)
    path.write_text(text.getvalue())
    return str(path)


CANVAS_HEADER = ("student_id", "Student", "ID", "SIS User ID", "SIS Login ID", "Section")


def _canvas_roster(tmp_path, students=STUDENTS + ("dropped",)):
    return _roster(tmp_path, [(s, f"{s.title()}, Student", str(1000 + i), f"S{i:04d}",
                               f"{s}@example.edu", "Robotics 101")
                              for i, s in enumerate(students)], CANVAS_HEADER)


def test_canvas_export_has_canvas_columns_and_net_scores(graded, tmp_path, capsys):
    course, rows, _ = graded
    assert float(rows["ref"]["score"]) == 10.0 and float(rows["blank"]["score"]) == 0.0
    late_raw = float(rows["late"]["raw_score"])
    assert late_raw == 3.0 and float(rows["late"]["late_submission_penalty"]) == late_raw
    out = tmp_path / "canvas.csv"
    assert main(["export", str(course), LAB, "--format", "canvas", "--roster",
                 _canvas_roster(tmp_path), "--canvas-id", "4711", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "without a submission" in err and "dropped" in err
    table = list(csv.reader(io.StringIO(out.read_text())))
    # Canvas' import: the identity columns, then "Title (id)"; the Points Possible row
    assert table[0] == ["Student", "ID", "SIS User ID", "SIS Login ID", "Section",
                        f"{LAB} (4711)"]
    assert table[1][0] == "Points Possible" and float(table[1][5]) == 10.0
    by_id = {r[1]: r for r in table[2:]}
    assert len(table[2:]) == len(STUDENTS) + 1
    score = {s: by_id[str(1000 + i)][5] for i, s in enumerate(STUDENTS + ("dropped",))}
    assert float(score["ref"]) == 10.0 and float(score["twin_a"]) == 10.0
    assert float(score["late"]) == 0.0          # 3 points less the penalty (late: zero)
    assert float(score["blank"]) == 0.0
    assert score["dropped"] == ""               # no submission: left as Canvas has it
    # the TA's manual score replaces the mistaken cell's automatic one
    mistake_auto = float(rows["mistake"]["score"])
    assert mistake_auto < 3.0
    assert float(score["mistake"]) == pytest.approx(MANUAL)


def test_moodle_export_maps_by_email_and_refuses_unrostered(graded, tmp_path, capsys):
    course, _, _ = graded
    roster = _roster(tmp_path, [(s, f"{s}@example.edu") for s in STUDENTS if s != "blank"],
                     ("student_id", "email"))
    out = tmp_path / "moodle.csv"
    args = ["export", str(course), LAB, "--format", "moodle", "--roster", roster,
            "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "not in the roster" in err and "blank" in err and "--skip-unrostered" in err
    assert not out.exists()
    assert main(args + ["--skip-unrostered"]) == 0
    assert "not in the roster, left out: blank" in capsys.readouterr().err
    table = list(csv.reader(io.StringIO(out.read_text())))
    # Moodle's CSV import: a column to map users by (email -> useremail), a grade column
    assert table[0] == ["email", LAB]
    got = {r[0]: float(r[1]) for r in table[1:]}
    assert got == {"ref@example.edu": 10.0, "twin_a@example.edu": 10.0,
                   "twin_b@example.edu": 10.0, "mistake@example.edu": MANUAL,
                   "late@example.edu": 0.0}


def test_plain_export_and_bad_rosters(graded, tmp_path, capsys):
    course, _, cell = graded
    out = tmp_path / "plain.csv"
    roster = _roster(tmp_path, [(s,) for s in STUDENTS], ("student_id",))
    assert main(["export", str(course), LAB, "--format", "csv", "--roster", roster,
                 "--out", str(out)]) == 0
    rows = {r["student_id"]: r for r in csv.DictReader(io.StringIO(out.read_text()))}
    assert rows["ref"]["email"] == "ada@example.edu" and rows["ref"]["status"] == "graded"
    assert float(rows["late"]["raw_score"]) == 3.0
    assert float(rows["late"]["late_submission_penalty"]) == 3.0
    assert float(rows["late"]["score"]) == 0.0
    assert rows["mistake"]["manual_cells"] == cell
    # the roster a format cannot use is refused, naming the fix
    assert main(["export", str(course), LAB, "--format", "canvas", "--roster", roster]) == 2
    assert "lacks the column(s)" in capsys.readouterr().err
    twice = _roster(tmp_path, [("ref", "a@x"), ("ref", "b@x")], ("student_id", "email"))
    assert main(["export", str(course), LAB, "--format", "moodle", "--roster", twice]) == 2
    assert "listed again" in capsys.readouterr().err


# --------------------------------------------------------------------------- report


def _read(path) -> list[dict]:
    return list(csv.DictReader(io.StringIO(path.read_text())))


def test_class_report_numbers_and_page_in_chromium(graded, tmp_path, browser):  # noqa: F811
    course, rows, _ = graded
    out = tmp_path / "report"
    assert main(["report", str(course), LAB, "--out", str(out)]) == 0

    scores = {r["student_id"]: r for r in _read(out / "scores.csv")}
    assert set(scores) == set(STUDENTS)
    assert scores["late"]["status"] == "late" and float(scores["late"]["score"]) == 0.0
    assert scores["ref"]["status"] == "graded" and float(scores["ref"]["score"]) == 10.0
    assert float(scores["mistake"]["score"]) == pytest.approx(MANUAL)

    lost = {(r["function"], r["check"]): r for r in _read(out / "lost_credit.csv")}
    # invert_pose: the mistake and the blank; compose and rotvec: the three who left them blank
    assert lost[("invert_pose", "")]["students"].split(";") == ["blank", "mistake"]
    for f in ("compose_chain", "pose_from_rotvec"):
        assert sorted(lost[(f, "")]["students"].split(";")) == ["blank", "late", "mistake"]
        assert lost[(f, "")]["share"] == f"{3 / 6:.3f}"
    assert all(r["students_rescored"] == "6" for r in lost.values())

    mistakes = _read(out / "mistakes.csv")
    named = [r for r in mistakes if r["mistake"].startswith(MISTAKE_LABEL)]
    assert [(r["function"], r["who"]) for r in named] == [("invert_pose", "mistake")]

    errors = _read(out / "check_errors.csv")
    ref_rot = [r for r in errors if r["student_id"] == "ref" and r["function"] == "invert_pose"]
    assert ref_rot and all(float(r["error_over_tolerance"]) <= 1.0 for r in ref_rot)
    wrong = [r for r in errors if r["student_id"] == "mistake" and r["function"] == "invert_pose"]
    assert any(float(r["error_over_tolerance"]) > 1.0 for r in wrong)
    assert {r["student_id"] for r in errors} == set(STUDENTS)

    pairs = _read(out / "similar_pairs.csv")
    assert [(p["student_a"], p["student_b"], p["functions_same"], p["n_both_wrote"])
            for p in pairs] == [("twin_a", "twin_b", ";".join(sorted(FUNCTIONS)), "3")]

    page = browser.new_page()
    try:
        page.goto((out / "index.html").as_uri())
        widths = page.eval_on_selector_all("img", "imgs => imgs.map(i => i.naturalWidth)")
        assert len(widths) == 3 and all(w > 0 for w in widths), widths
        text = page.inner_text("body")
        assert "How the code is compared" in text and "twin_a" in text
        assert "renamed in order of first use" in text and MISTAKE_LABEL in text
        page.screenshot(path=str(tmp_path / "class_report.png"), full_page=True)
    finally:
        page.close()
    assert (tmp_path / "class_report.png").stat().st_size > 0


# --------------------------------------------------------------------------- the code compared


def _canonical_of(source: str) -> str:
    return canonical(ast.parse(source).body[0])


def test_same_code_means_same_tree_up_to_names_and_layout():
    assert _canonical_of(TWIN_A["invert_pose"]) == _canonical_of(TWIN_B["invert_pose"])
    assert _canonical_of(TWIN_A["pose_from_rotvec"]) == _canonical_of(TWIN_B["pose_from_rotvec"])
    # the mistake (R kept, not R^T) and the late student's own code are other code
    forms = {_canonical_of(c) for c in (TWIN_A["invert_pose"], MISTAKE["invert_pose"],
                                        LATE["invert_pose"])}
    assert len(forms) == 3
    # a name the function only reads (a module) is no local: numpy's np is not renamed
    assert _canonical_of("def f(x):\n    return np.eye(x)\n") != \
        _canonical_of("def f(x):\n    return sp.eye(x)\n")
    assert _canonical_of("def f(x):\n    y = x + 1\n    return y\n") == \
        _canonical_of("def g(a):\n    '''doc'''\n    b = a + 1  # note\n    return (b)\n")


def test_the_released_stub_pairs_nobody():
    stub = "def invert_pose(a_T_b):\n    # YOUR CODE HERE\n    raise NotImplementedError()\n"

    def notebook(*sources):
        return {"n.ipynb": json.dumps({"cells": [
            {"cell_type": "code", "source": s} for s in sources]})}

    released = notebook_functions(notebook(stub)["n.ipynb"], ["invert_pose"])
    template = {name: canonical(f) for name, f in released.items()}
    written = {s: normalised_functions(notebook(stub), ["invert_pose"], template)
               for s in ("a", "b", "c")}
    assert written == {"a": {}, "b": {}, "c": {}} and similar_pairs(written) == []
    # the last definition counts, as a run of the notebook leaves it; a cell that does not
    # parse and IPython's magics are no obstacle
    written["a"] = normalised_functions(notebook(stub, "%timeit 1\ndef (", TWIN_A["invert_pose"]),
                                        ["invert_pose"], template)
    written["b"] = normalised_functions(notebook(TWIN_B["invert_pose"]), ["invert_pose"],
                                        template)
    assert similar_pairs(written) == [("a", "b", ["invert_pose"], 1)]


def test_a_submission_handed_in_again_is_not_scored_from_a_stale_execution(graded, tmp_path):
    course = kit.fresh_course(graded[0], tmp_path)   # a copy: the shared class stays as it is
    notebook = course / "submitted" / "twin_b" / LAB / f"{LAB}.ipynb"
    notebook.write_text(notebook.read_text().replace("result", "answer"))
    out = tmp_path / "report"
    assert main(["report", str(course), LAB, "--out", str(out)]) == 0
    page = (out / "index.html").read_text()
    assert "Not scored again here" in page
    assert "twin_b: submitted again since it was graded" in page
    lost = _read(out / "lost_credit.csv")
    assert {r["students_rescored"] for r in lost} == {"5"}
    assert "twin_b" in {r["student_id"] for r in _read(out / "scores.csv")}


def test_a_submission_the_grader_could_not_grade_is_named_not_zeroed(graded, tmp_path, capsys):
    course = kit.fresh_course(graded[0], tmp_path)
    # what a run leaves when the grader failed on every attempt (course._withdraw_ungraded)
    assert gradebook.withdraw_scores(course, LAB, "twin_a", "not graded") > 0
    out = tmp_path / "moodle.csv"
    roster = _roster(tmp_path, [(s, f"{s}@example.edu") for s in STUDENTS],
                     ("student_id", "email"))
    assert main(["export", str(course), LAB, "--format", "moodle", "--roster", roster,
                 "--out", str(out)]) == 0
    assert "1 submitted but not graded" in capsys.readouterr().err
    got = dict(list(csv.reader(io.StringIO(out.read_text())))[1:])
    assert got["twin_a@example.edu"] == "" and float(got["twin_b@example.edu"]) == 10.0
    assert main(["report", str(course), LAB, "--out", str(tmp_path / "report")]) == 0
    scores = {r["student_id"]: r for r in _read(tmp_path / "report" / "scores.csv")}
    assert scores["twin_a"]["status"].startswith("ungraded") and scores["twin_a"]["score"] == ""

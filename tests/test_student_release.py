"""`cobotlab labs student DIR`: the students' copies of every lab hold no answer.

The copies must be what `nbgrader generate_assignment` releases (checked cell by cell against a
real nbgrader run on lab 0), keep every graded function's name with an empty body, copy the
lab's other files, refuse to overwrite a student's work, and refuse a source whose answers
nbgrader's preprocessors would not remove. About 15 s (one nbgrader run).
"""

from __future__ import annotations

import json
import shutil

import course_kit as kit
import nbformat
import pytest

from autograder.course import LABS_DIR
from cobotlab import cli
from cobotlab.labs import RELEASE_LEAKS, lab_names, write_student_labs


def _solution_cells(nb) -> dict[str, str]:
    return {c.metadata["nbgrader"]["grade_id"]: c.source for c in nb.cells
            if c.metadata.get("nbgrader", {}).get("solution")}


@pytest.fixture(scope="module")
def student_dir(tmp_path_factory):
    dest = tmp_path_factory.mktemp("student")
    assert cli.main(["labs", "student", str(dest)]) == 0
    return dest


def test_every_lab_is_written_without_answers(student_dir):
    names = lab_names()
    assert len(names) >= 5
    for name in names:
        source = nbformat.read(LABS_DIR / name / f"{name}.ipynb", as_version=4)
        released = nbformat.read(student_dir / name / f"{name}.ipynb", as_version=4)
        text = json.dumps(released)
        for leak in RELEASE_LEAKS:
            assert leak not in text, (name, leak)
        solutions = _solution_cells(source)
        stubs = _solution_cells(released)
        assert stubs.keys() == solutions.keys(), name
        for grade_id, stub in stubs.items():
            assert "raise NotImplementedError()" in stub, (name, grade_id)
            # The signature and docstring stay: the student fills in the body.
            header = solutions[grade_id].split("### BEGIN SOLUTION")[0].strip()
            assert stub.startswith(header), (name, grade_id)
            body = solutions[grade_id].split("### BEGIN SOLUTION")[1].split("### END SOLUTION")[0]
            answer_lines = [line.strip() for line in body.splitlines() if len(line.strip()) > 25]
            assert not any(line in stub for line in answer_lines), (name, grade_id)
        assert not any(c.get("outputs") for c in released.cells if c.cell_type == "code")
        # Everything but the answers is still there, in the source's order.
        assert [c.get("id") for c in released.cells] == [c.get("id") for c in source.cells]
    readme = (student_dir / "README.md").read_text()
    assert all(f"`{name}/`" in readme for name in names)


def test_lab0_matches_nbgrader_generate_assignment(student_dir, tmp_path):
    course = kit.released_course(tmp_path, "lab0_frames")
    theirs = nbformat.read(course / "release" / "lab0_frames" / "lab0_frames.ipynb", as_version=4)
    ours = nbformat.read(student_dir / "lab0_frames" / "lab0_frames.ipynb", as_version=4)
    assert ours.metadata == theirs.metadata
    assert len(ours.cells) == len(theirs.cells)
    for mine, nbgraders in zip(ours.cells, theirs.cells):
        assert mine == nbgraders, mine.get("id")


def test_a_lab_s_other_files_are_copied_and_results_left_out(tmp_path):
    labs = tmp_path / "labs"
    shutil.copytree(LABS_DIR / "lab0_frames", labs / "lab0_frames")
    (labs / "lab0_frames" / "points.csv").write_text("0.1,0.2,0.3\n")
    (labs / "lab0_frames" / "lab0_results").mkdir()          # an instructor's test run
    (labs / "lab0_frames" / "lab0_results" / "x.yaml").write_text("a: 1\n")
    written = write_student_labs(tmp_path / "out", labs_dir=labs)
    assert [p.name for p in written] == ["lab0_frames.ipynb"]
    assert (tmp_path / "out" / "lab0_frames" / "points.csv").read_text() == "0.1,0.2,0.3\n"
    assert not (tmp_path / "out" / "lab0_frames" / "lab0_results").exists()


def test_a_student_s_work_is_never_overwritten(tmp_path, capsys):
    dest = tmp_path / "mine"
    write_student_labs(dest, labs=["lab0_frames"])
    notebook = dest / "lab0_frames" / "lab0_frames.ipynb"
    notebook.write_text(notebook.read_text().replace("raise NotImplementedError()", "pass", 1))
    assert cli.main(["labs", "student", str(dest), "--lab", "lab0_frames"]) == 2
    err = capsys.readouterr().err
    assert "already exists and may hold your work" in err and "--force" in err
    assert "pass" in notebook.read_text()
    assert cli.main(["labs", "student", str(dest), "--lab", "lab0_frames", "--force"]) == 0
    assert notebook.read_text().count("raise NotImplementedError()") == 3


def test_unknown_lab_and_missing_sources_are_named(tmp_path, capsys):
    assert cli.main(["labs", "student", str(tmp_path / "a"), "--lab", "lab9_nope"]) == 2
    assert "no lab named lab9_nope; the labs are lab0_frames" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="no lab sources at"):
        write_student_labs(tmp_path / "b", labs_dir=tmp_path / "nowhere")


def test_a_source_with_an_unmarked_answer_is_refused(tmp_path):
    labs = tmp_path / "labs"
    (labs / "lab9").mkdir(parents=True)
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "language": "python",
                                 "display_name": "Python 3"}
    # An answer typed into a plain cell: nbgrader leaves it alone, so the release must not.
    nb.cells = [nbformat.v4.new_code_cell("from solutions.handeye import calibrate_eye_in_hand")]
    nbformat.write(nb, labs / "lab9" / "lab9.ipynb")
    with pytest.raises(ValueError, match="cell 0 still holds from solutions"):
        write_student_labs(tmp_path / "out", labs_dir=labs)
    assert not (tmp_path / "out" / "lab9" / "lab9.ipynb").exists()

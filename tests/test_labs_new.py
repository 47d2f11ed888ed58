"""`cobotlab labs new`: the skeleton works straight away (loads, runs, releases, grades
fairly), a copy of a built-in lab grades like the original, and a refused name leaves nothing.

Each test uses a lab name of its own: autograder.practice caches drawn practice problems by
lab, function and seed for the rest of the process, so two courses must not share a name here.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient

from autograder import checks, registry, sandbox
from autograder.pipeline.pipeline import grade_course
from autograder.secret import SECRET_ENV
from cobotlab.authoring import new_lab
from cobotlab.labs import RELEASE_LEAKS, write_student_labs

SKELETON = "offsets"   # the skeleton course's lab (module-scoped: built once)


@pytest.fixture(autouse=True)
def _no_course_left():
    yield
    registry.use_course(None)   # the other test files see the built-in labs only


@pytest.fixture(scope="module")
def skeleton(tmp_path_factory):
    """A course holding the skeleton lab, as `new` wrote it: (course, written files)."""
    course = tmp_path_factory.mktemp("course")
    written = new_lab(SKELETON, course)
    yield course, written
    registry.use_course(None)


def _cells(notebook: Path) -> dict:
    nb = json.loads(notebook.read_text())
    return {c["metadata"].get("nbgrader", {}).get("grade_id"): c for c in nb["cells"]}


def _solution(notebook: Path, grade_id: str) -> str:
    source = "".join(_cells(notebook)[grade_id]["source"])
    return "\n".join(line for line in source.splitlines()
                     if line.strip() not in ("### BEGIN SOLUTION", "### END SOLUTION"))


def _function(source: str, name: str):
    namespace = {"np": np}
    exec(source, namespace)  # noqa: S102 - a reference solution of our own notebooks
    return namespace[name]


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# --------------------------------------------------------------------------- the skeleton


def test_the_skeleton_is_a_complete_lab_the_registry_finds(skeleton):
    course, written = skeleton
    lab = course / "labs" / SKELETON
    assert written == [lab / f"{SKELETON}.ipynb", lab / "scoring.py",
                       course / ".cobotlab" / "specs" / f"{SKELETON}.py",
                       course / "cobotlab.toml", course / ".gitignore"]
    assert 'lab_folders = ["labs"]' in (course / "cobotlab.toml").read_text()
    assert not [p for p in course.iterdir() if p.name.startswith(".cobotlab-new")]

    registry.use_course(course)
    public, (spec,) = checks.SCORING[SKELETON], checks.SPECS[SKELETON]
    assert public[0].make_trial is None and spec.name == "mean_offset"
    trials = checks.make_trials(spec, np.random.default_rng(5))
    assert len(trials) == spec.n_trials >= len(checks.PUBLIC_SEEDS) * spec.practice_trials
    for trial in trials:
        measured, commanded = trial.args
        n = len(commanded)
        assert measured.shape == commanded.shape == (n, 3) and 5 <= n <= 40
        assert 5.0 <= np.linalg.norm(trial.truth) * 1000 <= 50.0
        # tol = 6 sigma / sqrt(N) with sigma 0.2 to 2 mm
        assert 6 * 0.2 / np.sqrt(n) <= trial.tol["offset"] <= 6 * 2.0 / np.sqrt(n)

    # The notebook agrees with the spec: the def's parameters, the test cell's points.
    cells = _cells(written[0])
    solution = cells["mean_offset"]["metadata"]["nbgrader"]
    test = cells["test_mean_offset"]["metadata"]["nbgrader"]
    assert solution["solution"] and not solution["locked"]
    assert test["grade"] and test["locked"] and test["points"] == spec.points
    assert cells["imports"]["metadata"]["nbgrader"]["locked"]
    (func,) = ast.parse(_solution(written[0], "mean_offset")).body
    assert ast.unparse(func.args) == spec.parameters
    assert "### BEGIN HIDDEN TESTS" in "".join(cells["test_mean_offset"]["source"])
    assert all(not c.get("outputs") for c in cells.values() if c["cell_type"] == "code")


def test_the_skeleton_notebook_runs_top_to_bottom_in_its_folder(skeleton):
    course, written = skeleton
    notebook = written[0]
    nb = nbformat.read(notebook, as_version=4)
    # As an author's Jupyter runs it: the kernel starts in the lab folder and finds the course
    # from the cobotlab.toml above it, not from the environment.
    env = {k: v for k, v in os.environ.items() if k != registry.COURSE_ENV}
    NotebookClient(nb, timeout=120, kernel_name="python3",
                   resources={"metadata": {"path": str(notebook.parent)}}).execute(env=env)
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") + o.get("data", {}).get("text/plain", "") for o in outputs)
    assert "mean_offset: 2 / 2 points" in text


def test_the_skeleton_releases_without_its_solution_and_with_its_practice_data(
        skeleton, tmp_path, monkeypatch):
    course, written = skeleton
    registry.use_course(course)
    dest = tmp_path / "student"
    (released,) = write_student_labs(dest, labs=[SKELETON])
    folder = dest / SKELETON
    text = released.read_text()
    assert not [leak for leak in RELEASE_LEAKS if leak in text]
    assert "np.mean(measured - commanded" not in text
    assert text.count("raise NotImplementedError()") == 1
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [f"{SKELETON}.ipynb", "scoring.py", f"practice_{SKELETON}.json.gz"])
    assert not [p for p in dest.rglob("*") if ".cobotlab" in p.parts]

    # A student's folder: no course above it, no private spec; check() scores on the file.
    registry.use_course(None)
    monkeypatch.delenv(registry.COURSE_ENV, raising=False)
    monkeypatch.chdir(folder)
    assert SKELETON in checks.SCORING and not registry.private_available(SKELETON)
    reference = _function(_solution(written[0], "mean_offset"), "mean_offset")
    assert checks.evaluate(reference, "mean_offset").fraction == 1.0


def test_the_skeleton_grades_the_reference_fully_and_names_the_wrong_sign(skeleton):
    course, written = skeleton
    registry.use_course(course)
    reference = _function(_solution(written[0], "mean_offset"), "mean_offset")
    result = checks.evaluate(reference, "mean_offset", assignment=SKELETON)
    assert result.points == result.max_points == 2.0, result.summary()

    (spec,) = checks.SPECS[SKELETON]
    (mistake,) = spec.code_mistakes
    wrong = checks.evaluate(mistake.func, "mean_offset", assignment=SKELETON)
    assert wrong.points == 0.0, wrong.summary()
    assert any(mistake.label in error for error in wrong.errors), wrong.errors
    assert "wrong sign" in mistake.label


# --------------------------------------------------------------------------- --from


def test_a_copy_of_lab1_grades_lab1s_reference_fully(tmp_path):
    course = tmp_path / "course"
    written = new_lab("flange_copy", course, from_lab="lab1_flange")
    lab = course / "labs" / "flange_copy"
    spec_file = course / ".cobotlab" / "specs" / "flange_copy.py"
    assert written[0] == lab / "flange_copy.ipynb" and spec_file in written
    assert not (lab / "lab1_flange.ipynb").exists()
    spec_text = spec_file.read_text()
    assert 'scoring = public_scoring("flange_copy")' in spec_text
    assert "autograder.scoring.lab1_flange" not in spec_text
    code = "".join("".join(c["source"]) for c in _cells(written[0]).values()
                   if c["cell_type"] == "code")
    assert 'assignment="flange_copy"' in code and '"lab1_flange"' not in code

    registry.use_course(course)
    copied = checks.SPECS["flange_copy"]
    assert [s.name for s in copied] == [s.name for s in checks.SPECS["lab1_flange"]]
    fit_rigid = _function(_solution(written[0], "fit_rigid"), "fit_rigid")
    result = checks.evaluate(fit_rigid, "fit_rigid", assignment="flange_copy")
    assert result.points == result.max_points, result.summary()


# --------------------------------------------------------------------------- refusals


def _refused(course: Path, name: str, from_lab=None, *words: str) -> None:
    """new_lab refuses with one LabError naming ``words``, and changes nothing on disk."""
    before = _tree(course) if course.exists() else None
    with pytest.raises(registry.LabError) as caught:
        new_lab(name, course, from_lab=from_lab)
    message = str(caught.value)
    assert "\n" not in message
    for word in words:
        assert word in message, message
    assert (_tree(course) if course.exists() else None) == before


def test_the_course_gitignore_keeps_the_secret_and_the_students_data_out(tmp_path):
    """`labs new` writes the course's .gitignore, or completes the author's own: the grading
    secret, grades.csv, the gradebook with its backup and journals, the run logs and the
    students' folders are never committed; the private specs and verify's reports are."""
    from cobotlab.authoring import GITIGNORE_LINES

    course = tmp_path / "course"
    course.mkdir()
    (course / ".gitignore").write_text("*.pyc\ngrades.csv")   # the author's, no final newline
    written = new_lab("first", course)
    assert course / ".gitignore" in written
    text = (course / ".gitignore").read_text()
    lines = text.splitlines()
    assert lines[:2] == ["*.pyc", "grades.csv"] and lines.count("grades.csv") == 1
    assert set(GITIGNORE_LINES) <= set(lines)
    # a second lab changes nothing
    assert course / ".gitignore" not in new_lab("second", course)
    assert (course / ".gitignore").read_text() == text

    # What git itself ignores: every file the grader writes with students' data, and none
    # of the course's own work.
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    subprocess.run(["git", "init", "-q", str(course)], check=True)
    students = ["grades.csv", "nbgrader_grades.csv", "gradebook.db", "gradebook.db-journal",
                ".nbgrader.log", ".cobotlab/secret", ".cobotlab/runs.jsonl",
                ".cobotlab/last_run.log", ".cobotlab/gradebook.backup.db",
                ".cobotlab/nbgrader_cells.json", "submitted/s1/first/first.ipynb",
                "autograded/s1/first/first.ipynb", "feedback/s1/first/first.html",
                "feedback_cobotlab/s1/first/feedback.html", "exchange/cobotlab/inbound/x"]
    own = [".cobotlab/specs/first.py", ".cobotlab/verified/first.json", "labs/first/scoring.py",
           "cobotlab.toml", "source/first/first.ipynb"]
    for name in students + own:
        (course / name).parent.mkdir(parents=True, exist_ok=True)
        (course / name).touch()
    done = subprocess.run(["git", "-C", str(course), "check-ignore", *students, *own],
                          capture_output=True, text=True, check=False)
    assert sorted(done.stdout.split()) == sorted(students)


def test_bad_names_and_taken_places_are_refused_leaving_nothing(tmp_path):
    course = tmp_path / "course"
    _refused(course, "9lives", None, str(course / "labs"), "not a valid name", "e.g.")
    assert not course.exists()

    new_lab("taken", course)
    _refused(course, "lab1_flange", None, str(course / "labs" / "lab1_flange"), "built-in",
             "choose another name")
    _refused(course, "taken", None, str(course / "labs" / "taken"), "already has a lab")
    (course / "labs" / "stray").mkdir()
    _refused(course, "stray", None, str(course / "labs" / "stray"), "already exists")
    (course / ".cobotlab" / "specs" / "orphan.py").write_text("SPECS = ()\n")
    _refused(course, "orphan", None, str(course / ".cobotlab" / "specs" / "orphan.py"),
             "delete that file")
    _refused(course, "copy", "no_such_lab", "no_such_lab", "lab0_frames", "taken")

    # A refusal found while the copy is being built (a spec the rewrite does not understand)
    # leaves no staging folder and no part of the lab.
    (course / "labs" / "odd").mkdir()
    (course / "labs" / "odd" / "odd.ipynb").write_text((course / "labs" / "taken" /
                                                        "taken.ipynb").read_text())
    (course / "labs" / "odd" / "scoring.py").write_text("SPECS = ()\n")
    (course / ".cobotlab" / "specs" / "odd.py").write_text("SPECS = ()\n")
    _refused(course, "copy", "odd", str(course / ".cobotlab" / "specs" / "odd.py"),
             "public_scoring")


def test_the_command_reports_a_bad_name_in_one_line(tmp_path):
    cobotlab = Path(sys.executable).parent / "cobotlab"
    course = tmp_path / "course"
    bad = subprocess.run([str(cobotlab), "labs", "new", "no good", "--dir", str(course)],
                         capture_output=True, text=True, timeout=60, check=False)
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.startswith("cobotlab: error: ") and bad.stderr.count("\n") == 1, bad.stderr
    assert "Traceback" not in bad.stderr and not course.exists()

    good = subprocess.run([str(cobotlab), "labs", "new", "by_cli", "--dir", str(course)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert good.returncode == 0, good.stderr
    assert "wrote" in good.stdout and "cobotlab labs verify labs/by_cli" in good.stdout
    assert (course / "labs" / "by_cli" / "by_cli.ipynb").is_file()


@pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="grading runs in bubblewrap")
def test_a_course_lab_grades_in_a_shard_and_merges_into_the_home_course(tmp_path):
    """A cluster job executes its copy of the course (the lab's folder and private spec
    come with it, the secret does not); `merge` at home finds the lab in the home course's
    own folders and scores what the job did."""
    import course_kit as kit

    from autograder.course import init_course
    from autograder.shards import merge_shard, write_job

    home = tmp_path / "home" / "course"
    new_lab("gauge", home)
    init_course(home)
    kit.nbgrader(home, "generate_assignment", "gauge")
    source = (home / "source" / "gauge" / "gauge.ipynb").read_text()
    wrong = source.replace("measured - commanded, axis", "commanded - measured, axis")
    assert wrong != source
    for student, text in (("ref", source), ("wrong", wrong)):
        folder = home / "submitted" / student / "gauge"
        folder.mkdir(parents=True)
        (folder / "gauge.ipynb").write_text(text)
    job = kit.fresh_course(home, tmp_path / "job")
    (job / ".cobotlab" / "secret").unlink()
    assert write_job(home, "gauge", job) == ["ref", "wrong"]
    registry.use_course(None)
    with pytest.MonkeyPatch.context() as env:
        env.delenv(SECRET_ENV, raising=False)
        assert grade_course(job, "gauge", quiet=True, students=["ref", "wrong"],
                            run_nbgrader=True) == []

    registry.use_course(None)
    merged = merge_shard(home, "gauge", job, quiet=True)
    assert {r["student_id"]: float(r["raw_score"]) for r in merged} == {"ref": 2.0,
                                                                      "wrong": 0.0}
    assert {s: float(r["score"]) for s, r in kit.read_grades(home).items()} == {
        "ref": 2.0, "wrong": 0.0}
    page = home / "feedback_cobotlab" / "wrong" / "gauge" / "feedback.html"
    assert "the offset has the wrong sign" in page.read_text()

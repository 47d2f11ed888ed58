"""A lab's life cycle in a course (issue 40, part 6): a draft that does not load, or a lab
whose `labs verify` failed, never blocks the other labs; `labs student` finds the course from
anywhere; `labs remove` takes a lab out of the course, grades and all, after asking.

Real pieces throughout: `cobotlab course init` and `labs student` through the CLI, a spec
that raises on import, a real `cobotlab labs verify` run that fails (in bubblewrap), nbgrader's
own `generate_assignment` and gradebook, a real `grade_course` run.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import course_kit as kit
import pytest

from autograder import gradebook, registry
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.record import GRADE_COLUMNS, GRADES_CSV
from autograder.record import update_csv
from cobotlab import cli
from cobotlab.authoring import new_lab
from cobotlab.removal import run_remove

GOOD, DRAFT, FAILED = "gauge_offset", "draft_lab", "failing_lab"


def _stderr_lines(capsys) -> list[str]:
    return _stderr_lines_of(capsys.readouterr().err)


def _draft(course: Path) -> Path:
    """A draft lab whose private spec raises on import; returns the spec."""
    new_lab(DRAFT, course)
    spec = course / ".cobotlab" / "specs" / f"{DRAFT}.py"
    spec.write_text(spec.read_text() + "\nraise RuntimeError('half-written generator')\n")
    return spec


def _fail_verify(course: Path, name: str) -> Path:
    """Make lab ``name``'s test cell worth 3 points where the spec says 2 (an author's slip)
    and run the real `cobotlab labs verify` on it, which fails; returns the notebook."""
    notebook = course / "labs" / name / f"{name}.ipynb"
    nb = json.loads(notebook.read_text())
    (cell,) = [c for c in nb["cells"]
               if c["metadata"].get("nbgrader", {}).get("grade_id") == "test_mean_offset"]
    cell["metadata"]["nbgrader"]["points"] = 3
    notebook.write_text(json.dumps(nb, indent=1))
    assert cli.main(["labs", "verify", str(notebook.parent), "--draws", "5"]) == 1
    record = json.loads(registry.verification_path(name).read_text())
    assert record["passed"] is False and record["lab_digest"] == registry.lab_digest(name)
    return notebook


def test_a_draft_that_raises_on_import_never_blocks_the_other_labs(tmp_path, capsys,
                                                                    monkeypatch):
    course = tmp_path / "course"
    new_lab(GOOD, course)
    spec = _draft(course)
    assert cli.main(["course", "init", str(course)]) == 0
    lines = _stderr_lines(capsys)
    (skipped,) = [line for line in lines if DRAFT in line]
    # one line: the lab, the reason (the file, its line, the exception), the fix
    assert skipped.startswith(f"cobotlab: skipped lab {DRAFT}: it does not load: {spec} (line ")
    assert "RuntimeError: half-written generator" in skipped and "fix the file" in skipped
    assert not (course / "source" / DRAFT).exists()
    for name in (GOOD, "lab0_frames", "lab5_depth"):
        assert (course / "source" / name / f"{name}.ipynb").is_file(), name
    # the good lab was never verified: laid out, with the warning `grade` gives too
    assert any(line.startswith(f"cobotlab: warning: {GOOD} was never verified") for line in lines)

    # `labs student` from a folder outside the course: --course names it
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    out = tmp_path / "students"
    assert cli.main(["labs", "student", str(out), "--course", str(course),
                     "--lab", GOOD, "--lab", DRAFT]) == 0
    (skipped,) = _stderr_lines(capsys)
    assert skipped.startswith(f"cobotlab: skipped lab {DRAFT}: it does not load: {spec}")
    assert (out / GOOD / f"{GOOD}.ipynb").is_file() and not (out / DRAFT).exists()
    assert f"`{DRAFT}/`" not in (out / "README.md").read_text()
    # only the draft asked for: nothing to write is an error naming it
    assert cli.main(["labs", "student", str(tmp_path / "none"), "--course", str(course),
                     "--lab", DRAFT]) == 2
    (error,) = _stderr_lines(capsys)
    assert error.startswith("cobotlab: error: no lab left to write: draft_lab: ")

    # ... and found by walking up from a folder inside the course, as git finds its repository
    registry.use_course(None)
    monkeypatch.chdir(course / "labs" / DRAFT)
    assert cli.main(["labs", "student", str(tmp_path / "walked"), "--lab", GOOD]) == 0
    assert (tmp_path / "walked" / GOOD / f"{GOOD}.ipynb").is_file()

    # outside any course, the built-in labs only, and it says so
    registry.use_course(None)
    monkeypatch.chdir(elsewhere)
    assert cli.main(["labs", "student", str(tmp_path / "bare"), "--lab", "lab0_frames"]) == 0
    (note,) = _stderr_lines(capsys)
    assert note.startswith("cobotlab: no course found") and "--course DIR" in note
    assert cli.main(["labs", "student", str(tmp_path / "x"), "--lab", GOOD]) == 2
    note, error = _stderr_lines(capsys)
    assert note.startswith("cobotlab: no course found") and f"no lab named {GOOD}" in error
    assert cli.main(["labs", "student", str(tmp_path / "y"), "--course", str(elsewhere)]) == 2
    assert "not a course" in capsys.readouterr().err and not (tmp_path / "y").exists()


def test_a_lab_whose_verify_failed_is_released_only_with_force(tmp_path, capsys):
    course = tmp_path / "course"
    new_lab(FAILED, course)
    registry.use_course(course)
    notebook = _fail_verify(course, FAILED)
    capsys.readouterr()
    assert cli.main(["course", "init", str(course)]) == 0
    (skipped,) = [line for line in _stderr_lines(capsys) if FAILED in line]
    assert skipped.startswith(f"cobotlab: skipped lab {FAILED}: it failed `cobotlab labs "
                              f"verify` ({registry.verification_path(FAILED)}: {notebook}: "
                              "cell test_mean_offset is worth 3 points, the spec 2")
    assert skipped.endswith("or pass --force to release it as it is")
    assert not (course / "source" / FAILED).exists()
    out = tmp_path / "students"
    assert cli.main(["labs", "student", str(out), "--course", str(course), "--lab", FAILED,
                     "--lab", "lab0_frames"]) == 0
    assert [line for line in _stderr_lines(capsys) if FAILED in line][0].startswith(
        f"cobotlab: skipped lab {FAILED}: it failed `cobotlab labs verify`")
    assert not (out / FAILED).exists() and (out / "lab0_frames").is_dir()

    # --force lays it out, and says it failed
    assert cli.main(["course", "init", str(course), "--force"]) == 0
    lines = _stderr_lines(capsys)
    assert not any("skipped" in line for line in lines)
    assert f"cobotlab: warning: {FAILED} failed its last verification" in "\n".join(lines)
    assert (course / "source" / FAILED / f"{FAILED}.ipynb").is_file()
    assert cli.main(["labs", "student", str(out), "--course", str(course), "--lab", FAILED,
                     "--force"]) == 0
    assert (out / FAILED / f"{FAILED}.ipynb").is_file()

    # an edit of the notebook alone after verify makes the lab unverified, not failed: it is
    # laid out, with the warning (the record is keyed by the digest of every file of the lab)
    before = registry.spec_hash(FAILED)
    notebook.write_text(notebook.read_text().replace('"points": 3', '"points": 2'))
    registry.use_course(course)
    assert registry.spec_hash(FAILED) == before   # scoring and spec unchanged
    assert "changed since it was last verified" in registry.verification_note(FAILED)
    assert registry.release_problem(FAILED) is None
    assert cli.main(["course", "init", str(course)]) == 0
    assert f"cobotlab: warning: {FAILED} changed since it was last verified" in "\n".join(
        _stderr_lines(capsys))


def _gradebook_assignments(course: Path) -> dict[str, int]:
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        return {a.name: len(a.submissions) for a in gb.assignments}


def test_remove_a_graded_built_in_lab_from_the_course(tmp_path, capsys, monkeypatch):
    """lab0_frames, graded for two students, removed from one course: every folder, the
    gradebook's assignment and its grades.csv rows go; another lab's row stays; the package
    keeps the lab, and `course init` no longer brings it back."""
    lab = "lab0_frames"
    course = kit.released_course(tmp_path, lab)
    kit.submit(course, lab, "alice")
    kit.submit(course, lab, "bob")
    grade_course(course, lab, run_nbgrader=True, quiet=True)   # autograded/ too
    other = {"assignment": "lab1_flange", "student_id": "alice", "score": "1.0"}
    update_csv(course, GRADES_CSV, GRADE_COLUMNS, [other], key=("assignment", "student_id"))
    (course / "feedback" / "alice" / lab).mkdir(parents=True)   # nbgrader's generate_feedback
    kit.nbgrader(course, "release_assignment", lab)   # in the exchange, for students to fetch
    outbound = course / "exchange" / "cobotlab" / "outbound" / lab
    inbound = course / "exchange" / "cobotlab" / "inbound"
    assert outbound.is_dir()
    (inbound / f"carol+{lab}+2026-11-20 10:00:00.000000 UTC+abc").mkdir(parents=True)
    (inbound / "carol+lab1_flange+2026-11-20 10:00:00.000000 UTC+abc").mkdir()
    assert _gradebook_assignments(course)[lab] == 2
    kept = course / ".cobotlab" / "executions" / lab
    assert kept.is_dir() and (course / "feedback_cobotlab" / "bob" / lab).is_dir()
    before = sorted(str(p) for p in course.rglob("*"))
    capsys.readouterr()

    # without a terminal and without --yes: the plan, loudly, then a refusal
    monkeypatch.chdir(course / "source")   # the course is found from a folder inside it
    assert cli.main(["labs", "remove", lab]) == 2
    captured = capsys.readouterr()
    for shown in (f"source/{lab}/", f"release/{lab}/", f"submitted/alice/{lab}/",
                  f"autograded/bob/{lab}/", f"feedback/alice/{lab}/",
                  f"feedback_cobotlab/alice/{lab}/", f".cobotlab/executions/{lab}/",
                  f"exchange/cobotlab/outbound/{lab}/", f"exchange/cobotlab/inbound/carol+{lab}+",
                  f"gradebook.db: assignment {lab} with 2 submission(s), 2 of them graded",
                  f"grades.csv: 2 row(s) of {lab}", "added to removed_labs"):
        assert shown in captured.out, captured.out
    assert f"WARNING: {lab} HAS GRADED SUBMISSIONS" in captured.err
    assert "pass --yes" in captured.err
    # asked at a terminal: a graded lab wants its name typed; anything else removes nothing
    assert run_remove(lab, course, ask=lambda prompt: "y", interactive=True) == 1

    def end_of_input(prompt):
        raise EOFError
    assert run_remove(lab, course, ask=end_of_input, interactive=True) == 1   # Ctrl-D: no
    assert sorted(str(p) for p in course.rglob("*")) == before

    assert cli.main(["labs", "remove", lab, "--course", str(course), "--yes"]) == 0
    for gone in (course / "source" / lab, course / "release" / lab, kept,
                 course / "submitted" / "alice" / lab, course / "autograded" / "bob" / lab,
                 course / "feedback" / "alice" / lab, course / "feedback_cobotlab" / "bob" / lab,
                 outbound):
        assert not os.path.lexists(gone), gone
    assert [p.name.split("+")[1] for p in inbound.iterdir()] == ["lab1_flange"]
    assert lab not in _gradebook_assignments(course)
    with pytest.raises(ValueError, match="has no assignment"):
        gradebook.class_scores(course, lab)
    with open(course / GRADES_CSV) as f:
        rows = list(csv.DictReader(f))
    assert [(r["assignment"], r["student_id"]) for r in rows] == [("lab1_flange", "alice")]
    assert gradebook.problem(course / "gradebook.db") is None
    assert (course / "source" / "lab1_flange").is_dir()   # the other labs untouched
    assert registry.removed_labs(course) == [lab] and lab not in registry.lab_names()
    assert (registry.builtin_folder() / lab / f"{lab}.ipynb").is_file()   # the package keeps it

    capsys.readouterr()
    assert cli.main(["course", "init", str(course)]) == 0
    assert not (course / "source" / lab).exists()
    assert cli.main(["labs", "student", str(tmp_path / "s"), "--course", str(course),
                     "--lab", lab]) == 2
    assert f"no lab named {lab}" in capsys.readouterr().err
    assert cli.main(["labs", "remove", lab, "--course", str(course), "--yes"]) == 2
    assert "already in removed_labs" in capsys.readouterr().err


def test_remove_a_course_lab_that_does_not_load(tmp_path, capsys):
    """A draft whose spec raises is removed like any lab, with its own folder and spec (so
    `course init` does not bring it back); an ungraded lab asks a plain yes/no."""
    course = tmp_path / "course"
    new_lab(GOOD, course)
    spec = _draft(course)
    (course / "source" / DRAFT).mkdir(parents=True)   # an earlier init's copy
    answers = []
    assert run_remove(DRAFT, course, ask=lambda prompt: answers.append(prompt) or "y",
                      interactive=True) == 0
    assert answers == [f"Remove {DRAFT}? [y/N] "]
    captured = capsys.readouterr()
    assert "WARNING" not in captured.err
    for gone in (course / "labs" / DRAFT, spec, course / "source" / DRAFT):
        assert not gone.exists(), gone
        assert f"removed {gone.relative_to(course)}" in captured.out
    assert (course / "labs" / GOOD).is_dir() and registry.removed_labs(course) == []
    assert cli.main(["labs", "remove", "no_such_lab", "--course", str(course), "--yes"]) == 2
    assert "has no lab named 'no_such_lab'" in capsys.readouterr().err
    assert cli.main(["labs", "remove", GOOD, "--course", str(tmp_path), "--yes"]) == 2
    assert "is not a course" in capsys.readouterr().err
    (course / "source" / "keep").mkdir()
    assert cli.main(["labs", "remove", "../source", "--course", str(course), "--yes"]) == 2
    assert "is not a lab's name" in capsys.readouterr().err
    assert (course / "source" / "keep").is_dir()


@pytest.mark.parametrize("text, error", [
    ('removed_labs = ["gauge_offset"]\n', "not a built-in lab"),
    ('removed_labs = "lab0_frames"\n', "removed_labs must be a list of names"),
])
def test_removed_labs_names_only_built_in_labs(tmp_path, text, error):
    (tmp_path / registry.CONFIG_NAME).write_text(text)
    with pytest.raises(registry.LabError, match=error):
        registry.removed_labs(tmp_path)


def _lock(folder: Path, locked: bool) -> None:
    """Make ``folder``'s entries undeletable (or deletable again): immutable for root, who
    ignores permissions (ext4's chattr), read-only for anyone else."""
    import subprocess

    if os.geteuid() == 0:
        subprocess.run(["chattr", "+i" if locked else "-i", str(folder)], check=True)
    else:
        folder.chmod(0o555 if locked else 0o755)


def test_what_remove_may_not_delete_is_named_and_the_rest_goes(tmp_path, capsys):
    """A student's submission the instructor may not delete (one in a shared exchange, say;
    here a collected one, planned before the lab's own folder): the rest of the lab goes, the
    one left is named with the fix, and a second run finishes the job."""
    course = tmp_path / "course"
    new_lab(GOOD, course)
    (course / "nbgrader_config.py").write_text(
        "c = get_config()  # noqa: F821\nc.CourseDirectory.course_id = 'cobotlab'\n"
        f"c.Exchange.root = {str(course / 'exchange')!r}\n")
    inbound = course / "exchange" / "cobotlab" / "inbound" / f"dave+{GOOD}+2026-11-20 10:00 UTC"
    entry = course / "submitted" / "dave" / GOOD
    for folder in (inbound, entry):
        folder.mkdir(parents=True)
        (folder / f"{GOOD}.ipynb").write_text("{}")
    _lock(entry, True)
    try:
        assert cli.main(["labs", "remove", GOOD, "--course", str(course), "--yes"]) == 2
        captured = capsys.readouterr()
        assert f"removed labs/{GOOD}" in captured.out and not (course / "labs" / GOOD).exists()
        assert not inbound.exists()
        (error,) = _stderr_lines_of(captured.err)
        assert error.startswith(f"cobotlab: error: removed everything else of {GOOD}, but "
                                f"not {entry} (") and "run `cobotlab labs remove" in error
    finally:
        _lock(entry, False)
    assert cli.main(["labs", "remove", GOOD, "--course", str(course), "--yes"]) == 0
    assert not entry.exists()


def _stderr_lines_of(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]

"""What `cobotlab grade` leaves for nbgrader's feedback release, piece by piece (fast; the
whole exchange cycle, real nbgrader end to end, is in tests/test_course_cycle.py).

The exchange files come from the frozen copy and are checked; cobotlab's section is
student-safe and scoped; AddCobotlabFeedback puts it on nbgrader's page only for the
submission it graded; a course config from an earlier `course init` gets a message naming
the line to add.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_notebook
from traitlets.config import Config

from autograder import feedback_release, freeze
from autograder.checks import CheckResult, FunctionResult
from autograder.course import _CONFIG
from autograder.errors import ProblemError
from autograder.feedback import feedback_html, feedback_section
from autograder.nbgrader_hooks import AddCobotlabFeedback, HideHiddenTests
from autograder.outcomes import Place
from autograder.pipeline.execution import cell_error_note
from autograder.pipeline.score import SubmissionGrade

LAB = "lab0_frames"
SECRET = "ab" * 64   # what nbgrader's submit writes: token_hex(64)
STAMP = "2026-11-20 10:00:00.000000 UTC"


def _grade(flags=(), notes=()) -> SubmissionGrade:
    check = CheckResult("translation", "mm", 0.0, 0, 6, 1990.0, 1990.0, 1e-6, "")
    f = FunctionResult("invert_pose", 1.5, 3.0, [check], n_problems=6, n_failed=6,
                       problem_errors=(ProblemError("", "this answer looks like a "
                                                    "classic mistake: its translation is "
                                                    "-t, not -R^T t"),) * 6)
    return SubmissionGrade("ann", LAB, [f], list(flags), list(notes))


def _submission(root: Path, secret: bytes = SECRET.encode(), stamp: bytes = STAMP.encode()):
    folder = root / "submitted" / "ann" / LAB
    folder.mkdir(parents=True)
    (folder / f"{LAB}.ipynb").write_text(json.dumps({"cells": [], "metadata": {}}))
    (folder / "timestamp.txt").write_bytes(stamp)
    (folder / "submission_secret.txt").write_bytes(secret)
    return folder


def _freeze(root: Path) -> freeze.Frozen:
    (root / "store").mkdir()
    [frozen] = freeze.freeze_submissions(root / "submitted", LAB, {f"{LAB}.ipynb"},
                                         root / "store")
    return frozen


# --------------------------------------------------------------------------- exchange files


def test_the_exchange_files_come_from_the_frozen_copy_checked(tmp_path):
    live = _submission(tmp_path)
    frozen = _freeze(tmp_path)
    (live / "submission_secret.txt").write_text("cd" * 64)   # changed after the freeze
    assert frozen.exchange == {"timestamp.txt": STAMP.encode(),
                               "submission_secret.txt": SECRET.encode()}
    course = tmp_path / "course"
    course.mkdir()
    feedback_release.write_exchange_files(course, LAB, frozen)
    graded = course / "autograded" / "ann" / LAB
    assert (graded / "submission_secret.txt").read_text() == SECRET
    assert (graded / "timestamp.txt").read_text() == STAMP

    # a later submission without a secret: the earlier one's must not stay to misdirect
    frozen.exchange.pop("submission_secret.txt")
    feedback_release.write_exchange_files(course, LAB, frozen)
    assert not (graded / "submission_secret.txt").exists()
    # an autograded folder that is a link is never written through
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (course / "autograded" / "bob").mkdir()
    (course / "autograded" / "bob" / LAB).symlink_to(elsewhere)
    frozen.student_id = "bob"
    with pytest.raises(ValueError, match="symlink"):
        feedback_release.write_exchange_files(course, LAB, frozen)
    assert not os.listdir(elsewhere)


@pytest.mark.parametrize("secret, stamp, kept", [
    (b"ab cd", STAMP.encode(), {"timestamp.txt"}),                 # a blank in the secret
    (b"\x1b[31m" + b"a" * 20, STAMP.encode(), {"timestamp.txt"}),  # a control character
    (b"a" * 2000, STAMP.encode(), {"timestamp.txt"}),              # far longer than nbgrader's
    (SECRET.encode(), b"x" * 100, {"submission_secret.txt"}),      # not a timestamp
])
def test_exchange_files_a_student_wrote_are_refused_with_a_note(tmp_path, secret, stamp, kept):
    _submission(tmp_path, secret, stamp)
    frozen = _freeze(tmp_path)
    assert set(frozen.exchange) == kept
    assert any("cannot be released through nbgrader's exchange" in n for n in frozen.notes)


def test_a_class_partly_outside_the_exchange_is_named_with_the_way_out(tmp_path):
    frozen = [freeze.Frozen(sid, notebooks=[Path("x.ipynb")]) for sid in ("ann", "bob", "cy")]
    frozen[0].exchange = {"timestamp.txt": b"t", "submission_secret.txt": b"s"}
    frozen[1].exchange = {"timestamp.txt": b"t"}
    note = feedback_release.unreleasable_note(LAB, frozen)
    assert "bob, cy" in note and "--CourseDirectory.student_id_exclude=bob,cy" in note
    # nobody came through the exchange: no release_feedback to warn about
    assert feedback_release.unreleasable_note(LAB, frozen[1:]) is None


# --------------------------------------------------------------------------- the section


def test_the_section_is_the_students_page_without_instructor_notes_scoped():
    grade = _grade(flags=["suspicious_secret_probe"], notes=[
        cell_error_note("NameError: name 'x' is not defined", Place(0, 1)),
        "graded after 1 grader error(s), each retried in a fresh sandbox: WorkerFailure: "
        "the memory limit of the template",
        "no cgroup for this submission (unreadable cgroup.procs): per-process limits only",
        "nbgrader autograde: 1.2 s of its own"])
    for page in (feedback_html(grade), feedback_section(grade)):
        assert "classic mistake: its translation is -t" in page
        assert "NameError" in page   # the student's own error is theirs to read
        for needle in ("suspicious", "grader error", "WorkerFailure", "cgroup", "nbgrader"):
            assert needle not in page, needle
    section = feedback_section(grade)
    assert section.startswith("<div class='cobotlab-feedback'>") and "<body" not in section
    style = section[section.index("<style>") + 7:section.index("</style>")]
    selectors = [rule.split("{")[0] for rule in style.split("}") if "{" in rule]
    assert selectors and all(s.strip().startswith("div.cobotlab-feedback")
                             for rule in selectors for s in rule.split(","))
    assert "href='#cobotlab-invert_pose'" in section and "id='cobotlab-invert_pose'" in section


# --------------------------------------------------------------------------- the hook


def _generate(root: Path, autograded_stamp: str | None):
    """AddCobotlabFeedback on a notebook of ann's, as generate_feedback runs it; returns the
    notebook and nbgrader's warnings."""
    graded = root / "autograded" / "ann" / LAB
    graded.mkdir(parents=True, exist_ok=True)
    if autograded_stamp is not None:
        (graded / "timestamp.txt").write_text(autograded_stamp)
    config = Config()
    config.CourseDirectory.root = str(root)
    hook = AddCobotlabFeedback(config=config)
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append
    hook.log.addHandler(handler)
    try:
        nb = new_notebook(cells=[new_code_cell("def invert_pose(a_T_b): ...")])
        nb, _ = hook.preprocess(nb, {"nbgrader": {"student": "ann", "assignment": LAB}})
    finally:
        hook.log.removeHandler(handler)
    return nb, [r.getMessage() for r in records if r.levelno >= logging.WARNING]


def test_the_hook_puts_the_section_on_top_only_for_the_submission_graded(tmp_path):
    nb, warnings = _generate(tmp_path, STAMP)
    assert len(nb.cells) == 1 and "run `cobotlab grade` first" in warnings[0]

    feedback_release.write_section(tmp_path, LAB, _grade(), STAMP, {})
    nb, warnings = _generate(tmp_path, STAMP)
    assert not warnings and len(nb.cells) == 2
    top = nb.cells[0]
    assert top.source == "" and top.metadata["transient"]["remove_source"]
    assert "classic mistake" in top.outputs[0]["data"]["text/html"]
    nbformat.validate(nb)

    # the autograded notebook is of a newer submission: cobotlab's report is not about it
    nb, warnings = _generate(tmp_path, "2026-11-21 09:00:00.000000 UTC")
    assert len(nb.cells) == 1 and "run `cobotlab grade` again" in warnings[0]


def _hide(root: Path, comments: dict[str, str]) -> dict[str, str]:
    """HideHiddenTests on a notebook of ann's whose cells carry ``comments`` ({grade id:
    comment}, as nbgrader's GetGrades puts them), the first an autograded answer and the
    second a manually graded one; {grade id: the comment the feedback shows}."""
    config = Config()
    config.CourseDirectory.root = str(root)
    cells = []
    for i, (gid, comment) in enumerate(comments.items()):
        cells.append(new_code_cell("def invert_pose(a_T_b): ...", metadata={"nbgrader": {
            "grade_id": gid, "solution": True, "grade": i == 1, "comment": comment}}))
    nb, _ = HideHiddenTests(config=config).preprocess(
        new_notebook(cells=cells), {"nbgrader": {"student": "ann", "assignment": LAB}})
    return {c.metadata["nbgrader"]["grade_id"]: c.metadata["nbgrader"]["comment"]
            for c in nb.cells}


def test_the_feedback_shows_a_comment_as_its_section_says_never_by_its_words(tmp_path):
    """A comment cobotlab wrote (its digest in the section) is shown as its student lines;
    an instructor's own comment, even one that starts as cobotlab's do, as it is; with no
    section, the autograded answers' comments are withheld and a manual one is kept."""
    ours = feedback_release.Comment(
        ("cobotlab: 1.5 / 3 points on 6 hidden problems.", "Failed checks: translation."),
        ("nbgrader's own hidden-test cell: 3 / 3 (cross-check; the score above is the "
         "grade).", "Flags: suspicious_sys_modules."))
    assert ours.text == "\n".join(ours.student + ours.instructor)
    theirs = "cobotlab: Flags are how we spot copying; see me"   # a TA's words, kept whole
    shown = {"invert_pose": ours.text, "explain": theirs}
    assert _hide(tmp_path, shown) == {"invert_pose": "", "explain": theirs}
    feedback_release.write_section(tmp_path, LAB, _grade(), STAMP, {"invert_pose": ours})
    section = (tmp_path / feedback_release.section_path("ann", LAB)).read_text()
    assert "suspicious_sys_modules" not in section and "cross-check" not in section
    assert _hide(tmp_path, shown) == {"invert_pose": "\n".join(ours.student),
                                      "explain": theirs}
    # the gradebook holds another comment than the one the section stands for: kept whole
    other = ours.text.replace("1.5 / 3", "3 / 3")
    assert _hide(tmp_path, {"invert_pose": other, "explain": theirs})["invert_pose"] == other


# --------------------------------------------------------------------------- the config


def _config(root: Path, text: str) -> Path:
    root.mkdir(exist_ok=True)
    (root / "nbgrader_config.py").write_text(text)
    return root


def test_an_earlier_course_config_gets_the_line_to_add(tmp_path):
    current = _CONFIG.format(course_id="cobotlab", root=str(tmp_path), exchange="/x")
    assert feedback_release.config_problem(_config(tmp_path / "now", current)) is None
    earlier = current.replace('    "autograder.nbgrader_hooks.AddCobotlabFeedback",\n', "")
    message = feedback_release.config_problem(_config(tmp_path / "earlier", earlier))
    assert '"autograder.nbgrader_hooks.AddCobotlabFeedback"' in message
    assert "c.GenerateFeedback.preprocessors" in message and "HideHiddenTests" in message
    oldest = current[:current.index("c.GenerateFeedback")]
    message = feedback_release.config_problem(_config(tmp_path / "oldest", oldest))
    assert "hidden tests" in message and "AddCobotlabFeedback" in message


def test_a_course_laid_out_before_issue_51_gets_the_inert_pages_from_course_init(tmp_path):
    """`cobotlab course init` run again on a course whose config predates the preprocessor
    that makes formgrader's and the feedback's pages inert adds it, once, where nbgrader
    reads it; `cobotlab grade`'s config check asks for it until then."""
    import course_kit as kit

    from autograder.course import INERT_PAGES_CONFIG, _add_inert_pages, init_course

    course = kit.initialized_course(tmp_path)
    config = course / "nbgrader_config.py"
    inert_line = f'    "{feedback_release.INERT}",\n'
    earlier = config.read_text().replace(INERT_PAGES_CONFIG, "").replace(inert_line, "")
    assert feedback_release.INERT not in earlier
    config.write_text(earlier)
    assert "course init" in feedback_release.config_problem(course)

    init_course(course, quiet=True)
    assert feedback_release.config_problem(course) is None
    upgraded = config.read_text()
    _add_inert_pages(config)   # what the next `course init` does to it: nothing
    assert config.read_text() == upgraded
    from traitlets.config.loader import PyFileConfigLoader

    loaded = PyFileConfigLoader("nbgrader_config.py", path=str(course)).load_config()
    assert loaded.HTMLExporter.preprocessors == [feedback_release.INERT]
    steps = loaded.GenerateFeedback.preprocessors
    # after GetGrades (the comments) and before cobotlab's own section goes on top
    assert steps.index("nbgrader.preprocessors.GetGrades") < steps.index(
        feedback_release.INERT) == steps.index(feedback_release.HOOK) - 1

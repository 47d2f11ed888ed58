"""Get cobotlab's feedback to students through nbgrader's own release.

After ``cobotlab grade``, the instructor runs nbgrader's ``generate_feedback`` and
``release_feedback`` and each student ``fetch_feedback`` (docs/instructors.md, *How feedback
reaches students*). For that to work, ``cobotlab grade`` leaves two things in the course:

* in ``autograded/<student>/<assignment>/``, beside the autograded notebooks, the
  submission's ``timestamp.txt`` and ``submission_secret.txt`` as the freeze read them
  (:data:`autograder.freeze.EXCHANGE_FILES`), which plain ``nbgrader autograde`` would have
  copied there: ``release_feedback`` names each released page after the secret, and the
  student's ``fetch_feedback`` finds it with the same secret from its own cache;
* in ``feedback_cobotlab/<student>/<assignment>/``, :data:`SECTION`: cobotlab's feedback as a
  section for nbgrader's page (:func:`autograder.feedback.feedback_section`: the score, each
  function's verdict and failed checks, the named mistakes; never a flag, a note for the
  instructor, nbgrader's cross-check or test code), with the submission's timestamp.
  ``autograder.nbgrader_hooks.AddCobotlabFeedback``, one of ``generate_feedback``'s
  preprocessors in the course's ``nbgrader_config.py``, puts it on top of nbgrader's page.

The section is kept in cobotlab's own folder, not in ``autograded/``, because plain
``nbgrader autograde`` copies every file a student hands in there: a page a student wrote
must never pass for cobotlab's.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from autograder import freeze, record

__all__ = ["SECTION", "HOOK", "Comment", "comment_digest", "write_exchange_files",
           "write_section", "section_path", "config_problem", "unreleasable_note", "INERT"]

SECTION = "nbgrader_section.json"
HOOK = "autograder.nbgrader_hooks.AddCobotlabFeedback"
_HIDE = "autograder.nbgrader_hooks.HideHiddenTests"
# Makes a submission inert before nbgrader renders it as HTML (formgrader, feedback pages).
INERT = "autograder.sanitize_notebook.InertSubmission"


@dataclass(frozen=True)
class Comment:
    """cobotlab's auto comment on a solution cell, in two parts: the ``student`` lines
    (the score, the failed checks), which nbgrader's feedback shows too, and the
    ``instructor`` lines (nbgrader's cross-check, the flags), which only formgrader shows."""

    student: tuple[str, ...]
    instructor: tuple[str, ...] = ()

    @property
    def text(self) -> str:
        """The comment as the gradebook keeps it and formgrader shows it: every line."""
        return "\n".join(self.student + self.instructor)

    @property
    def for_student(self) -> str:
        """The comment as nbgrader's feedback shows it: the student lines."""
        return "\n".join(self.student)


def comment_digest(text: str) -> str:
    """A comment's SHA-256 (hex): the section names the comment it stands for by it, so the
    instructor's lines never reach a file of the student's feedback."""
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()


def section_path(student: str, assignment: str) -> str:
    """Where, below the course, :func:`write_section` writes a student's section."""
    return f"feedback_cobotlab/{student}/{assignment}/{SECTION}"


def write_exchange_files(root: Path, assignment: str, sub: freeze.Frozen) -> None:
    """The submission's exchange files, from its frozen copy, into its autograded folder
    (a stale one of an earlier submission, which the new one lacks, is removed: the feedback
    would otherwise go to the earlier submission)."""
    for name in freeze.EXCHANGE_FILES:
        relative = f"autograded/{sub.student_id}/{assignment}/{name}"
        if name in sub.exchange:
            record.write_file(root, relative, sub.exchange[name])
        else:
            record.remove_file(root, relative)


def write_section(root: Path, assignment: str, grade, timestamp: str,
                  comments: dict[str, Comment]) -> Path:
    """cobotlab's feedback of one graded submission (a
    :class:`autograder.pipeline.score.SubmissionGrade`) as the section nbgrader's feedback page
    gets, with the ``timestamp`` of the submission it grades. ``comments`` (grade id of a
    solution cell -> the :class:`Comment` written to the gradebook) go in as ``{grade id:
    {"digest": comment_digest(text), "student": for_student}}``: nbgrader's feedback shows
    a cell's comment whose digest matches as its student lines."""
    from autograder import feedback  # the grader's modules: not for nbgrader_hooks' import

    document = {"timestamp": timestamp, "score": grade.score, "max_score": grade.max_score,
                "html": feedback.feedback_section(grade),
                "comments": {gid: {"digest": comment_digest(c.text), "student": c.for_student}
                             for gid, c in comments.items()}}
    return record.write_file(root, section_path(grade.student_id, assignment),
                             json.dumps(document).encode("utf-8"))


def _names(preprocessors) -> list[str]:
    return [p if isinstance(p, str) else f"{p.__module__}.{p.__qualname__}"
            for p in preprocessors]


def config_problem(root: Path) -> str | None:
    """What the course's ``nbgrader_config.py`` lacks for nbgrader's feedback to carry
    cobotlab's and hide the tests (a config written by an earlier ``course init``), said
    with the line to add; None when it has both hooks."""
    from traitlets.config.loader import PyFileConfigLoader

    try:
        config = PyFileConfigLoader("nbgrader_config.py", path=str(root)).load_config()
    except Exception as exc:  # noqa: BLE001 - nbgrader will say more; grading goes on
        return f"nbgrader_config.py could not be read ({freeze.printable(exc, 200)})"
    names = _names(config.GenerateFeedback.get("preprocessors", []))
    if _HIDE not in names:
        return ("nbgrader_config.py does not set nbgrader's feedback preprocessors: "
                "`nbgrader generate_feedback` would show students the hidden tests and not "
                "cobotlab's feedback. Add: c.GenerateFeedback.preprocessors = "
                f'["nbgrader.preprocessors.GetGrades", "{_HIDE}", "{INERT}", "{HOOK}", '
                '"nbconvert.preprocessors.CSSHTMLHeaderPreprocessor"]')
    if HOOK not in names:
        return (f'nbgrader_config.py (from an earlier `cobotlab course init`) lacks "{HOOK}" '
                "in c.GenerateFeedback.preprocessors: nbgrader's feedback pages would not "
                f'carry cobotlab\'s. Add it to that list, after "{_HIDE}"')
    if INERT not in names or INERT not in _names(config.HTMLExporter.get("preprocessors", [])):
        return ("nbgrader_config.py (from a `cobotlab course init` before issue 51) lets "
                "formgrader and nbgrader's feedback pages run what a student's notebook holds "
                "(HTML, scripts) in the grader's browser: run `cobotlab course init` on the "
                "course again, which adds the lines (docs/instructors.md, *Pages that show a "
                "submission*)")
    return None


def unreleasable_note(assignment: str, frozen: list[freeze.Frozen]) -> str | None:
    """When some submissions came through nbgrader's exchange and others did not (copied by
    hand, or with a damaged secret): ``nbgrader release_feedback`` stops at the first of the
    others, so say who they are and how to release everyone else's feedback."""
    usable = [f for f in frozen if f.accepted and f.notebooks]
    missing = [f.student_id for f in usable if set(freeze.EXCHANGE_FILES) - set(f.exchange)]
    if not missing or len(missing) == len(usable):
        return None
    who = ",".join(missing)
    return (f"no usable {' or '.join(freeze.EXCHANGE_FILES)} from `nbgrader submit` for "
            f"{', '.join(missing)}: nbgrader release_feedback cannot release their feedback "
            f"and stops at the first; release the others' with `nbgrader release_feedback "
            f"{assignment} --CourseDirectory.student_id_exclude={who}` and give them "
            f"feedback_cobotlab/<student>/{assignment}/feedback.html")

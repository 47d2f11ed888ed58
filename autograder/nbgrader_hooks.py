"""Preprocessors that the course's ``nbgrader_config.py`` plugs into nbgrader's own commands.

:class:`HideHiddenTests` keeps the hidden tests out of the feedback nbgrader makes
(``nbgrader generate_feedback``, formgrader's "Generate Feedback" / "Release Feedback"): it
reads the autograded notebooks, whose test cells nbgrader restored from the source with
their hidden tests in them. :class:`AddCobotlabFeedback` puts cobotlab's own feedback on top
of the same pages, so that ``release_feedback`` and the students' ``fetch_feedback`` carry it
(:mod:`autograder.feedback_release`). nbgrader imports this module by name, so it stays light
(no grader, no numpy) and runs wherever nbgrader runs from the course's virtual environment.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from nbconvert.preprocessors import Preprocessor
from nbformat.v4 import new_code_cell, new_output
from traitlets import Bool, List, Unicode

from autograder import feedback_release, safe_files
from autograder.nbgrader_cells import nbgrader_metadata

__all__ = ["HideHiddenTests", "AddCobotlabFeedback"]

# nbgrader's own delimiters (ClearHiddenTests' defaults), which the labs use.
BEGIN = "BEGIN HIDDEN TESTS"
END = "END HIDDEN TESTS"


def strip_hidden(source: str, begin: str = BEGIN, end: str = END) -> tuple[str, bool]:
    """``source`` without its hidden-test regions (an unclosed one runs to the end), and
    whether it had any."""
    kept, inside, found = [], False, False
    for line in source.split("\n"):
        if begin in line:
            inside = found = True
        elif end in line and inside:
            inside = False
        elif not inside:
            kept.append(line)
    return "\n".join(kept), found


class HideHiddenTests(Preprocessor):
    """Cut every hidden-test region out of a notebook's cells, and replace the outputs of the
    cells that held one with a one-line note: a failing hidden assert prints its own source
    lines in the traceback, and a passing one may print what it checked. cobotlab's comments
    keep the score and the failed checks; their flags and cross-check lines are cut (the
    instructor reads those in formgrader, before anyone confronts a student with them).

    Unlike nbgrader's ClearHiddenTests it never raises on a notebook a student edited (a
    stray or unclosed marker), so one submission cannot stop the class's feedback.
    """

    # nbconvert registers a preprocessor named in a list disabled unless it says otherwise
    enabled = Bool(True, help="run this preprocessor").tag(config=True)
    begin_test_delimeter = Unicode(BEGIN, help="start of a hidden-test region").tag(config=True)
    end_test_delimeter = Unicode(END, help="end of a hidden-test region").tag(config=True)
    note = Unicode("(Output of the hidden tests removed: your cobotlab feedback page lists "
                   "what they found.)", help="what replaces the outputs").tag(config=True)

    instructor_only = List(Unicode(), ["Flags", "nbgrader's own"],
                           help="lines of cobotlab's cell comments that start so are for the "
                                "instructor (tamper flags, the cross-check): cut from feedback"
                           ).tag(config=True)

    def preprocess_cell(self, cell, resources, index):
        meta = nbgrader_metadata(cell)
        comment = meta.get("comment")
        if isinstance(comment, str) and comment.startswith("cobotlab:"):
            meta["comment"] = "\n".join(
                line for line in comment.split("\n")
                if not line.startswith(tuple(self.instructor_only)))
        source = cell.get("source", "")
        if isinstance(source, list):
            source = "".join(source)
        stripped, found = strip_hidden(source, self.begin_test_delimeter,
                                       self.end_test_delimeter)
        if found:
            cell.source = stripped
            if cell.get("cell_type") == "code":
                cell.outputs = [new_output("stream", name="stdout", text=self.note + "\n")]
        return cell, resources


class AddCobotlabFeedback(Preprocessor):
    """Put cobotlab's feedback of the submission (what ``cobotlab grade`` wrote to
    ``feedback_cobotlab/<student>/<assignment>/``, :func:`autograder.feedback_release.
    write_section`) at the top of its nbgrader feedback page, as the output of a cell without
    source. A submission cobotlab has not graded, or whose autograded notebook is of another
    submission than the one cobotlab graded (their timestamps differ: a newer one collected
    and autograded by nbgrader alone), keeps nbgrader's page alone, with a warning in
    nbgrader's log: a report on another submission would be a wrong answer."""

    enabled = Bool(True, help="run this preprocessor").tag(config=True)
    max_bytes = 4 * 2**20   # a section is tens of kilobytes

    def preprocess(self, nb, resources):
        from nbgrader.coursedir import CourseDirectory

        info = resources.get("nbgrader", {})
        student, assignment = info.get("student"), info.get("assignment")
        if not student or not assignment:
            return nb, resources
        coursedir = CourseDirectory(config=self.config)
        root = Path(coursedir.root)
        relative = feedback_release.section_path(student, assignment)
        path = root / relative
        try:   # no link followed: nbgrader's kernel ran student code in this course's folders
            data = safe_files.read_file(root, relative, self.max_bytes)
        except safe_files.Refused as refused:
            self.log.warning("no cobotlab feedback for %s's %s (%s: %s): run `cobotlab grade` "
                             "first; their page has nbgrader's part only", student, assignment,
                             path, refused.why.value)
            return nb, resources
        try:
            section = json.loads(data.decode("utf-8"))
            html, graded = str(section["html"]), str(section.get("timestamp") or "")
        except (ValueError, KeyError, TypeError):
            self.log.warning("%s is not cobotlab's feedback section: run `cobotlab grade` again",
                             path)
            return nb, resources
        stamp = os.path.relpath(Path(coursedir.format_path(
            coursedir.autograded_directory, student, assignment)) / "timestamp.txt", root)
        try:
            autograded = safe_files.read_file(root, stamp, 4096).decode(
                "utf-8", "replace").strip()
        except safe_files.Refused:
            autograded = ""
        if autograded != graded:
            self.log.warning("cobotlab graded %s's submission of %s, the autograded notebook is "
                             "of %s: run `cobotlab grade` again; their page has nbgrader's part "
                             "only", student, graded or "an unknown time",
                             autograded or "an unknown time")
            return nb, resources
        cell = new_code_cell(source="", metadata={"transient": {"remove_source": True}},
                             outputs=[new_output("display_data", data={"text/html": html})])
        nb.cells.insert(0, cell)
        return nb, resources

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
from traitlets import Bool, Unicode

from autograder import feedback_release, safe_files
from autograder.nbgrader_cells import cell_role, nbgrader_metadata

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


_SECTION_BYTES = 4 * 2**20   # a section is tens of kilobytes


def read_section(config, resources, log) -> dict | None:
    """cobotlab's feedback section of the submission nbgrader is rendering (the JSON
    :func:`autograder.feedback_release.write_section` wrote), or None when there is none or
    it is not one (a warning in ``log``, when given)."""
    from nbgrader.coursedir import CourseDirectory

    info = resources.get("nbgrader", {})
    student, assignment = info.get("student"), info.get("assignment")
    if not student or not assignment:
        return None
    root = Path(CourseDirectory(config=config).root)
    relative = feedback_release.section_path(student, assignment)
    try:   # no link followed: nbgrader's kernel ran student code in this course's folders
        data = safe_files.read_file(root, relative, _SECTION_BYTES)
    except safe_files.Refused as refused:
        if log is not None:
            log.warning("no cobotlab feedback for %s's %s (%s: %s): run `cobotlab grade` "
                        "first; their page has nbgrader's part only", student, assignment,
                        root / relative, refused.why.value)
        return None
    try:
        section = json.loads(data.decode("utf-8"))
    except ValueError:
        section = None
    if not isinstance(section, dict) or "html" not in section:
        if log is not None:
            log.warning("%s is not cobotlab's feedback section: run `cobotlab grade` again",
                        root / relative)
        return None
    return section


def _comment_map(section: dict | None) -> dict[str, tuple[str, str]] | None:
    """{grade id: (digest, student lines)} of a section's ``comments`` (well-formed entries
    only), or None without a section or when it has none (an older cobotlab's section)."""
    comments = section.get("comments") if section is not None else None
    if not isinstance(comments, dict):
        return None
    return {gid: (entry["digest"], entry["student"]) for gid, entry in comments.items()
            if isinstance(entry, dict) and isinstance(entry.get("digest"), str)
            and isinstance(entry.get("student"), str)}


class HideHiddenTests(Preprocessor):
    """Cut every hidden-test region out of a notebook's cells, and replace the outputs of the
    cells that held one with a one-line note: a failing hidden assert prints its own source
    lines in the traceback, and a passing one may print what it checked. cobotlab's comments
    keep the score and the failed checks; their flags and cross-check lines are cut (the
    instructor reads those in formgrader, before anyone confronts a student with them).

    Which lines a comment keeps is read from cobotlab's section of the submission
    (``comments``: the digest of each comment cobotlab wrote and its student lines), never
    from the comment's words: a comment whose digest matches is shown as its student lines,
    any other (an instructor's, nbgrader's) as it is. Without such a section, the comments
    of the autograded answers (the cells cobotlab writes them to) are withheld.

    Unlike nbgrader's ClearHiddenTests it never raises on a notebook a student edited (a
    stray or unclosed marker), so one submission cannot stop the class's feedback.
    """

    # nbconvert registers a preprocessor named in a list disabled unless it says otherwise
    enabled = Bool(True, help="run this preprocessor").tag(config=True)
    begin_test_delimeter = Unicode(BEGIN, help="start of a hidden-test region").tag(config=True)
    end_test_delimeter = Unicode(END, help="end of a hidden-test region").tag(config=True)
    note = Unicode("(Output of the hidden tests removed: your cobotlab feedback page lists "
                   "what they found.)", help="what replaces the outputs").tag(config=True)

    def preprocess(self, nb, resources):
        self._comments = _comment_map(read_section(self.config, resources, None))
        if self._comments is None:
            self.log.warning("no cobotlab feedback section of this submission says which lines "
                             "of its comments are the student's: the comments of its "
                             "autograded answers are withheld (run `cobotlab grade` first)")
        return super().preprocess(nb, resources)

    def _shown(self, cell, comment: str) -> str:
        """What the student's feedback shows of ``comment``, the cell's comment."""
        comments = getattr(self, "_comments", None)
        if comments is None:
            role = cell_role(cell)
            return "" if role.solution and not role.grade else comment
        mine = comments.get(cell_role(cell).grade_id)
        if mine is not None and mine[0] == feedback_release.comment_digest(comment):
            return mine[1]
        return comment

    def preprocess_cell(self, cell, resources, index):
        meta = nbgrader_metadata(cell)
        comment = meta.get("comment")
        if isinstance(comment, str):
            meta["comment"] = self._shown(cell, comment)
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

    def preprocess(self, nb, resources):
        from nbgrader.coursedir import CourseDirectory

        section = read_section(self.config, resources, self.log)
        if section is None:
            return nb, resources
        html, graded = str(section["html"]), str(section.get("timestamp") or "")
        info = resources["nbgrader"]
        student, assignment = info["student"], info["assignment"]
        coursedir = CourseDirectory(config=self.config)
        root = Path(coursedir.root)
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

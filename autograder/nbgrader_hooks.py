"""Preprocessors that the course's ``nbgrader_config.py`` plugs into nbgrader's own commands.

:class:`HideHiddenTests` keeps the hidden tests out of the feedback nbgrader makes
(``nbgrader generate_feedback``, formgrader's "Generate Feedback" / "Release Feedback"): it
reads the autograded notebooks, whose test cells nbgrader restored from the source with
their hidden tests in them. nbgrader imports this module by name, so it stays light (no
grader, no numpy) and runs wherever nbgrader runs from the course's virtual environment.
"""

from __future__ import annotations

from nbconvert.preprocessors import Preprocessor
from nbformat.v4 import new_output
from traitlets import Bool, List, Unicode

__all__ = ["HideHiddenTests"]

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
        meta = cell.get("metadata", {}).get("nbgrader", {})
        comment = meta.get("comment") if isinstance(meta, dict) else None
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

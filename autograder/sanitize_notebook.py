"""The nbconvert preprocessor that makes a submission inert before nbgrader renders it as HTML.

Formgrader (its submission pages) and nbgrader's feedback (``generate_feedback``, formgrader's
"Generate Feedback") turn the autograded notebook into HTML with nbconvert's
``HTMLExporter``. Their templates render markdown cells without sanitising (formgrader's
own ``formgrade`` and ``feedback`` templates replace the block that honours
``HTMLExporter.sanitize_html``, which is why that setting stops nothing there), and write
nbgrader's cell metadata and the student's names into the page unescaped. So the notebook is
made inert before any template sees it, whatever the template:

- markdown and raw cells, ``text/html`` and ``text/markdown`` outputs: rendered and
  sanitised by :mod:`autograder.sanitize_html` (text, formulas, tables, embedded images kept);
- ``image/svg+xml`` outputs: shown as an ``<img>`` (an SVG there runs no script);
- ``image/png``/``image/jpeg`` outputs (plots) and ``text/plain``/``text/latex`` kept, the
  templates escape them; every other MIME type (``application/javascript``, widget views,
  anything unknown) dropped, with a line of text saying so;
- output metadata: only an image's numeric width and height; notebook metadata: only the
  kernel and language (no widget state, which the templates would hand to a widget script);
- nbgrader's grade id, comment and the student's names and ids the page shows: escaped.

Registered by the course's ``nbgrader_config.py`` (:func:`autograder.course.init_course`):
``c.HTMLExporter.preprocessors`` reaches every HTMLExporter nbgrader makes (formgrader's,
generate_feedback's), and ``c.GenerateFeedback.preprocessors`` runs it again after
``GetGrades`` has put the comments in. Running twice changes nothing a browser shows.
"""

from __future__ import annotations

import base64
import binascii
import html
import numbers

from nbconvert.preprocessors import Preprocessor
from nbformat import NotebookNode
from traitlets import Bool

from autograder.nbgrader_cells import nbgrader_metadata
from autograder.sanitize_html import image_html, inert_html, inert_markdown

__all__ = ["InertSubmission"]

# Kept as they are: the templates escape text, and draw PNG/JPEG data as an <img>.
_SAFE_AS_IS = ("text/plain", "text/latex")
_RASTER = ("image/png", "image/jpeg")
# What formgrader's submission page writes of ``resources`` into its HTML unescaped
# (nbgrader's formgrader/handlers.py SubmissionHandler, templates/formgrade).
_PAGE_RESOURCES = ("student", "last_name", "first_name", "notebook_id", "assignment_id",
                   "notebook_path")
_NOTEBOOK_METADATA = ("kernelspec", "language_info")


def _is_base64(data) -> bool:
    try:
        base64.b64decode("".join(str(data).split()), validate=True)
    except (binascii.Error, ValueError):
        return False
    return True


def _inert_bundle(data: dict) -> tuple[dict, list[str]]:
    """A display bundle (MIME type -> data) with only inert representations, and the MIME
    types it left out."""
    kept = {mime: data[mime] for mime in _SAFE_AS_IS if mime in data}
    kept.update({mime: data[mime] for mime in _RASTER if mime in data and _is_base64(data[mime])})
    if "text/html" in data:
        kept["text/html"] = inert_html(data["text/html"])
    elif "text/markdown" in data:
        kept["text/html"] = inert_markdown(data["text/markdown"])
    elif "image/svg+xml" in data and not any(m in kept for m in _RASTER):
        svg = str(data["image/svg+xml"]).encode("utf-8")
        kept["text/html"] = image_html("image/svg+xml", base64.b64encode(svg).decode("ascii"))
    shown = set(kept) | ({"text/markdown", "image/svg+xml"} if "text/html" in kept else set())
    return kept, sorted(set(data) - shown)


def _image_size(metadata) -> dict:
    """Of an output's metadata, each image's width and height when they are numbers."""
    kept = {}
    for mime in _RASTER:
        size = metadata.get(mime) if isinstance(metadata, dict) else None
        if isinstance(size, dict):
            numeric = {k: v for k, v in size.items() if k in ("width", "height")
                       and isinstance(v, numbers.Real) and not isinstance(v, bool)}
            if numeric:
                kept[mime] = numeric
    return kept


def _inert_output(output) -> None:
    if output.get("output_type") not in ("display_data", "execute_result"):
        return   # stream and error outputs are text, which the templates escape
    data, dropped = _inert_bundle(dict(output.get("data", {})))
    if dropped and not data:
        data["text/plain"] = ("[output not shown in the grader's page: "
                              + ", ".join(dropped) + "]")
    output["data"] = data
    output["metadata"] = NotebookNode(_image_size(output.get("metadata", {})))


def _inert_nbgrader_metadata(cell) -> None:
    meta = nbgrader_metadata(cell)   # {} when missing or malformed: nothing to render
    if "grade_id" in meta:
        meta["grade_id"] = html.escape(str(meta["grade_id"]))
    if meta.get("comment"):   # the feedback template renders it as markdown
        meta["comment"] = inert_markdown(meta["comment"])


class InertSubmission(Preprocessor):
    """Make a notebook safe to render as HTML in a grader's browser (see the module's
    docstring for what changes); the student's text, formulas, code and plots stay."""

    enabled = Bool(True, help="run this preprocessor").tag(config=True)

    def preprocess(self, nb, resources):
        nb.metadata = NotebookNode({k: v for k, v in nb.metadata.items()
                                    if k in _NOTEBOOK_METADATA})
        for key in _PAGE_RESOURCES:
            if isinstance(resources.get(key), str):
                resources[key] = html.escape(resources[key])
        return super().preprocess(nb, resources)

    def preprocess_cell(self, cell, resources, index):
        _inert_nbgrader_metadata(cell)
        if cell.cell_type == "markdown":
            cell.source = inert_markdown(cell.source, cell.get("attachments"))
            cell.pop("attachments", None)   # embedded above
        elif cell.cell_type == "raw":
            cell.source = inert_html(cell.source)
        elif cell.cell_type == "code":
            for output in cell.get("outputs", []):
                _inert_output(output)
        return cell, resources

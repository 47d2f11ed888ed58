"""A student's HTML and markdown made inert: what a grader's browser shows of a submission.

Formgrader and nbgrader's feedback pages show a submission inside the grading account's own
web origin, where a script would act with the grader's session (write files through the
server's API, open a terminal). Everything a student wrote that becomes HTML goes through
:func:`inert_html` first: an allow-list of tags and attributes that carries text, headings,
lists, tables, code, links to web pages and embedded images, and nothing that runs (no script,
style, SVG or MathML element, event handler, frame, form, ``javascript:`` or ``data:`` link).
A tag outside the list is shown as text, so the grader sees what the student wrote; an
attribute outside it is dropped. Nothing is recognised by its words: the list decides.

:func:`inert_markdown` renders markdown the way nbconvert's templates do (the same mistune
renderer, LaTeX kept as text for MathJax, ``attachment:`` images embedded) and then makes the
HTML inert. It returns one line wrapped in a ``<div>``, which the templates' own
``markdown2html`` filter passes through unchanged (an HTML block of CommonMark ends only at a
blank line), so a template that renders markdown cells without sanitising still shows only
sanitised HTML.

bleach (nbconvert's own sanitiser, a requirement of nbconvert) does the parsing and
serialising: an HTML5 parser, so the browser reads the same tree.
"""

from __future__ import annotations

import html
import re

import bleach
from nbconvert.filters.markdown_mistune import InvalidNotebook, IPythonRenderer, MarkdownWithMath

__all__ = ["inert_html", "inert_markdown", "image_html", "INERT_CLASS"]

# Elements that only lay out or mark up text: what markdown renders, and what students
# write by hand in markdown cells (<sub>, <br>, <details> for a long derivation).
TAGS = frozenset({
    "a", "abbr", "b", "blockquote", "br", "caption", "code", "col", "colgroup", "dd", "del",
    "details", "div", "dl", "dt", "em", "figcaption", "figure", "h1", "h2", "h3", "h4", "h5",
    "h6", "hr", "i", "img", "ins", "kbd", "li", "mark", "ol", "p", "pre", "q", "s", "samp",
    "small", "span", "strong", "sub", "summary", "sup", "table", "tbody", "td", "tfoot", "th",
    "thead", "tr", "u", "ul", "var",
})
# Links: to web pages and mail only (a relative link stays in the grading server, where a
# GET changes nothing). Images: embedded raster or SVG data only. An SVG drawn by <img> runs
# no script, and no remote image tells a site that the grader opened the page.
_LINK_SCHEMES = ("http", "https", "mailto")
_IMAGE_DATA = re.compile(r"data:image/(png|jpeg|gif|webp|svg\+xml);base64,[A-Za-z0-9+/=\s]*\Z")
_NUMBER = re.compile(r"\d{1,5}\Z")
# Classes style, but formgrader's scripts also find their own elements by class (.score,
# .comment): only the classes nbconvert's renderer gives (highlighted code's short pygments
# token classes, fenced code's language, anchor links) and this module's wrapper.
INERT_CLASS = "cobotlab-inert"
_CLASS = re.compile(r"[a-z][a-z0-9]{0,2}|highlight|hll|anchor-link|language-[\w+#-]{1,30}|"
                    + INERT_CLASS)


def _link(value: str) -> bool:
    scheme = re.match(r"\s*([A-Za-z][A-Za-z0-9+.-]*):", value)
    return scheme is None or scheme.group(1).lower() in _LINK_SCHEMES


def _allowed_attribute(tag: str, name: str, value: str) -> bool:
    """Whether ``tag`` may keep attribute ``name="value"`` (bleach's attribute filter)."""
    if name == "class":
        return all(_CLASS.fullmatch(token) for token in value.split())
    if name in ("title", "alt"):
        return True
    if tag == "a" and name == "href":
        return _link(value)
    if tag == "img" and name == "src":
        return _IMAGE_DATA.match(value) is not None
    if name in ("width", "height", "colspan", "rowspan", "start"):
        return tag in ("img", "td", "th", "ol", "col") and _NUMBER.match(value) is not None
    return name == "open" and tag == "details"


_CLEANER = bleach.Cleaner(tags=TAGS, attributes=_allowed_attribute,
                          protocols=[*_LINK_SCHEMES, "data"], strip=False, strip_comments=True)
_TEXT_ONLY = bleach.Cleaner(tags=set(), strip=True, strip_comments=True)


def _text(html_text: str) -> str:
    return "".join(_TEXT_ONLY.clean(html_text).split())


def _cleaned_whole(fragment: str) -> str | None:
    """``fragment`` through the allow-list, or None when that lost some of its text: the
    HTML5 parser moves what misnested markup holds (text and elements inside an unclosed
    ``<table>``), and bleach drops part of what it moves. Safe either way; the grader must
    still read everything the student wrote."""
    cleaned = _CLEANER.clean(fragment)
    return cleaned if len(_text(cleaned)) >= len(_text(fragment)) else None


def _as_text(text: str) -> str:
    return f"<pre>{html.escape(text)}</pre>"


def inert_html(fragment: str) -> str:
    """``fragment`` (HTML a student controls) with every element and attribute outside the
    allow-list shown as text or dropped: safe to put in a page of the grading server. Markup
    the allow-list cannot pass whole (see :func:`_cleaned_whole`) is shown as its source."""
    fragment = str(fragment)
    cleaned = _cleaned_whole(fragment)
    return cleaned if cleaned is not None else _as_text(fragment)


def _one_block(html: str) -> str:
    """``html`` as one ``<div>`` on one line: a newline of a text node becomes ``&#10;``
    (the same character to the browser, also inside ``<pre>``), so markdown's renderer
    takes the whole as one HTML block and passes it through."""
    return f'<div class="{INERT_CLASS}">' + html.strip().replace("\n", "&#10;") + "</div>"


def inert_markdown(source: str, attachments: dict | None = None) -> str:
    """The HTML of markdown ``source`` (a markdown cell, a ``text/markdown`` output, a
    comment), its ``attachment:`` images embedded from ``attachments`` (a cell's
    ``attachments``), made inert; one ``<div>`` on one line (see the module's docstring)."""
    renderer = IPythonRenderer(escape=False, attachments=attachments or {})
    try:
        cleaned = _cleaned_whole(MarkdownWithMath(renderer=renderer).render(str(source)))
    except InvalidNotebook:   # an ``attachment:`` the cell does not have
        cleaned = None
    # what cannot be shown rendered and whole is shown as the student's source
    return _one_block(cleaned if cleaned is not None else _as_text(str(source)))


def image_html(mime: str, base64_data: str) -> str:
    """An ``<img>`` showing an image output (``mime`` image/..., data in base64), inert."""
    return _one_block(inert_html(f'<img src="data:{mime};base64,{base64_data}">'))

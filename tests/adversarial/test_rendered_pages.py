"""Nothing a student wrote runs in a grader's browser (issue 51, Required 1).

Two hostile submissions of lab 0 are graded with the real ``cobotlab grade``; then nbgrader's
``generate_feedback`` and ``cobotlab report`` make their pages, a real Jupyter server with
nbgrader's formgrader serves the course (token login, as on one machine), and Debian's
Chromium opens each page a grader or student opens:

- formgrader's submission page of each hostile student;
- nbgrader's feedback page, cobotlab's feedback page and the class report, each put at the
  server's own origin (where a script would have the page's ``_xsrf`` cookie: the worst
  place one could be shown, as formgrader's pages are).

Every payload (``attack``) would PUT a file ``PWNED-<where>.txt`` into the course through the
server's contents API with that cookie, and log ``ran:<where>``: the payloads sit in a
markdown cell (raw HTML, SVG, iframe, ``javascript:`` links, an SVG attachment), a raw
cell, cell and notebook metadata (tags, widget state, title), outputs of every MIME type
(HTML, SVG, JavaScript, markdown, a widget view), an exception message, a graded function's
error, the roster's names and a submission folder's name. Nothing may run: no file, no
``ran:`` on the console, no dialog. And the page must still show the student's work: the
markdown text, the formula (as TeX: MathJax comes from a CDN this closed network does not
reach) and the plot.
"""

from __future__ import annotations

import base64
import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import course_kit as kit
import pytest
from test_browser_lab import LabServer, browser  # noqa: F401  (browser: the fixture)

from autograder.page_policy import POLICY_META

pytestmark = pytest.mark.slow
ASSIGNMENT = "lab0_frames"
STUDENT = "mallory"
WORDS = "My derivation of the inverse pose"
FORMULA = r"T^{-1}"
PLOT_TITLE = "my residuals"


attack = kit.page_attack


def _img(where: str) -> str:
    return f'<img src=x onerror="{attack(where)}">'


# A submission folder named as HTML: `cobotlab grade` refuses it (formgrader's page for a
# missing notebook would print it unescaped), and the pages that list it show it as text.
NAME_FOLDER = "<img src=x onerror=console.log('ran:folder')>"

MARKDOWN = f"""## {WORDS}

The inverse of a pose: ${FORMULA} = \\begin{{bmatrix}} R^\\top & -R^\\top t \\\\ 0 & 1
\\end{{bmatrix}}$, checked on the plot below.

{_img('md-img')}
<svg onload="{attack('md-svg')}"><script>{attack('md-svg-script')}</script></svg>
<iframe srcdoc="<script>{attack('md-iframe')}</script>"></iframe>
<details open ontoggle="{attack('md-details')}"><summary>details</summary>d</details>
<a href="javascript:{attack('md-link')}">hostile link</a>
[hostile markdown link](javascript:console.log('ran:md-mdlink'))
<form action="javascript:{attack('md-form')}"><button>hostile button</button></form>

![an attachment](attachment:evil.svg)
"""

# Vectors held out while the sanitiser was written (measured once at the end: none ran; 9
# of them ran unsanitised in the same page): mutation XSS, entity-hidden schemes, plugins,
# <base>, refresh, SVG animation, autofocus, templates, CSS, broken markup.
HELD_OUT = [
    '<math><mtext><table><mglyph><style><img src=x onerror="{}">',
    '<noscript><p title="</noscript><img src=x onerror={}>">',
    '<a href="jav&#x09;ascript:{}">hostile tab link</a>',
    '<a href="&#106;avascript:{}">hostile entity link</a>',
    '<object data="javascript:{}"></object>', '<embed src="javascript:{}">',
    '<base href="javascript:{}//">',
    '<meta http-equiv="refresh" content="0;url=javascript:{}">',
    '<svg><animate onbegin="{}" attributeName=x dur=1s>',
    '<svg><a xlink:href="javascript:{}"><text x=20 y=20>hostile svg link</text></a></svg>',
    '<input autofocus onfocus="{}">', '<video><source onerror="{}"></video>',
    '<style>@import "javascript:{}";</style>', '<iframe src="javascript:{}"></iframe>',
    '<form><button formaction="javascript:{}">hostile formaction</button></form>',
    '<div style="background:url(javascript:{})">bg</div>',
    '<select><template><img src=x onerror="{}"></template></select>',
    '<scr<script>ipt>{}</scr</script>ipt>', '<<img src=x onerror="{}">',
    '<img """><script>{}</script>">', '<marquee onstart="{}">m</marquee>',
    '![md img](x" onerror="{})', '$<img src=x onerror={}>$ in math',
]
HELD_OUT_CELL = "\n\n".join(v.replace("{}", f"console.log('ran:held-{i}')")
                              for i, v in enumerate(HELD_OUT))

SVG = (f'<svg xmlns="http://www.w3.org/2000/svg" width="20" height="20" '
       f'onload="{attack("svg-onload")}"><script>{attack("svg-script")}</script>'
       '<rect width="20" height="20" fill="red"/></svg>')

OUTPUTS = f"""
import base64, io
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
from IPython.display import Image, display
display({{"text/html": {_img('out-html')!r} + "<b>html output</b>"}}, raw=True)
display({{"text/html": {_img('out-isolated')!r}}}, raw=True,
        metadata={{"text/html": {{"isolated": True}}}})
display({{"image/svg+xml": {SVG!r}}}, raw=True)
display({{"application/javascript": {attack('out-js')!r}, "text/plain": "js"}}, raw=True)
display({{"text/markdown": {_img('out-md')!r}}}, raw=True)
display({{"application/vnd.jupyter.widget-view+json": {{"model_id": "m", "version_major": 2,
         "version_minor": 0}}, "text/plain": "a widget"}}, raw=True)
fig, ax = plt.subplots(figsize=(3, 2))
ax.plot([0, 1, 2], [0.0, 0.5, 0.2])
ax.set_title({PLOT_TITLE!r})
buffer = io.BytesIO()
fig.savefig(buffer, format="png")
display(Image(data=buffer.getvalue()))
"""

RAISES = f"raise ValueError({_img('exception')!r})\n"
GRADED = ("def invert_pose(a_T_b):\n"
          f"    raise ValueError({_img('graded-error')!r})\n")


def _hostile_notebook(course: Path, student: str) -> None:
    """Add the hostile cells and metadata to ``student``'s submitted notebook."""
    path = course / "submitted" / student / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    nb = json.loads(path.read_text())
    evil_svg = base64.b64encode(SVG.encode()).decode()
    hostile = [
        {"cell_type": "markdown", "source": MARKDOWN,
         "attachments": {"evil.svg": {"image/svg+xml": evil_svg}},
         # nbformat refuses a tag with a comma (nbgrader would not grade the notebook)
         "metadata": {"tags": ['x" onmouseover="console.log(\'ran:tag\')"']}},
        {"cell_type": "markdown", "source": HELD_OUT_CELL, "metadata": {}},
        {"cell_type": "raw", "source": _img("raw"), "metadata": {"raw_mimetype": "text/html"}},
        {"cell_type": "code", "source": OUTPUTS, "metadata": {}, "outputs": [],
         "execution_count": None},
        {"cell_type": "code", "source": RAISES, "metadata": {}, "outputs": [],
         "execution_count": None},
    ]
    at = next(i for i, c in enumerate(nb["cells"])
              if c["metadata"].get("nbgrader", {}).get("grade_id") == "imports") + 1
    nb["cells"][at:at] = hostile
    nb["metadata"]["title"] = f"</title>{_img('title')}"
    nb["metadata"]["widgets"] = {"application/vnd.jupyter.widget-state+json": {
        "state": {}, "version_major": 2, "version_minor": 0,
        "note": f"</script>{_img('widget-state')}"}}
    path.write_text(json.dumps(nb))


def _run(*command: str, cwd: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k != "COBOTLAB_COURSE"}
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def graded(tmp_path_factory) -> Path:
    """The course with the hostile submissions graded, their feedback and the class report
    made: the commands an instructor runs."""
    course = kit.released_course(tmp_path_factory.mktemp("hostile"), ASSIGNMENT)
    kit.submit(course, ASSIGNMENT, STUDENT, replace={"invert_pose": GRADED})
    _hostile_notebook(course, STUDENT)
    kit.submit(course, ASSIGNMENT, NAME_FOLDER)
    # the roster's names (from an LMS, where students write their own)
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        gb.update_or_create_student(STUDENT, last_name=_img("last-name"),
                                    first_name=_img("first-name"))
    bin_dir = Path(sys.executable).parent
    # nbgrader's own kernel: the autograded notebooks keep every output (plots, HTML, ...)
    _run(str(bin_dir / "cobotlab"), "grade", str(course), ASSIGNMENT, "--nbgrader-kernel",
         cwd=course)
    _run(sys.executable, "-m", "nbgrader", "generate_feedback", ASSIGNMENT, cwd=course)
    _run(str(bin_dir / "cobotlab"), "report", str(course), ASSIGNMENT, cwd=course)
    return course


@pytest.fixture(scope="module")
def server(graded, tmp_path_factory):
    """Jupyter server with nbgrader's formgrader, in the course (its nbgrader_config.py)."""
    pytest.importorskip("jupyterlab", reason="needs JupyterLab (pip install -e '.[dev]')")
    running = LabServer(tmp_path_factory.mktemp("formgrader"), notebooks=graded)
    try:
        running.start()
        yield running
    finally:
        running.stop()


def _submission_ids(course: Path) -> dict[str, str]:
    """{student id: formgrader's id of that student's lab 0 notebook submission}."""
    with sqlite3.connect(course / "gradebook.db") as db:
        rows = db.execute(
            "select submission.student_id, submitted_notebook.id from submitted_notebook "
            "join submitted_assignment submission "
            "on submitted_notebook.assignment_id = submission.id").fetchall()
    return dict(rows)


class Visit:
    """One logged-in page; what its scripts logged and every dialog they opened."""

    def __init__(self, browser, server: LabServer):  # noqa: F811 (the fixture's name)
        self.server = server
        self.context = browser.new_context()
        self.page = self.context.new_page()
        self.signs: list[str] = []
        self.page.on("console", lambda message: self.signs.append(message.text))
        self.page.on("dialog", lambda dialog: (self.signs.append(f"dialog {dialog.message}"),
                                               dialog.dismiss()))
        # token login: the server sets its login and _xsrf cookies, as for a TA
        self.page.goto(f"{server.url}/formgrader?token={server.token}")

    def open(self, path: str) -> None:
        self.page.goto(f"{self.server.url}/{path}")
        self.settle()

    def open_as_served(self, page: Path, at: str) -> None:
        """``page`` shown at ``/<at>`` of the server's origin, with its files beside it."""
        folder = page.parent

        def fulfil(route):
            name = route.request.url.rsplit("/", 1)[-1].split("?")[0]
            target = folder / name
            if target.is_file():
                kind = "text/html" if name.endswith(".html") else "image/png"
                route.fulfill(body=target.read_bytes(), content_type=kind)
            else:
                route.fulfill(status=404, body=b"")

        self.page.route(f"{self.server.url}/{at}/*", fulfil)
        self.open(f"{at}/{page.name}")

    def settle(self) -> None:
        """Let whatever could run run: hover and click every link, button and element."""
        self.page.wait_for_load_state("load")
        for link in self.page.locator("a:has-text('hostile'), button:has-text('hostile')").all():
            link.click(no_wait_after=True, timeout=2000)
        self.page.mouse.move(10, 10)
        for element in self.page.locator(".cell").all()[:40]:
            element.hover(timeout=2000)
        self.page.wait_for_timeout(1500)   # a fetch a payload started would be done by now

    def ran(self) -> list[str]:
        return [s for s in self.signs if "ran:" in s or s.startswith("dialog")]

    def plot_shown(self) -> bool:
        return self.page.evaluate("""() => [...document.querySelectorAll('img')].some(
            i => i.src.startsWith('data:image/png') && i.naturalWidth > 100
                 && i.getBoundingClientRect().width > 100)""")

    def text(self) -> str:
        return self.page.inner_text("body")


@pytest.fixture(scope="module")
def visit(server, browser):  # noqa: F811
    """One logged-in browser context for the module's pages (a context and formgrader's
    token login each cost Chromium a page load for nothing the other test lacked); each
    test starts by asserting that nothing ran on a page opened before it."""
    shared = Visit(browser, server)
    try:
        yield shared
    finally:
        shared.context.close()


def _planted(course: Path) -> list[str]:
    return sorted(p.name for p in course.rglob("PWNED-*"))


def test_formgrader_shows_hostile_submissions_inertly(graded, server, visit):
    ids = _submission_ids(graded)
    assert set(ids) == {STUDENT}, ids   # the folder named as HTML is refused
    grades = kit.read_grades(graded)
    assert grades[NAME_FOLDER]["flags"] == "rejected_student_id", grades
    assert not visit.ran(), visit.ran()   # the login page, or the pages of a test before
    # the control: the same kind of payload, unsanitised at this origin, does write
    control = server.root / "control.html"
    control.write_text(f"<!DOCTYPE html><p>control</p>{_img('control')}")
    visit.open_as_served(control, "shown-control")
    assert visit.ran() == ["ran:control"] and _planted(graded) == ["PWNED-control"]
    (graded / "PWNED-control").unlink()
    visit.signs.clear()

    visit.open(f"formgrader/submissions/{ids[STUDENT]}/")
    text = visit.text()
    shot = server.root / "formgrader-mallory.png"
    visit.page.screenshot(path=str(shot), full_page=True)
    print(f"formgrader's page of the hostile submission: {shot}")
    # the student's work, legible: the markdown, the formula, the plot, the code
    assert WORDS in text and FORMULA in text, text[:3000]
    assert visit.plot_shown(), "the student's plot is not on the page"
    assert "def invert_pose" in text and "hostile link" in text
    # what could not be shown inertly is said, not silently lost
    assert "application/javascript" in text
    names = visit.page.locator("a.name-shown").text_content()   # shown by the eye icon
    assert _img("last-name") in names and _img("first-name") in names, names
    # the refused folder: listed by formgrader (nbgrader's own list), as text
    visit.open(f"formgrader/manage_submissions/{ASSIGNMENT}")
    visit.page.wait_for_selector("td.student-id", timeout=30_000)
    assert NAME_FOLDER in visit.text()
    assert not visit.ran(), visit.ran()
    assert not _planted(graded), _planted(graded)


def test_feedback_pages_and_class_report_are_inert(graded, visit):
    nbgrader_page = graded / "feedback" / STUDENT / ASSIGNMENT / f"{ASSIGNMENT}.html"
    cobotlab_page = graded / "feedback_cobotlab" / STUDENT / ASSIGNMENT / "feedback.html"
    report = graded / "reports" / ASSIGNMENT / "index.html"
    for page in (nbgrader_page, cobotlab_page, report):
        assert page.is_file(), page
    assert not visit.ran(), visit.ran()   # the login page, or the pages of a test before
    visit.open_as_served(nbgrader_page, "shown-nbgrader-feedback")
    text = visit.text()
    assert WORDS in text and FORMULA in text and visit.plot_shown(), text[:3000]
    assert "cobotlab:" in text   # cobotlab's own section, on top, still styled and whole
    visit.open_as_served(cobotlab_page, "shown-cobotlab-feedback")
    assert "invert_pose" in visit.text() and "ValueError" in visit.text()
    visit.open_as_served(report, "shown-report")
    assert "the class at a glance" in visit.text()
    # cobotlab's own pages carry their policy, and it lets their figures load
    assert all(POLICY_META in p.read_text() for p in (cobotlab_page, report))
    assert visit.page.evaluate(
        "() => [...document.images].filter(i => i.naturalWidth > 100).length") == 3
    assert not visit.ran(), visit.ran()
    assert not _planted(graded), _planted(graded)

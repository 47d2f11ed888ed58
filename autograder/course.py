"""The nbgrader course's layout: lay it out, configure nbgrader, run nbgrader's own autograde.

``init_course(DIR)`` makes a directory where the instructor's usual nbgrader commands work
(``nbgrader generate_assignment lab0_frames``, ``nbgrader autograde lab0_frames``, ...): the
config, the labs' sources, the gradebook and the grading secret
(:mod:`autograder.secret`). Grading it is the line of :mod:`autograder.pipeline`
(:func:`autograder.pipeline.pipeline.grade_course`, docs/architecture.md).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

from autograder import checks, freeze, gradebook, registry, scratch
from autograder.feedback_release import (
    HOOK,
    INERT,
)
from autograder.pipeline.record import record_nbgrader
from autograder.practice import releasable, save_practice
from autograder.secret import create_secret

__all__ = ["LABS_DIR", "init_course", "run_nbgrader_autograde"]


LABS_DIR = registry.builtin_folder()

# Formgrader and nbgrader's feedback show a student's notebook in the grading account's own
# browser origin: what it holds must not run there (autograder.sanitize_notebook). Written by
# `cobotlab course init` into a new course, and added to a course laid out before it.
INERT_PAGES_CONFIG = f'''\
# A submission rendered as HTML (formgrader's pages, generate_feedback's) is made inert
# first: every HTMLExporter nbgrader makes reads this. (HTMLExporter.sanitize_html does not
# reach formgrader's own templates.)
c.HTMLExporter.preprocessors = ["{INERT}"]
'''

_CONFIG = '''\
# nbgrader configuration written by cobotlab (autograder.course.init_course).
c = get_config()  # noqa: F821
c.CourseDirectory.course_id = {course_id!r}
c.CourseDirectory.root = {root!r}
# Where release_assignment / fetch_assignment / submit / collect meet (and formgrader looks):
# made by `cobotlab course init`; students' servers must see the same folder at this path.
c.Exchange.root = {exchange!r}
# Each cell gets this long in nbgrader's kernel; the authoritative grade comes from
# `cobotlab grade`, which runs the code again in an isolated, limited worker.
c.Execute.timeout = 30
c.Execute.interrupt_on_timeout = True
c.ClearSolutions.code_stub = {{"python": "# YOUR CODE HERE\\nraise NotImplementedError()"}}
# `cobotlab grade` keeps grades.csv (every assignment, with flags); `nbgrader export`, whose
# default is the same name, writes its own file (`--to` still chooses another).
c.ExportPlugin.to = "nbgrader_grades.csv"
# nbgrader's feedback (generate_feedback, formgrader's buttons) reads the autograded
# notebooks, which hold the hidden tests: they and their outputs are cut out first. Then
# cobotlab's own feedback goes on top of each page, so release_feedback carries it too.
c.GenerateFeedback.preprocessors = [
    "nbgrader.preprocessors.GetGrades",
    "autograder.nbgrader_hooks.HideHiddenTests",
    "autograder.sanitize_notebook.InertSubmission",
    "autograder.nbgrader_hooks.AddCobotlabFeedback",
    "nbconvert.preprocessors.CSSHTMLHeaderPreprocessor",
]
''' + INERT_PAGES_CONFIG


def init_course(course_dir, labs_dir=None, exchange=None, course_id: str = "cobotlab",
                force: bool = False, quiet: bool = False) -> Path:
    """Lay out an nbgrader course in ``course_dir`` with every lab: the built-in ones (or
    those in ``labs_dir``) and those of the folders its ``cobotlab.toml`` names.

    Writes ``nbgrader_config.py`` (``course_id``, the course root, and nbgrader's exchange:
    ``exchange``, default ``course_dir/exchange``, created world-writable as nbgrader
    requires, unless root made it a private exchange with ``cobotlab course exchange``:
    then its modes are kept and the config names its classes, docs/exchange.md), copies
    each ``labs/<name>/`` (notebook and data, no saved outputs) to ``source/<name>/``, creates an empty ``gradebook.db`` (so nbgrader run from the virtual
    environment without activating it never needs ``alembic`` on ``$PATH``), and the
    grading secret in ``.cobotlab/secret`` (mode 0600; not copied into any assignment).
    Existing config, sources, gradebook and secret are kept, so running it again after
    adding a lab is safe; only the course's own labs are copied again into ``source/``
    (their lab folder is where they are edited and verified). Returns the path.

    A lab that does not load, or whose last ``cobotlab labs verify`` failed
    (:func:`autograder.registry.release_problem`; ``force`` lets the latter through), is
    skipped: nothing of it is written, every other lab is laid out, and one line on stderr
    (unless ``quiet``) names it, why, and the fix. A course lab never verified, or edited
    since, is laid out with a warning line.
    """
    root = Path(course_dir).resolve()
    registry.use_course(root)   # its cobotlab.toml names the instructor's own lab folders
    if labs_dir is None and not LABS_DIR.is_dir() and not registry.source_folders():
        raise ValueError(f"labs directory {LABS_DIR} not found: the lab sources come with the "
                         "instructor's package (pip install cobotlab, not cobotlab-student); "
                         "or pass labs_dir=")
    sources = registry.source_folders(labs_dir)
    # Every lab's spec is loaded and its practice problems drawn before anything is written:
    # a broken lab (an instructor's draft, say) is left out whole, with its file named, and
    # never stops the others. The draws are cached per spec version (autograder.practice):
    # the generators' closed loops and depth images take seconds, and a process laying out
    # several courses pays once.
    documents, skipped = releasable([n for n in sources if n in checks.SPECS], force)
    sources = {name: folder for name, folder in sources.items() if name not in skipped}
    root.mkdir(parents=True, exist_ok=True)
    _write_config(root, exchange, course_id)
    if not (root / "gradebook.db").exists():
        scratch.speed_up_new_gradebooks()   # and no `alembic` needed on $PATH
        gradebook.create(root, course_id)
    own = {name for name, lab in registry.all_labs().items() if not lab.builtin}
    for name, folder in sources.items():
        target = root / "source" / name
        if not target.exists():
            shutil.copytree(folder, target, ignore=shutil.ignore_patterns(
                ".ipynb_checkpoints", "__pycache__"))
        elif name in own:
            # The course's own lab is edited in its lab folder, and `labs verify` proved that
            # folder fair: nbgrader must release the same notebook, not an older copy.
            _sync_folder(folder, target)
        if name in documents:
            # The practice problems, as data, beside the notebook: nbgrader copies them into
            # the release (the students' check()) and the hidden tests score on them in
            # nbgrader's kernel, which sees no generator. Written again on every init, so a
            # changed spec reaches the next release.
            save_practice(documents[name], target)
    create_secret(root)
    if not quiet:
        for name, why in skipped.items():
            kept = (f" (source/{name}/ keeps what an earlier `course init` wrote)"
                    if (root / "source" / name).exists() else "")
            print(f"cobotlab: skipped lab {name}{kept}: {why}", file=sys.stderr)
        for name in sorted(set(sources) & own):
            note = registry.verification_note(name)
            if note:
                print(f"cobotlab: warning: {note}", file=sys.stderr)
    return root


def _write_config(root: Path, exchange, course_id: str) -> None:
    """The course's nbgrader_config.py, with its exchange folder (see :func:`init_course`);
    one already there is kept, with the inert-pages block added if it lacks it."""
    config = root / "nbgrader_config.py"
    if config.exists():
        _add_inert_pages(config)
        return
    exchange_dir = Path(exchange).expanduser().resolve() if exchange else root / "exchange"
    exchange_dir.mkdir(parents=True, exist_ok=True)
    text = _CONFIG.format(root=str(root), exchange=str(exchange_dir), course_id=course_id)
    from autograder import exchange as private

    if private.layout_problem(exchange_dir, course_id) is None:
        # root laid out a private exchange here (`cobotlab course exchange`): keep its
        # modes, and release and collect with its classes
        text += private.config_block(exchange_dir, course_id)
    else:
        os.chmod(exchange_dir, 0o777)   # nbgrader's own requirement (it resets others)
    config.write_text(text)


def _add_inert_pages(config: Path) -> None:
    """Bring a course's ``nbgrader_config.py`` written before issue 51 up to date: append
    the lines that make formgrader's and the feedback's pages inert, and put the same step
    into its feedback preprocessors (after ``GetGrades``, which brings the comments in)."""
    text = config.read_text()
    if INERT in text:
        return
    hook = f'    "{HOOK}",\n'
    if hook in text:
        text = text.replace(hook, f'    "{INERT}",\n' + hook, 1)
    config.write_text(text + "\n" + INERT_PAGES_CONFIG)


def _sync_folder(folder: Path, target: Path) -> None:
    """Copy every file of ``folder`` whose content differs into ``target`` (files only in
    ``target``, such as practice data, are left)."""
    for path in folder.rglob("*"):
        relative = path.relative_to(folder)
        if not path.is_file() or {".ipynb_checkpoints", "__pycache__"} & set(relative.parts):
            continue
        dest = target / relative
        if not dest.is_file() or dest.read_bytes() != path.read_bytes():
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, dest)


def run_nbgrader_autograde(course_dir, assignment: str, student_id,
                           timeout_s: float = 1800, memory_mb: int = 3072,
                           cell_timeout_s: int | None = None) -> str:
    """nbgrader's autograde of one student (or a list of them), the safe way, into the
    gradebook.

    The same three stages as :func:`grade_course` for nbgrader alone: freeze the
    submissions, run ``nbgrader autograde`` in a throwaway sandboxed course per student
    (:mod:`autograder.scratch`), record the validated cell scores into ``gradebook.db``.
    Returns nbgrader's output.
    """
    root = Path(course_dir).resolve()
    wanted = [student_id] if isinstance(student_id, str) else list(student_id)
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    logs = []
    with tempfile.TemporaryDirectory(prefix="cobotlab-frozen-") as store:
        (Path(store) / "submissions").mkdir()
        frozen = {f.student_id: f for f in freeze.freeze_submissions(
            root / "submitted", assignment, expected, Path(store) / "submissions")
            if f.accepted}
        missing = [s for s in wanted if s not in frozen]
        if missing:
            raise ValueError(f"no usable submission of {assignment!r} by {missing}")
        template = scratch.make_template(root, assignment, Path(store),
                                         gradebook.duedate(root, assignment))
        known = gradebook.template_cells(template, assignment)
        for sid in wanted:
            result = scratch.autograde_one(frozen[sid], assignment, root, template, known,
                                           timeout_s=timeout_s, cell_timeout_s=cell_timeout_s,
                                           memory_mb=memory_mb)
            record_nbgrader(root, assignment, frozen[sid], result)
            logs.append(f"--- {sid}\n{result.log}")
    return "\n".join(logs)


# --------------------------------------------------------------------------- nbgrader's view


# --------------------------------------------------------------------------- grading


# ----------------------------------------------------------------- stage 1: begin


# ----------------------------------------------------------------- stage 2: freeze


# ----------------------------------------------------------------- stage 3: draw


# ----------------------------------------------------------------- stage 4: execute


# ----------------------------------------------------------------- stage 4': kept executions


# ----------------------------------------------------------------- stage 5: score


# ----------------------------------------------------------------- stage 6: record


# ----------------------------------------------------------------- cobotlab's score in nbgrader



"""Freeze submissions: copy what students handed in into grader-private storage, as data.

Nothing in ``submitted/`` is followed or trusted: it is read through
:mod:`autograder.safe_files`, component by component, so only folders and regular files
are copied (a symlink to ``source/`` or to a classmate's folder, at any depth, a FIFO named
like the notebook, a socket or a device is skipped with a note), sizes and counts are
capped, and a notebook that is not JSON (or has too many cells) is dropped and scored zero
with a note. Everything after this stage reads only the frozen copy, before any student
code has run. Student ids with control characters or path separators are refused; their
rows are keyed by :func:`student_key`, an escape no other folder name shares.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import stat
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

from autograder import safe_files
from autograder.safe_files import Why

__all__ = ["Caps", "Frozen", "EXCHANGE_FILES", "freeze_submissions", "student_id_problem",
           "student_key", "exchange_file_problem", "printable"]


@dataclass(frozen=True)
class Caps:
    """What one submission may hold."""

    file_mb: float = 20.0           # any one file (a lab notebook is under 1 MB)
    total_mb: float = 50.0          # the whole folder
    files: int = 200
    depth: int = 4
    cells: int = 2000               # a lab notebook has under 100


@dataclass
class Frozen:
    """One submission, frozen. ``student_id`` is the folder name's :func:`student_key`
    (the name itself when accepted); ``accepted`` is False for a refused id (the row then
    says why and nothing is graded or recorded)."""

    student_id: str
    folder: Path | None = None
    notebooks: list[Path] = field(default_factory=list)
    timestamp: str = ""
    notes: list[str] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    accepted: bool = True
    # nbgrader's exchange files of the submission, as frozen and checked (:data:`EXCHANGE_FILES`)
    exchange: dict[str, bytes] = field(default_factory=dict)


# What `nbgrader submit` writes beside the notebooks. `nbgrader release_feedback` reads both
# from each student's feedback folder (which `generate_feedback` fills from autograded/) to
# name the released page after the submission's secret, so that only that submission's
# author finds it; plain `nbgrader autograde` copies them into autograded/.
EXCHANGE_FILES = ("timestamp.txt", "submission_secret.txt")


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def _hidden(ch: str) -> bool:
    """A character a terminal, log or spreadsheet would act on or not show: controls,
    invisible format characters, line and paragraph separators, and the lone surrogates
    Python reads a file name's non-UTF-8 bytes as (they cannot even be written as UTF-8)."""
    return bool(_CONTROL.match(ch)) or unicodedata.category(ch) in ("Cf", "Zl", "Zp", "Cs")


def printable(text, limit: int = 400) -> str:
    """``text`` with control and invisible format characters escaped (``\\n``, ``\\x1b``,
    ``\\u202e``), cut to ``limit`` characters: safe in a log, a summary or a CSV cell."""
    text = "".join(ch.encode("unicode_escape").decode("ascii") if _hidden(ch) else ch
                   for ch in str(text))
    return text if len(text) <= limit else text[:limit] + "..."


def student_key(name: str) -> str:
    """The student id of the folder ``submitted/<name>`` in grades.csv rows, the summary and
    the run log: ``name`` itself when it is accepted (:func:`student_id_problem`), so
    existing gradebooks keep their rows; else ``name`` escaped as Python's
    ``unicode_escape`` codec would escape it, for a backslash, a hidden character
    (``\\n``, ``\\x1b``, ``\\u202e``, ``\\udcff`` for a byte that is not UTF-8) and a
    leading ``- = + @`` (``\\x3d``), all of it, never cut.

    So no two folders share a key: every backslash in a refused name's key starts an escape
    (``key.encode("ascii", "backslashreplace").decode("unicode_escape")`` gives the name
    back), and no accepted id equals a refused one's key, because an accepted id has no
    backslash, no surrounding blank, at most 128 characters, no leading ``- = + @`` and no
    ``< > & "``, while each refused key has one of these. A spreadsheet shows the key as written: no
    cell of it starts a formula, so :func:`autograder.record.csv_cell` leaves it alone.
    (Percent-encoding is reversible too, but an accepted id may hold ``%``, so a refused
    name's encoding could be an accepted id; no accepted id holds a backslash.)
    """
    if student_id_problem(name) is None:
        return name
    key = "".join(ch.encode("unicode_escape").decode("ascii") if ch == "\\" or _hidden(ch)
                  else ch for ch in name)
    return f"\\x{ord(key[0]):02x}{key[1:]}" if key[:1] in ("-", "=", "+", "@") else key


def _name_problem(name: str) -> str | None:
    """Why ``name`` (a folder or file name of a submission) cannot be used, or None."""
    if not name or name in (".", ".."):
        return "empty or a dot name"
    if len(name) > 128:
        return "longer than 128 characters"
    if "/" in name or "\\" in name or os.sep in name:
        return "contains a path separator"
    if printable(name, 10**6) != name or name != name.strip():
        return "contains control characters or surrounding blanks"
    if name.startswith(("-", "=", "+", "@")):
        return "starts with - = + or @ (an option or a spreadsheet formula)"
    return None


def student_id_problem(student_id: str) -> str | None:
    """Why ``student_id`` (a folder name in submitted/) cannot be used, or None."""
    if set(student_id) & set('<>&"'):
        # formgrader writes the id of a submission into some of its pages unescaped (its
        # page for a missing notebook): HTML in it would run in the grader's browser
        return 'contains < > & or " (HTML, which formgrader would show unescaped)'
    return _name_problem(student_id)


def _copy_submission(src: safe_files.Folder, dst: Path, caps: Caps, frozen: Frozen) -> None:
    """Copy one assignment folder into the store as data, each skip noted (and flagged where
    it may be an attack or a lost file)."""
    skipped = safe_files.copy_tree(
        src, dst, safe_files.TreeCaps(int(caps.file_mb * 2**20), int(caps.total_mb * 2**20),
                                      caps.files, caps.depth),
        ignore={".ipynb_checkpoints", "__pycache__"},
        bad_name=lambda name: _name_problem(name) is not None)
    for skip in skipped:
        name = printable(skip.name)
        if skip.why is Why.TOO_DEEP:
            frozen.notes.append(f"{name}/: skipped ({skip.detail})")
        elif skip.why in (Why.BAD_NAME, Why.TOO_MANY):
            frozen.notes.append(f"{name}: skipped ({skip.detail})")
        elif skip.why in (Why.LINK, Why.NOT_REGULAR, Why.NOT_A_FOLDER):
            frozen.notes.append(f"{name}: skipped ({skip.kind}, not a regular file)")
            frozen.flags.append(f"not_a_regular_file:{name}")
        else:   # too big, unreadable, gone while copied
            frozen.notes.append(f"{name}: skipped ({skip.detail})")
            frozen.flags.append(f"file_refused:{name}")


def _check_notebook(path: Path, caps: Caps, frozen: Frozen) -> bool:
    """True when ``path`` (frozen) is a JSON notebook within the cell cap; else it is
    removed from the frozen copy (nbgrader then scores it as missing) with a note."""
    problem = None
    try:
        nb = json.loads(path.read_bytes().decode("utf-8"))
        cells = nb.get("cells") if isinstance(nb, dict) else None
        if not isinstance(cells, list):
            problem = "no list of cells"
        elif len(cells) > caps.cells:
            problem = f"{len(cells)} cells, over the {caps.cells} cap"
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        problem = f"not JSON ({type(exc).__name__})"
    if problem is None:
        return True
    frozen.notes.append(f"{printable(path.name)}: not graded, {problem}; scored 0")
    frozen.flags.append(f"unreadable_notebook:{printable(path.name)}")
    path.unlink()
    return False


def exchange_file_problem(name: str, data: bytes) -> str | None:
    """Why ``data`` is not what nbgrader's exchange writes as ``name`` (one of
    :data:`EXCHANGE_FILES`), or None. A student can write anything in them."""
    if name == "timestamp.txt":
        text = data.decode("utf-8", "replace").strip()
        return None if 0 < len(text) <= 64 and printable(text) == text else \
            "not a timestamp (one line, at most 64 characters)"
    # nbgrader's is 128 hex digits; it hashes the file's text exactly as read
    if 0 < len(data) <= 1024 and all(0x21 <= byte <= 0x7e for byte in data):
        return None
    return "not a secret as nbgrader writes it (printable ASCII without blanks)"


def _exchange_files(frozen: Frozen) -> dict[str, bytes]:
    """The frozen copy's :data:`EXCHANGE_FILES` that are usable (a note for each one that
    is not: that submission's feedback cannot be released through the exchange)."""
    out = {}
    for name in EXCHANGE_FILES:
        try:
            data = safe_files.read_file(frozen.folder, name, 4096)
        except safe_files.Refused as refused:
            if refused.why is not Why.MISSING:
                frozen.notes.append(f"{name}: {refused.why.value}; this submission's feedback "
                                    "cannot be released through nbgrader's exchange")
            continue
        problem = exchange_file_problem(name, data)
        if problem is None:
            out[name] = data
        else:
            frozen.notes.append(f"{name}: {problem}; this submission's feedback cannot be "
                                "released through nbgrader's exchange")
    return out


def freeze_submissions(submitted: Path, assignment: str, expected: set[str], store: Path,
                       caps: Caps = Caps()) -> list[Frozen]:
    """Freeze ``submitted/*/<assignment>/`` into ``store/<student>/``, one entry per student.

    ``expected`` names the assignment's notebooks (``lab0_frames.ipynb``): found ones are
    listed last in ``Frozen.notebooks`` so their definitions win over a renamed copy's.
    ``store`` must be a new, grader-private directory. A student entry that is a link gets
    an entry (flagged, nothing graded) whatever it points at: it is not followed even to
    see whether it holds this assignment.
    """
    try:
        top = safe_files.open_folder(submitted)
    except safe_files.Refused as exc:
        raise ValueError(f"{submitted} is {exc.detail}: it must be the folder of submissions")
    out = []
    with top:
        for entry in top.entries():
            frozen = _freeze_one(top, entry, assignment, expected, store, caps)
            if frozen is not None:
                out.append(frozen)
    return out


def _freeze_one(top: safe_files.Folder, entry: safe_files.Entry, assignment: str,
                expected: set[str], store: Path, caps: Caps) -> Frozen | None:
    """The frozen submission of the student entry ``entry`` of submitted/, or None when it
    holds no ``assignment`` (or is a stray file, not a student's folder)."""
    with contextlib.ExitStack() as stack:
        student, problem = None, None
        try:
            if entry.kind == "folder":
                student = stack.enter_context(top.folder(entry.name))
                info = student.lstat(assignment)
                if info is None:
                    return None   # this student did not hand in this assignment
                if not stat.S_ISDIR(info.st_mode):
                    problem = _not_a_folder("assignment folder", safe_files.kind_of(info.st_mode))
            elif entry.kind == "symlink":
                problem = _not_a_folder("student folder", "symlink")
            else:
                return None   # a stray file beside the students' folders
        except safe_files.Refused as exc:   # swapped since the listing, or unreadable
            problem = _unusable("student folder", exc)
        sid = entry.name
        frozen = Frozen(student_key(sid))
        if why := student_id_problem(sid):
            frozen.accepted = False
            frozen.flags.append("rejected_student_id")
            frozen.notes.append(f"student id refused: {why}; rename the folder in submitted/")
            return frozen
        if problem is None:
            try:
                work = stack.enter_context(student.folder(assignment))
            except safe_files.Refused as exc:
                problem = _unusable("assignment folder", exc)
        if problem is not None:
            frozen.notes.append(problem[0])
            frozen.flags.append(problem[1])
        else:
            frozen.folder = store / sid
            frozen.folder.mkdir(mode=0o755)
            _copy_submission(work, frozen.folder, caps, frozen)
            found = sorted(p for p in frozen.folder.rglob("*.ipynb") if p.is_file()
                           and _check_notebook(p, caps, frozen))
            frozen.notebooks = ([p for p in found if p.name not in expected]
                                + [p for p in found if p.name in expected])
            frozen.timestamp = _timestamp(frozen.folder)
            frozen.exchange = _exchange_files(frozen)
    if not frozen.notebooks:
        frozen.notes.append("no notebook to grade")
    return frozen


def _not_a_folder(what: str, kind: str) -> tuple[str, str]:
    """(note, flag) for a student or assignment folder that is a ``kind`` instead."""
    return (f"the {what} is a {kind}, not a folder: nothing graded",
            f"not_a_folder:{kind.replace(' ', '_')}")


def _unusable(what: str, refused: safe_files.Refused) -> tuple[str, str]:
    """(note, flag) for a student or assignment folder that could not be opened."""
    if refused.kind:
        return _not_a_folder(what, refused.kind)
    return (f"the {what} cannot be read ({refused.detail}): nothing graded; make it readable "
            "by the grader", "unreadable_folder")


def _timestamp(folder: Path) -> str:
    """The submission's timestamp.txt (as nbgrader's collect writes it), or "" if unusable."""
    try:
        text = safe_files.read_file(folder, "timestamp.txt", 4096).decode(
            "utf-8", "replace").strip()
    except safe_files.Refused:
        return ""
    return text if len(text) <= 64 and printable(text) == text else ""


def freeze_course(root: Path, assignment: str, store: Path, caps: Caps,
                  students=None) -> list[Frozen]:
    submitted = root / "submitted"
    expected = {p.name for p in (root / "source" / assignment).glob("*.ipynb")}
    (store / "submissions").mkdir(mode=0o700)
    frozen = (freeze_submissions(submitted, assignment, expected, store / "submissions",
                                 caps) if os.path.lexists(submitted) else [])
    if not frozen:
        raise ValueError(f"no submissions for {assignment!r} in {submitted}; collect them "
                         "first (nbgrader collect / zip_collect) or check the assignment name")
    if students is not None:
        wanted = list(dict.fromkeys(students))
        missing = sorted(set(wanted) - {f.student_id for f in frozen})
        if missing:
            raise ValueError(f"no submission of {assignment!r} by {', '.join(missing)} in "
                             f"{submitted}; check the --students list")
        frozen = [f for f in frozen if f.student_id in set(wanted)]
    return frozen

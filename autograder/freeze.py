"""Freeze submissions: copy what students handed in into grader-private storage, as data.

Nothing in ``submitted/`` is followed or trusted: each entry is looked at with ``lstat``,
only regular files are copied (a symlink to ``source/`` or to a classmate's folder, a FIFO
named like the notebook, a socket or a device is skipped with a note), every file is opened
``O_NOFOLLOW | O_NONBLOCK`` and checked again on the open descriptor, sizes and counts are
capped, and a notebook that is not JSON (or has too many cells) is dropped and scored zero
with a note. Everything after this stage reads only the frozen copy, before any student
code has run. Student ids with control characters or path separators are refused.
"""

from __future__ import annotations

import json
import os
import re
import stat
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Caps", "Frozen", "EXCHANGE_FILES", "freeze_submissions", "student_id_problem",
           "exchange_file_problem", "printable"]


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
    """One submission, frozen. ``student_id`` is printable; ``accepted`` is False for a
    refused id (the row then says why and nothing is graded or recorded)."""

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


def printable(text, limit: int = 400) -> str:
    """``text`` with control and invisible format characters escaped (``\\n``, ``\\x1b``,
    ``\\u202e``), cut to ``limit`` characters: safe in a log, a summary or a CSV cell."""
    out = []
    for ch in str(text):
        if ch in "\t\n\r" or _CONTROL.match(ch) or unicodedata.category(ch) in ("Cf", "Zl", "Zp"):
            out.append(ch.encode("unicode_escape").decode("ascii"))
        else:
            out.append(ch)
    text = "".join(out)
    return text if len(text) <= limit else text[:limit] + "..."


def student_id_problem(student_id: str) -> str | None:
    """Why ``student_id`` (a folder name in submitted/) cannot be used, or None."""
    if not student_id or student_id in (".", ".."):
        return "empty or a dot name"
    if len(student_id) > 128:
        return "longer than 128 characters"
    if "/" in student_id or "\\" in student_id or os.sep in student_id:
        return "contains a path separator"
    if printable(student_id, 10**6) != student_id or student_id != student_id.strip():
        return "contains control characters or surrounding blanks"
    if student_id.startswith(("-", "=", "+", "@")):
        return "starts with - = + or @ (an option or a spreadsheet formula)"
    return None


def _read_regular(path: Path, cap_bytes: int) -> tuple[bytes | None, str]:
    """(content, "") of a regular file, or (None, why not); never follows a link or blocks."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        return None, f"cannot be opened ({exc.strerror})"
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            return None, "not a regular file"
        if info.st_size > cap_bytes:
            return None, f"{info.st_size / 2**20:.1f} MB, over the {cap_bytes / 2**20:g} MB cap"
        chunks, size = [], 0
        while chunk := os.read(fd, 1 << 20):
            chunks.append(chunk)
            size += len(chunk)
            if size > cap_bytes:  # grew while we read
                return None, f"over the {cap_bytes / 2**20:g} MB cap"
        return b"".join(chunks), ""
    finally:
        os.close(fd)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "symlink"), (stat.S_ISFIFO, "named pipe"),
                       (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "device"),
                       (stat.S_ISBLK, "device")):
        if test(mode):
            return name
    return "special file"


def _copy_tree(src: Path, dst: Path, caps: Caps, frozen: Frozen, depth: int = 0,
               budget: list | None = None) -> None:
    budget = budget if budget is not None else [int(caps.total_mb * 2**20), caps.files]
    try:
        entries = sorted(os.scandir(src), key=lambda e: e.name)
    except OSError as exc:
        frozen.notes.append(f"{printable(src.name)}: cannot be listed ({exc.strerror})")
        return
    for entry in entries:
        name = printable(entry.name)
        rel = f"{name}"
        if entry.name in (".ipynb_checkpoints", "__pycache__") or student_id_problem(entry.name):
            if student_id_problem(entry.name) and entry.name not in (".ipynb_checkpoints",):
                frozen.notes.append(f"{rel}: skipped (unusable file name)")
            continue
        info = entry.stat(follow_symlinks=False)
        if stat.S_ISDIR(info.st_mode):
            if depth + 1 >= caps.depth:
                frozen.notes.append(f"{rel}/: skipped (folders nested over {caps.depth} deep)")
                continue
            (dst / entry.name).mkdir(mode=0o755)
            _copy_tree(Path(entry.path), dst / entry.name, caps, frozen, depth + 1, budget)
            continue
        if not stat.S_ISREG(info.st_mode):
            frozen.notes.append(f"{rel}: skipped ({_kind(info.st_mode)}, not a regular file)")
            frozen.flags.append(f"not_a_regular_file:{name}")
            continue
        if budget[1] <= 0:
            frozen.notes.append(f"{rel}: skipped (more than {caps.files} files)")
            continue
        data, why = _read_regular(Path(entry.path), min(int(caps.file_mb * 2**20), budget[0]))
        if data is None:
            frozen.notes.append(f"{rel}: skipped ({why})")
            frozen.flags.append(f"file_refused:{name}")
            continue
        budget[0] -= len(data)
        budget[1] -= 1
        fd = os.open(dst / entry.name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW,
                     0o644)
        with os.fdopen(fd, "wb") as f:
            f.write(data)


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
        path = frozen.folder / name if frozen.folder is not None else None
        if path is None or not path.is_file() or path.is_symlink():
            continue
        data = path.read_bytes()
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
    ``store`` must be a new, grader-private directory.
    """
    info = os.lstat(submitted)
    if not stat.S_ISDIR(info.st_mode):
        raise ValueError(f"{submitted} is a {_kind(info.st_mode)}, not a folder of submissions")
    out = []
    for entry in sorted(os.scandir(submitted), key=lambda e: e.name):
        try:
            os.lstat(os.path.join(entry.path, assignment))
        except OSError:
            continue  # this student did not hand in this assignment
        sid = entry.name
        frozen = Frozen(printable(sid, 200))
        out.append(frozen)
        if why := student_id_problem(sid):
            frozen.accepted = False
            frozen.flags.append("rejected_student_id")
            frozen.notes.append(f"student id refused: {why}; rename the folder in submitted/")
            continue
        for path, what in ((entry.path, "student folder"),
                           (os.path.join(entry.path, assignment), "assignment folder")):
            mode = os.lstat(path).st_mode
            if not stat.S_ISDIR(mode):
                frozen.notes.append(f"the {what} is a {_kind(mode)}, not a folder: nothing graded")
                frozen.flags.append(f"not_a_folder:{_kind(mode).replace(' ', '_')}")
                break
        else:
            frozen.folder = store / sid
            frozen.folder.mkdir(mode=0o755)
            _copy_tree(Path(entry.path) / assignment, frozen.folder, caps, frozen)
            found = sorted(p for p in frozen.folder.rglob("*.ipynb") if p.is_file()
                           and _check_notebook(p, caps, frozen))
            frozen.notebooks = ([p for p in found if p.name not in expected]
                                + [p for p in found if p.name in expected])
            stamp = frozen.folder / "timestamp.txt"
            if stamp.is_file():
                text = stamp.read_text(errors="replace").strip()
                frozen.timestamp = text if len(text) <= 64 and printable(text) == text else ""
            frozen.exchange = _exchange_files(frozen)
        if not frozen.notebooks:
            frozen.notes.append("no notebook to grade")
    return out

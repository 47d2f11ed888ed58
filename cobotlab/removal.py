"""``cobotlab labs remove NAME``: take a lab out of a course, all of it, after saying what goes.

What a lab leaves in a course, as nbgrader and cobotlab lay it out:

* nbgrader's folders: ``source/NAME/``, ``release/NAME/``, and per student
  ``submitted/<student>/NAME/``, ``autograded/<student>/NAME/``, ``feedback/<student>/NAME/``;
  in nbgrader's exchange, ``<exchange>/<course_id>/outbound/NAME/`` (students could still
  fetch it) and the ``inbound/<student>+NAME+<time>...`` submissions (``nbgrader collect``
  would bring them back);
* the gradebook's assignment with every submission and score of it
  (:func:`autograder.gradebook.remove_assignment`, after a backup of the whole gradebook to
  ``.cobotlab/gradebook.backup.db``), and its rows of ``grades.csv``;
* cobotlab's feedback (``feedback_cobotlab/<student>/NAME/``), kept executions
  (``.cobotlab/executions/NAME/``) and verify record (``.cobotlab/verified/NAME.json``);
* a course's own lab: its folder (``labs/NAME/``) and private spec
  (``.cobotlab/specs/NAME.py``) too, so the next ``course init`` does not bring it back (they
  stay in the course's git history if they were committed).

A built-in lab lives in the package, which every course shares: it is removed from this course
only, by adding its name to ``removed_labs`` in the course's ``cobotlab.toml``; ``course init``
and ``labs student`` leave it out from then on, and deleting the name brings it back.

Nothing is removed before the plan is shown and confirmed; a lab with graded submissions is
announced loudly and confirmed by typing its name.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

from autograder import gradebook, record, registry
from autograder.secret import PRIVATE_DIR

__all__ = ["Removal", "plan_removal", "carry_out", "run_remove"]

# nbgrader's per-student folders (and cobotlab's feedback beside them): <top>/<student>/<lab>/
_PER_STUDENT = ("submitted", "autograded", "feedback", "feedback_cobotlab")


@dataclass
class Removal:
    """What removing lab ``name`` from ``course`` takes: ``paths`` (files and folders, none
    reached through a symlink), the gradebook's (submissions, graded submissions) of it or
    None, its ``grades.csv`` rows, and for a built-in lab the ``cobotlab.toml`` line."""

    course: Path
    name: str
    builtin: bool
    paths: list[Path] = field(default_factory=list)
    gradebook: tuple[int, int] | None = None
    grade_rows: int = 0
    scored_rows: int = 0
    outside: list[Path] = field(default_factory=list)   # the lab's files out of the course

    @property
    def graded(self) -> bool:
        """Whether any student of the lab was graded (gradebook, grades.csv or feedback)."""
        return bool((self.gradebook and self.gradebook[1]) or self.scored_rows or any(
            p.relative_to(self.course).parts[0] in ("autograded", "feedback",
                                                    "feedback_cobotlab")
            for p in self.paths if p.is_relative_to(self.course)))

    def lines(self) -> list[str]:
        """The plan, one line per thing removed (paths relative to the course)."""
        def shown(path: Path) -> str:
            text = os.path.relpath(path, self.course)
            return text + ("/" if path.is_dir() and not path.is_symlink() else "")

        out = [f"  {shown(p)}" for p in self.paths]
        if self.gradebook is not None:
            subs, graded = self.gradebook
            out.append(f"  gradebook.db: assignment {self.name} with {subs} submission(s), "
                       f"{graded} of them graded")
        if self.grade_rows:
            out.append(f"  grades.csv: {self.grade_rows} row(s) of {self.name}")
        if self.builtin:
            out.append(f"  cobotlab.toml: {self.name} added to removed_labs (the built-in lab "
                       "stays in the package for other courses)")
        out += [f"  (kept: {p} is outside the course; delete it, or take its folder out of "
                "lab_folders, or `course init` brings the lab back)" for p in self.outside]
        return out


def _course(course_dir) -> Path:
    """The course folder: ``course_dir``, else the course found from the current folder."""
    if course_dir is not None:
        root = Path(course_dir).expanduser().resolve()
    else:
        root = registry.course_root() or Path.cwd()
    if not ((root / registry.CONFIG_NAME).is_file() or (root / "nbgrader_config.py").is_file()):
        raise ValueError(f"{root} is not a course (no {registry.CONFIG_NAME} or "
                         "nbgrader_config.py): run it in the course folder or pass "
                         "--course DIR")
    registry.use_course(root)
    return root


def _exchange(root: Path) -> tuple[Path, str] | None:
    """(exchange root, course id) of the course's nbgrader_config.py, or None."""
    from traitlets.config.loader import PyFileConfigLoader

    try:
        config = PyFileConfigLoader("nbgrader_config.py", path=str(root)).load_config()
    except Exception:  # noqa: BLE001 - no config, or one nbgrader itself will complain about
        return None
    where = config.Exchange.get("root")
    course_id = config.CourseDirectory.get("course_id")
    return (Path(where), str(course_id)) if where and course_id else None


def _real_dirs(folder: Path) -> list[Path]:
    """The folders directly in ``folder`` that are folders, not links to one."""
    try:
        return sorted(Path(e.path) for e in os.scandir(folder) if e.is_dir(follow_symlinks=False))
    except OSError:
        return []


def _there(path: Path) -> bool:
    return os.path.lexists(path) and not path.parent.is_symlink()


def plan_removal(name: str, course_dir=None) -> Removal:
    """What ``cobotlab labs remove NAME`` would remove from the course (nothing is touched).
    ValueError when the course has no lab and nothing left of one by that name."""
    if not registry.NAME_PATTERN.match(name):   # it becomes a path below the course
        raise ValueError(f"{name!r} is not a lab's name (a letter, then letters, digits or _)")
    root = _course(course_dir)
    builtin = name in registry.builtin_names()
    lab = registry.all_labs().get(name)
    removal = Removal(root, name, builtin and name not in registry.removed_labs(root))
    paths = [root / "source" / name, root / "release" / name]
    for top in _PER_STUDENT:
        paths += [student / name for student in _real_dirs(root / top)]
    paths.append(root / PRIVATE_DIR / "executions" / name)
    paths.append(root / registry.PRIVATE_DIR.parent / "verified" / f"{name}.json")
    if lab is not None and not lab.builtin:
        own = [lab.folder, lab.spec_file, registry.verification_path(name)]
        # a lab folder outside the course (lab_folders = ["../shared"]) may be another
        # course's too: it is named, not removed
        paths += [p for p in own if p.is_relative_to(root)]
        removal.outside = [p for p in own if not p.is_relative_to(root) and os.path.lexists(p)]
    exchange = _exchange(root)
    if exchange is not None:
        place = exchange[0] / exchange[1]
        paths.append(place / "outbound" / name)
        try:
            paths += sorted(p for p in (place / "inbound").iterdir()
                            if p.name.split("+")[1:2] == [name])
        except OSError:
            pass
    removal.paths = list(dict.fromkeys(p for p in paths if p is not None and _there(p)))
    removal.gradebook = _gradebook_counts(root, name)
    rows = _grade_rows(root, name)
    removal.grade_rows = len(rows)
    removal.scored_rows = sum(1 for row in rows if row.get("score", "") not in ("", None))
    if not (removal.paths or removal.gradebook or removal.grade_rows or removal.builtin):
        known = ", ".join(registry.lab_names())
        already = (" (it is already in removed_labs of cobotlab.toml)"
                   if builtin else "")
        raise ValueError(f"{root} has no lab named {name!r} and nothing left of one"
                         f"{already}; the course's labs are {known}")
    return removal


def _gradebook_counts(root: Path, name: str) -> tuple[int, int] | None:
    """(submissions, graded submissions) of lab ``name`` in the course's gradebook, None
    when it has none of it. Graded: a total nbgrader would show, or a manual score."""
    try:
        scores = gradebook.class_scores(root, name)
    except ValueError:   # no gradebook, or no such assignment in it
        return None
    return len(scores), sum(1 for s in scores.values() if s["score"] is not None or s["manual"])


def _grade_rows(root: Path, name: str) -> list[dict]:
    import csv

    from autograder.pipeline.record import GRADES_CSV

    try:
        with open(root / GRADES_CSV, newline="", encoding="utf-8") as f:
            return [row for row in csv.DictReader(f) if row.get("assignment") == name]
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def _add_removed(root: Path, name: str) -> None:
    """Put ``name`` in ``removed_labs`` of ``root/cobotlab.toml`` (the file made if needed)."""
    path = root / registry.CONFIG_NAME
    names = registry.removed_labs(root)
    if name in names:
        return
    line = "removed_labs = [" + ", ".join(f'"{n}"' for n in [*names, name]) + "]"
    text = path.read_text() if path.is_file() else ""
    pattern = re.compile(r"^removed_labs\s*=\s*\[[^\]]*\]", re.MULTILINE)
    if pattern.search(text):
        new = pattern.sub(line, text, count=1)
    else:
        comment = ("# removed_labs: built-in labs this course does without (cobotlab labs "
                   "remove);\n# delete a name and run `cobotlab course init` to bring it back.\n")
        new = text + ("\n" if text and not text.endswith("\n") else "") + comment + line + "\n"
    path.write_text(new)
    registry.use_course(root)
    if name not in registry.removed_labs(root):
        raise ValueError(f"{path}: could not add {name} to removed_labs; write "
                         f"{line} there yourself")


def carry_out(removal: Removal) -> list[str]:
    """Remove what ``removal`` lists; return what was done, one line each."""
    from autograder.pipeline.record import GRADE_COLUMNS, GRADES_CSV

    root, name, done = removal.course, removal.name, []
    if removal.gradebook is not None:
        private = root / PRIVATE_DIR
        private.mkdir(mode=0o700, exist_ok=True)
        copy = gradebook.backup(root, private)
        gradebook.remove_assignment(root, name)
        done.append(f"removed {name} from gradebook.db (the gradebook before: {copy})")
    if removal.grade_rows:
        count = record.drop_csv_rows(root, GRADES_CSV, GRADE_COLUMNS,
                                     ("assignment", "student_id"), "assignment", name)
        done.append(f"removed {count} row(s) of {name} from {GRADES_CSV}")
    failed = []
    for path in removal.paths:
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)   # never follows a link inside
            else:
                path.unlink()
        except OSError as exc:   # a student's files in a shared exchange, say: go on
            failed.append(f"{path} ({exc.strerror or exc})")
            continue
        done.append(f"removed {os.path.relpath(path, root)}")
    if removal.builtin:
        _add_removed(root, name)
        done.append(f"{registry.CONFIG_NAME}: {name} is in removed_labs (`course init` and "
                    "`labs student` leave it out)")
    registry.use_course(root)
    if failed:
        print("\n".join(done))
        raise ValueError(f"removed everything else of {name}, but not {'; '.join(failed)}: "
                         "delete these as a user who may (root, or the files' owner), or run "
                         f"`cobotlab labs remove {name}` again once you can")
    return done


def run_remove(name: str, course_dir=None, yes: bool = False, ask=input,
               interactive=None) -> int:
    """The command: show the plan, ask (or take ``yes``), remove. Refuses (ValueError) in a
    run without a terminal unless ``yes``. Returns 0, or 1 when the answer was no."""
    removal = plan_removal(name, course_dir)
    print(f"cobotlab labs remove {name} from {removal.course} removes:")
    for line in removal.lines():
        print(line)
    if removal.graded:
        subs = removal.gradebook[1] if removal.gradebook else 0
        print(f"WARNING: {name} HAS GRADED SUBMISSIONS ({subs} graded in the gradebook, "
              f"{removal.scored_rows} scored row(s) in grades.csv): their grades and feedback "
              "are deleted for good. Export them first (copy grades.csv, or nbgrader export).",
              file=sys.stderr)
    if not yes:
        interactive = sys.stdin.isatty() if interactive is None else interactive
        if not interactive:
            raise ValueError("labs remove asks before it deletes, and this run has no terminal "
                             "to ask on: nothing removed; pass --yes to remove without asking")
        try:
            if removal.graded:
                answer = ask(f"Type the lab's name ({name}) to remove it and its grades: ")
                confirmed = answer.strip() == name
            else:
                confirmed = ask(f"Remove {name}? [y/N] ").strip().lower() in ("y", "yes")
        except EOFError:   # Ctrl-D: no
            confirmed = False
        if not confirmed:
            print("nothing removed")
            return 1
    for line in carry_out(removal):
        print(line)
    return 0

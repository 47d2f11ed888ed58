"""``cobotlab labs new``: a new lab in a course repository, from the skeleton or as a copy.

A course's own lab has three parts (see :mod:`autograder.registry`)::

    <course>/cobotlab.toml                  lab_folders = ["labs"]
    <course>/labs/<name>/<name>.ipynb       the nbgrader source notebook (and its data)
    <course>/labs/<name>/scoring.py         the public scoring, released with the notebook
    <course>/.cobotlab/specs/<name>.py      the private spec: hidden problems, truths, mistakes

:func:`new_lab` writes all of them, either from the skeleton (``cobotlab/templates/skeleton``:
one graded function, ``mean_offset``, whose tolerance and mistake are worked out in its spec)
or as a copy of an existing lab, built in or the course's, under the new name. Everything is
built in a temporary folder inside the course and moved into place at the end, so a refusal
or a failure leaves nothing behind.
"""

from __future__ import annotations

import ast
import fnmatch
import importlib.util
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from autograder import registry
from autograder.registry import LabError

__all__ = ["SKELETON", "GITIGNORE_LINES", "new_lab", "next_steps", "write_gitignore"]

SKELETON = Path(__file__).resolve().parent / "templates" / "skeleton"
DEFAULT_LAB_FOLDER = "labs"

# Left behind by a run or an editor, not part of the lab (practice data is rebuilt from the
# new lab's own spec when it is released); nor of its digest (registry.lab_digest).
_NOT_COPIED = registry.LEFT_BEHIND

_CONFIG_TEXT = f"""\
# cobotlab course settings. lab_folders: the folders (relative to this file) that hold the
# course's own labs, one folder per lab (<name>/<name>.ipynb and its public scoring.py);
# their private specs are in {registry.PRIVATE_DIR.as_posix()}/.
# Add a lab with `cobotlab labs new NAME`.
lab_folders = ["{DEFAULT_LAB_FOLDER}"]
"""


# What a course folder holds that must never reach its git repository: the grading secret
# and every file with students' work, scores or names (the grader's files are named in
# autograder/course.py and record.py; nbgrader's gradebook, its SQLite journals and its log).
# The private specs and verify's reports (.cobotlab/specs/, .cobotlab/verified/) are the
# course's own work and stay in it.
GITIGNORE_LINES = (
    ".cobotlab/secret",
    ".cobotlab/runs.jsonl",
    ".cobotlab/last_run.log",
    ".cobotlab/gradebook.backup.db",
    ".cobotlab/.gradebook.backup.tmp",
    ".cobotlab/grading-in-progress",
    ".cobotlab/nbgrader_cells.json",
    "gradebook.db*",
    ".gradebook.restore.tmp",
    "grades.csv",
    "nbgrader_grades.csv",
    ".nbgrader.log",
    "submitted/",
    "autograded/",
    "feedback/",
    "feedback_cobotlab/",
    "exchange/",
)
_GITIGNORE_HEADER = ("# cobotlab: the grading secret and the students' data (submissions, "
                     "grades, gradebook, logs)\n# never go into the repository\n")


def write_gitignore(course_dir) -> bool:
    """Make the course's ``.gitignore`` ignore every line of :data:`GITIGNORE_LINES`: write
    it if there is none, else append the lines it lacks (an author's own lines stay as they
    are). True when the file was written or changed."""
    path = Path(course_dir) / ".gitignore"
    text = path.read_text(encoding="utf-8") if path.is_file() else ""
    present = {line.strip() for line in text.splitlines()}
    missing = [line for line in GITIGNORE_LINES if line not in present]
    if not missing:
        return False
    if text and not text.endswith("\n"):
        text += "\n"
    header = _GITIGNORE_HEADER if _GITIGNORE_HEADER.splitlines()[0] not in present else ""
    path.write_text(text + ("\n" if text and header else "") + header
                    + "".join(f"{line}\n" for line in missing), encoding="utf-8")
    return True


@dataclass(frozen=True)
class _Source:
    """A lab to copy: its folder, public scoring file and private spec file."""

    name: str
    folder: Path
    scoring_file: Path
    spec_file: Path
    builtin: bool


# --------------------------------------------------------------------------- where it goes


def _check_name(name: str, parent: Path) -> None:
    if not isinstance(name, str) or not registry.NAME_PATTERN.match(name):
        raise LabError(f"{parent}: {name!r} is not a valid name for a lab in this folder: it "
                       "becomes a folder, an nbgrader assignment and part of a Python module "
                       "name, so use a letter followed by letters, digits or _ (64 at most), "
                       "e.g. lab6_gripper")


def _lab_parent(root: Path) -> tuple[Path, bool]:
    """(the folder the new lab goes into, whether ``cobotlab.toml`` must be written)."""
    config = root / registry.CONFIG_NAME
    if not config.exists():
        return root / DEFAULT_LAB_FOLDER, True
    folders = registry.lab_folders(root)
    if not folders:
        raise LabError(f"{config} names no lab folder; add a line lab_folders = "
                       f'["{DEFAULT_LAB_FOLDER}"] to it, then run the command again')
    return folders[0], False


def _refuse_taken(name: str, root: Path, target: Path, spec: Path) -> None:
    """LabError if ``name`` is a lab already, or its folder or spec file exists."""
    builtin = registry.builtin_names()
    if name in builtin:
        raise LabError(f"{target}: {name} is the name of a built-in lab ({', '.join(builtin)}); "
                       "choose another name")
    # Any lab folder of the course, not only the one the new lab goes into: the registry
    # refuses two labs of one name.
    for parent in registry.lab_folders(root):
        if (parent / name / registry.SCORING_FILE).is_file():
            raise LabError(f"{parent / name}: the course already has a lab named {name}; "
                           "choose another name (or edit that lab)")
    if target.exists() or target.is_symlink():
        raise LabError(f"{target} already exists; choose another name, or move that folder "
                       "out of the way first")
    if spec.exists() or spec.is_symlink():
        raise LabError(f"{spec}: a private spec named {name} already exists (left from a "
                       "removed lab?); choose another name, or delete that file if it is stale")


def _relative(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` in POSIX form (as written in docs and commands)."""
    return Path(os.path.relpath(path, root)).as_posix()


# --------------------------------------------------------------------------- the skeleton


def _fill(text: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        text = text.replace("{{" + key + "}}", value)
    return text


def _write_notebook(nb: dict, path: Path) -> None:
    # nbformat's own layout, so a later save from Jupyter changes only what was edited.
    path.write_text(json.dumps(nb, indent=1, sort_keys=True, ensure_ascii=False) + "\n",
                    encoding="utf-8")


def _stage_skeleton(name: str, lab: Path, spec: Path, values: dict[str, str]) -> None:
    # Templates are *.template, not .py or .ipynb: setuptools would put a .py in the student
    # wheel (answer code), and linters would hold nbgrader's hidden-test import against it.
    nb = json.loads((SKELETON / "notebook.ipynb.template").read_text(encoding="utf-8"))
    for cell in nb["cells"]:
        source = cell["source"]
        cell["source"] = ([_fill(line, values) for line in source] if isinstance(source, list)
                          else _fill(source, values))
    _write_notebook(nb, lab / f"{name}.ipynb")
    scoring = _fill((SKELETON / "scoring.py.template").read_text(encoding="utf-8"), values)
    (lab / registry.SCORING_FILE).write_text(scoring, encoding="utf-8")
    spec.write_text(_fill((SKELETON / "spec.py.template").read_text(encoding="utf-8"), values),
                    encoding="utf-8")


# --------------------------------------------------------------------------- a copy


def _module_file(module: str) -> Path | None:
    try:
        found = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    return Path(found.origin) if found is not None and found.origin else None


def _source_lab(lab: str, root: Path) -> _Source:
    """The files of lab ``lab`` (built in, or one of the course at ``root``), or LabError."""
    if lab in registry.builtin_names():
        folder = registry.builtin_folder() / lab
        if not (folder / f"{lab}.ipynb").is_file():
            raise LabError(f"{folder}: the notebook of the built-in lab {lab} is not installed "
                           "here; copy it from an instructor's install (a full checkout or "
                           "`pip install cobotlab`), not a student's")
        spec = _module_file(f"autograder.specs.{lab}")
        if spec is None or not spec.is_file():
            raise LabError(f"the private spec of {lab} (autograder/specs/{lab}.py) is not on "
                           "this machine; copy the lab from an instructor's install")
        return _Source(lab, folder, _module_file(f"autograder.scoring.{lab}"), spec, True)
    folders = registry.lab_folders(root)
    for parent in folders if registry.NAME_PATTERN.match(lab) else ():   # no ../ escapes
        folder = parent / lab
        if (folder / registry.SCORING_FILE).is_file():
            spec = root / registry.PRIVATE_DIR / f"{lab}.py"
            if not (folder / f"{lab}.ipynb").is_file() or not spec.is_file():
                missing = spec if not spec.is_file() else folder / f"{lab}.ipynb"
                raise LabError(f"{missing}: not found, so the lab {lab} cannot be copied; "
                               "restore the file first")
            return _Source(lab, folder, folder / registry.SCORING_FILE, spec, False)
    known = sorted(set(registry.builtin_names()) | {
        p.name for parent in folders if parent.is_dir() for p in parent.iterdir()
        if (p / registry.SCORING_FILE).is_file()})
    raise LabError(f"--from {lab}: no lab of that name to copy (in {root} or built in); the "
                   f"labs are {', '.join(known)}")


def _rename_in_notebook(nb: dict, old: str, new: str, renames) -> None:
    """The lab's name as a string literal in code (``assignment="lab1_flange"``) -> ``new``,
    and the paths of ``renames`` in every cell."""
    pattern = re.compile(r"""(["'])""" + re.escape(old) + r"\1")

    def swap(text: str, code: bool) -> str:
        if code:
            text = pattern.sub(lambda m: m[1] + new + m[1], text)
        return _renamed(text, renames)

    for cell in nb["cells"]:
        code = cell.get("cell_type") == "code"
        source = cell["source"]
        cell["source"] = [swap(line, code) for line in source] if isinstance(source, list) \
            else swap(source, code)


def _own_scoring_imports(tree: ast.Module, lab: str, path: Path):
    """The top-level imports of lab ``lab``'s own public scoring in a built-in spec:
    yields (statement, [names bound to the module], [(name, attribute) imported from it],
    [other aliases the statement keeps])."""
    module = f"autograder.scoring.{lab}"
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module in (
                "autograder.scoring", module):
            if node.module == module:
                if any(a.name == "*" for a in node.names):
                    raise LabError(f"{path}: `from {module} import *` cannot be rewritten for a "
                                   "copy; name the imports in the file first")
                yield node, [], [(a.asname or a.name, a.name) for a in node.names], []
            elif any(a.name == lab for a in node.names):
                yield (node, [a.asname or a.name for a in node.names if a.name == lab], [],
                       [a for a in node.names if a.name != lab])
        elif isinstance(node, ast.Import) and any(a.name == module for a in node.names):
            if any(a.name == module and not a.asname for a in node.names):
                raise LabError(f"{path}: `import {module}` (used as a dotted name) cannot be "
                               f"rewritten for a copy; write `from autograder.scoring import "
                               f"{lab} as scoring` in the file first")
            yield (node, [a.asname for a in node.names if a.name == module], [],
                   [a for a in node.names if a.name != module])


def _rewrite_builtin_spec(text: str, source: _Source, name: str, scoring_rel: str) -> str:
    """A built-in spec as a course lab's: the import of its public scoring (a package module)
    becomes ``scoring = public_scoring("<name>")``, what it imported from that module
    attributes of it; every other import stays as it is."""
    tree = ast.parse(text)
    lines = text.splitlines(keepends=True)
    found = list(_own_scoring_imports(tree, source.name, source.spec_file))
    if not found:
        raise LabError(f"{source.spec_file}: found no import of its public scoring "
                       f"(autograder.scoring.{source.name}) to point at the copy")
    module_names = [n for _, names, _, _ in found for n in names] or ["scoring"]
    attributes = [pair for _, _, pairs, _ in found for pair in pairs]
    first_import = min(node.lineno for node, _, _, _ in found)
    edits = []   # (start, stop, new lines) over the original lines, 0-based, stop exclusive
    for node, _, _, kept in found:
        new = ["from autograder.registry import public_scoring\n"] \
            if node.lineno == first_import else []
        if kept:
            spelled = ", ".join(a.name + (f" as {a.asname}" if a.asname else "") for a in kept)
            new.append(f"from autograder.scoring import {spelled}\n"
                       if isinstance(node, ast.ImportFrom) else f"import {spelled}\n")
        edits.append((node.lineno - 1, node.end_lineno, new))
    # The names are bound after the module's leading block of imports (docstring first).
    body = tree.body[1:] if tree.body and isinstance(tree.body[0], ast.Expr) else tree.body
    end = 0
    for node in body:
        if not isinstance(node, (ast.Import, ast.ImportFrom)):
            break
        end = node.end_lineno
    first = module_names[0]
    edits.append((end, end, [
        "\n",
        "# The lab's public scoring: a course lab is no package to import from, so the\n",
        f"# registry loads the file from the lab folder, {scoring_rel}.\n",
        f'{first} = public_scoring("{name}")\n',
        *(f"{other} = {first}\n" for other in module_names[1:]),
        *(f"{local} = {first}.{attribute}\n" for local, attribute in attributes),
    ]))
    # From the last edit up, so the line numbers of the earlier ones stay valid.
    for start, stop, new in sorted(edits, key=lambda e: (e[0], e[1]), reverse=True):
        lines[start:stop] = new
    return "".join(lines)


def _rewrite_course_spec(text: str, source: _Source, name: str) -> str:
    """A course lab's spec for the copy: its ``public_scoring("<old>")`` names the new lab."""
    pattern = re.compile(r"""public_scoring\(\s*(["'])""" + re.escape(source.name)
                         + r"""\1\s*\)""")
    if not pattern.search(text):
        raise LabError(f"{source.spec_file}: found no public_scoring(\"{source.name}\") to "
                       "point at the copy; load the lab's scoring that way in the file first")
    return pattern.sub(f'public_scoring("{name}")', text)


def _path_renames(source: _Source, name: str, root: Path, target: Path,
                  spec_target: Path) -> list[tuple[re.Pattern, str]]:
    """(pattern, replacement) for where a copied file names the old lab's files: the built-in
    modules (in docstrings and comments), or the course lab's folder and spec."""
    old = source.name
    scoring_rel = _relative(target / registry.SCORING_FILE, root)
    spec_rel = _relative(spec_target, root)
    pairs = [(f":mod:`autograder.scoring.{old}`", f"``{scoring_rel}``"),
             (f":mod:`autograder.specs.{old}`", f"``{spec_rel}``"),
             (f"autograder.scoring.{old}", scoring_rel),
             (f"autograder/scoring/{old}.py", scoring_rel),
             (f"autograder.specs.{old}", spec_rel),
             (f"autograder/specs/{old}.py", spec_rel)]
    if not source.builtin:
        old_dir, new_dir = _relative(source.folder, root), _relative(target, root)
        pairs += [(_relative(source.spec_file, root), spec_rel),
                  (f"{old_dir}/{old}.ipynb", f"{new_dir}/{name}.ipynb"), (old_dir, new_dir)]
    # Whole paths only: labs/lab1 must not turn labs/lab10 into labs/newlab0.
    return [(re.compile(r"(?<![\w/.])" + re.escape(before) + r"(?![\w])"), after)
            for before, after in pairs]


def _renamed(text: str, renames) -> str:
    for pattern, after in renames:
        text = pattern.sub(lambda _, after=after: after, text)   # taken literally
    return text


_COPIED = "# Copied from the lab "


def _with_header(text: str, source: _Source, name: str) -> str:
    """``text`` under one line saying where it came from (a copy's copy keeps the first)."""
    if text.startswith(_COPIED):
        return text
    return (f"{_COPIED}{source.name} by `cobotlab labs new {name} --from {source.name}`.\n"
            + text)


def _stage_copy(source: _Source, name: str, lab: Path, spec: Path, root: Path, target: Path,
                spec_target: Path) -> None:
    def ignore(folder, names):
        return {n for n in names if any(fnmatch.fnmatch(n, p) for p in _NOT_COPIED)}

    renames = _path_renames(source, name, root, target, spec_target)
    shutil.copytree(source.folder, lab, ignore=ignore, dirs_exist_ok=True)
    nb = json.loads((lab / f"{source.name}.ipynb").read_text(encoding="utf-8"))
    _rename_in_notebook(nb, source.name, name, renames)
    (lab / f"{source.name}.ipynb").unlink()
    _write_notebook(nb, lab / f"{name}.ipynb")

    scoring = _renamed(source.scoring_file.read_text(encoding="utf-8"), renames)
    (lab / registry.SCORING_FILE).write_text(_with_header(scoring, source, name),
                                             encoding="utf-8")

    text = source.spec_file.read_text(encoding="utf-8")
    text = (_rewrite_builtin_spec(text, source, name,
                                  _relative(target / registry.SCORING_FILE, root))
            if source.builtin else _rewrite_course_spec(text, source, name))
    spec.write_text(_with_header(_renamed(text, renames), source, name), encoding="utf-8")


# --------------------------------------------------------------------------- all or nothing


def _move_in(staged: list[tuple[Path, Path]]) -> None:
    """Move each staged path to its target; on any failure undo the moves and the folders
    made for them, and re-raise."""
    done: list[tuple[Path, Path]] = []
    made: list[Path] = []
    try:
        for source, target in staged:
            missing = [p for p in (target.parent, *target.parent.parents) if not p.exists()]
            for folder in reversed(missing):
                folder.mkdir()
                made.append(folder)
            if target.exists() or target.is_symlink():  # appeared since the checks
                raise LabError(f"{target} appeared while the lab was being written; nothing "
                               "was written, run the command again")
            os.rename(source, target)
            done.append((source, target))
    except BaseException:
        for source, target in reversed(done):
            os.rename(target, source)
        for folder in reversed(made):
            try:
                folder.rmdir()
            except OSError:
                pass
        raise


def new_lab(name: str, course_dir=".", from_lab: str | None = None) -> list[Path]:
    """Write a new lab ``name`` into the course folder ``course_dir``; return the files
    written (absolute paths: the notebook and the lab folder's other files, the public
    scoring, the private spec, and ``cobotlab.toml`` when it was created).

    The lab goes into the first of the course's ``lab_folders`` (``labs/``, with a new
    ``cobotlab.toml`` saying so, when the course has none) and its private spec into
    ``.cobotlab/specs/<name>.py``. Without ``from_lab`` it is the skeleton: one graded function,
    ``mean_offset(measured, commanded)`` (positions in metres), with its scoring, hidden
    problems and classic mistake. With ``from_lab`` (a built-in lab or one of the course) it is
    a copy of that lab under the new name: notebook, data files, public scoring and private
    spec, its references to the old name rewritten.

    The course's ``.gitignore`` is written, or completed, so that the grading secret and the
    students' data (:data:`GITIGNORE_LINES`) stay out of its repository; it is among the
    files returned when it changed.

    Raises :class:`autograder.registry.LabError`, having written nothing, for a name that is
    not valid or is already a lab, an existing lab folder or spec file, or an unknown
    ``from_lab``. ``registry.use_course(course_dir)`` then finds the new lab.
    """
    root = Path(course_dir).expanduser().resolve()
    if root.exists() and not root.is_dir():
        raise LabError(f"{root} is a file, not a course folder; pass the folder with --dir")
    parent, new_config = _lab_parent(root)
    _check_name(name, parent)
    target = parent / name
    spec_target = root / registry.PRIVATE_DIR / f"{name}.py"
    _refuse_taken(name, root, target, spec_target)
    source = _source_lab(from_lab, root) if from_lab is not None else None
    if source is None and not (SKELETON / "spec.py.template").is_file():
        raise LabError(f"{SKELETON}: the lab skeleton is not installed here; it comes with the "
                       "instructor's install (pip install cobotlab), not cobotlab-student")

    made_root = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".cobotlab-new-", dir=root))
    try:
        lab, spec = staging / "lab", staging / "spec.py"
        lab.mkdir()
        if source is None:
            values = {"name": name, "lab_dir": _relative(target, root),
                      "spec_path": _relative(spec_target, root)}
            _stage_skeleton(name, lab, spec, values)
        else:
            _stage_copy(source, name, lab, spec, root, target, spec_target)
        staged = [(spec, spec_target), (lab, target)]
        if new_config:
            (staging / "cobotlab.toml").write_text(_CONFIG_TEXT, encoding="utf-8")
            staged.append((staging / "cobotlab.toml", root / registry.CONFIG_NAME))
        files = sorted(p.relative_to(lab) for p in lab.rglob("*") if p.is_file())
        _move_in(staged)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if made_root:
            shutil.rmtree(root, ignore_errors=True)
        raise
    shutil.rmtree(staging, ignore_errors=True)
    notebook = Path(f"{name}.ipynb")
    ordered = [notebook] + [f for f in files if f not in (notebook, Path(registry.SCORING_FILE))]
    written = [target / f for f in ordered] + [target / registry.SCORING_FILE, spec_target]
    written += [root / registry.CONFIG_NAME] if new_config else []
    return written + ([root / ".gitignore"] if write_gitignore(root) else [])


def next_steps(written: list[Path], course_dir) -> list[str]:
    """What to do after :func:`new_lab` wrote ``written``: commands to run in the course."""
    root = Path(course_dir).expanduser().resolve()
    notebook = written[0]
    lab_dir = _relative(notebook.parent, root)
    spec = next(p for p in written if registry.PRIVATE_DIR.as_posix() in p.as_posix())
    steps = []
    if root != Path.cwd().resolve():
        steps.append(f"cd {os.path.relpath(root)}")
    steps += [
        f"edit the notebook {lab_dir}/{notebook.name} and the hidden problems "
        f"{_relative(spec, root)} (and {lab_dir}/{registry.SCORING_FILE} if the scoring "
        "changes)",
        f"cobotlab labs verify {lab_dir}    (correct code keeps full credit, each mistake "
        "loses it)",
        "cobotlab course init .    (adds the lab to the nbgrader course)",
    ]
    return steps

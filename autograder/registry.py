"""Where a course's labs come from, each loaded on its own when first asked for.

A lab has three parts, wherever it lives:

* its **folder**: the nbgrader source notebook ``<name>.ipynb`` and the files it reads. nbgrader
  copies the folder whole into the release, so everything in it is public;
* its **public scoring** (points, checks, ``measure``, signatures: what ``check()`` scores
  practice problems with in a student's copy);
* its **private spec** (the hidden-problem generators and their truths, the code mistakes):
  only the instructor's process ever imports it.

The built-in labs keep them in the package (``labs/<name>/``, ``autograder/scoring/<name>.py``,
``autograder/specs/<name>.py``). An instructor's lab keeps them in the course repository::

    mycourse/cobotlab.toml             lab_folders = ["labs"]   (relative to this file)
    mycourse/labs/<name>/<name>.ipynb  the notebook (and its data)
    mycourse/labs/<name>/scoring.py    the public scoring (released with the notebook)
    mycourse/.cobotlab/specs/<name>.py the private spec (no release, copy or sandbox sees it)

Both kinds are :class:`Lab` entries of one table and load through :func:`scoring` and
:func:`specs`; nothing else tells them apart. A lab whose files fail to load raises
:class:`LabError` for that lab only: every other lab still loads, checks and grades.

The course is found from ``$COBOTLAB_COURSE`` (set by :func:`use_course`, which the course
commands call, so their child processes agree), else from the nearest ``cobotlab.toml`` above
the current folder. A notebook's kernel in a lab folder of its own (a student's download, a
lab under development) also finds that lab from the ``scoring.py`` beside the notebook.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CONFIG_NAME", "COURSE_ENV", "LEFT_BEHIND", "NAME_PATTERN", "PRIVATE_DIR",
           "SCORING_FILE", "Lab", "LabError", "all_labs", "builtin_folder", "builtin_names",
           "course_root", "find_lab", "lab_digest", "lab_folders", "lab_names", "loaded_specs",
           "notebook_packages", "private_available", "public_scoring", "raised_at",
           "release_problem", "removed_labs", "scoring", "source_folders", "spec_hash",
           "spec_path", "specs", "use_course", "verification_note", "verification_path"]

CONFIG_NAME = "cobotlab.toml"
COURSE_ENV = "COBOTLAB_COURSE"
SCORING_FILE = "scoring.py"
PRIVATE_DIR = Path(".cobotlab") / "specs"
# A lab name is a folder name, an nbgrader assignment name and part of a module name.
NAME_PATTERN = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")


class LabError(ValueError):
    """A lab that cannot be used as it is: the message names the file and the fix."""


@dataclass(frozen=True)
class Lab:
    """One lab: ``folder`` holds its notebook (None where the sources are not installed, as in
    a student's copy of a built-in lab); ``scoring_file`` and ``spec_file`` are its public
    scoring and private spec for an instructor's lab, None for a built-in one (the package's
    modules). ``spec_file`` may name a file that does not exist on this machine."""

    name: str
    folder: Path | None
    scoring_file: Path | None = None
    spec_file: Path | None = None

    @property
    def builtin(self) -> bool:
        return self.scoring_file is None

    @property
    def notebook(self) -> Path | None:
        return None if self.folder is None else self.folder / f"{self.name}.ipynb"


# --------------------------------------------------------------------------- the course


def use_course(root) -> Path | None:
    """Make ``root`` (a course folder, with or without a ``cobotlab.toml``) the course whose
    labs this process and its children load; None goes back to finding it from the current
    folder. Returns the resolved path."""
    if root is None:
        os.environ.pop(COURSE_ENV, None)
        _clear()
        return None
    path = Path(root).expanduser().resolve()
    os.environ[COURSE_ENV] = str(path)
    _clear()
    return path


def course_root() -> Path | None:
    """The course whose labs are loaded: ``$COBOTLAB_COURSE``, else the nearest folder at or
    above the current one holding a ``cobotlab.toml``, else None (the built-in labs only)."""
    named = os.environ.get(COURSE_ENV)
    if named:
        return Path(named)
    try:
        here = Path.cwd()
    except OSError:
        return None
    for folder in (here, *here.parents):
        try:
            if (folder / CONFIG_NAME).is_file():
                return folder
        except OSError:   # a sandbox hides the folder: nothing of the course to see there
            return None
    return None


SETTINGS = ("lab_folders", "notebook_packages", "removed_labs")


def _config(root: Path) -> dict:
    """``root/cobotlab.toml`` checked ({} without the file)."""
    path = root / CONFIG_NAME
    try:
        text = path.read_text()
    except OSError:
        return {}
    try:
        import tomllib
    except ModuleNotFoundError:   # Python 3.10: the same parser, packaged (a dependency there)
        import tomli as tomllib
    try:
        config = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise LabError(f"{path}: not valid TOML ({exc}); write for example "
                       'lab_folders = ["labs"]') from None
    for key, example in (("lab_folders", '["labs"]'), ("notebook_packages", '["sympy"]'),
                         ("removed_labs", '["lab4_stereo"]')):
        value = config.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise LabError(f"{path}: {key} must be a list of names, for example "
                           f"{key} = {example}")
    unknown = sorted(set(config) - set(SETTINGS))
    if unknown:
        raise LabError(f"{path}: unknown setting(s) {', '.join(unknown)}; the file holds only "
                       + " and ".join(SETTINGS))
    return config


def lab_folders(root: Path) -> list[Path]:
    """The lab folders ``root/cobotlab.toml`` names (absolute), or [] without the file."""
    return [(root / Path(f).expanduser()).resolve()
            for f in _config(root).get("lab_folders", [])]


def removed_labs(root: Path | None) -> list[str]:
    """The built-in labs the course at ``root`` does without (``removed_labs`` of its
    ``cobotlab.toml``, written by ``cobotlab labs remove``): neither ``course init`` nor
    ``labs student`` lays them out, and the course has no lab of that name. LabError names
    one that is not a built-in lab (a course's own lab is removed with its folder)."""
    if root is None:
        return []
    names = list(_config(root).get("removed_labs", []))
    builtin = set(builtin_names())
    for name in names:
        if name not in builtin:
            raise LabError(f"{root / CONFIG_NAME}: removed_labs names {name!r}, which is not a "
                           f"built-in lab ({', '.join(sorted(builtin))}); remove it from the "
                           "list (a course's own lab leaves with its folder)")
    return names


def notebook_packages() -> tuple[str, ...]:
    """The installed distributions the course's ``cobotlab.toml`` lets its lab notebooks
    import besides cobotlab's own requirements (``notebook_packages``): the grading sandbox's
    allow list gets each with its dependencies. LabError names one that is not installed."""
    from importlib import metadata

    root = course_root()
    if root is None:
        return ()
    names = tuple(_config(root).get("notebook_packages", []))
    for name in names:
        try:
            metadata.distribution(name)
        except metadata.PackageNotFoundError:
            raise LabError(f"{root / CONFIG_NAME}: notebook_packages names {name!r}, which is "
                           "not installed beside cobotlab; install it in the same environment "
                           f"(pip install {name}) or remove it from the list") from None
    return names


def builtin_folder() -> Path:
    """The built-in labs' sources: the package ``cobotlab_labs`` (``labs/`` of the checkout in
    an editable install, a copy in site-packages in a regular one). A student install has
    none: the path returned then does not exist, and the commands that need it say so."""
    try:
        found = importlib.util.find_spec("cobotlab_labs")
    except (ImportError, ValueError):
        found = None
    if found is not None and found.submodule_search_locations:
        return Path(list(found.submodule_search_locations)[0])
    return Path(__file__).resolve().parent.parent / "labs"


def builtin_names() -> list[str]:
    import pkgutil

    import autograder.scoring as package

    return sorted(m.name for m in pkgutil.iter_modules(package.__path__))


def _lab_in(folder: Path, name: str, root: Path | None) -> Lab:
    private = (root or folder.parent) / PRIVATE_DIR / f"{name}.py"
    return Lab(name, folder, folder / SCORING_FILE, private)


def _course_labs(root: Path) -> dict[str, Lab]:
    labs: dict[str, Lab] = {}
    for parent in lab_folders(root):
        if not parent.is_dir():
            raise LabError(f"{root / CONFIG_NAME}: the lab folder {parent} does not exist; "
                           "create it (cobotlab labs new NAME) or remove it from lab_folders")
        for folder in sorted(p for p in parent.iterdir() if (p / SCORING_FILE).is_file()):
            lab = _lab_in(folder, folder.name, root)
            if lab.name in labs:
                raise LabError(f"two labs are named {lab.name}: {labs[lab.name].folder} and "
                               f"{folder}; rename one folder (and its notebook and spec)")
            labs[lab.name] = lab
    return labs


def _here_lab() -> Lab | None:
    """The lab whose folder is the current one, if it is an instructor's lab (a notebook
    ``<folder name>.ipynb`` beside a ``scoring.py``): a student's download or a kernel."""
    try:
        here = Path.cwd()
        if (here / SCORING_FILE).is_file() and (here / f"{here.name}.ipynb").is_file():
            return _lab_in(here, here.name, None)
    except OSError:
        pass
    return None


_table: dict[str, Lab] | None = None


def all_labs() -> dict[str, Lab]:
    """{name: Lab}: the built-in labs, then the course's (an instructor's lab may not take a
    built-in lab's name), then the current folder's own lab. Nothing is imported."""
    global _table
    if _table is None:
        folder = builtin_folder()
        root = course_root()
        gone = set(removed_labs(root))
        table = {name: Lab(name, folder / name if (folder / name).is_dir() else None)
                 for name in builtin_names() if name not in gone}
        for name, lab in (_course_labs(root) if root is not None else {}).items():
            if name in table or name in gone:   # a removed built-in lab keeps its name
                raise LabError(f"{lab.folder}: {name} is the name of a built-in lab; rename "
                               "the folder, its notebook and its spec")
            table[name] = lab
        here = _here_lab()
        if here is not None and here.name not in table:
            table[here.name] = here
        _table = table
    return _table


def _clear() -> None:
    global _table
    _table = None
    _scoring.clear()
    _specs.clear()
    for module_name in _loaded_files:   # another course may have a lab of the same name
        sys.modules.pop(module_name, None)
    _loaded_files.clear()


def lab_names() -> list[str]:
    return sorted(all_labs())


def source_folders(builtin_dir=None) -> dict[str, Path]:
    """{name: source folder} of every lab whose notebook is on this machine: the built-in
    labs' (from ``builtin_dir`` when given, every folder there with a notebook) and the
    course's."""
    folder = Path(builtin_dir) if builtin_dir is not None else builtin_folder()
    found = {}
    if folder.is_dir():
        gone = set(removed_labs(course_root()))
        found = {p.name: p for p in sorted(folder.iterdir())
                 if p.is_dir() and any(p.glob("*.ipynb")) and p.name not in gone}
    for name, lab in all_labs().items():
        if not lab.builtin and lab.folder is not None:
            found[name] = lab.folder
    return dict(sorted(found.items()))


def find_lab(name: str) -> Lab:
    """The lab called ``name``, or LabError listing the labs there are."""
    labs = all_labs()
    if name not in labs:
        raise LabError(f"no lab named {name!r}; the labs are {', '.join(sorted(labs))}")
    return labs[name]


# --------------------------------------------------------------------------- loading


def _load_file(module_name: str, path: Path, what: str, fix: str):
    """Import ``path`` as ``module_name``; any failure becomes a LabError naming the file."""
    if not path.is_file():
        raise LabError(f"{path}: {what} not found; {fix}")
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    _loaded_files.append(module_name)
    try:
        # compiled from the source every time, never from a cached .pyc: the cache is keyed by
        # the file's mtime in seconds and its size, so a spec edited and put back within one
        # second (a tolerance 6.0 -> 2.0 -> 6.0) would load the edited code
        exec(spec.loader.source_to_code(path.read_bytes(), str(path)), module.__dict__)
    except Exception as exc:  # noqa: BLE001 - an author's file: say which and why
        sys.modules.pop(module_name, None)
        line = ""
        tb = exc.__traceback__
        while tb is not None:
            if tb.tb_frame.f_code.co_filename == str(path):
                line = f" (line {tb.tb_lineno})"
            tb = tb.tb_next
        raise LabError(f"{path}{line}: {what} failed to load: {type(exc).__name__}: {exc}; "
                       f"fix the file, then run `cobotlab labs verify` on the lab") from None
    return module


def raised_at(exc: BaseException) -> str:
    """Where ``exc`` was raised: "FILE, line N" of its innermost frame."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    return f"{frames[-1].filename}, line {frames[-1].lineno}" if frames else "no traceback"


def _specs_of(module, path, what: str) -> tuple:
    from autograder.spec_types import FunctionSpec

    found = getattr(module, "SPECS", None)
    if not isinstance(found, tuple) or not found or not all(
            isinstance(s, FunctionSpec) for s in found):
        raise LabError(f"{path}: {what} must define SPECS, a non-empty tuple of FunctionSpec")
    names = [s.name for s in found]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise LabError(f"{path}: {', '.join(twice)} graded twice in SPECS; a lab grades each "
                       "function once (give one of them another name)")
    return found


_scoring: dict[str, tuple] = {}
_loaded_files: list[str] = []
_specs: dict[str, tuple] = {}


def public_scoring(name: str):
    """The public scoring module of lab ``name`` (a private spec completes its entries)."""
    lab = find_lab(name)
    if lab.builtin:
        return importlib.import_module(f"autograder.scoring.{name}")
    module_name = f"cobotlab_lab_{name}_scoring"
    if module_name in sys.modules:
        return sys.modules[module_name]
    return _load_file(module_name, lab.scoring_file, "the lab's public scoring",
                      "it defines SPECS, the public FunctionSpec entries (see docs/authoring.md)")


def scoring(name: str) -> tuple:
    """The public scoring entries of lab ``name`` (what ``check()`` scores with)."""
    if name not in _scoring:
        lab = find_lab(name)
        module = public_scoring(name)
        _scoring[name] = _specs_of(module, lab.scoring_file or module.__file__,
                                   "the public scoring")
    return _scoring[name]


def spec_path(name: str) -> Path | None:
    """Where lab ``name``'s private spec is (None: a built-in lab without its package)."""
    lab = find_lab(name)
    if not lab.builtin:
        return lab.spec_file
    found = importlib.util.find_spec("autograder.specs")
    if found is None or not found.origin or not found.origin.endswith("__init__.py"):
        return None
    return Path(found.origin).parent / f"{name}.py"


def private_available(name: str) -> bool:
    """Whether lab ``name``'s private spec is on this machine (an instructor's install)."""
    try:
        path = spec_path(name)
    except LabError:
        return False
    try:
        return path is not None and path.is_file()
    except OSError:
        return False


def specs(name: str) -> tuple:
    """The full specs of lab ``name``: the public entries completed by the private spec
    (generators, truths, code mistakes). Raises LabError when it is missing or broken."""
    if name not in _specs:
        lab = find_lab(name)
        path = spec_path(name)
        if path is None or not path.is_file():
            raise LabError(f"{path or 'autograder/specs'}: the private spec of {name} is not on "
                           "this machine; it holds the hidden problems, so only the instructor's "
                           "install or course repository has it")
        if lab.builtin:
            module = importlib.import_module(f"autograder.specs.{name}")
        else:
            module = _load_file(f"cobotlab_lab_{name}_spec", path, "the lab's private spec",
                                "it defines SPECS, the public entries completed with "
                                "make_trial (see docs/authoring.md)")
        full = _specs_of(module, path, "the private spec")
        public = [s.name for s in scoring(name)]
        if [s.name for s in full] != public:
            raise LabError(f"{path}: SPECS grades {[s.name for s in full]} but the public "
                           f"scoring grades {public}; the two must list the same functions in "
                           "the same order")
        missing = [s.name for s in full if s.make_trial is None]
        if missing:
            raise LabError(f"{path}: {', '.join(missing)} has no make_trial; complete the "
                           "public entry with dataclasses.replace(entry, make_trial=...)")
        _specs[name] = full
    return _specs[name]


def verification_path(name: str) -> Path:
    """Where ``cobotlab labs verify`` keeps lab ``name``'s evidence: beside the private specs,
    in ``.cobotlab/verified/`` of the course (of the current folder for a built-in lab
    outside a course)."""
    lab = find_lab(name)
    if not lab.builtin:
        return lab.spec_file.parent.parent / "verified" / f"{name}.json"
    return (course_root() or Path.cwd()) / ".cobotlab" / "verified" / f"{name}.json"


def _verification(name: str) -> tuple[Path, dict | None, bool]:
    """(where lab ``name``'s verify record is, the record or None, whether it was made of the
    lab as it is now). A record holds ``spec_hash`` and, since verify recorded it,
    ``lab_digest`` (the notebook and its data too): both must match, so an edit of any file
    after verify makes the lab unverified."""
    import json

    path = verification_path(name)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return path, None, False
    if not isinstance(record, dict):
        return path, None, False
    current = record.get("spec_hash") == spec_hash(name) and (
        "lab_digest" not in record or record["lab_digest"] == lab_digest(name))
    return path, record, current


def verification_note(name: str) -> str | None:
    """None when lab ``name`` was verified as it is now, else a warning saying what to run.
    The built-in labs are verified by the project (docs/benchmarks/grading_fairness.md)
    unless their files were changed locally and verified since."""
    path, record, current = _verification(name)
    if record is None:
        if find_lab(name).builtin:
            return None
        return (f"{name} was never verified: run `cobotlab labs verify {name}` before grading "
                "it (it shows whether correct code can lose credit on the hidden problems)")
    if not current:
        return (f"{name} changed since it was last verified ({path}): run `cobotlab labs "
                f"verify {name}` again")
    if not record.get("passed"):
        return f"{name} failed its last verification ({path}): see its report and fix the lab"
    return None


def release_problem(name: str, force: bool = False) -> str | None:
    """Why lab ``name`` must not be released (laid out by ``course init``, written by ``labs
    student``), as one sentence with the fix; None when it may be. Two reasons: its files
    fail to load (its scoring, its private spec, or its generators drawing the practice
    problems: the caller draws those, see :func:`autograder.practice.build_practice`), or
    its last ``cobotlab labs verify`` failed and the lab has not changed since (an edited
    lab is unverified: it may be released, with :func:`verification_note`'s warning).
    ``force`` releases a lab that failed verify; one that does not load never is."""
    try:
        scoring(name)
        specs(name)
    except LabError as exc:
        return f"it does not load: {exc}"
    path, record, current = _verification(name)
    if force or record is None or not current or record.get("passed"):
        return None
    findings = record.get("findings") or [{}]
    first = findings[0].get("message", "") if isinstance(findings[0], dict) else ""
    first = " ".join(str(first).split())
    if len(first) > 200:
        first = first[:197] + "..."
    more = f" (and {len(findings) - 1} more)" if len(findings) > 1 else ""
    where = find_lab(name).folder or name
    return (f"it failed `cobotlab labs verify` ({path}: {first or 'see the report'}{more}); "
            f"fix the lab and run `cobotlab labs verify {where}` again, or pass --force to "
            "release it as it is")


def loaded_specs() -> dict[str, tuple]:
    """{name: full specs} of the labs whose private spec this process has loaded so far."""
    return dict(_specs)


def spec_hash(name: str) -> str:
    """A hash of everything that decides lab ``name``'s grades: its public scoring and its
    private spec, as files (16 hex digits). ``labs verify`` records it, ``grade`` compares."""
    lab = find_lab(name)
    scoring_file = lab.scoring_file or Path(public_scoring(name).__file__)
    digest = hashlib.sha256()
    for path in (scoring_file, spec_path(name)):
        digest.update(path.read_bytes() if path is not None and path.is_file() else b"-")
    return digest.hexdigest()[:16]


# Left in a lab folder by a kernel, an editor or `check()`, not part of the lab.
LEFT_BEHIND = ("practice_*.json.gz", "__pycache__", "*_results", ".ipynb_checkpoints")


def lab_digest(name: str) -> str:
    """A digest of everything of lab ``name`` that ``labs verify`` checks (16 hex digits):
    :func:`spec_hash` and every file of its folder (the notebook and its data) but what
    :data:`LEFT_BEHIND` names. ``labs verify`` records it; :func:`verification_note` and
    :func:`release_problem` compare it, so a lab edited after verify is unverified."""
    import fnmatch

    lab = find_lab(name)
    digest = hashlib.sha256(spec_hash(name).encode())
    if lab.folder is not None and lab.folder.is_dir():
        for path in sorted(lab.folder.rglob("*")):
            relative = path.relative_to(lab.folder)
            if any(fnmatch.fnmatch(part, pattern) for part in relative.parts
                   for pattern in LEFT_BEHIND) or not path.is_file():
                continue
            digest.update(relative.as_posix().encode("utf-8", "surrogateescape") + b"\0")
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:16]

"""What student code may see: an allow list of files, the same in every install.

The grading worker and nbgrader's kernel run student code in a bubblewrap sandbox
(:mod:`autograder.sandbox`) whose root holds nothing but what is listed here:

* the operating system read-only (``/usr``, ``/etc``, ``/lib*``), with every Python package
  directory in it (``site-packages``, ``dist-packages``) emptied;
* the interpreter: its executable, its shared library, the standard library (its own
  ``site-packages`` emptied too) and, in a virtual environment, ``pyvenv.cfg``;
* in every package directory on the interpreter's path, only the distributions a lab
  notebook needs: the dependency closure of cobotlab's own requirements and of the
  notebook's front-end libraries (read from the installed metadata, so the same list holds
  for an editable install, a regular one, a container image or a cluster worker's);
* of cobotlab itself, ``robots/`` and ``sim_backends/`` (what the labs run on) and the listed
  modules of ``autograder/`` (the worker's own, the practice data's; never the specs,
  the grading, the course or ``solutions/``).

Anything else (``solutions/``, ``autograder/specs/``, the course, the source notebooks,
the secret, ``$HOME``, a checkout) is absent from the view because it was never listed,
not because a list of forbidden places named it.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import re
import site
import sys
import sysconfig
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path

__all__ = ["View", "interpreter_view", "worker_view", "kernel_view", "OWN_PACKAGES",
           "WORKER_MODULES", "KERNEL_MODULES"]

# cobotlab's packages a lab notebook imports, bound whole: student-facing by design (the
# student install ships them as they are).
OWN_PACKAGES = ("robots", "sim_backends")
# The parts of autograder/ the grading worker needs: itself, the namespaces and the keyring
# filter of a template's forks, its wire protocol, the forbidden-routine tripwire, the
# stand-ins, and the practice data the notebooks import.
WORKER_MODULES = ("__init__.py", "inside", "datasets.py", "synthetic.py", "data")
# nbgrader's kernel runs the notebook's hidden_test cells: the public scoring and the
# practice problems of the kernel seeds (data, not the generators behind them).
KERNEL_MODULES = WORKER_MODULES + ("checks.py", "spec_types.py", "mistakes.py", "practice.py",
                                   "registry.py", "forbidden.py", "outcomes.py", "errors.py",
                                   "scoring", "families", "nbgrader_hooks.py")
# Distributions whose closure a lab notebook may import besides cobotlab's requirements
# (the notebook's own display libraries), and what nbgrader's run needs on top.
NOTEBOOK_DISTRIBUTIONS = ("ipython", "ipywidgets")
NBGRADER_DISTRIBUTIONS = ("nbgrader", "ipykernel")
_PACKAGE_DIRS = ("site-packages", "dist-packages")


@dataclass(frozen=True)
class View:
    """``ro``: host paths bound read-only at the same place. ``masked``: (directory, the
    host paths inside it that stay visible); the directory itself is replaced by an empty
    read-only one holding only those. ``notes``: what could not be listed, for the run log."""

    ro: tuple[str, ...]
    masked: tuple[tuple[str, tuple[str, ...]], ...]
    notes: tuple[str, ...] = ()

    def paths(self) -> tuple[str, ...]:
        """Every host path the view shows (for tests and the run log)."""
        return self.ro + tuple(p for _, kept in self.masked for p in kept)


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _existing(paths) -> list[str]:
    return [p for p in dict.fromkeys(paths) if p and os.path.lexists(p)]


def _interpreter() -> tuple[list[str], list[str]]:
    """(files and trees to bind whole, package directories inside them to empty)."""
    ro = [sys.executable]
    # Every link on the way to the binary: a view that binds the venv's bin/ whole (the
    # kernel's) shows python -> python3 -> <base>/bin/python3 -> python3.11 as links.
    path = sys.executable
    while os.path.islink(path) and len(ro) < 16:
        path = os.path.join(os.path.dirname(path), os.readlink(path))
        ro.append(os.path.normpath(path))
    ro.append(os.path.realpath(sys.executable))
    if sysconfig.get_config_var("Py_ENABLE_SHARED"):
        libdir, library = sysconfig.get_config_var("LIBDIR"), sysconfig.get_config_var(
            "LDLIBRARY")
        if libdir and library:
            shared = os.path.join(libdir, library)
            ro += [shared, os.path.realpath(shared)]
    stdlib = [sysconfig.get_paths()["stdlib"], sysconfig.get_paths()["platstdlib"]]
    stdlib += [p for p in sys.path if p.endswith("lib-dynload") or p.endswith(".zip")]
    ro += stdlib
    if sys.prefix != sys.base_prefix:   # a virtual environment: python finds it by this
        ro.append(os.path.join(sys.prefix, "pyvenv.cfg"))
    # A standard library may hold the base interpreter's own site-packages (pyenv, the
    # python.org images): bound with it, so emptied like every other package directory.
    emptied = [os.path.join(d, name) for d in stdlib for name in _PACKAGE_DIRS]
    return _existing(ro), _existing(emptied)


def _package_dirs() -> list[str]:
    """Every directory Python packages may live in, on the path or under /usr."""
    found = [p for p in sys.path if p and os.path.isdir(p)]
    found += site.getsitepackages() if hasattr(site, "getsitepackages") else []
    found += [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    for pattern in ("/usr/lib/python3*/*-packages", "/usr/local/lib/python3*/*-packages",
                    "/usr/lib/python3/dist-packages"):
        found += glob.glob(pattern)
    return [os.path.realpath(p) for p in _existing(found)
            if os.path.basename(p.rstrip("/")) in _PACKAGE_DIRS]


def _distribution(name: str) -> metadata.Distribution | None:
    """The installed distribution ``name`` as the sandboxed interpreter finds it: on the
    path but not in the current folder (a checkout's stray ``*.egg-info`` would answer
    first there, with another file list)."""
    search = [p for p in sys.path if p and os.path.isabs(p)
              and os.path.realpath(p) != os.path.realpath(os.getcwd())]
    for dist in metadata.distributions(name=name, path=search):
        return dist
    return None


def _requirements(dist: metadata.Distribution, extras=()) -> list[tuple[str, tuple]]:
    """(name, extras asked for) of the distributions ``dist`` needs with ``extras`` (markers
    evaluated here: nbconvert needs ``bleach[css]``, whose ``css`` extra brings tinycss2)."""
    try:
        from packaging.requirements import InvalidRequirement, Requirement
    except ImportError:   # packaging comes with matplotlib; without it, plain names only
        return [(re.split(r"[\s;<>=!~\[(]", r, maxsplit=1)[0], ()) for r in dist.requires or ()
                if "extra ==" not in r and "extra==" not in r]
    names = []
    for text in dist.requires or ():
        try:
            req = Requirement(text)
        except InvalidRequirement:
            continue
        if req.marker is None or any(req.marker.evaluate({"extra": e})
                                     for e in ("", *extras)):
            names.append((req.name, tuple(sorted(req.extras))))
    return names


def _closure(roots) -> dict[str, metadata.Distribution]:
    """The installed distributions ``roots`` (names) need, transitively, by canonical name."""
    seen: dict[str, metadata.Distribution] = {}
    done: set[tuple[str, tuple]] = set()
    todo = [(name, ()) for name in roots]
    while todo:
        name, extras = todo.pop()
        key = (_canonical(name), extras)
        if key in done or key[0] == "cobotlab":
            continue
        done.add(key)
        dist = seen.get(key[0]) or _distribution(key[0])
        if dist is None:
            continue   # an optional library not installed here
        seen[key[0]] = dist
        todo += _requirements(dist, extras)
    return seen


def _top_level(dist: metadata.Distribution) -> tuple[list[str], str | None]:
    """(host paths of the distribution's top-level entries, a note if they are unknown)."""
    entries: set[str] = set()
    for f in dist.files or ():
        parts = Path(f).parts
        if not parts or parts[0] == "..":
            continue
        # A top-level module's bytecode sits in the folder's shared __pycache__: only its own
        # file, not the folder (which caches every other top-level module too).
        top = f if parts[0] == "__pycache__" else parts[0]
        entries.add(str(dist.locate_file(top)))
    if not entries:   # no RECORD (an old or a system install): its import names instead
        names = (dist.read_text("top_level.txt") or "").split()
        entries = {str(dist.locate_file(n)) for n in names}
        entries |= {str(dist.locate_file(n + ".py")) for n in names}
    own = getattr(dist, "_path", None)   # its .dist-info: versions read at import time
    if own is not None:
        entries.add(str(own))
    found = _existing(os.path.realpath(e) for e in entries)
    if not found:
        return [], f"{dist.metadata['Name']}: its files are not listed (no RECORD, no " \
                   "top_level.txt); it is not in the sandbox's view"
    return found, None


def _own_distribution() -> list[str]:
    """Of cobotlab's own installed files: its metadata and an editable install's finder
    (which maps the package names to the checkout; the checkout itself is not bound)."""
    dist = _distribution("cobotlab")
    if dist is None:
        return []
    kept = [str(dist._path)] if getattr(dist, "_path", None) is not None else []
    for f in dist.files or ():
        name = Path(f).name
        if len(Path(f).parts) == 1 and name.startswith("__editable__"):
            kept.append(str(dist.locate_file(f)))
    return _existing(os.path.realpath(p) for p in kept)


def _package_dir(name: str) -> str | None:
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return None
    return os.path.realpath(list(spec.submodule_search_locations)[0])


def _module_files(package_dir: str, names) -> list[str]:
    """The listed files and folders of a package, each .py with its cached bytecode."""
    kept = []
    for name in names:
        path = os.path.join(package_dir, name)
        kept.append(path)
        if name.endswith(".py"):
            kept.append(importlib.util.cache_from_source(path))
    return _existing(kept)


def _build(distributions, autograder_modules, extra_ro=()) -> View:
    ro, emptied = _interpreter()
    notes: list[str] = []
    allowed: list[str] = _own_distribution()
    for dist in _closure(distributions).values():
        paths, note = _top_level(dist)
        allowed += paths
        if note:
            notes.append(note)
    own_dirs = {name: _package_dir(name) for name in (*OWN_PACKAGES, "autograder")}
    allowed += [d for name, d in own_dirs.items() if d and name in OWN_PACKAGES]
    masked: dict[str, list[str]] = {d: [] for d in emptied + _package_dirs()}
    for path in dict.fromkeys(allowed):
        parent = os.path.dirname(path)
        if parent in masked:
            masked[parent].append(path)
        else:   # outside every package directory (an editable checkout): bound on its own
            ro.append(path)
    grader = own_dirs["autograder"]
    if grader:
        masked.setdefault(grader, [])
        masked[grader] += _module_files(grader, autograder_modules)
    ro += _existing(extra_ro)
    return View(tuple(dict.fromkeys(ro)),
                tuple((d, tuple(dict.fromkeys(kept))) for d, kept in masked.items()),
                tuple(notes))


def _roots(course_packages: tuple[str, ...]) -> list[str]:
    own = _distribution("cobotlab")
    return [name for name, _ in (_requirements(own) if own is not None else [])] + list(
        NOTEBOOK_DISTRIBUTIONS) + list(course_packages)


@lru_cache(maxsize=1)
def interpreter_view() -> View:
    """The interpreter alone (the sandbox probe's view)."""
    ro, emptied = _interpreter()
    return View(tuple(ro), tuple((d, ()) for d in emptied + _package_dirs()))


@lru_cache(maxsize=4)
def worker_view(course_packages: tuple[str, ...] = ()) -> View:
    """What the grading worker sees: a lab notebook's libraries and nothing of the grader.
    ``course_packages``: the distributions a course adds for its own labs
    (:func:`autograder.registry.notebook_packages`)."""
    return _build(_roots(course_packages), WORKER_MODULES)


@lru_cache(maxsize=4)
def kernel_view(course_packages: tuple[str, ...] = ()) -> View:
    """What nbgrader's autograde and its kernel see: the worker's view, nbgrader's own
    closure and its command-line scripts and data files, and the public scoring."""
    prefix = sys.prefix
    return _build(_roots(course_packages) + list(NBGRADER_DISTRIBUTIONS), KERNEL_MODULES,
                  extra_ro=(os.path.join(prefix, "bin"),
                            os.path.join(prefix, "share", "jupyter")))

"""The students' copies of the labs: nbgrader's release versions, without an nbgrader course.

``labs/`` in the repository holds the instructor's source notebooks, with every
``### BEGIN SOLUTION`` region and hidden test. :func:`write_student_labs` runs each one through
the preprocessors ``nbgrader generate_assignment`` uses (solutions replaced by the code stub,
hidden tests and mark schemes removed, outputs cleared, cells locked and checksummed), checks
that nothing of the answers is left, and writes it with the lab's other files into a folder
students can be given, with the lab's practice problems as data beside the notebook
(``check()`` scores on them: the generators stay with the instructor, see
:mod:`autograder.practice`). Only the gradebook step is left out: that belongs to the course.
"""

from __future__ import annotations

import shutil
from pathlib import Path

__all__ = ["RELEASE_LEAKS", "lab_names", "release_notebook", "write_student_labs"]



def _default_labs() -> Path:
    from autograder.course import LABS_DIR

    return LABS_DIR

# Text that only an instructor's notebook holds. A release still carrying one is refused.
RELEASE_LEAKS = ("BEGIN SOLUTION", "END SOLUTION", "BEGIN HIDDEN TESTS", "END HIDDEN TESTS",
                 "BEGIN MARK SCHEME", "hidden_test", "import solutions", "from solutions")

# nbgrader's own stub, written out so the release does not depend on a course's config.
CODE_STUB = "# YOUR CODE HERE\nraise NotImplementedError()"

_SKIP = shutil.ignore_patterns(".ipynb_checkpoints", "__pycache__", "*_results", "*.ipynb")

_README = """\
# cobotlab labs: student notebooks

Made by `cobotlab labs student` from the course's source notebooks: the graded functions are
empty (`raise NotImplementedError()`), ready for your code. Open this folder in JupyterLab
(`jupyter lab`), start with `lab0_frames/`, and run the cells top to bottom. After each function
you write, its `check(...)` cell scores it on practice problems the way the grader will on
hidden ones.

{labs}
"""


def _sources(labs_dir) -> dict[str, Path]:
    """{name: source folder} of the labs: the built-in ones (those in ``labs_dir`` instead,
    when given) and the current course's (:mod:`autograder.registry`)."""
    from autograder import registry

    sources = registry.source_folders(labs_dir)
    if not sources:
        where = labs_dir if labs_dir is not None else _default_labs()
        raise FileNotFoundError(
            f"no lab sources at {where}: `cobotlab labs student` turns the instructor's source "
            "notebooks (labs/ in the cobotlab repository, or a course's own lab folders) into "
            "student copies, so run it from the full checkout or the course, or ask your "
            "instructor for the student notebooks")
    return sources


def lab_names(labs_dir=None) -> list[str]:
    """Names of the labs (built in, or in ``labs_dir``, and the course's), sorted."""
    return sorted(_sources(labs_dir))


def release_notebook(path):
    """The release version (an ``nbformat`` notebook) of the source notebook at ``path``.

    Runs nbgrader's ``generate_assignment`` preprocessors in its order, minus the gradebook
    (``SaveCells``) and the header/footer and test-instantiation steps the labs do not use.
    Raises ``ValueError`` naming the cell if any solution or hidden-test text survives.
    """
    import nbformat
    from nbgrader.preprocessors import (
        CheckCellMetadata,
        ClearHiddenTests,
        ClearMarkScheme,
        ClearOutput,
        ClearSolutions,
        ComputeChecksums,
        LockCells,
    )

    path = Path(path)
    nb = nbformat.read(path, as_version=nbformat.NO_CONVERT)
    resources: dict = {"metadata": {"path": str(path.parent)}}
    # ClearHiddenTests must follow the checksums (nbgrader's own note), and the checksums are
    # computed again on what the students get.
    steps = [LockCells(), ClearSolutions(code_stub={"python": CODE_STUB}), ClearOutput(),
             CheckCellMetadata(), ComputeChecksums(), ClearHiddenTests(), ClearMarkScheme(),
             ComputeChecksums(), CheckCellMetadata()]
    for step in steps:
        nb, resources = step.preprocess(nb, resources)
    for index, cell in enumerate(nb.cells):
        leaks = [word for word in RELEASE_LEAKS if word in cell.source]
        if leaks:
            raise ValueError(f"{path.name}: cell {index} still holds {', '.join(leaks)} after "
                             "nbgrader's preprocessors; mark the region with ### BEGIN/END "
                             "SOLUTION (or HIDDEN TESTS) in a cell with nbgrader metadata")
    return nb


def write_student_labs(dest, labs_dir=None, labs=None, force: bool = False,
                       quiet: bool = False) -> list[Path]:
    """Write the student version of every lab (or of ``labs``) into ``dest``; return the paths.

    ``dest/<lab>/<lab>.ipynb`` is the release notebook of ``labs_dir/<lab>/`` (default: the
    repository's ``labs/``), beside copies of that lab's other files (data a lab reads from
    its own folder) and the lab's practice data (``practice_<lab>.json.gz``, what its
    ``check()`` cells score on); ``dest/README.md`` says how to start. An existing notebook
    is never overwritten unless ``force``: it may hold a student's work.

    A lab that does not load, whose notebook nbgrader cannot release, or whose last ``labs
    verify`` failed (unless ``force``) is skipped with one line on stderr (unless ``quiet``)
    naming it, why and the fix; the others are written. ValueError when none is left.
    """
    import sys

    import nbformat

    from autograder import checks, practice

    sources = _sources(labs_dir)
    names = list(labs) if labs else list(sources)
    unknown = [n for n in names if n not in sources]
    if unknown:
        raise ValueError(f"no lab named {', '.join(unknown)}; the labs are "
                         f"{', '.join(sources)}")
    data, skipped = practice.releasable([n for n in names if n in checks.SCORING], force)
    released = {}   # all of a lab or nothing of it, before anything is written
    for name in names:
        if name in skipped:
            continue
        try:
            released[name] = {source: release_notebook(source)
                              for source in sorted(sources[name].glob("*.ipynb"))}
        except ValueError as exc:
            skipped[name] = f"nbgrader cannot release its notebook: {exc}"
    names = [n for n in names if n not in skipped]
    if not names:
        raise ValueError("no lab left to write: " + "; ".join(
            f"{name}: {why}" for name, why in skipped.items()))
    dest = Path(dest)
    planned = {source: dest / name / source.name
               for name in names for source in released[name]}
    existing = [str(p) for p in planned.values() if p.exists()]
    if existing and not force:
        verb = "already exists" if len(existing) == 1 else "already exist"
        raise FileExistsError(f"{', '.join(existing)} {verb} and may hold your work; write "
                              "into a new folder, or pass --force to replace them")
    written = []
    for name in names:
        shutil.copytree(sources[name], dest / name, ignore=_SKIP, dirs_exist_ok=True)
        if name in data:
            practice.save_practice(data[name], dest / name)
        for source, notebook in released[name].items():
            nbformat.write(notebook, planned[source])
            written.append(planned[source])
    listing = "\n".join(f"- `{name}/`" for name in names)
    (dest / "README.md").write_text(_README.format(labs=listing))
    if not quiet:
        for name, why in skipped.items():
            print(f"cobotlab: skipped lab {name}: {why}", file=sys.stderr)
    return written

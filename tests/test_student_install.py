"""The student install: every lab runs in it, and the reference solvers are not in it.

Builds the `cobotlab-student` wheel (student/pyproject.toml) from a copy of the repository's
packages, installs it into a fresh virtual environment (no system site-packages; its
dependencies from the package registry), then, in that environment's own Jupyter kernel, runs
the student copy of lab 0 with correct answers filled in and tries `import solutions`. It also
imports every module any lab imports there, and runs the instructor-only commands to see them
refuse in one line. Costs about 1-3 minutes, most of it pip installing the dependencies.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import course_kit as kit
import nbformat
import pytest
import tomllib

from autograder import checks
from autograder.course import LABS_DIR
from cobotlab.labs import write_student_labs

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("cobotlab", "robots", "sim_backends", "autograder")

# Installing JupyterLab and PyBullet into a fresh environment takes minutes on a busy machine:
# more than the suite's default 300 s per test, which counts the fixtures' setup.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1200)]

# Run inside the student environment: execute each notebook with that environment's kernel.
RUNNER = """
import sys
import nbformat
from nbclient import NotebookClient

for path in sys.argv[1:]:
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(__import__("pathlib").Path(path).parent)}}
                   ).execute()
    nbformat.write(nb, path)
"""

PROBE = """\
import sys
try:
    import solutions
except ModuleNotFoundError as err:
    print("import solutions raised:", err)
else:
    print("import solutions worked:", solutions.__file__)
print("kernel prefix:", sys.prefix)
"""


def _run(command, **kwargs) -> subprocess.CompletedProcess:
    done = subprocess.run(command, capture_output=True, text=True, timeout=900, **kwargs)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done


# A fixture that failed once is not retried by every later test (each retry costs minutes).
_FAILED: dict[str, str] = {}


def _once(name: str, build):
    if name in _FAILED:
        pytest.fail(f"{name} could not be built earlier in this run: {_FAILED[name]}")
    try:
        return build()
    except BaseException as exc:
        _FAILED[name] = f"{type(exc).__name__}: {str(exc)[:500]}"
        raise


@pytest.fixture(scope="module")
def wheel() -> Path:
    return _once("the student wheel", _build_wheel)


def _build_wheel() -> Path:
    """The student wheel, built once per test run (tests/test_answer_free.py reads the same
    one)."""
    (found,) = kit.built_once("student-wheel", _build_student_wheel).glob(
        "cobotlab_student-*.whl")
    return found


def _build_student_wheel(dist: Path) -> None:
    # A copy, so no build/ or egg-info from an earlier build can slip files in.
    src = dist / "src"
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for name in (*PACKAGES, "student"):
        shutil.copytree(ROOT / name, src / name, ignore=skip)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", str(src / "student"),
          "-w", str(dist)])
    shutil.rmtree(src)


@pytest.fixture(scope="module")
def student_env(tmp_path_factory, wheel) -> Path:
    return _once("the student environment", lambda: _build_env(tmp_path_factory, wheel))


def _build_env(tmp_path_factory, wheel) -> Path:
    env_dir = tmp_path_factory.mktemp("student-venv")
    venv.EnvBuilder(with_pip=True, system_site_packages=False, clear=True).create(env_dir)
    python = env_dir / "bin" / "python"
    # --no-compile: the test imports each module once, so byte-compiling all of JupyterLab
    # and its dependencies up front would only cost time. --only-binary: a student's laptop
    # has no compiler, so every dependency must come as a wheel (issue 49).
    _run([str(python), "-m", "pip", "install", "--quiet", "--no-compile",
          "--only-binary", ":all:", str(wheel)])
    return env_dir


def _env(student_env: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{student_env / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    # Kernel specs only from the student environment, not from the user's Jupyter folders.
    env["JUPYTER_PATH"] = str(student_env / "share" / "jupyter")
    env["JUPYTER_DATA_DIR"] = str(student_env / "share" / "jupyter")
    env.update(MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return env


def test_the_wheel_holds_no_solutions(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} >= set(PACKAGES)
    assert not any(n.startswith("solutions/") for n in names), names
    assert not any(n.endswith(".ipynb") for n in names)
    assert any(n.startswith("autograder/data/") and n.endswith(".npz") for n in names)
    assert not any(n.startswith("autograder/specs/") for n in names), names
    assert not any(n.startswith("cobotlab/templates/") for n in names), names   # labs new
    assert "autograder/scoring/__init__.py" in names and "autograder/practice.py" in names
    assert any(n.startswith("sim_backends/urdf/") for n in names)


def test_students_md_installs_the_wheel_built_here(wheel):
    """docs/students.md's steps are this test's: a venv, pip install of this very wheel
    (on Windows through the venv's Scripts folder), then JupyterLab from the venv."""
    text = (ROOT / "docs" / "students.md").read_text()
    posix, windows = (text.split(f"```{kind}\n", 1)[1].split("```", 1)[0]
                      for kind in ("sh", "powershell"))
    assert "python3 -m venv ~/cobotlab-env" in posix
    assert f"~/cobotlab-env/bin/pip install {wheel.name}" in posix, posix
    assert "~/cobotlab-env/bin/jupyter lab" in posix
    assert f"Scripts\\pip install {wheel.name}" in windows, windows
    assert "Scripts\\jupyter lab" in windows


def test_student_pyproject_keeps_up_with_the_main_one():
    main = tomllib.loads((ROOT / "pyproject.toml").read_text())
    student = tomllib.loads((ROOT / "student" / "pyproject.toml").read_text())
    # What a student's JupyterLab runs: the runtime dependencies and the course extra, whose
    # nbgrader is for the instructor's course tools.
    needed = set(main["project"]["dependencies"]) | {
        d for d in main["project"]["optional-dependencies"]["course"] if "nbgrader" not in d}
    missing = needed - set(student["project"]["dependencies"])
    assert not missing, f"add {sorted(missing)} to student/pyproject.toml"
    assert student["project"]["version"] == main["project"]["version"]
    main_data = main["tool"]["setuptools"]["package-data"]
    student_data = student["tool"]["setuptools"]["package-data"]
    # Except the skeleton of `cobotlab labs new`: its private spec template is an answer key
    # (a lab made from it unchanged grades on exactly those problems), and students write
    # no labs.
    assert main_data["cobotlab"] == ["templates/*/*"]
    assert student_data == {k: v for k, v in main_data.items()
                            if k in PACKAGES and k != "cobotlab"}
    included = student["tool"]["setuptools"]["packages"]["find"]["include"]
    assert sorted(included) == sorted(f"{name}*" for name in PACKAGES)
    # The private side (generators, truths, answer functions) stays out, and so do the
    # instructors' templates (the hub's config, `labs new`'s skeleton); the rest is kept.
    excluded = student["tool"]["setuptools"]["packages"]["find"]["exclude"]
    assert sorted(excluded) == ["autograder.specs", "autograder.specs.*", "cobotlab.templates*"]


def _lab_imports() -> set[str]:
    """Top-level modules imported by any cell of any lab (parsed, not guessed)."""
    found = set()
    for path in sorted(LABS_DIR.glob("*/*.ipynb")):
        for cell in nbformat.read(path, as_version=4).cells:
            if cell.cell_type != "code":
                continue
            for node in ast.walk(ast.parse(cell.source)):
                if isinstance(node, ast.Import):
                    found.update(a.name for a in node.names)
                elif isinstance(node, ast.ImportFrom) and node.module:
                    found.add(node.module)
                    found.update(f"{node.module}.{a.name}" for a in node.names)
    return found


def test_every_module_the_labs_import_loads_without_solutions(student_env):
    modules = sorted(_lab_imports())
    assert "autograder.checks" in modules and "robots.capture" in modules
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    try:\n"
        "        importlib.import_module(name)\n"
        "    except ModuleNotFoundError:\n"
        "        parent, _, attr = name.rpartition('.')\n"
        "        assert hasattr(importlib.import_module(parent), attr), name\n"
        "assert 'solutions' not in sys.modules, 'a lab module imported solutions'\n"
        "print('ok', len(sys.modules))\n")
    done = _run([str(student_env / "bin" / "python"), "-c", code], env=_env(student_env),
                cwd=student_env)
    assert done.stdout.startswith("ok")


def _with_answers(release: Path, source: Path) -> None:
    """Fill each graded function's stub in ``release`` with the source's solution."""
    answers = {}
    for cell in nbformat.read(source, as_version=4).cells:
        meta = cell.metadata.get("nbgrader", {})
        if meta.get("solution"):
            answers[meta["grade_id"]] = "\n".join(
                line for line in cell.source.splitlines()
                if line.strip() not in ("### BEGIN SOLUTION", "### END SOLUTION"))
    nb = nbformat.read(release, as_version=4)
    for cell in nb.cells:
        grade_id = cell.metadata.get("nbgrader", {}).get("grade_id")
        if grade_id in answers:
            cell.source = answers[grade_id]
    nb.cells.append(nbformat.v4.new_code_cell(PROBE))
    nbformat.write(nb, release)


def test_lab0_runs_in_the_student_env_and_solutions_is_missing(student_env, tmp_path):
    labs = tmp_path / "labs"
    (notebook,) = write_student_labs(labs, labs=["lab0_frames"])
    _with_answers(notebook, LABS_DIR / "lab0_frames" / "lab0_frames.ipynb")
    _run([str(student_env / "bin" / "python"), "-c", RUNNER, str(notebook)],
         env=_env(student_env), cwd=tmp_path)
    nb = nbformat.read(notebook, as_version=4)
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors, errors
    text = "".join(o.get("text", "") + o.get("data", {}).get("text/plain", "")
                   for c in nb.cells for o in c.get("outputs", []))
    for spec in checks.SPECS["lab0_frames"]:  # full marks from check(...) on every function
        assert f"{spec.name}: {spec.points:g} / {spec.points:g} points" in text, text
    assert "import solutions raised: No module named 'solutions'" in text, text
    # Lab 0's simulator cell ran on MuJoCo: the student install has no PyBullet at all.
    assert not list((student_env / "lib").glob("python*/site-packages/pybullet*")), \
        "the student install must not pull PyBullet in"
    assert list((student_env / "lib").glob("python*/site-packages/mujoco/__init__.py"))
    prefix = text.split("kernel prefix:")[1].split()[0]
    assert Path(prefix).resolve() == student_env.resolve(), prefix


@pytest.mark.parametrize("argv, command", [
    (["demo", "--synthetic"], "cobotlab demo --synthetic"),
    (["demo", "--quick"], "cobotlab demo"),
    (["calibrate", "some_capture"], "cobotlab calibrate"),
    # the import decides the pose file's conventions with the solvers' hand-eye checks
    (["data", "import", "poses.csv", "capture", "--corners", "corners.npz"],
     "cobotlab data import"),
])
def test_instructor_commands_say_in_one_line_what_is_missing(student_env, tmp_path, argv,
                                                             command):
    done = subprocess.run([str(student_env / "bin" / "cobotlab"), *argv], capture_output=True,
                          text=True, env=_env(student_env), cwd=tmp_path, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"cobotlab: error: {command} needs the reference solvers"), err
    assert "student install" in err and "full cobotlab" in err


def test_labs_student_needs_the_sources(student_env, tmp_path):
    done = subprocess.run([str(student_env / "bin" / "cobotlab"), "labs", "student", "out"],
                          capture_output=True, text=True, env=_env(student_env), cwd=tmp_path,
                          timeout=120)
    assert done.returncode == 2
    assert "no lab sources at" in done.stderr or "nbgrader" in done.stderr, done.stderr
    assert json.dumps(done.stderr).count("\\n") == 1

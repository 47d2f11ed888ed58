"""A regular install runs a course, and the answer key is out of student code's reach in every
install (issue 29, items 1 and 2).

Two installs are made outside the repository, each in a fresh virtual environment:

* **regular**: the wheel built from the repository, installed by pip (not editable), as a
  course server or a cluster worker's image has it;
* **editable**: a copy of the checkout installed with ``pip install -e``, as a developer has it.

The libraries both need are this environment's, hard-linked into the new one (no download,
a few seconds; pip installs cobotlab itself). In the regular install the whole course runs
from a temporary folder with no checkout in reach: ``cobotlab course init`` (docs/authoring.md's
steps), ``cobotlab labs student``, ``nbgrader generate_assignment``, ``cobotlab grade`` and the
demo. In both, marker files are planted in solutions/, the specs, autograder/ beside the
checks, the course, the source notebook and the secret, and a probe run in the grading
worker's view and in nbgrader's kernel view must neither read nor import any of them.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import uuid
import venv
from pathlib import Path

import course_kit as kit
import pytest
from test_cli import check_quick_demo

from autograder import sandbox

ROOT = Path(__file__).resolve().parent.parent
SOURCES = ("cobotlab", "robots", "sim_backends", "autograder", "solutions", "labs",
           "pyproject.toml", "README.md")
TOKEN = f"zz_marker_{uuid.uuid4().hex[:12]}"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500),
              pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                 reason="the views are bubblewrap's: " + "; ".join(
                                     sandbox.capabilities().evidence))]


def run(argv, **kwargs) -> subprocess.CompletedProcess:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=900, **kwargs)
    assert done.returncode == 0, (argv, done.stdout[-3000:], done.stderr[-3000:])
    return done


def _copy_sources(dest: Path) -> Path:
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", ".ipynb_checkpoints")
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=skip)
        else:
            shutil.copy2(src, dest / name)
    return dest


def _link_tree(src: Path, dst: Path) -> None:
    """``src`` copied to ``dst`` as hard links where the filesystem allows, else as copies."""
    def link(a, b):
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)
    shutil.copytree(src, dst, copy_function=link, symlinks=True, dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("__editable__*", "cobotlab-*.dist-info",
                                                  "cobotlab_student-*.dist-info"))


def new_env(path: Path) -> dict:
    """A fresh virtual environment holding this one's libraries but not cobotlab; returns
    the environment variables to run its programs with (no PYTHONPATH, its bin/ first)."""
    venv.EnvBuilder(with_pip=False, symlinks=True, clear=True).create(path)
    site = Path(run([str(path / "bin" / "python"), "-c",
                     "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    _link_tree(Path(sysconfig.get_paths()["purelib"]), site)
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "COBOTLAB_GRADING_SECRET",
                        "COBOTLAB_COURSE")}
    env.update(PATH=f"{path / 'bin'}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=str(path),
               MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return env


def _build_wheel(dist: Path) -> None:
    (dist / "src").mkdir()
    src = _copy_sources(dist / "src")
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
         str(src), "-w", str(dist)])
    shutil.rmtree(src)   # nothing of the sources is left but the wheel


def cobotlab_wheel() -> Path:
    """cobotlab's wheel, built from a copy of the working tree's sources once per test run
    (tests/test_unprivileged.py installs the same one)."""
    (wheel,) = kit.built_once("cobotlab-wheel", _build_wheel).glob("cobotlab-*.whl")
    return wheel


@pytest.fixture(scope="module")
def regular(tmp_path_factory):
    """(environment folder, its variables): the built wheel installed the regular way."""
    wheel = cobotlab_wheel()
    env_dir = tmp_path_factory.mktemp("regular") / "env"
    env = new_env(env_dir)
    run([str(env_dir / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-deps",
         "--no-index", "--no-compile", str(wheel)], env=env)
    # The libraries were linked in, not installed, so pip wrote no `nbgrader` script: the
    # one it would write for the course extra.
    script = env_dir / "bin" / "nbgrader"
    script.write_text(f'#!/bin/sh\nexec "{env_dir / "bin" / "python"}" -m nbgrader "$@"\n')
    script.chmod(0o755)
    return env_dir, env


@pytest.fixture(scope="module")
def editable(tmp_path_factory):
    """(environment folder, its variables, the checkout): a copy of the checkout, editable."""
    checkout = _copy_sources(tmp_path_factory.mktemp("checkout"))
    env_dir = tmp_path_factory.mktemp("editable") / "env"
    env = new_env(env_dir)
    run([str(env_dir / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-deps",
         "-e", str(checkout)], env=env)
    return env_dir, env, checkout


@pytest.fixture(scope="module")
def regular_course() -> Path:
    """A course as `course init` lays it out: the run's one (course_kit.initialized_master;
    nothing in a course names the install that made it); each test works on a copy
    (kit.fresh_course: its own path, the same files). `cobotlab course init` of the regular
    install itself runs as docs/authoring.md writes it, in
    test_the_authoring_page_runs_as_written_from_a_regular_install: one of its own here cost
    11.7 s of CPU (it draws every built-in lab's practice problems). From an editable
    install (the project's own .venv) it runs as written by tests/test_instructor_docs.py."""
    return kit.initialized_master()


def where(env_dir: Path, env: dict, cwd: Path) -> dict[str, str]:
    code = ("import importlib.util, json\n"
            "print(json.dumps({n: importlib.util.find_spec(n).origin for n in "
            "('autograder', 'solutions', 'cobotlab_labs', 'robots')}))")
    return json.loads(run([str(env_dir / "bin" / "python"), "-c", code], env=env,
                          cwd=cwd).stdout)


def test_pyproject_lists_every_package_of_the_tree():
    import tomllib
    from setuptools import find_packages

    listed = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = find_packages(str(ROOT), include=["cobotlab*", "robots*", "sim_backends*",
                                              "autograder*", "solutions*"])
    assert sorted(listed["packages"]) == sorted(found + ["cobotlab_labs"])
    assert listed["package-dir"] == {"cobotlab_labs": "labs"}


def test_a_regular_install_runs_a_course(regular, regular_course, tmp_path):
    env_dir, env = regular
    bin_dir = env_dir / "bin"
    here = where(env_dir, env, tmp_path)
    site = sysconfig.get_paths()["purelib"]
    for name, origin in here.items():   # every package from the install, none from a checkout
        assert origin.startswith(str(env_dir)), (name, origin)
        assert not origin.startswith((str(ROOT), site)), (name, origin)

    course = kit.fresh_course(regular_course, tmp_path)   # as `cobotlab course init` makes it
    assert (course / "source" / "lab0_frames" / "lab0_frames.ipynb").is_file()
    run([str(bin_dir / "cobotlab"), "labs", "student", "student_labs"], env=env, cwd=tmp_path)
    released = (tmp_path / "student_labs" / "lab0_frames" / "lab0_frames.ipynb").read_text()
    assert "BEGIN SOLUTION" not in released and "raise NotImplementedError()" in released
    run([str(bin_dir / "python"), "-m", "nbgrader", "generate_assignment", "lab0_frames"],
        env=env, cwd=course)

    functions = ("invert_pose", "compose_chain", "pose_from_rotvec")
    kit.submit(course, "lab0_frames", "ref", replace=kit.solution_sources("lab0_frames",
                                                                          functions))
    kit.submit(course, "lab0_frames", "blank")
    reader = kit.parse_case(kit.ADVERSARIAL / "reader_source_notebook.py")
    kit.submit(course, "lab0_frames", "reader", replace=reader["replace"])
    done = run([str(bin_dir / "cobotlab"), "grade", str(course), "lab0_frames", "--workers",
                "2", "--no-progress"], env=env, cwd=tmp_path)
    assert "sandbox: bubblewrap" in done.stdout, done.stdout
    with open(course / "grades.csv") as f:
        rows = {r["student_id"]: r for r in csv.DictReader(f)}
    assert float(rows["ref"]["score"]) == 10.0, rows["ref"]
    assert float(rows["blank"]["score"]) == 0.0
    # the reader found no source notebook in this install either: the blank's score, flagged
    assert float(rows["reader"]["score"]) == float(rows["blank"]["score"]), rows["reader"]
    assert "suspicious_file_search" in rows["reader"]["flags"]
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        assert gb.find_submission("lab0_frames", "ref").score == 10.0

    demo = subprocess.run([str(bin_dir / "cobotlab"), "demo", "--quick"], capture_output=True,
                          text=True, env=env, cwd=tmp_path, timeout=600)
    assert demo.returncode == 0, demo.stdout[-2000:] + demo.stderr[-2000:]
    check_quick_demo(demo, tmp_path / "out")   # the demo's own checks (its default --out)


# The probe runs as student code would: it lists what it can read and import of the planted
# markers, and walks the whole view for any file that carries the token in its name.
PROBE = textwrap.dedent('''
    def probe(paths, modules, token):
        import importlib, os
        readable = []
        for path in paths:
            try:
                with open(path, errors="replace") as f:
                    if token in f.read():
                        readable.append(path)
            except OSError:
                pass
        importable = []
        for name in modules:
            try:
                importlib.import_module(name)
                importable.append(name)
            except Exception:
                pass
        named, listed = [], 0
        for folder, dirs, files in os.walk("/"):
            dirs[:] = [d for d in dirs if d not in ("proc", "sys", "dev")]
            listed += 1
            named += [os.path.join(folder, n) for n in files + dirs
                      if token in n or (n == "secret" and folder.endswith(".cobotlab"))]
        return {"readable": readable, "importable": importable, "named": named,
                "listed": listed}
''')

RUN_IN_WORKER = textwrap.dedent('''
    import json, sys
    from autograder.pipeline.worker import Limits, Worker
    args = json.loads(sys.argv[1])
    with Worker([sys.argv[2]], Limits(call_timeout_s=120)) as worker:
        outcome = worker.call("probe", tuple(args), 120)
    print(json.dumps({"value": outcome.value, "error": outcome.error}))
''')

RUN_IN_KERNEL_VIEW = textwrap.dedent('''
    import json, subprocess, sys, tempfile
    from pathlib import Path
    from autograder import sandbox, scratch
    args, course = json.loads(sys.argv[1]), Path(sys.argv[3])
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in ("course", "home"):
            (tmp / name).mkdir()
        source = scratch.copy_source_files(course, "lab0_frames", tmp / "source")
        jail = scratch.kernel_jail(tmp / "course", tmp / "home", source,
                                   course / "nbgrader_config.py", "lab0_frames")
        code = sys.argv[2] + "\\nimport json\\nprint(json.dumps(probe(*%r)))" % (args,)
        done = subprocess.run(sandbox.command([sys.executable, "-I", "-c", code], jail),
                              capture_output=True, text=True, timeout=300)
    print(json.dumps({"value": json.loads(done.stdout) if done.returncode == 0 else None,
                      "error": done.stderr[-2000:] or None}))
''')


def plant_markers(package_root: Path, course: Path) -> tuple[list[str], list[str]]:
    """Marker files at every place student code must not reach; (paths, module names)."""
    places = {
        package_root / "solutions" / f"{TOKEN}.py": f"solutions.{TOKEN}",
        package_root / "autograder" / "specs" / f"{TOKEN}.py": f"autograder.specs.{TOKEN}",
        package_root / "autograder" / f"{TOKEN}.py": f"autograder.{TOKEN}",   # beside checks
        course / f"{TOKEN}.txt": None,
        course / "source" / "lab0_frames" / f"{TOKEN}.ipynb": None,
        # where an instructor's own lab keeps its private spec (autograder.registry)
        course / ".cobotlab" / "specs" / f"{TOKEN}.py": None,
    }
    for path in places:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f'MARKER = "{TOKEN}"\n')
    # The source notebook itself and the secret carry the token too.
    notebook = course / "source" / "lab0_frames" / "lab0_frames.ipynb"
    nb = json.loads(notebook.read_text())
    nb["cells"].append({"cell_type": "markdown", "metadata": {}, "source": TOKEN})
    notebook.write_text(json.dumps(nb))
    secret = course / ".cobotlab" / "secret"
    secret.write_text(secret.read_text().strip() + TOKEN + "\n")
    paths = [str(p) for p in places] + [str(notebook), str(secret),
                                        str(package_root / "autograder" / "checks.py")]
    return paths, [m for m in places.values() if m]


def unplant_markers(package_root: Path) -> None:
    """Remove what plant_markers put in the install's packages: the install is shared by
    the later tests of this file (a source file left in autograder/ changes the key of its
    practice-problem cache, and the authoring page's `course init` drew them all again)."""
    for folder in ("solutions", "autograder/specs", "autograder"):
        (package_root / folder / f"{TOKEN}.py").unlink(missing_ok=True)


def probe_views(env_dir: Path, env: dict, cwd: Path, course: Path, paths, modules) -> dict:
    args = json.dumps([paths, modules, TOKEN])
    out = {}
    for view, script in (("worker", RUN_IN_WORKER), ("kernel", RUN_IN_KERNEL_VIEW)):
        done = run([str(env_dir / "bin" / "python"), "-c", script, args, PROBE, str(course)],
                   env=env, cwd=cwd)
        result = json.loads(done.stdout.strip().splitlines()[-1])
        assert result["value"] is not None, (view, result["error"])
        out[view] = result["value"]
    return out


def assert_out_of_reach(seen: dict, install: str) -> None:
    for view, found in seen.items():
        # The walk saw the view (so an empty result is not a probe that never ran) ...
        assert found["listed"] > 100, (install, view, found)
        # ... and none of the places, by content, by import or by name.
        assert found["readable"] == [], (install, view, found["readable"])
        assert found["importable"] == [], (install, view, found["importable"])
        assert found["named"] == [], (install, view, found["named"])


def test_the_answer_key_is_out_of_reach_in_a_regular_install(regular, regular_course,
                                                              tmp_path):
    env_dir, env = regular
    kit.fresh_course(regular_course, tmp_path)
    package_root = Path(where(env_dir, env, tmp_path)["autograder"]).parent.parent
    paths, modules = plant_markers(package_root, tmp_path / "course")
    # checks.py has no token: what matters is that the worker cannot open it (its stub
    # stands in); the kernel may, as its hidden tests score through it.
    checks_py = next(p for p in paths if p.endswith("checks.py"))
    with open(checks_py, "a") as f:
        f.write(f"# {TOKEN}\n")
    try:
        seen = probe_views(env_dir, env, tmp_path, tmp_path / "course", paths, modules)
    finally:
        text = Path(checks_py).read_text().replace(f"# {TOKEN}\n", "")
        Path(checks_py).write_text(text)
        unplant_markers(package_root)
    assert seen["kernel"]["readable"] == [checks_py], seen["kernel"]["readable"]
    seen["kernel"]["readable"] = []
    assert_out_of_reach(seen, "regular")


def test_the_answer_key_is_out_of_reach_in_an_editable_install(editable, regular_course,
                                                               tmp_path):
    env_dir, env, checkout = editable
    here = where(env_dir, env, tmp_path)
    assert here["solutions"].startswith(str(checkout)), here
    # the course: a copy of the regular install's `course init` (the same files as this
    # install's would be; what is checked here is the view of the checkout and the course)
    kit.fresh_course(regular_course, tmp_path)
    paths, modules = plant_markers(checkout, tmp_path / "course")
    # The checkout's own lab sources too (labs/, the package cobotlab_labs in this install).
    lab_marker = checkout / "labs" / "lab0_frames" / f"{TOKEN}.txt"
    lab_marker.write_text(TOKEN)
    try:
        seen = probe_views(env_dir, env, tmp_path, tmp_path / "course",
                           paths + [str(lab_marker)], modules)
    finally:
        unplant_markers(checkout)
    assert_out_of_reach(seen, "editable")


# --------------------------------------------------------------------------- docs/authoring.md

AUTHORING = ROOT / "docs" / "authoring.md"


def _authoring_blocks() -> list[str]:
    import re

    fence = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)
    return [body for lang, body in fence.findall(AUTHORING.read_text()) if lang == "bash"]


def _bash(env: dict, home: Path, cwd: Path, blocks: list[str], check: bool = True
          ) -> subprocess.CompletedProcess:
    """The blocks in one bash shell (a `cd` carries over, as for a reader), HOME fresh."""
    script = "\n".join(["set -euo pipefail", *blocks])
    done = subprocess.run(["bash", "-c", script], cwd=cwd, env={**env, "HOME": str(home)},
                          capture_output=True, text=True, timeout=900, check=False)
    if check:
        assert done.returncode == 0, (done.stdout[-4000:], done.stderr[-4000:])
    return done


def test_the_authoring_page_runs_as_written_from_a_regular_install(regular, tmp_path):
    """A lab that is not built in: made, verified in the sandbox, added to the course,
    released by nbgrader and graded by `cobotlab grade` with real nbgrader, from the wheel."""
    env_dir, env = regular
    home = tmp_path / "home"
    home.mkdir()
    blocks = _authoring_blocks()
    assert len(blocks) >= 4 and "cobotlab labs new gauge_offset" in blocks[0]
    assert "../" not in "\n".join(blocks) and ".venv" not in "\n".join(blocks)
    done = _bash(env, home, tmp_path, blocks)
    course = home / "course"
    assert "gauge_offset" not in where(env_dir, env, tmp_path)["cobotlab_labs"]

    report = json.loads((course / ".cobotlab" / "verified" / "gauge_offset.json").read_text())
    assert report["passed"] and report["draws"] == 3688, report
    (row,) = report["functions"]
    variants = {v["variant"]: v for v in row["variants"]}
    assert variants["reference"]["lost"] == 0 and variants["reference"]["draws"] == 3688
    (mistake,) = [v for v in variants.values() if not v["correct"]]
    assert mistake["lost"] == mistake["draws"] == 1000 and mistake["low"] >= 0.99
    assert "gauge_offset: passed" in done.stdout

    # The released notebook has no answer, and the private spec went nowhere near it.
    released = (course / "release" / "gauge_offset" / "gauge_offset.ipynb").read_text()
    assert "np.mean(measured - commanded" not in released and "hidden_test" not in released
    assert not list((course / "release").rglob("*.py")) or all(
        "make_trial=" not in p.read_text() or "make_trial=None" in p.read_text()
        for p in (course / "release").rglob("*.py"))

    # The scores, from nbgrader's gradebook.
    code = textwrap.dedent("""
        import json
        from nbgrader.api import Gradebook
        with Gradebook("sqlite:///gradebook.db") as gb:
            print(json.dumps({s.student.id: [s.score, s.max_score]
                              for s in gb.assignment_submissions("gauge_offset")}))
    """)
    scores = json.loads(run([str(env_dir / "bin" / "python"), "-c", code], env=env,
                            cwd=course).stdout)
    assert scores == {"reference": [2.0, 2.0], "mistake": [0.0, 2.0], "blank": [0.0, 2.0]}
    feedback = (course / "feedback_cobotlab" / "mistake" / "gauge_offset" / "feedback.html")
    assert "the offset has the wrong sign (commanded - measured)" in feedback.read_text()
    run_entry = json.loads((course / ".cobotlab" / "runs.jsonl").read_text().splitlines()[-1])
    assert run_entry["spec_hash"] == report["spec_hash"]
    assert "never verified" not in done.stderr and "changed since" not in done.stderr


def test_labs_verify_refuses_the_pages_lab_broken_two_ways(regular, tmp_path):
    """A tolerance ten times too tight, then a code mistake equal to the reference: each
    makes `labs verify` fail, saying what is wrong and the fix. 100 draws each: the
    reference loses on the first, the mistake on none, and each run's cost is mostly its
    fixed part (the sandbox, the trivial and family tables' first 100 draws); 400 cost
    2.3 s more of CPU a run. The page's own verify runs at the default draws above."""
    env_dir, env = regular
    home = tmp_path / "home"
    home.mkdir()
    _bash(env, home, tmp_path, _authoring_blocks()[:1])   # the lab, as the page makes it
    course = home / "course"
    spec = course / ".cobotlab" / "specs" / "gauge_offset.py"
    good = spec.read_text()
    verify = ["cobotlab labs verify labs/gauge_offset --draws 100"]

    tight = good.replace("tol_mm = 6.0 * sigma", "tol_mm = 0.6 * sigma")
    assert tight != good
    spec.write_text(tight)
    done = _bash(env, home, course, verify, check=False)
    assert done.returncode == 1, done.stdout[-3000:]
    assert "FAIL reference: mean_offset: the reference lost credit on" in done.stdout
    assert "check offset" in done.stdout and "derive that problem's tolerance" in done.stdout
    assert "gauge_offset: FAILED" in done.stdout

    same = good.replace(
        "return np.mean(commanded - np.asarray(measured, dtype=float), axis=0)",
        "return np.mean(np.asarray(measured, dtype=float) - commanded, axis=0)")
    assert same != good
    spec.write_text(same)
    done = _bash(env, home, course, verify, check=False)
    assert done.returncode == 1, done.stdout[-3000:]
    assert "FAIL mistake: mean_offset: the code mistake 'the offset has the wrong sign" \
        in done.stdout
    assert "lost credit on only 0 of 100 draws" in done.stdout
    assert "is not a mistake" in done.stdout
    assert "FAIL reference" not in done.stdout   # the reference itself is fine
    report = json.loads((course / ".cobotlab" / "verified" / "gauge_offset.json").read_text())
    assert not report["passed"] and [f["check"] for f in report["findings"]] == ["mistake"]

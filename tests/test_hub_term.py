"""docs/hub.md followed literally, and a course term on that hub in a real browser.

The page's ```bash blocks run in order, as root, in one bash shell, with this test's values
in the settings block (accounts named ``hubt_*``, free ports on 127.0.0.1, folders in a
temporary directory); the hub starts with the command of the page's ``Start the hub`` block:
JupyterHub with configurable-http-proxy (npm, installed by ``make hub-proxy``), PAM logins
for real Unix accounts with real passwords, LocalProcessSpawner starting each user's
``jupyterhub-singleuser`` as that user. Debian's Chromium (tests/test_browser_lab.py's
conventions) then plays a term of lab 0 through the hub's pages: see test_a_term_in_chromium.

Artefacts (screenshots of every step, the hub's log with every server's in it, the grading
run's output) go to a folder the test prints (``-s`` to see it), kept after the run.

The environment every account's server runs from is made as tests/test_unprivileged.py makes
its user's (this venv's libraries linked in, cobotlab's wheel installed the regular way), on
this venv's own interpreter made runnable by every account (pyenv puts it under root's mode-700
home; Debian's older python3.11 cannot run some of the libraries, e.g. soupsieve >= 4.1 wants
Python 3.11.5).

The Kubernetes values of the page cannot run here: they are checked against the
zero-to-jupyterhub chart's values schema (tests/z2jh_4.4.0/, vendored).
"""

from __future__ import annotations

import contextlib
import copy
import importlib.metadata
import json
import os
import pwd
import re
import secrets
import shutil
import signal
import subprocess
import sys
import sysconfig
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import course_kit as kit
import jsonschema
import nbformat
import pytest
import yaml
from test_browser_lab import (
    CHROMIUM,
    LAB_SETTINGS,
    NOTEBOOK,
    PAGE_STATE_JS,
    _free_port,
    _wait_for_run,
    errors_in_file,
    errors_on_page,
    execution_counts,
    launch_chromium,
)
from test_course_install import _link_tree, cobotlab_wheel

from autograder import practice_cache

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "hub.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)
Z2JH = Path(__file__).resolve().parent / "z2jh_4.4.0"
PROXY = REPO / ".tools" / "chp" / "node_modules" / ".bin" / "configurable-http-proxy"
ASSIGNMENT = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")
PREFIX = "hubt_"
GRADER, INSTRUCTOR, STAFF_GROUP = f"{PREFIX}grader", f"{PREFIX}instr", f"{PREFIX}staff"
STUDENTS = tuple(f"{PREFIX}s{i}" for i in (1, 2))
HUB_TIMEOUT_S = 30        # the hub, from start to answering /hub/health
SPAWN_TIMEOUT_S = 60      # a user's server, from login to JupyterLab on the page
KERNEL_TIMEOUT_S = 90     # a kernel, from Run All to every cell numbered
STEP_TIMEOUT_S = 30       # one click's effect (a fetch, a submit, a page)

pytestmark = pytest.mark.slow


def _blocks(kind: str) -> list[str]:
    return [body for lang, body in FENCE.findall(DOC.read_text()) if lang == kind]


def _settings_names(block: str) -> list[str]:
    return [line.split("=", 1)[0] for line in block.splitlines()
            if line and not line.startswith("#")]


# --------------------------------------------------------------------------- versions


def _pins(text: str) -> dict[str, str]:
    return dict(re.findall(r"\b([a-z][a-z-]+)==([0-9][0-9.]*)", text))


def test_the_page_pins_the_versions_the_tests_run():
    table = dict(re.findall(r"^\| ([a-z-]+)(?: \(npm\))? \| ([0-9.]+) \|$", DOC.read_text(),
                            re.M))
    for name in ("jupyterhub", "jupyterlab", "notebook", "nbgrader"):
        assert table[name] == importlib.metadata.version(name), name
    chp = json.loads((PROXY.parent.parent / "configurable-http-proxy" / "package.json")
                     .read_text())["version"]
    assert table["configurable-http-proxy"] == chp, "make hub-proxy installs another version"
    [install, *_] = [b for b in _blocks("sh") if "pip install" in b]
    assert {k: v for k, v in _pins(install).items() if k in table} == \
        {k: table[k] for k in ("jupyterhub", "jupyterlab", "notebook", "nbgrader")}
    assert f"configurable-http-proxy@{chp}" in install
    # the Kubernetes user image: the same JupyterLab, notebook and nbgrader; the chart's hub
    [image] = [b for b in _blocks("sh") if "Dockerfile.user" in b]
    assert _pins(image) == {**{k: table[k] for k in ("jupyterlab", "notebook", "nbgrader")},
                            "jupyterhub": "5.5.0"}
    assert "--version 4.4.0" in "\n".join(_blocks("sh"))


# --------------------------------------------------------------------------- Kubernetes


def _helm_merge(defaults, values):
    """Helm's merge of user values over a chart's defaults: maps merge key by key, anything
    else (lists included) is replaced, and null deletes the default."""
    out = copy.deepcopy(defaults)
    for key, value in values.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _helm_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _z2jh_values() -> dict:
    [block] = [b for b in _blocks("yaml") if b.startswith("# cobotlab-z2jh-values.yaml")]
    return yaml.safe_load(block)


def _validate_z2jh(values: dict) -> None:
    schema = json.loads((Z2JH / "values.schema.json").read_text())
    defaults = yaml.safe_load((Z2JH / "values.yaml").read_text())
    jsonschema.validate(_helm_merge(defaults, values), schema)


def test_the_kubernetes_values_pass_the_chart_schema():
    values = _z2jh_values()
    _validate_z2jh(values)
    single = values["singleuser"]
    # the simulator's core, and the exchange at the path its nbgrader config names
    assert single["cpu"]["guarantee"] >= 1 and single["cpu"]["limit"] >= 2
    [mount] = single["storage"]["extraVolumeMounts"]
    config = single["extraFiles"]["nbgrader-config"]["stringData"]
    assert f'c.Exchange.root = "{mount["mountPath"]}"' in config
    assert single["extraEnv"]["DASK_GATEWAY__AUTH__TYPE"] == "jupyterhub"
    assert "dask-gateway" in values["hub"]["services"]
    # the schema does catch a mistake: a misspelt key, a wrong type
    typo = copy.deepcopy(values)
    typo["singleuser"]["cpu"]["limt"] = 2
    with pytest.raises(jsonschema.ValidationError, match="limt"):
        _validate_z2jh(typo)
    wrong = copy.deepcopy(values)
    wrong["singleuser"]["extraFiles"]["nbgrader-config"]["stringData"] = ["c = 1"]
    with pytest.raises(jsonschema.ValidationError):
        _validate_z2jh(wrong)


# --------------------------------------------------------------------------- the hub


def _reachable_by_all(path: Path) -> bool:
    """Every folder above ``path`` lets other accounts through (mode o+x)."""
    return all(os.stat(folder).st_mode & 0o001 for folder in path.parents)


def _python_for_all(base: Path) -> Path:
    """This interpreter (the venv's base: same version, same libraries' ABI), runnable by
    every account. Where it sits under a folder others cannot enter (pyenv under root's
    mode-700 home), a copy: its files hard-linked, the executable copied with its library
    search path made relative (patchelf), since it names libpython by absolute path."""
    prefix = Path(sys.base_prefix)
    version = "{}.{}".format(*sys.version_info[:2])
    if _reachable_by_all(prefix):
        return prefix / "bin" / f"python{version}"
    copy_ = base / "python"
    subprocess.run(["cp", "-al", str(prefix), str(copy_)], check=True, timeout=120)
    executable = copy_ / "bin" / f"python{version}"
    executable.unlink()   # a file of its own: patchelf must not change the original
    shutil.copy2(prefix / "bin" / f"python{version}", executable)
    assert shutil.which("patchelf"), "patchelf missing: make test installs it (SYSTEM_PACKAGES)"
    subprocess.run(["patchelf", "--set-rpath", "$ORIGIN/../lib", str(executable)], check=True,
                   timeout=60)
    return executable


# The programs the page calls in $ENV/bin that pip writes when it installs their packages;
# linked in, they have none (cobotlab's own comes with its wheel).
PROGRAMS = {"jupyterhub": "jupyterhub", "jupyterhub-singleuser": "jupyterhub.singleuser",
            "nbgrader": "nbgrader", "jupyter": "jupyter_core"}


def _course_environment(path: Path) -> Path:
    """The course environment as hub.md installs it, built without the network: this
    interpreter made runnable by every account, this checkout's libraries linked in (the
    same versions the other tests run), and cobotlab's wheel installed the regular way (what
    the grader's sandbox expects)."""
    subprocess.run([str(_python_for_all(path.parent)), "-m", "venv", "--without-pip",
                    str(path)], check=True, capture_output=True, timeout=120)
    python = path / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig."
                                "get_paths()['purelib'])"], capture_output=True, text=True,
                               check=True).stdout.strip())
    _link_tree(Path(sysconfig.get_paths()["purelib"]), site)
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                    "--no-compile", str(cobotlab_wheel())], check=True, capture_output=True,
                   timeout=300)
    for name, module in PROGRAMS.items():
        script = path / "bin" / name
        script.write_text(f'#!/bin/sh\nexec "{python}" -m {module} "$@"\n')
        script.chmod(0o755)
    # Jupyter's files live under the environment's prefix: which server extensions are on
    # (etc/jupyter), the lab extensions and kernel specs (share/jupyter).
    for folder in ("etc", "share"):
        (path / folder).symlink_to(Path(sys.prefix) / folder)
    return path


def _kill_processes_of(uid: int) -> int:
    """SIGKILL every process running as ``uid``; how many there were."""
    found = 0
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and entry.stat().st_uid == uid:
                os.kill(int(entry.name), signal.SIGKILL)
                found += 1
        except (OSError, ProcessLookupError):
            pass
    return found


def _remove_accounts() -> None:
    """Our accounts, their processes (by pid: each is one this test started, as that user)
    and their homes."""
    # every account of the prefix: a run of an older version of this test had more students
    ours = {GRADER, INSTRUCTOR, *STUDENTS} | {e.pw_name for e in pwd.getpwall()
                                             if e.pw_name.startswith(PREFIX)}
    for name in sorted(ours):
        try:
            uid = pwd.getpwnam(name).pw_uid
        except KeyError:
            continue
        deadline = time.monotonic() + 10
        while _kill_processes_of(uid) and time.monotonic() < deadline:
            time.sleep(0.1)   # userdel refuses a user whose process is not yet reaped
        done = subprocess.run(["userdel", "--remove", name], capture_output=True, text=True,
                              timeout=60)
        if done.returncode not in (0, 12):   # 12: the home could not be removed (already gone)
            raise AssertionError(f"userdel {name} failed: {done.stderr.strip()}")
    subprocess.run(["groupdel", STAFF_GROUP], capture_output=True, timeout=60)


class Hub:
    """The hub the page sets up, run by its own commands; ``url`` is its public address."""

    def __init__(self, base: Path, artefacts: Path):
        self.base, self.artefacts = base, artefacts
        self.env = _course_environment(base / "env")
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.passwords = {name: secrets.token_urlsafe(12) for name in (INSTRUCTOR, *STUDENTS)}
        self.settings = {
            "COURSE_ID": "cobotlab", "ENV": str(self.env), "PROXY": str(PROXY),
            "HUB_DIR": str(base / "srv" / "hub"), "COURSE_DIR": str(base / "srv" / "course"),
            "EXCHANGE": str(base / "nbgrader" / "exchange"), "GRADER": GRADER,
            "STAFF_GROUP": STAFF_GROUP, "INSTRUCTORS": INSTRUCTOR, "TAS": "",
            "STAFF": str(base / "staff.txt"), "ROSTER": str(base / "roster.txt"),
            "DEADLINE": "2099-01-01 00:00:00 UTC",
            "HUB_IP": "127.0.0.1", "HUB_PORT": str(self.port),
            "HUB_API_PORT": str(_free_port()), "PROXY_API_PORT": str(_free_port()),
            "GRADING_PORT": str(_free_port()),
        }
        self.course = Path(self.settings["COURSE_DIR"])
        self.log_path = artefacts / "hub.log"
        self.process: subprocess.Popen | None = None

    def settings_block(self) -> str:
        return "".join(f"{k}={_sh_quote(v)}\n" for k, v in self.settings.items())

    def set_up(self) -> None:
        """Every ```bash block of the page, in order, the settings block replaced by ours."""
        blocks = _blocks("bash")
        assert _settings_names(blocks[0]) == list(self.settings), \
            "the page's settings block names other settings than this test sets"
        for path, names in (("STAFF", [INSTRUCTOR]), ("ROSTER", STUDENTS)):
            roster = Path(self.settings[path])
            roster.touch(mode=0o600)   # first passwords: root's only, as the page says
            roster.write_text("".join(f"{n}:{self.passwords[n]}\n" for n in names))
        steps = blocks[1:]
        [accounts] = [i for i, block in enumerate(steps) if "useradd" in block]
        steps.insert(accounts + 1, self.practice_cache_step())
        script = "\n".join(["set -euo pipefail", self.settings_block(), *steps])
        done = subprocess.run(["bash", "-c", script], cwd=self.base, env=_root_env(),
                              capture_output=True, text=True, timeout=300, check=False)
        (self.artefacts / "setup.log").write_text(done.stdout + done.stderr)
        assert done.returncode == 0, ("docs/hub.md's set-up failed:\n" + done.stdout[-3000:]
                                      + done.stderr[-3000:])
        self.check_practice_cache_read()

    def check_practice_cache_read(self) -> None:
        """The grading account's `course init` drew nothing: its cache holds no file the
        run's lacks (a regular install whose code gave another key would draw them all)."""
        source = os.environ.get(practice_cache.ENV, "off")
        if source == "off":
            return
        cache = Path(pwd.getpwnam(GRADER).pw_dir) / ".cache" / "cobotlab" / "practice"

        def files(root: Path) -> set[str]:
            return {str(f.relative_to(root)) for f in root.rglob("*") if f.is_file()}

        drawn = files(cache) - files(Path(source))
        assert not drawn, f"course init as {GRADER} drew practice problems again: {drawn}"

    def practice_cache_step(self) -> str:
        """The test's own step between the page's accounts and its course: the grading
        account's practice cache (autograder/practice_cache.py, ~/.cache/cobotlab/practice,
        owned by it and no one else's to write) filled from the run's, as on a machine where
        it laid out a course before. The page's `course init` as that account then reads the
        six labs' practice problems instead of drawing them (about 10 s of CPU); the run's
        cache holds them once its one course init ran (tests/course_kit.initialized_master,
        shared with the other tests of the run): that one drew into an empty cache; the cache's
        own rules (a hit is a fresh draw's bytes, a damaged file refused) are
        tests/test_practice_cache.py's."""
        source = os.environ.get(practice_cache.ENV, "off")
        if source == "off":
            return ""
        kit.initialized_master()   # the run's one course init: the cache holds every lab
        return ('cache="$(getent passwd "$GRADER" | cut -d: -f6)/.cache/cobotlab"\n'
                'install -d -o "$GRADER" -g "$GRADER" -m 0700 "$(dirname "$cache")" "$cache"\n'
                f'cp -r {_sh_quote(source)} "$cache/practice"\n'
                'chown -R "$GRADER:$GRADER" "$cache"\n'
                'chmod -R go-w "$cache"\n')

    def start(self) -> None:
        [start] = [b for b in _blocks("sh") if "jupyterhub -f" in b or "/jupyterhub\" -f" in b]
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(
                ["bash", "-c", "set -eu\n" + self.settings_block() + start],
                cwd=self.base, env=_root_env(), stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)
        deadline = time.monotonic() + HUB_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise AssertionError(f"the hub exited with code {self.process.returncode}: "
                                     f"see {self.log_path}\n{self.log()[-3000:]}")
            try:
                with urllib.request.urlopen(f"{self.url}/hub/health", timeout=2):
                    return
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                time.sleep(0.25)
        raise AssertionError(f"the hub did not answer on {self.url} in {HUB_TIMEOUT_S} s: see "
                             f"{self.log_path}\n{self.log()[-3000:]}")

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def stop(self) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        os.killpg(self.process.pid, signal.SIGTERM)   # the hub stops its servers and proxy
        try:
            self.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=10)

    def as_grader(self, *argv: str, timeout: float = 300) -> subprocess.CompletedProcess:
        """A command as the grading account, in the course folder (the service's terminal)."""
        return subprocess.run(["runuser", "-u", GRADER, "--", *argv], cwd=self.course,
                              env={**_root_env(), "PATH": f"{self.env}/bin:/usr/bin:/bin",
                                   "HOME": os.path.expanduser(f"~{GRADER}")},
                              capture_output=True, text=True, timeout=timeout, check=False)


def _sh_quote(value: str) -> str:
    return "'" + value.replace("'", "'\\''") + "'"


def _root_env() -> dict:
    """What the page's shell has: root's login basics, no secret, no Jupyter folders."""
    keep = {k: v for k, v in os.environ.items() if k in ("LANG", "LC_ALL", "TZ")}
    return {**keep, "HOME": "/root", "USER": "root", "LOGNAME": "root",
            "PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"}


@pytest.fixture(scope="module")
def hub():
    if os.geteuid() != 0:
        raise AssertionError("the hub test makes Unix accounts and runs JupyterHub as root: "
                             "run it as root (CI does)")
    assert PROXY.is_file(), f"{PROXY} missing: run `make hub-proxy`"
    artefacts = Path(tempfile.mkdtemp(prefix="cobotlab-hub-term-"))
    base = Path(tempfile.mkdtemp(prefix="cobotlab-hub-", dir="/var/tmp"))
    os.chmod(base, 0o755)   # every account reaches the environment and the exchange in it
    print(f"\nhub term artefacts (screenshots, logs): {artefacts}")
    _remove_accounts()      # what an interrupted run left
    hub = Hub(base, artefacts)
    try:
        hub.set_up()
        hub.start()
        yield hub
    finally:
        # the accounts' servers first: the hub then finds them gone, rather than stopping
        # each one politely (20 s or more at the end of every run); it reaps them as it
        # stops, and only then will userdel take their accounts
        for name in (GRADER, INSTRUCTOR, *STUDENTS):
            with contextlib.suppress(KeyError):
                _kill_processes_of(pwd.getpwnam(name).pw_uid)
        hub.stop()
        _remove_accounts()
        shutil.rmtree(base, ignore_errors=True)


# --------------------------------------------------------------------------- the browser


@pytest.fixture(scope="module")
def browser():
    from playwright import sync_api

    assert CHROMIUM.is_file(), f"{CHROMIUM} missing: make test installs chromium"
    with launch_chromium(sync_api) as chromium:
        yield chromium


class Person:
    """One account in its own browser context (its own cookies), photographed at each step."""

    def __init__(self, hub: Hub, browser, name: str):
        self.hub, self.name = hub, name
        self.context = browser.new_context(viewport={"width": 1280, "height": 900})
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("pageerror", lambda error: self.errors.append(str(error)))
        self.shots = 0
        self.lab_response = None

    def shot(self, what: str, page=None) -> Path:
        self.shots += 1
        path = self.hub.artefacts / f"{self.name}-{self.shots:02d}-{what}.png"
        (page or self.page).screenshot(path=str(path))
        return path

    def fail(self, what: str, page=None):
        shot = self.shot("FAILED", page)
        raise AssertionError(f"{self.name}: {what}; screenshot {shot}, hub log (every "
                             f"server's too) {self.hub.log_path}")

    def wait(self, condition, what: str, timeout_s: float, page=None, **kwargs):
        from playwright.sync_api import TimeoutError as PlaywrightTimeout

        try:
            return (page or self.page).wait_for_function(condition, timeout=timeout_s * 1000,
                                                         polling=250, **kwargs)
        except PlaywrightTimeout:
            self.fail(f"no {what} within {timeout_s:.0f} s", page)

    def log_in(self, next_url: str = "") -> None:
        """The hub's login page, this account's Unix password: starts the server (no wait)."""
        self.page.goto(f"{self.hub.url}/hub/login{next_url}", timeout=STEP_TIMEOUT_S * 1000)
        self.shot("login")
        self.page.fill("#username_input", self.name)
        self.page.fill("#password_input", self.hub.passwords[self.name])
        with self.page.expect_navigation(timeout=STEP_TIMEOUT_S * 1000):
            self.page.click("#login_submit")

    def lab_ready(self) -> None:
        self.wait("() => document.querySelector('#jp-main-dock-panel') && [...document"
                  ".querySelectorAll('.lm-MenuBar-itemLabel')].some(e => e.textContent === "
                  "'Nbgrader')",
                  "JupyterLab with its Nbgrader menu after the login (the user's server, "
                  "which the hub starts)", SPAWN_TIMEOUT_S)
        assert f"/user/{self.name}/lab" in self.page.url, self.page.url
        self.shot("jupyterlab")

    def menu(self, menu: str, command: str) -> None:
        self.page.get_by_role("menuitem", name=menu, exact=True).click()
        self.page.locator(f'.lm-Menu-item[data-command="{command}"]').click()

    def close(self) -> None:
        self.context.close()


# The three submissions' answers: the reference, and the classic mistake of lab 0 (the
# inverse's translation as -t, not -R^T t) that the feedback names.
MISTAKE = ("-R.T @ t", "-t")


def _answers(mistake: bool) -> dict[str, str]:
    answers = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    if mistake:
        assert MISTAKE[0] in answers["invert_pose"]
        answers["invert_pose"] = answers["invert_pose"].replace(*MISTAKE)
    return answers


ASSIGNMENTS_TAB = ".lm-TabBar-tab:has-text('Assignments')"
RELEASED = "#released_assignments_list .list_item"
FETCHED = "#fetched_assignments_list > .list_item"
SUBMITTED = "#submitted_assignments_list > .list_item"


class Student(Person):
    """A student's steps in JupyterLab, each through the page as the student would."""

    def home(self) -> Path:
        return Path(pwd.getpwnam(self.name).pw_dir)

    def open_assignments(self) -> None:
        self.menu("Nbgrader", "nbgrader:open-assignment-list")
        self.wait(f"() => [...document.querySelectorAll('{RELEASED}')].some(e => "
                  "e.textContent.includes('lab0_frames'))",
                  "lab 0 in the Assignments tab's released list", STEP_TIMEOUT_S)
        self.shot("assignments")

    def fetch(self) -> None:
        self.page.locator(RELEASED, has_text=ASSIGNMENT).get_by_role("button",
                                                                      name="Fetch").click()
        self.wait(f"() => [...document.querySelectorAll('{FETCHED}')].some(e => "
                  "e.textContent.includes('lab0_frames'))",
                  "the fetch of lab 0 (its row in 'Downloaded assignments')", STEP_TIMEOUT_S)
        self.shot("fetched")

    def open_notebook(self) -> None:
        row = self.page.locator(FETCHED, has_text=ASSIGNMENT)
        row.locator(".assignment-notebooks-link").click()
        row.locator(".nested_list_item a", has_text=ASSIGNMENT).click()
        self.wait("([js]) => { const s = eval(js)(); return s && s.kernel === 'idle' "
                  "&& s.prompts.length > 0; }", "lab 0's notebook with its kernel started",
                  SPAWN_TIMEOUT_S, arg=[PAGE_STATE_JS])
        self.shot("notebook")

    def write(self, answers: dict[str, str]) -> None:
        """Type each graded function into its cell (CodeMirror: select all, insert text)."""
        nb = json.loads((self.home() / ASSIGNMENT / f"{ASSIGNMENT}.ipynb").read_text())
        index = {c["metadata"].get("nbgrader", {}).get("grade_id"): i
                 for i, c in enumerate(nb["cells"])}
        cells = self.page.locator(f"{NOTEBOOK} .jp-Notebook .jp-Cell")
        for name, source in answers.items():
            editor = cells.nth(index[name]).locator(".cm-content")
            editor.click()
            self.page.keyboard.press("Control+a")
            self.page.keyboard.insert_text(source)
        self.shot("written")

    def run_all(self) -> None:
        self.menu("Run", "runmenu:run-all")

    def wait_for_run(self) -> dict:
        """The page once Run All ended: every cell ran, or one raised (Run All stops there)."""
        nb = json.loads((self.home() / ASSIGNMENT / f"{ASSIGNMENT}.ipynb").read_text())
        n_code_cells = sum(c["cell_type"] == "code" for c in nb["cells"])
        state = _wait_for_run(self.page, n_code_cells,
                              self.hub.artefacts / f"{self.name}-run-timeout.png")
        self.shot("ran")
        return state

    def check_scores(self) -> dict[str, tuple[float, float]]:
        """What each check() cell showed: {function: (points, out of)}."""
        text = self.page.locator(f"{NOTEBOOK} .jp-OutputArea").all_inner_texts()
        found = re.findall(r"(\w+): ([\d.]+) / ([\d.]+) points", "\n".join(text))
        return {name: (float(got), float(out_of)) for name, got, out_of in found}

    def save(self) -> None:
        self.menu("File", "docmanager:save")
        self.wait("() => !document.querySelector('.lm-TabBar-tab.jp-mod-current.jp-mod-dirty')",
                  "end of File > Save Notebook (the tab still marked unsaved)",
                  STEP_TIMEOUT_S)

    def submit(self) -> None:
        self.page.locator(ASSIGNMENTS_TAB).click()
        before = self.page.locator(f"{SUBMITTED} .nested_list_item").count()
        self.page.locator(FETCHED, has_text=ASSIGNMENT).get_by_role("button",
                                                                     name="Submit").click()
        self.wait(f"([n]) => document.querySelectorAll('{SUBMITTED} .nested_list_item')"
                  ".length > n", "the submission (a new row in 'Submitted assignments')",
                  STEP_TIMEOUT_S, arg=[before])
        self.shot("submitted")

    def fix_invert_pose(self) -> None:
        """Retype invert_pose (the reference) and run its cell and its test cell again."""
        self.page.locator(f".lm-TabBar-tab:has-text('{ASSIGNMENT}.ipynb')").click()
        before = self._last_count()
        self.write({"invert_pose": _answers(False)["invert_pose"]})
        self.page.keyboard.press("Shift+Enter")   # the function's cell, then its test cell
        self.page.keyboard.press("Shift+Enter")
        self.wait("""([js, n]) => { const s = eval(js)();
                       return s && s.kernel === 'idle' && s.prompts.some(p => p === `[${n}]:`); }""",
                  "second run of invert_pose's cell and its test cell", KERNEL_TIMEOUT_S,
                  arg=[PAGE_STATE_JS, before + 2])
        self.shot("fixed")

    def _last_count(self) -> int:
        prompts = self.page.evaluate(PAGE_STATE_JS)["prompts"]
        return max(int(p[1:-2]) for p in prompts if re.fullmatch(r"\[\d+\]:", p))

    def fetch_feedback(self) -> str:
        """Fetch Feedback in the Assignments tab, then open the page in a browser tab of its
        own (the file browser's 'Open in New Browser Tab'); returns its text."""
        self.page.locator(ASSIGNMENTS_TAB).click()
        self.page.locator("#refresh_assignments_list").click()
        row = self.page.locator(SUBMITTED, has_text=ASSIGNMENT)
        row.get_by_role("button", name="Fetch Feedback").click()
        self.wait(f"() => [...document.querySelectorAll('{SUBMITTED} a')].some(a => "
                  "a.textContent.includes('view feedback'))",
                  "'(view feedback)' after Fetch Feedback", STEP_TIMEOUT_S)
        self.page.locator(f"{SUBMITTED} a", has_text="view feedback").last.click()
        self.shot("feedback-fetched")
        [page_file] = sorted((self.home() / ASSIGNMENT / "feedback").glob(
            f"*/{ASSIGNMENT}.html"))[-1:]
        relative = page_file.relative_to(self.home())
        tab = self.context.new_page()
        tab.goto(f"{self.hub.url}/user/{self.name}/files/{relative}",
                 timeout=STEP_TIMEOUT_S * 1000)
        self.shot("feedback", tab)
        return tab.inner_text("body")


class Instructor(Person):
    """The instructor: formgrader of the grading service in a tab of its own, and a terminal
    of the service's JupyterLab (commands run as the grading account)."""

    FORMGRADER = "/services/cobotlab/formgrader"

    def open_formgrader(self) -> None:
        self.log_in("?next=" + urllib.parse.quote(f"{self.FORMGRADER}/manage_assignments"))
        self.wait("() => [...document.querySelectorAll('h1')].some(h => h.textContent === "
                  "'Manage Assignments') && document.querySelector('td a')",
                  "formgrader's Manage Assignments page", SPAWN_TIMEOUT_S)
        self.shot("formgrader")

    def open_terminal(self) -> None:
        self.terminal = self.context.new_page()
        self.terminal.goto(f"{self.hub.url}/services/cobotlab/lab",
                           timeout=SPAWN_TIMEOUT_S * 1000)
        self.wait("() => [...document.querySelectorAll('.lm-MenuBar-itemLabel')].some(e => "
                  "e.textContent === 'File')", "the grading service's JupyterLab",
                  SPAWN_TIMEOUT_S, page=self.terminal)
        self.terminal.get_by_role("menuitem", name="File", exact=True).click()
        self.terminal.locator('.lm-Menu-item[data-command="filemenu:new"], '
                              '.lm-Menu-item:has-text("New")').first.hover()
        self.terminal.locator('.lm-Menu-item[data-command="terminal:create-new"]').click()
        self.wait("() => document.querySelector('.jp-Terminal .xterm-helper-textarea')",
                  "a terminal in the grading service", STEP_TIMEOUT_S, page=self.terminal)

    def type(self, command: str, done: Path, timeout_s: float) -> str:
        """Type ``command`` into the terminal; it writes its exit code to ``done``, which
        the test waits for. Returns the code."""
        self.terminal.locator(".jp-Terminal .xterm-helper-textarea").focus()
        self.terminal.keyboard.type(f"{command}; echo $? > {done}\n")
        deadline = time.monotonic() + timeout_s
        while not done.exists() and time.monotonic() < deadline:
            time.sleep(0.25)
        self.shot("terminal", self.terminal)
        if not done.exists():
            self.fail(f"`{command}` typed in the grading service's terminal did not finish "
                      f"in {timeout_s:.0f} s", self.terminal)
        return done.read_text().strip()

    def formgrader_action(self, column: str, what: str) -> None:
        """Click ``column``'s link in lab 0's row of Manage Assignments; wait for its dialog."""
        self.page.reload()
        row = self.page.locator("tr", has=self.page.locator("td a", has_text=ASSIGNMENT)).first
        row.locator(f".{column} a").click()
        self.wait("() => document.querySelector('#success-modal.in, #error-modal.in')",
                  f"dialog after formgrader's {what}", STEP_TIMEOUT_S * 4)
        self.shot(column)
        error = self.page.locator("#error-modal.in")
        if error.count():
            self.fail(f"formgrader's {what} failed: {error.inner_text()[:2000]}")
        self.page.keyboard.press("Escape")


def _give_lab_settings(user: str) -> None:
    """JupyterLab's user settings of tests/test_browser_lab.py (every cell in the page, no
    news toast over it) in the user's own ~/.jupyter, owned by the user."""
    account = pwd.getpwnam(user)
    root = Path(account.pw_dir) / ".jupyter"
    for name, values in LAB_SETTINGS.items():
        target = root / "lab" / "user-settings" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(values))
    subprocess.run(["chown", "-R", f"{account.pw_uid}:{account.pw_gid}", str(root)],
                   check=True)


HOSTILE_WORDS = "Notes on the inverse"


def _edit_hostile(notebook: Path, answers: dict[str, str]) -> None:
    """The fetched notebook edited as a student could in any editor: each graded
    function's cell given ``answers``' source, and a markdown cell added whose HTML would
    write a file through the grading service's API if it ran in the instructor's formgrader
    page (issue 51). (Typing answers into JupyterLab is s1's part of the term.)"""
    attack = kit.page_attack("hub", ("services", "cobotlab"))
    nb = json.loads(notebook.read_text())
    for cell in nb["cells"]:
        grade_id = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if grade_id in answers:
            cell["source"] = answers[grade_id]
    nb["cells"].insert(1, {"cell_type": "markdown", "metadata": {}, "source":
                           f"{HOSTILE_WORDS}: $T^{{-1}}$ <img src=x onerror=\"{attack}\">"})
    notebook.write_text(json.dumps(nb))   # in place: the student keeps the file


def _hostile_cell_is_inert(teacher, course: Path, student: str) -> None:
    """The student's submission page in formgrader shows the hostile cell's text and runs
    none of it; a script that did run in that page could write (the control)."""
    import sqlite3

    with sqlite3.connect(course / "gradebook.db") as db:
        (submission,) = db.execute(
            "select submitted_notebook.id from submitted_notebook join submitted_assignment "
            "on submitted_notebook.assignment_id = submitted_assignment.id "
            "where submitted_assignment.student_id = ?", (student,)).fetchone()
    ran: list[str] = []
    # a tab of its own: the page's MathJax, from a CDN this closed network does not reach,
    # raises in it, which is no error of the term's
    tab = teacher.context.new_page()
    tab.on("console", lambda message: ran.append(message.text))
    try:
        tab.goto(f"{teacher.hub.url}{teacher.FORMGRADER}/submissions/{submission}/")
        teacher.wait(f"() => document.body.textContent.includes('{HOSTILE_WORDS}')",
                     "the hostile submission's page in formgrader", STEP_TIMEOUT_S, page=tab)
        teacher.shot("hostile-submission", tab)
        tab.wait_for_timeout(1500)
        assert not [m for m in ran if "ran:" in m] and not list(course.glob("PWNED-*")), ran
        tab.evaluate(f"() => {{ {kit.page_attack('control', ('services', 'cobotlab'))} }}")
        deadline = time.monotonic() + STEP_TIMEOUT_S
        while not (course / "PWNED-control").exists() and time.monotonic() < deadline:
            time.sleep(0.25)
        assert (course / "PWNED-control").exists(), "the control script could not write"
        (course / "PWNED-control").unlink()
    finally:
        tab.close()


def _ran_whole(state: dict, saved: Path) -> None:
    """Lab 0 ran whole in JupyterLab, on the page and in the file File > Save wrote:
    tests/test_browser_lab.py's checks of a lab's run (lab 0's run in the browser is this
    one: the viewer's widgets and every cell of the lab, through the hub's JupyterLab), its
    counts continuing from the cells run before (Run All, the fix, Run All again)."""
    assert not errors_on_page(state), errors_on_page(state)
    assert not state["dialogs"], f"JupyterLab showed a dialog: {state['dialogs']}"
    counts = [int(p[1:-2]) if re.fullmatch(r"\[\d+\]:", p) else None
              for p in state["prompts"]]
    assert None not in counts and counts == list(range(counts[0], counts[0] + len(counts))), \
        state["prompts"]
    nb = nbformat.read(saved, as_version=4)
    assert execution_counts(nb) == counts, (execution_counts(nb), counts)
    assert not errors_in_file(nb), errors_in_file(nb)
    assert any(cell.get("outputs") for cell in nb.cells), "no cell printed anything"


def _grades(course: Path) -> dict[str, dict]:
    return kit.read_grades(course)


@pytest.mark.timeout(600)
def test_a_term_in_chromium(hub, browser):
    """Two students and an instructor, through the hub's pages, in Chromium.

    s1 hands in the classic mistake, fixes it (check() then gives every function full
    marks on a second Run All) and hands in again; s2 hands in the mistake too, edited
    into the fetched file, unrun, after the deadline, with a hostile markdown cell. The
    instructor collects in formgrader (its own tab), grades with `cobotlab
    grade` in the grading service's terminal, generates and releases the feedback there;
    each student fetches it and reads their score and reasons. (Two students, not three:
    the one who handed in the reference at once proved nothing s1's second submission
    does not, and a JupyterLab in Chromium costs ~20 s of CPU.)
    """
    s1, s2 = STUDENTS
    for name in STUDENTS:
        _give_lab_settings(name)
    students = {name: Student(hub, browser, name) for name in STUDENTS}
    teacher = Instructor(hub, browser, INSTRUCTOR)
    try:
        # log in: the servers start side by side
        for student in students.values():
            student.log_in()
        for student in students.values():
            student.lab_ready()
        # formgrader cannot be framed by JupyterLab on this hub: why hub.md opens it alone
        csp = students[s1].page.request.get(f"{hub.url}/user/{s1}/lab").headers.get(
            "content-security-policy", "")
        assert "frame-ancestors 'none'" in csp, csp
        # the grading service is the formgrade group's alone
        refused = students[s1].page.request.get(f"{hub.url}{Instructor.FORMGRADER}/")
        assert refused.status == 403, (refused.status, refused.url)
        for student in students.values():
            student.open_assignments()
            student.fetch()
        # s1 types the mistake and runs it: check() showed the loss, then the sanity test
        # stopped Run All. (s2's notebook, its kernel and a Run All of the same cells showed
        # the same and cost about 5 s of CPU: s2 edits the file and hands it in unrun, below.)
        students[s1].open_notebook()
        students[s1].write(_answers(True))
        students[s1].run_all()
        state = students[s1].wait_for_run()
        raised = [t for t in state["stderr"] if "Traceback" in t]
        scores = students[s1].check_scores()
        assert len(raised) == 1 and "AssertionError" in raised[0], state["stderr"]
        got, out_of = scores["invert_pose"]
        assert list(scores) == ["invert_pose"] and got < out_of, scores
        students[s1].save()
        students[s1].submit()
        students[s1].fix_invert_pose()
        assert students[s1].check_scores()["invert_pose"][0] == \
            students[s1].check_scores()["invert_pose"][1]
        # Run All again: every cell runs; check() gives every function full marks
        students[s1].run_all()
        state = students[s1].wait_for_run()
        assert not [t for t in state["stderr"] if "Traceback" in t], state["stderr"]
        scores = students[s1].check_scores()
        assert set(scores) == set(FUNCTIONS), scores
        assert all(got == out_of for got, out_of in scores.values()), scores
        students[s1].save()
        _ran_whole(state, students[s1].home() / ASSIGNMENT / f"{ASSIGNMENT}.ipynb")
        students[s1].submit()   # the second submission is the one graded

        # the deadline passes: the instructor moves it to now, in the grading service
        teacher.open_formgrader()
        teacher.open_terminal()
        now = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
        assert teacher.type(f"nbgrader db assignment add {ASSIGNMENT} --duedate '{now}'",
                            hub.course / ".deadline.done", STEP_TIMEOUT_S) == "0"
        time.sleep(1.1)   # the late one's timestamp is strictly after
        _edit_hostile(students[s2].home() / ASSIGNMENT / f"{ASSIGNMENT}.ipynb", _answers(True))
        students[s2].submit()

        # each submission went into its student's own folder of the private exchange, which
        # no other student can enter; nor can one reach another's server or the hub's record
        inbound = Path(hub.settings["EXCHANGE"]) / "cobotlab" / "inbound"
        assert sorted(p.name for p in inbound.iterdir()) == sorted(STUDENTS)
        assert {n: len(list((inbound / n).iterdir())) for n in STUDENTS} == \
            {s1: 2, s2: 1}
        assert all((inbound / n).stat().st_mode & 0o7777 == 0o2750 for n in STUDENTS)
        for path in (f"/user/{s2}/api/contents", f"/user/{s2}/files/{ASSIGNMENT}",
                     f"/hub/api/users/{s2}"):
            answer = students[s1].page.request.get(f"{hub.url}{path}", max_redirects=0)
            assert answer.status in (302, 403, 404), (path, answer.status)
            assert s2 not in (answer.headers.get("location") or "").split("?")[0], \
                (path, answer.headers)

        # collect, grade, feedback
        teacher.formgrader_action("collect", "Collect")
        assert sorted(p.name for p in (hub.course / "submitted").iterdir()) == sorted(STUDENTS)
        code = teacher.type(f"cobotlab grade \"$PWD\" {ASSIGNMENT} --workers 2 > grade.log 2>&1",
                            hub.course / ".grade.done", 300)
        shutil.copy(hub.course / "grade.log", hub.artefacts / "grade.log")
        assert code == "0", (hub.course / "grade.log").read_text()[-3000:]
        teacher.formgrader_action("generate-feedback", "Generate Feedback")
        teacher.formgrader_action("release-feedback", "Release Feedback")
        teacher.page.goto(f"{hub.url}{teacher.FORMGRADER}/manage_submissions/{ASSIGNMENT}")
        teacher.wait(f"() => document.body.textContent.includes('{s2}')",
                     "formgrader's list of lab 0's submissions", STEP_TIMEOUT_S)
        teacher.shot("submissions")
        _hostile_cell_is_inert(teacher, hub.course, s2)

        grades = _grades(hub.course)
        assert set(grades) == set(STUDENTS), grades
        assert float(grades[s1]["score"]) == float(grades[s1]["max_score"]) == 10.0
        assert float(grades[s2]["score"]) < 10.0, grades[s2]
        assert grades[s2]["timestamp"] > now[:19] >= grades[s1]["timestamp"][:19], grades

        # each student reads their own page
        for name, student in students.items():
            text = student.fetch_feedback()
            score = float(grades[name]["score"])
            assert f"{score:g} / 10" in text, (name, text[:3000])
            if name == s2:
                assert "classic mistake: its translation is -t, not -R^T t" in text, text[:3000]
            else:
                assert "classic mistake" not in text, (name, text[:3000])
        for person in (*students.values(), teacher):
            assert not person.errors, (person.name, person.errors)
    finally:
        for person in (*students.values(), teacher):
            person.close()
        print(f"\nhub term artefacts: {hub.artefacts}")

"""docs/instructors.md, followed literally on a fresh machine.

Every ```bash block of the page runs, in order, in one bash shell (so a `cd` carries over as
it does for a reader) with a fresh, empty HOME, the repository's virtual environment
activated as the page's install block says, and a minimal environment: no course next to the
checkout, nothing in ~/.jupyter, real nbgrader. ```sh blocks (installing, grading a whole
class, a cluster) are not run. Lab 0 only, to stay fast.
"""

from __future__ import annotations

import csv
import getpass
import os
import re
import subprocess
from pathlib import Path

import course_kit as kit
import pytest

from autograder import practice_cache, sandbox

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "instructors.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)


def _blocks(kind: str) -> list[str]:
    return [body for lang, body in FENCE.findall(DOC.read_text()) if lang == kind]


def test_the_page_names_no_checkout_relative_path():
    runnable = "\n".join(_blocks("bash"))
    assert runnable, "no ```bash block in docs/instructors.md"
    assert "../" not in runnable and ".venv" not in runnable
    install = "\n".join(_blocks("sh"))
    assert "source .venv/bin/activate" in install


@pytest.mark.timeout(600)
def test_every_bash_block_runs_in_order_in_a_fresh_home(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    script = "\n".join(["set -euo pipefail", f"source {REPO / '.venv/bin/activate'}",
                        f"cd {home}", *_blocks("bash")])
    env = {"HOME": str(home), "PATH": "/usr/bin:/bin", "LANG": "C.UTF-8",
           "USER": getpass.getuser(), "TMPDIR": str(tmp_path),
           # the run's practice-problem cache, as an instructor's own ~/.cache would be on
           # a second `course init` (drawing the six labs again cost ~10 s of CPU)
           practice_cache.ENV: os.environ[practice_cache.ENV]}
    done = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=580, check=False)
    log = done.stdout[-3000:] + done.stderr[-3000:]
    assert done.returncode == 0, log
    assert "alembic" not in done.stderr and "Traceback" not in done.stderr, log

    course = home / "course"
    # what `cobotlab course init` laid out: the sources, a secret only its owner may read,
    # and a .gitignore that keeps the secret and the grades out of the course's repository
    assert (course / "source" / "lab0_frames" / "lab0_frames.ipynb").is_file()
    secret = course / ".cobotlab" / "secret"
    assert secret.is_file() and (secret.stat().st_mode & 0o077) == 0
    ignored = (course / ".gitignore").read_text().splitlines()
    assert ".cobotlab/secret" in ignored and "grades.csv" in ignored
    config = (course / "nbgrader_config.py").read_text()
    assert f"c.Exchange.root = {str(course / 'exchange')!r}" in config
    assert (course / "exchange" / "cobotlab" / "outbound" / "lab0_frames").is_dir()
    assert not Path("/usr/local/share/nbgrader/exchange/cobotlab/outbound/lab0_frames"
                    ).resolve().is_relative_to(home)
    rows = list(csv.DictReader((course / "grades.csv").open()))
    mine = [r for r in rows if r["student_id"] == getpass.getuser()]
    assert len(mine) == 1 and mine[0]["assignment"] == "lab0_frames", rows
    assert float(mine[0]["score"]) == 0.0 and float(mine[0]["max_score"]) > 0
    assert (course / "feedback_cobotlab" / getpass.getuser() / "lab0_frames"
            / "feedback.html").is_file()
    assert "graded 1 submissions in" in done.stdout and "wall clock" in done.stdout, log
    # scored again from the kept execution, no student code run
    assert "rescored 1 submissions" in done.stdout and "no student code ran" in done.stdout, log
    # the feedback block: the student fetched nbgrader's page with cobotlab's on top
    [page] = (home / "dry-run" / "lab0_frames" / "feedback").glob("*/lab0_frames.html")
    text = page.read_text()
    assert "cobotlab-feedback" in text and "Not implemented yet" in text, text[:2000]
    assert text.index("cobotlab-feedback") < text.index("Lab 0: frames and poses")
    assert (course / ".cobotlab" / "secret").read_text().strip() not in text
    if sandbox.capabilities().bwrap:
        assert "sandbox:rlimits_only" not in mine[0]["flags"]
    # grades to the LMS (Moodle's import, by email) and the class at a glance
    export = (course / "exports" / "lab0_frames_moodle.csv").read_text().splitlines()
    assert export == ["email,lab0_frames", f"{getpass.getuser()}@example.edu,0"], export
    report = course / "reports" / "lab0_frames"
    assert "the class at a glance" in (report / "index.html").read_text()
    assert getpass.getuser() in (report / "scores.csv").read_text()


def test_nbgrader_from_the_venv_works_without_activating_it(tmp_path):
    """`<checkout>/.venv/bin/nbgrader` on a course made by `course init`, PATH without it.

    The course is the run's one `course init` made (a copy: course_kit.initialized_course,
    the same init_course the command calls); `cobotlab course init` itself runs from the
    command line in the page's test above, and a second run of it here cost ~7 s of CPU."""
    home = tmp_path / "home"
    home.mkdir()
    course = kit.initialized_course(home)
    env = {"HOME": str(home), "PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"}
    bin_dir = REPO / ".venv" / "bin"
    done = subprocess.run([str(bin_dir / "nbgrader"), "db", "student", "list"],
                          cwd=course, env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0 and "alembic" not in done.stderr, done.stderr[-2000:]
    assert os.stat(course / "exchange").st_mode & 0o777 == 0o777

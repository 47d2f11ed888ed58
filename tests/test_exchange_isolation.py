"""No student reaches another's work through the private exchange (autograder.exchange).

Real Unix users (made with useradd, removed at the end): two students and an instructor in
an instructors' group. Root sets the exchange up from a roster with `cobotlab course
exchange`, as docs/exchange.md says; everyone's nbgrader reads the lines it writes (here
through JUPYTER_CONFIG_PATH, on a hub /etc/jupyter). Then one term, each command run as
its user: the instructor releases lab 0, both students fetch and submit with nbgrader's own
commands, one of them also leaves traps in his own folder, the instructor collects, grades
with `cobotlab grade`, generates and releases feedback, and each student fetches theirs.
Every attack a student can make on another's submission and feedback, through nbgrader's
commands and the file system (listing, reading, replacing, renaming, deleting, linking),
is tried as that student, knowing the exact names, and must be refused by the kernel.
"""

from __future__ import annotations

import ast
import csv
import grp
import json
import os
import pwd
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import course_kit as kit
import pytest

from autograder import exchange
from autograder.secret import SECRET_ENV, load_secret

ASSIGNMENT = "lab0_frames"
STAFF, TEACHER, ANA, BEN = "exch_staff", "exch_teach", "exch_ana", "exch_ben"
COURSE_ID = "cobotlab"
BIN = Path(sys.executable).parent
DOC = Path(__file__).resolve().parent.parent / "docs" / "exchange.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

# Run as the attacker: each attack on the paths it is given, and how the kernel answered.
ATTACKS = r"""
import errno, json, os, shutil, sys
t = json.loads(sys.argv[1])
out = {}

def attempt(name, action):
    try:
        action()
        out[name] = "done"
    except PermissionError as exc:
        out[name] = "refused"
    except OSError as exc:
        out[name] = errno.errorcode.get(exc.errno, str(exc.errno))

def write(path):
    with open(path, "w") as f:
        f.write("mine now")

attempt("list inbound", lambda: os.listdir(t["inbound"]))
attempt("list their inbound folder", lambda: os.listdir(t["their_inbound"]))
attempt("read their notebook", lambda: open(t["their_notebook"], "rb").read())
attempt("list their submission", lambda: os.listdir(t["their_submission"]))
attempt("replace their notebook", lambda: write(t["their_notebook"]))
attempt("delete their notebook", lambda: os.unlink(t["their_notebook"]))
attempt("delete their submission", lambda: shutil.rmtree(t["their_submission"]))
attempt("rename their submission", lambda: os.rename(t["their_submission"],
                                                     t["my_inbound"] + "/taken"))
attempt("rename their inbound folder", lambda: os.rename(t["their_inbound"],
                                                         t["inbound"] + "/gone"))
attempt("plant a submission in their folder", lambda: os.mkdir(
    t["their_inbound"] + "/" + os.path.basename(t["their_submission"]) + "x"))
attempt("plant a folder in inbound", lambda: os.mkdir(t["inbound"] + "/planted"))
attempt("hard-link their notebook", lambda: os.link(t["their_notebook"],
                                                    t["my_inbound"] + "/linked"))
attempt("chmod their inbound folder", lambda: os.chmod(t["their_inbound"], 0o777))
attempt("list feedback", lambda: os.listdir(t["feedback"]))
attempt("list their feedback folder", lambda: os.listdir(t["their_feedback"]))
attempt("read their feedback", lambda: open(t["their_page"], "rb").read())
attempt("replace their feedback", lambda: write(t["their_page"]))
attempt("delete their feedback", lambda: os.unlink(t["their_page"]))
attempt("rename their feedback folder", lambda: os.rename(t["their_feedback"],
                                                          t["feedback"] + "/gone"))
attempt("plant a page in their feedback folder", lambda: write(t["their_feedback"] + "/x.html"))
attempt("replace the released notebook", lambda: write(t["released"]))
attempt("delete the released notebook", lambda: os.unlink(t["released"]))
attempt("rename the course", lambda: os.rename(t["course"], t["course"] + "-old"))
attempt("make a course in the exchange", lambda: os.mkdir(t["root"] + "/squat"))
# through a link of one's own: the kernel still checks every folder on the way
os.symlink(t["their_submission"], t["my_inbound"] + "/through-a-link")
attempt("read their notebook through a link", lambda: open(
    t["my_inbound"] + "/through-a-link/" + os.path.basename(t["their_notebook"]), "rb").read())
os.unlink(t["my_inbound"] + "/through-a-link")
print(json.dumps(out))
"""


# Run as a student: what the JupyterLab Assignments tab's server side does (nbgrader's
# assignment_list extension, the same exchange classes, the same config).
TAB = r"""
import json, os, sys
from nbgrader.server_extensions.assignment_list.handlers import AssignmentList
course, assignment = sys.argv[1:]
tab = AssignmentList()
tab.root_dir = os.getcwd()
out = {"courses": tab.list_courses(), "before": tab.list_assignments(course)["value"],
       "fetched": tab.fetch_feedback(course, assignment)}
out["after"] = tab.list_assignments(course)["value"]
print(json.dumps(out))
"""


@dataclass
class Machine:
    base: Path
    root: Path          # the exchange
    etc: Path           # the config folder every user's nbgrader reads
    course: Path        # the instructor's course

    def home(self, user: str) -> Path:
        return self.base / "home" / user

    def run(self, user: str, argv, cwd: Path, check: bool = True,
            etc: Path | None = None) -> subprocess.CompletedProcess:
        """``argv`` as ``user`` (its groups too), with its own HOME and the nbgrader config
        of ``etc`` (default: the machine's, which the set-up wrote)."""
        env = {"HOME": str(self.home(user)), "USER": user, "LOGNAME": user,
               "PATH": f"{BIN}:/usr/bin:/bin", "LANG": "C.UTF-8",
               "JUPYTER_CONFIG_PATH": str(etc or self.etc), "OPENBLAS_NUM_THREADS": "1",
               "OMP_NUM_THREADS": "1"}
        done = subprocess.run(["setpriv", f"--reuid={user}", f"--regid={user}",
                               "--init-groups", "--", *map(str, argv)], cwd=cwd, env=env,
                              capture_output=True, text=True, timeout=600, check=False)
        if check:
            assert done.returncode == 0, f"{argv}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        return done

    def nbgrader(self, user: str, *args, cwd: Path | None = None, check: bool = True,
                 etc: Path | None = None):
        cwd = cwd or (self.course if user == TEACHER else self.home(user) / "work")
        return self.run(user, [sys.executable, "-m", "nbgrader", *args], cwd, check, etc)


def _each(step, items) -> list:
    """``step(item)`` for every item at once (each a command of its own user): the
    students act independently, and each nbgrader start costs seconds."""
    with ThreadPoolExecutor(len(items)) as pool:
        return list(pool.map(step, items))


def _quiet(*argv) -> None:
    subprocess.run(argv, capture_output=True, check=False)


def _remove_accounts() -> None:
    for user in (TEACHER, ANA, BEN):
        _quiet("userdel", user)
    _quiet("groupdel", STAFF)
    for user in (TEACHER, ANA, BEN):   # their own groups, if userdel left them
        _quiet("groupdel", user)


def _give(path: Path, user: str) -> None:
    ids = pwd.getpwnam(user)
    for folder, dirs, files in os.walk(path):
        for name in [folder, *(os.path.join(folder, n) for n in dirs + files)]:
            os.chown(name, ids.pw_uid, ids.pw_gid, follow_symlinks=False)


@pytest.fixture(scope="module")
def machine():
    assert os.geteuid() == 0, ("this test makes Unix users and runs as them: run it as root "
                               "(make test does)")
    _remove_accounts()   # a run killed before its teardown
    base = Path(tempfile.mkdtemp(prefix="cobotlab-exchange-", dir="/var/tmp"))
    try:
        os.chmod(base, 0o755)
        subprocess.run(["groupadd", STAFF], check=True)
        for user, groups in ((TEACHER, [STAFF]), (ANA, []), (BEN, [])):
            subprocess.run(["useradd", "--no-create-home", "--user-group", "--shell",
                            "/usr/sbin/nologin", *(["-G", ",".join(groups)] if groups else []),
                            user], check=True)
            (base / "home" / user / "work").mkdir(parents=True)
            os.chmod(base / "home" / user, 0o700)
            _give(base / "home" / user, user)
        os.chmod(base / "home", 0o755)
        (base / "teach").mkdir()
        course = kit.released_course(base / "teach", ASSIGNMENT)
        m = Machine(base, base / "srv" / "exchange", base / "etc", course)
        with (course / "nbgrader_config.py").open("a") as f:   # the course's own config
            f.write(f"c.Exchange.root = {str(m.root)!r}\n")
        _give(base / "teach", TEACHER)
        roster = base / "roster.csv"
        roster.write_text(f"id,first_name,last_name\n{ANA},Ana,A\n{BEN},Ben,B\n")
        done = subprocess.run([BIN / "cobotlab", "course", "exchange", m.root, "--students",
                               roster, "--instructors", STAFF, "--config",
                               m.etc / "nbgrader_config.py"],
                              capture_output=True, text=True, timeout=120, check=False)
        assert done.returncode == 0, done.stdout + done.stderr
        yield m
    finally:
        _remove_accounts()
        shutil.rmtree(base, ignore_errors=True)


def _no_secret() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != SECRET_ENV}


def _answer(m: Machine, student: str, functions: dict[str, str]) -> None:
    """Fill the student's fetched notebook (kept theirs: written in place)."""
    path = m.home(student) / "work" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb"
    nb = json.loads(path.read_text())
    for cell in nb["cells"]:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if gid in functions:
            cell["source"] = functions[gid]
    path.write_text(json.dumps(nb))


@pytest.fixture(scope="module")
def term(machine):
    """The term, up to the feedback released: returns what each step printed."""
    m = machine
    log = {}
    m.nbgrader(TEACHER, "release_assignment", ASSIGNMENT)
    _each(lambda student: m.nbgrader(student, "fetch_assignment", ASSIGNMENT), (ANA, BEN))
    solutions = kit.solution_sources(ASSIGNMENT, ("invert_pose", "compose_chain",
                                                  "pose_from_rotvec"))
    _answer(m, ANA, solutions)                                    # all right: 10 points
    _answer(m, BEN, {"invert_pose": solutions["invert_pose"]})    # one function: 3 points
    _each(lambda student: m.nbgrader(student, "submit", ASSIGNMENT), (ANA, BEN))
    # Ben's traps in his own folder, for the instructor's collect: a later "submission" that
    # is a link to Ana's, a folder named as Ana's, one named as handed in long ago, and a
    # link to her notebook in his real one
    mine = m.root / COURSE_ID / "inbound" / BEN
    [real] = os.listdir(mine)
    ana_sub = _submission(m, ANA)
    traps = (f"import os; os.symlink({str(ana_sub)!r}, {str(mine)!r} + "
             f"'/{BEN}+{ASSIGNMENT}+2099-01-01 00:00:00.000000 UTC+link'); "
             f"os.mkdir({str(mine)!r} + '/{ANA}+{ASSIGNMENT}+2099-01-01 00:00:00.000000 UTC+x'); "
             f"os.mkdir({str(mine)!r} + '/{BEN}+{ASSIGNMENT}+2000-01-01 00:00:00.000000 UTC+y'); "
             f"os.symlink({str(ana_sub / (ASSIGNMENT + '.ipynb'))!r}, "
             f"{str(mine / real)!r} + '/stolen.ipynb')")
    m.run(BEN, [sys.executable, "-c", traps], m.home(BEN))
    log["collect"] = m.nbgrader(TEACHER, "collect", ASSIGNMENT)
    # Graded by the grading account, root here, with nbgrader's generate_feedback (neither
    # touches the exchange): this checkout's interpreter lives under /root, so another user's
    # Python runs on the system's standard library, where the sandbox and nbconvert's HTML
    # fail (tests/test_unprivileged.py builds an environment to grade as an instructor).
    # Then the course is the instructor's again.
    for argv in ([BIN / "cobotlab", "grade", m.course, ASSIGNMENT],
                 [sys.executable, "-m", "nbgrader", "generate_feedback", ASSIGNMENT]):
        done = subprocess.run(argv, capture_output=True, text=True, timeout=600, check=False,
                              env=_no_secret(), cwd=m.course)
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    _give(m.course, TEACHER)
    log["release_feedback"] = m.nbgrader(TEACHER, "release_feedback", ASSIGNMENT)
    return log


def _submission(m: Machine, student: str) -> Path:
    """The student's one real submission in the exchange (as root sees it)."""
    folder = m.root / COURSE_ID / "inbound" / student
    [name] = [n for n in os.listdir(folder) if "2099" not in n and "2000" not in n]
    return folder / name


def _page(m: Machine, student: str) -> Path:
    [page] = (m.root / COURSE_ID / "feedback" / student).glob("*.html")
    return page


def test_two_students_and_an_instructor_through_nbgrader(machine, term):
    m = machine
    # what the instructor collected: each student's own work, none of the traps
    submitted = m.course / "submitted"
    assert sorted(os.listdir(submitted)) == [ANA, BEN]
    for student in (ANA, BEN):
        assert sorted(os.listdir(submitted / student / ASSIGNMENT)) == [
            f"{ASSIGNMENT}.ipynb", f"practice_{ASSIGNMENT}.json.gz", "submission_secret.txt",
            "timestamp.txt"]
        assert (submitted / student / ASSIGNMENT / "timestamp.txt").read_text() != \
            "2099-01-01 00:00:00.000000 UTC"
    collect_log = term["collect"].stdout + term["collect"].stderr
    assert "stolen.ipynb" in collect_log and f"{ANA}+{ASSIGNMENT}+2099" in collect_log
    assert "2000-01-01 00:00:00+00:00, but the folder was made or changed" in collect_log
    rows = {r["student_id"]: r for r in csv.DictReader((m.course / "grades.csv").open())}
    assert float(rows[ANA]["score"]) == 10.0 and float(rows[BEN]["score"]) == 3.0, rows
    # each student fetches their own feedback with nbgrader's command, and it is theirs
    # Ben with nbgrader's commands, Ana through the JupyterLab Assignments tab's server side
    def fetch(student):
        if student == BEN:
            listed = m.nbgrader(BEN, "list", "--cached")
            m.nbgrader(BEN, "fetch_feedback", ASSIGNMENT)
            return "feedback ready to be fetched" in listed.stdout + listed.stderr
        done = m.run(ANA, [sys.executable, "-c", TAB, COURSE_ID, ASSIGNMENT],
                     m.home(ANA) / "work")
        tab = json.loads(done.stdout)
        assert tab["courses"] == {"success": True, "value": [COURSE_ID]}, tab
        assert tab["fetched"] == {"success": True}, tab
        [released] = [a for a in tab["before"] if "submissions" not in a]
        [submitted] = [a for a in tab["before"] if "submissions" in a]
        [after] = [a for a in tab["after"] if "submissions" in a]
        assert released["status"] == "fetched" and submitted["student_id"] == ANA, tab
        assert after["submissions"][-1]["has_local_feedback"], tab
        return submitted["submissions"][-1]["has_exchange_feedback"]

    for (student, score), ready in zip(((ANA, "10"), (BEN, "3")), _each(fetch, (ANA, BEN))):
        assert ready, student
        [page] = (m.home(student) / "work" / ASSIGNMENT / "feedback").glob(
            f"*/{ASSIGNMENT}.html")
        assert f"Score: {score} / 10<" in page.read_text()
        assert load_secret(m.course) not in page.read_text()
    # the modes the set-up and the classes left
    info = os.stat(_submission(m, ANA))
    assert info.st_uid == pwd.getpwnam(ANA).pw_uid and info.st_gid == grp.getgrnam(STAFF).gr_gid
    assert info.st_mode & 0o007 == 0
    assert os.stat(_page(m, ANA)).st_uid == pwd.getpwnam(TEACHER).pw_uid


def _targets(m: Machine, me: str, them: str) -> dict[str, str]:
    course = m.root / COURSE_ID
    theirs = _submission(m, them)
    assert (theirs / f"{ASSIGNMENT}.ipynb").is_file() and _page(m, them).is_file()
    return {"root": str(m.root), "course": str(course), "inbound": str(course / "inbound"),
            "feedback": str(course / "feedback"), "my_inbound": str(course / "inbound" / me),
            "their_inbound": str(course / "inbound" / them), "their_submission": str(theirs),
            "their_notebook": str(theirs / f"{ASSIGNMENT}.ipynb"),
            "their_feedback": str(course / "feedback" / them), "their_page": str(_page(m, them)),
            "released": str(course / "outbound" / ASSIGNMENT / f"{ASSIGNMENT}.ipynb")}


@pytest.mark.parametrize("me, them", [(BEN, ANA), (ANA, BEN)])
def test_a_student_cannot_list_read_replace_or_delete_anothers_work(machine, term, me, them):
    m = machine
    targets = _targets(m, me, them)
    before = {p: Path(targets[p]).read_bytes() for p in ("their_notebook", "their_page",
                                                          "released")}
    done = m.run(me, [sys.executable, "-c", ATTACKS, json.dumps(targets)], m.home(me))
    outcomes = json.loads(done.stdout)
    assert len(outcomes) == 25
    assert {k: v for k, v in outcomes.items() if v != "refused"} == {}, outcomes
    for name, data in before.items():
        assert Path(targets[name]).read_bytes() == data, name
    assert sorted(os.listdir(m.root / COURSE_ID / "inbound")) == [ANA, BEN]


def test_nbgrader_commands_act_for_the_student_only(machine, term):
    m = machine
    # a page of his own making, to release as Ana's feedback from a course of his own
    forged = m.home(BEN) / "work" / "feedback" / ANA / ASSIGNMENT
    forged.mkdir(parents=True)
    for name, text in ((f"{ASSIGNMENT}.html", "forged"), ("timestamp.txt", "x"),
                       ("submission_secret.txt", "guess")):
        (forged / name).write_text(text)
    _give(m.home(BEN) / "work" / "feedback", BEN)
    page = _page(m, ANA).read_bytes()
    # and nbgrader's default exchange classes, which a student may configure for himself
    default = m.base / "default-etc"
    default.mkdir()
    (default / "nbgrader_config.py").write_text(
        f"c = get_config()\nc.Exchange.root = {str(m.root)!r}\n"
        f"c.CourseDirectory.course_id = {COURSE_ID!r}\n")
    listed, as_ana, theirs, collect, release, plain = _each(
        lambda args: m.nbgrader(BEN, *args[1:], check=False, etc=args[0]),
        [(None, "list", "--inbound"), (None, "submit", ASSIGNMENT, f"--student={ANA}"),
         (None, "fetch_feedback", ASSIGNMENT, f"--student={ANA}"), (None, "collect", ASSIGNMENT),
         (None, "release_feedback", ASSIGNMENT), (default, "submit", ASSIGNMENT)])
    assert plain.returncode != 0 and "Unwritable directory" in plain.stderr, plain.stderr
    text = listed.stdout + listed.stderr
    assert listed.returncode == 0 and f"{BEN} {ASSIGNMENT}" in text and ANA not in text, text
    assert as_ana.returncode != 0 and "your own Unix user" in as_ana.stderr, as_ana.stderr
    assert len(os.listdir(m.root / COURSE_ID / "inbound" / ANA)) == 1
    assert theirs.returncode != 0 and "your own Unix user" in theirs.stderr, theirs.stderr
    assert collect.returncode != 0 and "instructors' group" in collect.stderr, collect.stderr
    assert release.returncode != 0 and "feedback not released for exch_ana" in release.stderr
    assert [p.read_bytes() for p in (m.root / COURSE_ID / "feedback" / ANA).iterdir()] == \
        [page]


def test_set_up_refuses_what_would_leave_work_exposed(machine, tmp_path):
    m = machine
    with pytest.raises(ValueError, match="no Unix group 'exch_nogroup'.*groupadd"):
        exchange.set_up(m.base / "other", [ANA], "exch_nogroup")
    with pytest.raises(ValueError, match="'exch_nobody' has no Unix user"):
        exchange.set_up(m.base / "other", ["exch_nobody"], STAFF)
    with pytest.raises(ValueError, match=f"'{TEACHER}' is root or in the instructors"):
        exchange.set_up(m.base / "other", [ANA, TEACHER], STAFF)
    with pytest.raises(ValueError, match="not a Unix user name"):
        exchange.set_up(m.base / "other", ["ana+lab"], STAFF)
    shared = m.base / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)   # what `cobotlab course init` makes for the default exchange
    with pytest.raises(ValueError, match="nbgrader's default exchange is 0777"):
        exchange.set_up(shared, [ANA], STAFF)
    # the classes, pointed at a folder that is not a private exchange, refuse it
    from nbgrader.coursedir import CourseDirectory
    from nbgrader.exchange import ExchangeError

    lister = exchange.PrivateList(coursedir=CourseDirectory(course_id=COURSE_ID), root=str(shared))
    with pytest.raises(ExchangeError, match="not a private exchange"):
        lister.start()
    roster = tmp_path / "roster.csv"
    roster.write_text("student,name\nana,Ana\n")
    with pytest.raises(ValueError, match="no id column"):
        exchange.read_roster(roster)


def test_the_admin_page_runs_as_written(machine):
    """docs/exchange.md's ```bash blocks, in order, in one root shell (as
    tests/test_instructor_docs.py runs instructors.md), with its settings given as the
    page allows; then the folders are as its layout table says."""
    m = machine
    blocks = [body for lang, body in FENCE.findall(DOC.read_text()) if lang == "bash"]
    assert len(blocks) >= 4 and "cobotlab course exchange" in "\n".join(blocks)
    root = m.base / "srv2" / "exchange"
    env = {"PATH": f"{BIN}:/usr/sbin:/usr/bin:/sbin:/bin", "LANG": "C.UTF-8",
           "HOME": str(m.base), "EXCHANGE": str(root), "STAFF": STAFF,
           "INSTRUCTOR": TEACHER, "ROSTER": str(m.base / "roster.csv"),
           "CONFIG": str(m.base / "etc2" / "nbgrader_config.py")}
    done = subprocess.run(["bash", "-c", "\n".join(["set -euo pipefail", *blocks])],
                          cwd=m.base, env=env, capture_output=True, text=True, timeout=120,
                          check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert f"ok: {ANA} cannot list" in done.stdout
    config = (m.base / "etc2" / "nbgrader_config.py").read_text()
    assert exchange.config_block(root, COURSE_ID) in config
    layout = DOC.read_text().split("## The layout", 1)[1].split("```")[1]
    staff = grp.getgrnam(STAFF).gr_gid
    for key, (owner, group, mode) in exchange.MODES.items():
        relative = {"root": "", "course": COURSE_ID}.get(key, f"{COURSE_ID}/{key}")
        path = root / relative.replace("SID", ANA)
        info = os.stat(path)
        uid = pwd.getpwnam(ANA).pw_uid if owner == "student" else 0
        gid = staff if group == "staff" else 0
        assert (info.st_uid, info.st_gid, info.st_mode & 0o7777) == (uid, gid, mode), key
        line = next(x for x in layout.splitlines()
                    if x.strip() and x.split()[0] == f"ROOT/{relative.replace(COURSE_ID, 'cobotlab')}/"
                    .replace("//", "/"))
        assert f"{mode:04o}" in line.split()[2], (line, key)


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports (at any depth of its code), as written."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.add(node.module)
    return names


def test_the_module_imports_only_what_a_student_server_has():
    """It runs in each student's server (the Assignments tab): the standard library,
    nbgrader (which that tab is), autograder.safe_files and autograder.roster, which need
    the library only."""
    package = Path(exchange.__file__).parent
    outside = {n for n in _imports(package / "exchange.py")
               if n.split(".")[0] not in sys.stdlib_module_names}
    # autograder.gradebook only inside PrivateCollect, which runs on the instructors' side
    assert outside == {"nbgrader.exchange", "nbgrader.utils", "autograder.safe_files",
                       "autograder.roster", "autograder.gradebook"}
    for light in ("safe_files.py", "roster.py"):
        assert all(n.split(".")[0] in sys.stdlib_module_names
                   for n in _imports(package / light)), _imports(package / light)

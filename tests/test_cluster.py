"""Grading on a Dask cluster (issue 25, item 5): `cobotlab grade --cluster`.

The cluster is real: a distributed.LocalCluster of two worker processes speaking TLS only
(Security.temporary(): every connection needs a certificate its CA signed), each grading in
the same bubblewrap sandbox as a local run, with the grading secret in the workers'
environment, never in a task. One worker process is killed (SIGKILL) while it grades; Dask
reruns its task elsewhere, and every submission still gets exactly one row, with the scores a
local run gives. The rest checks what the trusted side refuses: unauthenticated schedulers,
workers with another secret, and replies that do not add up.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import course_kit as kit
import pytest
from nbgrader.api import Gradebook

from autograder import checks, cluster, grading, registry, sandbox
from autograder.course import grade_course
from cobotlab.cli import main

distributed = pytest.importorskip("distributed")
pytest.importorskip("cryptography")

ASSIGNMENT = "lab0_frames"
FUNCTIONS = ("invert_pose", "compose_chain", "pose_from_rotvec")


# --------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "127.0.0.1:8786",
                                     "tcp://10.0.0.5:8786", "ws://127.0.0.1:8786",
                                     "inproc://x"])
def test_unauthenticated_or_unknown_schedulers_are_refused(address):
    with pytest.raises(ValueError, match="unauthenticated|expected tls://"):
        cluster.connect(address)


def test_tls_without_a_ca_and_client_certificate_is_refused(monkeypatch):
    for name in list(os.environ):
        if name.startswith("DASK_DISTRIBUTED__COMM__TLS"):
            monkeypatch.delenv(name)
    with pytest.raises(ValueError, match="CA certificate and a client certificate"):
        cluster.security_from()


def test_cli_refuses_tcp_with_a_clear_message(tmp_path, capsys):
    code = main(["grade", str(tmp_path), ASSIGNMENT, "--cluster", "tcp://127.0.0.1:8786"])
    assert code == 2
    err = capsys.readouterr().err
    assert "refusing the unauthenticated scheduler" in err and "tls://" in err


def test_ctrl_c_cancels_the_task_within_seconds():
    class Pending:
        cancelled = False

        def result(self, timeout):
            time.sleep(timeout)
            raise TimeoutError

        def cancel(self):
            self.cancelled = True

    grader = cluster.ClusterGrader(client=None, address="test")
    future = Pending()
    threading.Timer(0.3, sandbox.stop_all).start()
    started = time.monotonic()
    try:
        with pytest.raises(sandbox.Interrupted):
            grader._wait(future)
    finally:
        sandbox.allow_starts()
    assert future.cancelled and time.monotonic() - started < 3


# --------------------------------------------------------------------------- the wire


def _full_marks() -> grading.SubmissionGrade:
    grade = grading.SubmissionGrade("ada", ASSIGNMENT, flags=["suspicious_x"], notes=["n"])
    for spec in checks.SPECS[ASSIGNMENT]:
        result = checks.score_function(spec, [], [])
        for c in result.checks:
            c.credit, c.n_trials, c.n_full = 1.0, 8, 8
        result.points = spec.points
        grade.functions.append(result)
    grade.cell_origins = [grading.CellOrigin(f"{ASSIGNMENT}.ipynb", 3, 1)]
    grade.cell_runs = [grading.CellRun(grade.cell_origins[0], "", "", "printed", "")]
    grade.kernel_checks = {"invert_pose": None}
    return grade


def _decode(data):
    return cluster.grade_from_wire(json.loads(json.dumps(data)), ASSIGNMENT, "ada",
                                   {f"{ASSIGNMENT}.ipynb"})


def test_a_valid_reply_round_trips():
    grade = _full_marks()
    back = _decode(cluster.grade_to_wire(grade))
    assert back.score == grade.score == 10.0 and back.max_score == 10.0
    assert [f.name for f in back.functions] == list(FUNCTIONS)
    assert back.flags == grade.flags and back.cell_runs == grade.cell_runs
    assert back.kernel_checks == {"invert_pose": None}
    # units and descriptions are the local spec's, not the worker's
    spec = checks.SPECS[ASSIGNMENT][0]
    assert back.functions[0].checks[0].unit == spec.checks[0].unit


def _tampered(edit):
    data = cluster.grade_to_wire(_full_marks())
    edit(data)
    return data


@pytest.mark.parametrize("edit, why", [
    (lambda d: d["functions"][0].update(points=99.0), "outside"),
    (lambda d: d["functions"][0].update(points=float("nan")), "not finite"),
    (lambda d: d["functions"][0].update(points=-1.0), "outside"),
    (lambda d: d["functions"][0].update(max_points=100.0), "out of 100 points"),
    (lambda d: d["functions"][0].update(name="answer_key"), "expected function"),
    (lambda d: d["functions"].reverse(), "expected function"),
    (lambda d: d["functions"].pop(), "functions scored"),
    (lambda d: d["functions"][0]["checks"][0].update(credit=0.0), "check credits give"),
    (lambda d: d["functions"][0]["checks"][0].update(credit=2.0), "outside"),
    (lambda d: d["functions"][0]["checks"][0].update(n_full=True), "count"),
    (lambda d: d["functions"][0]["checks"][0].update(name="other"), "not this lab's"),
    (lambda d: d.update(student_id="bo"), "another submission"),
    (lambda d: d.update(seconds=float("inf")), "not finite"),
    (lambda d: d.update(flags="a;b"), "not a list"),
    (lambda d: d["cell_origins"].append(["/etc/passwd", 1, 1]), "notebooks sent"),
    (lambda d: d.update(kernel_checks={str(i): None for i in range(40)}), "too many"),
])
def test_replies_that_do_not_add_up_are_refused(edit, why):
    with pytest.raises(cluster.WireRefused, match=why):
        _decode(_tampered(edit))


def test_strings_are_capped():
    data = _tampered(lambda d: d.update(flags=["x" * 10_000], notes=["y" * 10_000]))
    back = _decode(data)
    assert len(back.flags[0]) == 200 and len(back.notes[0]) == 1000


# --------------------------------------------------------------------------- a real cluster


@pytest.fixture(scope="module")
def released(tmp_path_factory):
    return kit.released_course(tmp_path_factory.mktemp("released"), ASSIGNMENT)


def _submit_class(course):
    solutions = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    kit.submit(course, ASSIGNMENT, "reference", replace=solutions)
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace={
        **solutions, "invert_pose": solutions["invert_pose"].replace("-R.T @ t", "-t")})
    for name in ("reply_flood", "huge_values"):
        case = kit.corpus(ASSIGNMENT)[name]
        kit.submit(course, ASSIGNMENT, name, replace=case["replace"], extra=case["extra"])


def _cobotlab_cells(course) -> dict:
    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        return {s.student.id: {g.name: g.auto_score for nb in s.notebooks for g in nb.grades}
                for s in gb.assignment_submissions(ASSIGNMENT)}


# sleepers are cut at 2x their limit, as in the corpus batches: the cluster is tested here
LIMITS = grading.Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=60, wall_factor=2)
COLUMNS = ("student_id", "raw_score", "score", "max_score")


def _comparable(row: dict) -> tuple:
    flags = [f for f in row["flags"].split(";") if f and not f.startswith("timed_out:")]
    return (*(row[c] for c in COLUMNS), flags)


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="needs bubblewrap")
def test_a_tls_cluster_grades_as_locally_even_when_a_worker_dies(released, tmp_path,
                                                                  monkeypatch):
    from distributed import Client, LocalCluster
    from distributed.security import Security

    home, away = tmp_path / "home", tmp_path / "away"
    home.mkdir()
    away.mkdir()
    local, remote = kit.fresh_course(released, home), kit.fresh_course(released, away)
    for course in (local, remote):
        _submit_class(course)
    # the workers hold the secret (a Kubernetes Secret in a real deployment), set before
    # their processes start; tasks never carry it
    monkeypatch.setenv(grading.SECRET_ENV, grading.load_secret(remote))

    local_rows = grade_course(local, ASSIGNMENT, workers=2, limits=LIMITS, quiet=True,
                              run_nbgrader=True)

    security = Security.temporary()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, protocol="tls",
                      host="127.0.0.1", security=security, dashboard_address=None) as dask, \
            Client(dask, security=security, set_as_default=False) as watcher:
        grader = cluster.connect(dask.scheduler_address, security=security)
        try:
            with pytest.raises(ValueError, match="does not hold this course's grading secret"):
                grader.check(ASSIGNMENT, "another-course-secret-0123456789")
            pids = watcher.run(os.getpid)
            outcome: dict = {}

            def run():
                try:
                    outcome["rows"] = grade_course(remote, ASSIGNMENT, workers=2, limits=LIMITS,
                                                   quiet=True, run_nbgrader=True,
                                                   cluster=grader)
                except BaseException as exc:  # noqa: BLE001 - reported below
                    outcome["error"] = exc

            grading_thread = threading.Thread(target=run)
            grading_thread.start()
            killed = None
            deadline = time.monotonic() + 120
            while killed is None and grading_thread.is_alive() and time.monotonic() < deadline:
                running = watcher.run(lambda dask_worker: [
                    str(t.key) for t in dask_worker.state.executing])
                busy = [(w, keys[0]) for w, keys in running.items()
                        if keys and keys[0].startswith("cobotlab-grade")]
                if busy:
                    time.sleep(0.5)   # well inside its sandboxed run
                    worker, key = busy[0]
                    os.kill(pids[worker], signal.SIGKILL)
                    killed = key
                time.sleep(0.1)
            grading_thread.join(timeout=400)
        finally:
            grader.close()
        # no certificate, no connection
        with pytest.raises(Exception):   # noqa: B017 - refused by the TLS handshake
            Client(dask.scheduler_address, timeout=5, set_as_default=False)
    assert "error" not in outcome, outcome.get("error")
    assert killed is not None, "no task was seen running to kill its worker"

    rows = outcome["rows"]
    ids = [r["student_id"] for r in rows]
    assert sorted(ids) == sorted({"reference", "blank", "wrong", "reply_flood",
                                  "huge_values"}) == sorted(
        r["student_id"] for r in local_rows), "one row per submission"
    by_id = {r["student_id"]: r for r in rows}
    # the same scores and flags as the local run, the killed worker's submission too. Only
    # `timed_out:` may differ: reply_flood builds 64 MB replies close to its 3 s CPU limit,
    # so on a loaded machine a function of it times out in one run and not the other (it
    # scores 0 either way).
    assert {r["student_id"]: _comparable(r) for r in local_rows} == \
        {s: _comparable(r) for s, r in by_id.items()}
    assert by_id["reference"]["score"] == 10.0 and by_id["blank"]["score"] == 0.0
    assert by_id["reply_flood"]["score"] == 0.0
    # 400-digit answers and a forged reply cost the student, never the grader (no
    # grader_error on the worker's side, nor in this process's validation of its reply)
    assert by_id["huge_values"]["score"] == 0.0
    assert "grader_error" not in by_id["huge_values"]["flags"]
    assert 0 < by_id["wrong"]["score"] < 10
    # recorded once per submission: grades.csv and the gradebook as a local run has them
    csv_rows = kit.read_grades(remote)
    assert sorted(csv_rows) == sorted(ids)
    assert _cobotlab_cells(remote) == _cobotlab_cells(local)
    for student in ids:
        assert (remote / "feedback_cobotlab" / student / ASSIGNMENT / "feedback.html").is_file()
    run = json.loads((remote / ".cobotlab" / "runs.jsonl").read_text().splitlines()[-1])
    assert any("graded on the Dask cluster" in n for n in run["notes"])
    assert not any(grading.load_secret(remote) in n for n in run["notes"])



@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_course_lab_reaches_the_workers_only_with_the_course(tmp_path, monkeypatch):
    """An instructor's own lab lives in the course folder, not in the workers' image: a
    worker without the course is refused, naming the setting; with $COBOTLAB_COURSE on a
    copy of the course, it proves the same lab version."""
    from distributed import LocalCluster
    from distributed.security import Security

    from cobotlab.authoring import new_lab

    course = tmp_path / "course"
    new_lab("gauge_offset", course)
    secret = "0123456789abcdef" * 4
    monkeypatch.setenv(grading.SECRET_ENV, secret)
    monkeypatch.delenv(registry.COURSE_ENV, raising=False)
    monkeypatch.chdir(tmp_path)   # no cobotlab.toml at or above the workers' folder
    security = Security.temporary()
    try:
        for workers_have_the_course in (False, True):
            registry.use_course(course if workers_have_the_course else None)
            with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                              protocol="tls", host="127.0.0.1", security=security,
                              dashboard_address=None) as dask:
                registry.use_course(course)   # the instructor's side knows its course
                grader = cluster.connect(dask.scheduler_address, security=security)
                try:
                    if workers_have_the_course:
                        assert "graded on the Dask cluster" in grader.check("gauge_offset",
                                                                            secret)
                    else:
                        with pytest.raises(ValueError, match="cannot load the lab gauge_offset"
                                           ".*COBOTLAB_COURSE"):
                            grader.check("gauge_offset", secret)
                finally:
                    grader.close()
    finally:
        registry.use_course(None)

"""Grading on a Dask cluster (issue 25, item 5): `cobotlab grade --cluster`.

The cluster is real: a distributed.LocalCluster of two worker processes speaking TLS only
(Security.temporary(): every connection needs a certificate its CA signed), each grading in
the same bubblewrap sandbox as a local run, on the problems' inputs each task carries: the
workers hold no grading secret. One worker process is killed (SIGKILL) while it grades; Dask
reruns its task elsewhere, and every submission still gets exactly one row, with the scores a
local run gives. The rest checks what the trusted side refuses (unauthenticated schedulers,
replies that do not add up) and what a task carries: no secret, no tolerance.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import tempfile
import threading
import time
from pathlib import Path

import course_kit as kit
import pytest
from nbgrader.api import Gradebook

from autograder import checks, cluster, executions, registry, sandbox
from autograder.inside import wire
from autograder.outcomes import Place, note_place, student_words
from autograder.pipeline.cells import CellOrigin
from autograder.pipeline.execution import CellRun, Execution, FunctionRun, cell_error_note
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.problems import draw_problems
from autograder.pipeline.score import score_execution
from autograder.pipeline.worker import Limits
from autograder.secret import SECRET_ENV, load_secret
from cobotlab.cli import main

# Found, not imported: importing distributed here cost every test worker 1.4 s of CPU while
# collecting, whether it ran this file or not; the tests import it where they use it.
pytestmark = pytest.mark.skipif(
    not all(importlib.util.find_spec(name) for name in ("distributed", "cryptography")),
    reason="needs distributed and cryptography (dask's cluster extra)")

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

SECRET = "cluster-test-secret-" + "0" * 24


def _execution() -> Execution:
    """A real execution: the reference of lab 0 run in this process on one student's
    problems (the cluster's reply carries exactly this)."""
    problems = draw_problems(ASSIGNMENT, "ada", SECRET, None)
    ex = Execution("ada", ASSIGNMENT, suspicious=["suspicious_x"],
                   notes=["n", cell_error_note("KeyError: 'frames'", Place(1, 4)),
                          cell_error_note("timed out after 40 s", Place(0))])
    for spec in checks.SPECS[ASSIGNMENT]:
        answer = spec.code_mistakes[0].func if spec.name == "compose_chain" else None
        outcomes = []
        for trial in problems.trials[spec.name]:
            value = trial.truth if answer is None else answer(*trial.args)
            outcomes.append(checks.TrialOutcome(value=value, seconds=0.01, cpu_seconds=0.01))
        ex.functions.append(FunctionRun(spec.name, outcomes))
    ex.functions[0].outcomes[0] = checks.TrialOutcome(
        error="timed out", failure=checks.Failure(
            checks.Failed.TIMED_OUT, place=Place(1, 2)))
    ex.cell_origins = [CellOrigin(f"{ASSIGNMENT}.ipynb", 3, 1),
                       CellOrigin(f"{ASSIGNMENT}.ipynb", 5, 2)]
    ex.cell_runs = [CellRun(ex.cell_origins[0], "", "printed", ""),
                    CellRun(ex.cell_origins[1], "KeyError: 'frames'", exception="KeyError",
                            message="'frames'", place=Place(1, 4))]
    ex.kernel_tests = ["invert_pose"]
    ex.kernel_runs = {"invert_pose": FunctionRun("invert_pose", [
        checks.TrialOutcome(value=t.truth) for t in problems.kernel_trials("invert_pose")])}
    return ex


def _decode(data):
    return executions.from_wire(json.loads(json.dumps(data)), ASSIGNMENT, "ada",
                                {f"{ASSIGNMENT}.ipynb"})


def test_an_execution_round_trips_and_scores_the_same():
    ex = _execution()
    back = _decode(executions.to_wire(ex))
    problems = draw_problems(ASSIGNMENT, "ada", SECRET, None)
    before, after = score_execution(problems, ex), score_execution(problems,
                                                                                  back)
    assert after.functions == before.functions and after.flags == before.flags
    assert after.score == before.score and 0 < before.score < before.max_score
    assert back.cell_runs == ex.cell_runs and back.kernel_tests == ["invert_pose"]
    assert (back.cell_runs[1].exception, back.cell_runs[1].place) == ("KeyError", Place(1, 4))
    assert back.functions[0].outcomes[0].failure.kind is checks.Failed.TIMED_OUT
    assert back.functions[0].outcomes[0].failure.place == Place(1, 2)
    assert back.notes == ex.notes and [note_place(n) for n in back.notes] == [
        None, Place(1, 4), Place(0)]
    assert [student_words(n) for n in back.notes] == [None, "KeyError: 'frames'",
                                                      "timed out after 40 s"]
    assert before.kernel_checks == after.kernel_checks == {"invert_pose": None}


def _keys(data) -> set[str]:
    if isinstance(data, dict):
        return set(data) | {k for v in data.values() for k in _keys(v)}
    if isinstance(data, (list, tuple)):
        return {k for v in data for k in _keys(v)}
    return set()


def test_a_task_carries_no_secret_tolerance_or_one_call_truth():
    """The cluster never holds the secret: a task is the notebook and the inputs."""
    for lab in ("lab0_frames", "lab3_servoing"):
        problems = draw_problems(lab, "ada", SECRET, None)
        payload = cluster.task_payload([("x.ipynb", b"{}")], problems, LIMITS, False)
        text = json.dumps(payload, default=str)
        assert SECRET not in text and not _keys(payload) & {"tol", "secret", "nonce"}
        wired = payload["problems"]["trials"]
        for spec in checks.SPECS[lab]:
            rows = [wire.decode(r) for r in wired[spec.name]]
            assert all(set(r) == {"args", "truth"} for r in rows)
            if spec.drive is None:   # a closed loop flies by its truth; nothing else gets one
                assert all(r["truth"] is None for r in rows), spec.name
        back = executions.problems_from_wire(json.loads(json.dumps(payload["problems"])),
                                             lab, "ada")
        assert executions.inputs_digest(back) == executions.inputs_digest(problems)


def _tampered(edit):
    data = executions.to_wire(_execution())
    edit(data)
    return data


@pytest.mark.parametrize("edit, why", [
    (lambda d: d["functions"][0].update(name="answer_key"), "not invert_pose's"),
    (lambda d: d["functions"].reverse(), "not invert_pose's"),
    (lambda d: d["functions"].pop(), "functions run"),
    (lambda d: d["functions"][0]["outcomes"].extend(d["functions"][0]["outcomes"] * 9),
     "list of at most"),
    (lambda d: d["functions"][0]["outcomes"][1].update(seconds=float("inf")), "outside"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(kind="full_marks"),
     "no kind of failure"),
    (lambda d: d["functions"][0]["outcomes"][1].update(value={"__nd__": "x", "dtype": "o"}),
     "malformed array"),
    (lambda d: d.update(student_id="bo"), "another submission"),
    (lambda d: d.update(seconds=float("nan")), "outside"),
    (lambda d: d.update(suspicious="a;b"), "not a list"),
    (lambda d: d.update(notes=["a bare string"]), "not a list"),
    (lambda d: d["cell_origins"].append(["/etc/passwd", 1, 1]), "notebooks"),
    (lambda d: d["kernel_runs"].update(compose_chain=d["kernel_runs"]["invert_pose"]),
     "no test cell called"),
    (lambda d: d.update(format=0), "format"),
    # kept in format 1, whose messages held their places in words: refused, naming the fix
    (lambda d: d.update(format=1), "format 1, not 2 .by an older cobotlab.*run the student "
     "code again.*`cobotlab grade` without --rescore"),
    (lambda d: d["notes"][1].pop(), r"not \[text, what a student reads, place\]"),
    (lambda d: d["notes"][1].__setitem__(2, "cell 1, line 4"), "notes.place is not a list"),
    (lambda d: d["notes"][1].__setitem__(2, [1, -4]), "notes.place.line is not a count"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place=[-1, 2]),
     "place.cell is not a count"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place=[1, True]),
     "place.line is not a count"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place=[1, 0]),
     "Place.line = 0"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place=[10**6, 2]),
     "Place.cell"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place=[1, 2, 3]),
     "list of at most 2"),
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(place="cell 1, line 2"),
     "not a list"),
    # kept by the cobotlab that wrote a place as words: refused, naming what grades it again
    (lambda d: d["functions"][0]["outcomes"][0]["failure"].update(
        {"where": "cell 1, line 2"}) or d["functions"][0]["outcomes"][0]["failure"].pop(
        "place"), "older cobotlab.*`cobotlab grade` without --rescore"),
    # a cell run kept with its exception as words only ("where", no "exception"): refused
    (lambda d: d["cell_runs"][1].update({"where": "cell 1, line 4"}) or [
        d["cell_runs"][1].pop(k) for k in ("exception", "message", "place")],
     "cell_runs has no exception.*older cobotlab"),
    (lambda d: d["cell_runs"][1].update(exception=["KeyError"]), "cell_runs.exception is not"),
    (lambda d: d["cell_runs"][1].update(message=None), "cell_runs.message is not"),
    (lambda d: d["cell_runs"][1].update(place=[1, 0]), "Place.line = 0"),
    (lambda d: d["cell_runs"][1].pop("place"), "cell_runs has no place"),
])
def test_replies_that_do_not_add_up_are_refused(edit, why):
    with pytest.raises(executions.ExecutionRefused, match=why):
        _decode(_tampered(edit))


def test_strings_are_capped():
    data = _tampered(lambda d: d.update(suspicious=["x" * 10_000],
                                        notes=[["y" * 10_000, "z" * 10_000, None]]))
    back = _decode(data)
    assert len(back.suspicious[0]) == 200 and len(back.notes[0]) == 1000
    assert len(back.notes[0].for_student) == 1000


# --------------------------------------------------------------------------- a real cluster


@pytest.fixture(scope="module")
def released(tmp_path_factory):
    return kit.released_course(tmp_path_factory.mktemp("released"), ASSIGNMENT)


# The case of the corpus whose attack crosses the cluster's wire: its forged reply and
# 400-digit answers reach this process's validation from a Dask task. An attack that stays
# inside the sandbox meets the same Worker there as in a local run: reply_flood (refused from
# its header by tests/test_grading_sandbox.py) cost this file 17 s of CPU (66 against 49),
# graded locally and on the cluster, and met nothing of the cluster; it is graded here too in
# the full corpus (COBOTLAB_FULL_CORPUS=1, benchmarks/adversarial_corpus.py).
CLUSTER_CASES = ("huge_values", "reply_flood") if kit.full_corpus() else ("huge_values",)


def _submit_class(course):
    solutions = kit.solution_sources(ASSIGNMENT, FUNCTIONS)
    kit.submit(course, ASSIGNMENT, "reference", replace=solutions)
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace={
        **solutions, "invert_pose": solutions["invert_pose"].replace("-R.T @ t", "-t")})
    for name in CLUSTER_CASES:
        case = kit.corpus(ASSIGNMENT)[name]
        kit.submit(course, ASSIGNMENT, name, replace=case["replace"], extra=case["extra"])


def _cobotlab_cells(course) -> dict:
    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        return {s.student.id: {g.name: g.auto_score for nb in s.notebooks for g in nb.grades}
                for s in gb.assignment_submissions(ASSIGNMENT)}


# sleepers are cut at 2x their limit, as in the corpus batches: the cluster is tested here
LIMITS = Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=60, wall_factor=2)
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
    # the workers hold no secret: the tasks carry the problems' inputs
    monkeypatch.delenv(SECRET_ENV, raising=False)

    local_rows = grade_course(local, ASSIGNMENT, workers=2, limits=LIMITS, quiet=True,
                              run_nbgrader=True)

    security = Security.temporary()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, protocol="tls",
                      host="127.0.0.1", security=security, dashboard_address=None) as dask, \
            Client(dask, security=security, set_as_default=False) as watcher:
        grader = cluster.connect(dask.scheduler_address, security=security)
        try:
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
                    killed, killed_pid = key, pids[worker]
                time.sleep(0.1)
            grading_thread.join(timeout=400)
        finally:
            grader.close()
        # no certificate, no connection
        with pytest.raises(Exception):   # noqa: B017 - refused by the TLS handshake
            Client(dask.scheduler_address, timeout=5, set_as_default=False)
    assert "error" not in outcome, outcome.get("error")
    assert killed is not None, "no task was seen running to kill its worker"
    # what the killed worker's task left in the temporary folder (its sandbox's folder, its
    # copy of the student's notebook) was removed by the task that ran next on the machine
    left = [str(p) for prefix in sandbox.PRIVATE_PREFIXES
            for p in Path(tempfile.gettempdir()).glob(f"{prefix}{killed_pid}-*")]
    assert not left, left

    rows = outcome["rows"]
    ids = [r["student_id"] for r in rows]
    assert sorted(ids) == sorted({"reference", "blank", "wrong", *CLUSTER_CASES}) == sorted(
        r["student_id"] for r in local_rows), "one row per submission"
    by_id = {r["student_id"]: r for r in rows}
    # the same scores and flags as the local run, the killed worker's submission too (but
    # `timed_out:`: on a loaded machine a call close to its CPU limit may time out in one run
    # and not the other)
    assert {r["student_id"]: _comparable(r) for r in local_rows} == \
        {s: _comparable(r) for s, r in by_id.items()}
    assert by_id["reference"]["score"] == 10.0 and by_id["blank"]["score"] == 0.0
    if "reply_flood" in by_id:
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
    assert not any(load_secret(remote) in n for n in run["notes"])



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
                        assert "graded on the Dask cluster" in grader.check("gauge_offset")
                    else:
                        with pytest.raises(ValueError, match="cannot load the lab gauge_offset"
                                           ".*COBOTLAB_COURSE"):
                            grader.check("gauge_offset")
                finally:
                    grader.close()
    finally:
        registry.use_course(None)

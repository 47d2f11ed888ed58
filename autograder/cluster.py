"""Grade on a Dask cluster: ``cobotlab grade COURSE LAB --cluster ADDRESS``.

Stage 2 of :func:`autograder.course.grade_course` (execute untrusted code) moves to the
workers of a Dask distributed cluster, the engine JupyterHub-on-Kubernetes deployments run
beside the hub (dask-gateway); stages 1 and 3 stay in this trusted process. No scheduler or
RPC layer of our own: Dask schedules, retries and moves the data.

- **One task per frozen submission.** The task carries the frozen notebook's bytes (never a
  path on this machine), the assignment, the student id, the run's nonce and the limits; on
  its worker it runs :func:`autograder.grading.grade_notebook`, the same bubblewrap sandbox
  as a local run, and returns one JSON text of plain numbers and strings.
- **The trusted side validates before it records.** :func:`grade_from_wire` rebuilds the
  :class:`~autograder.grading.SubmissionGrade` only from a reply whose functions are this
  lab's, in order, each out of its own points, with points that follow from the check
  credits by the lab's own weights, finite where a score is concerned, counts within bounds
  and every string capped; the units and descriptions come from the local specs. A reply that
  fails is the grader's failure (retried, then no score), never a student's grade.
- **The secret stays on the workers.** Each worker reads it from ``$COBOTLAB_GRADING_SECRET``
  (a Kubernetes Secret), as a shard job does; tasks never carry it, so it is in no task
  graph, scheduler memory, dashboard or log. Each reply names the secret by an HMAC
  fingerprint, which must match this course's, so a worker with another course's secret
  cannot grade on other problems unnoticed.
- **Authenticated only.** A ``tls://`` scheduler with Dask's TLS security (mutual: the
  scheduler accepts only clients and workers whose certificate the course's CA signed), or a
  dask-gateway cluster (the gateway's authentication, then the per-cluster TLS certificate
  it issues). A plain ``tcp://`` address is refused: a Dask scheduler runs any function it is
  sent, so an unauthenticated one is code execution for anyone who reaches its port, and on
  a shared course server "localhost" is every account on it.
- **Exactly once.** Dask reruns a task whose worker is lost (``distributed.scheduler.
  allowed-failures``); each submission has one task at a time, under a key named after the
  student, and its first validated reply is the one recorded.
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import ipaddress
import json
import math
import re
import shutil
import tempfile
import threading
import uuid
from pathlib import Path
from urllib.parse import urlsplit

from autograder import checks, grading, registry, sandbox
from autograder.freeze import printable

__all__ = ["ClusterGrader", "connect", "grade_to_wire", "grade_from_wire",
           "secret_fingerprint", "WireRefused"]

# The largest reply accepted (JSON text): every cell's captured output at its 4 KB caps.
MAX_REPLY_BYTES = 32 * 2**20
# The largest submission shipped to a worker (freeze caps one file at 20 MB).
MAX_NOTEBOOK_BYTES = 64 * 2**20
# How often a waiting thread looks for Ctrl-C (sandbox.stop_all) while its task runs.
POLL_S = 0.5


class WireRefused(ValueError):
    """A worker's reply failed validation: nothing of it is recorded."""


# --------------------------------------------------------------------------- fingerprints


def secret_fingerprint(secret: str) -> str:
    """Names a grading secret without revealing it (HMAC-SHA256 of a fixed label)."""
    return hmac.new(secret.encode(), b"cobotlab grading secret fingerprint",
                    hashlib.sha256).hexdigest()[:16]


def spec_digest(assignment: str) -> str:
    """The lab's graded functions, points, checks and weights, and the hash of its scoring
    and private spec files (:func:`autograder.registry.spec_hash`), hashed: a worker whose
    lab version differs would score out of other totals or draw other problems."""
    shape = [(s.name, s.points, [(c.name, c.weight) for c in s.checks])
             for s in checks.SPECS[assignment]]
    shape.append(registry.spec_hash(assignment))
    return hashlib.sha256(json.dumps(shape).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- the wire


def grade_to_wire(grade: grading.SubmissionGrade) -> dict:
    """A :class:`~autograder.grading.SubmissionGrade` as plain numbers and strings."""
    return {
        "student_id": grade.student_id, "assignment": grade.assignment,
        "functions": [{
            "name": f.name, "points": f.points, "max_points": f.max_points,
            "checks": [{"name": c.name, "credit": c.credit, "n_full": c.n_full,
                        "n_trials": c.n_trials, "worst_error": c.worst_error,
                        "median_error": c.median_error, "tolerance": c.tolerance,
                        "n_voided": c.n_voided} for c in f.checks],
            "errors": list(f.errors), "n_problems": f.n_problems, "n_failed": f.n_failed,
            "error_counts": dict(f.error_counts), "forbidden": list(f.forbidden)}
            for f in grade.functions],
        "flags": list(grade.flags), "notes": list(grade.notes), "seconds": grade.seconds,
        "cell_origins": [[o.notebook, o.position, o.prompt] for o in grade.cell_origins],
        "cell_runs": [{"origin": [r.origin.notebook, r.origin.position, r.origin.prompt],
                       "error": r.error, "where": r.where, "stdout": r.stdout,
                       "stderr": r.stderr} for r in grade.cell_runs],
        "kernel_checks": dict(grade.kernel_checks),
    }


def _text(value, limit: int, what: str) -> str:
    if not isinstance(value, str):
        raise WireRefused(f"{what} is not a string")
    return value[:limit]


def _count(value, what: str, top: int = 10**6) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= top:
        raise WireRefused(f"{what} is not a count within 0..{top}")
    return value


def _number(value, what: str, finite: bool = True, low=-math.inf, high=math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise WireRefused(f"{what} is not a number")
    try:
        value = float(value)
    except OverflowError:   # an integer of hundreds of digits: no score or time is that
        raise WireRefused(f"{what} is an integer too large for a float") from None
    if math.isnan(value) or math.isinf(value):
        if finite:
            raise WireRefused(f"{what} is not finite")
        return value   # an error figure with no usable answer behind it (feedback says so)
    if not low <= value <= high:
        raise WireRefused(f"{what} = {value:g} is outside {low:g}..{high:g}")
    return value


def _items(value, top: int, what: str) -> list:
    if not isinstance(value, list) or len(value) > top:
        raise WireRefused(f"{what} is not a list of at most {top}")
    return value


def _mapping(value, what: str) -> dict:
    if not isinstance(value, dict):
        raise WireRefused(f"{what} is not an object")
    return value


def _function(data, spec) -> checks.FunctionResult:
    data = _mapping(data, f"function {spec.name}")
    if data.get("name") != spec.name:
        raise WireRefused(f"expected function {spec.name!r}, got "
                          f"{printable(data.get('name'), 80)!r}")
    what = f"{spec.name}"
    max_points = _number(data.get("max_points"), f"{what}.max_points")
    if abs(max_points - spec.points) > 1e-9:
        raise WireRefused(f"{what} is out of {max_points:g} points, this lab's {spec.points:g}")
    points = _number(data.get("points"), f"{what}.points", low=0.0, high=spec.points)
    forbidden = tuple(_text(n, 80, f"{what}.forbidden") for n in
                      _items(data.get("forbidden"), 16, f"{what}.forbidden"))
    rows = _items(data.get("checks"), len(spec.checks), f"{what}.checks")
    results = []
    if forbidden or not rows:
        if rows or points != 0.0:
            raise WireRefused(f"{what}: a function with no checks run scores 0")
    else:
        names = [c.get("name") if isinstance(c, dict) else None for c in rows]
        if names != [c.name for c in spec.checks]:
            raise WireRefused(f"{what}: checks {printable(names, 200)} are not this lab's")
        for row, check in zip(rows, spec.checks):
            where = f"{what}.{check.name}"
            n_trials = _count(row.get("n_trials"), f"{where}.n_trials", 10**5)
            results.append(checks.CheckResult(
                name=check.name, unit=check.unit, describe=check.describe,
                credit=_number(row.get("credit"), f"{where}.credit", low=0.0, high=1.0),
                n_full=_count(row.get("n_full"), f"{where}.n_full", n_trials),
                n_trials=n_trials,
                worst_error=_number(row.get("worst_error"), f"{where}.worst_error", False),
                median_error=_number(row.get("median_error"), f"{where}.median_error", False),
                tolerance=_number(row.get("tolerance"), f"{where}.tolerance", False),
                n_voided=_count(row.get("n_voided"), f"{where}.n_voided", n_trials)))
        weights = sum(c.weight for c in spec.checks)
        expected = round(spec.points * sum(c.weight * r.credit for c, r in
                                           zip(spec.checks, results)) / weights, 2)
        if abs(expected - points) > 0.006:
            raise WireRefused(f"{what} claims {points:g} points; its check credits give "
                              f"{expected:g}")
    counts = _mapping(data.get("error_counts"), f"{what}.error_counts")
    if len(counts) > 32:
        raise WireRefused(f"{what}.error_counts has {len(counts)} entries")
    n_problems = _count(data.get("n_problems"), f"{what}.n_problems", 10**5)
    return checks.FunctionResult(
        name=spec.name, points=points, max_points=spec.points, checks=results,
        errors=[_text(e, 1000, f"{what}.errors") for e in
                _items(data.get("errors"), 5, f"{what}.errors")],
        n_problems=n_problems,
        n_failed=_count(data.get("n_failed"), f"{what}.n_failed", n_problems),
        error_counts={_text(k, 1000, f"{what}.error_counts"):
                      _count(v, f"{what}.error_counts", 10**5) for k, v in counts.items()},
        forbidden=forbidden)


def _origin(data, notebooks: set[str], what: str) -> grading.CellOrigin:
    data = _items(data, 3, what)
    if len(data) != 3 or data[0] not in notebooks:
        raise WireRefused(f"{what} does not name a cell of the notebooks sent")
    return grading.CellOrigin(data[0], _count(data[1], f"{what}.position"),
                              _count(data[2], f"{what}.prompt"))


def grade_from_wire(data, assignment: str, student_id: str,
                    notebooks) -> grading.SubmissionGrade:
    """The :class:`~autograder.grading.SubmissionGrade` a worker's reply describes, or
    :class:`WireRefused`. ``notebooks``: the names of the notebooks the task carried."""
    data = _mapping(data, "the reply")
    if data.get("student_id") != student_id or data.get("assignment") != assignment:
        raise WireRefused("the reply is for another submission")
    specs = checks.SPECS[assignment]
    functions = _items(data.get("functions"), len(specs), "functions")
    if len(functions) != len(specs):
        raise WireRefused(f"{len(functions)} functions scored, this lab has {len(specs)}")
    names = set(notebooks)
    grade = grading.SubmissionGrade(student_id=student_id, assignment=assignment)
    grade.functions = [_function(f, spec) for f, spec in zip(functions, specs)]
    grade.flags = [_text(f, 200, "flags") for f in _items(data.get("flags"), 64, "flags")]
    grade.notes = [_text(n, 1000, "notes") for n in _items(data.get("notes"), 256, "notes")]
    grade.seconds = _number(data.get("seconds"), "seconds", low=0.0, high=86400.0)
    grade.cell_origins = [_origin(o, names, "cell_origins") for o in
                          _items(data.get("cell_origins"), 20000, "cell_origins")]
    runs = []
    for run in _items(data.get("cell_runs"), len(grade.cell_origins), "cell_runs"):
        run = _mapping(run, "cell_runs")
        runs.append(grading.CellRun(
            _origin(run.get("origin"), names, "cell_runs.origin"),
            _text(run.get("error"), 400, "cell_runs.error"),
            _text(run.get("where"), 80, "cell_runs.where"),
            _text(run.get("stdout"), 4096, "cell_runs.stdout"),
            _text(run.get("stderr"), 4096, "cell_runs.stderr")))
    grade.cell_runs = runs
    kernel = _mapping(data.get("kernel_checks"), "kernel_checks")
    if len(kernel) > 32:
        raise WireRefused("kernel_checks has too many entries")
    grade.kernel_checks = {_text(k, 80, "kernel_checks"):
                           None if v is None else _text(v, 2000, "kernel_checks")
                           for k, v in kernel.items()}
    return grade


# --------------------------------------------------------------------------- on the worker


def _worker_reply(payload: dict) -> dict:
    secret = grading.load_secret(None)   # $COBOTLAB_GRADING_SECRET of the worker
    folder = tempfile.mkdtemp(prefix="cobotlab-cluster-")
    try:
        paths = []
        for name, data in payload["notebooks"]:
            if not re.fullmatch(r"[^/\\\x00]{1,200}\.ipynb", name) or name.startswith("."):
                raise ValueError(f"unsafe notebook name {printable(name, 80)!r}")
            path = Path(folder) / name
            path.write_bytes(data)
            paths.append(path)
        limits = grading.Limits(**payload["limits"])
        grade = grading.grade_notebook(paths, payload["assignment"], payload["student_id"],
                                       secret, payload["nonce"], limits,
                                       run_tests=payload["run_tests"])
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {"ok": True, "fingerprint": secret_fingerprint(secret),
            "specs": spec_digest(payload["assignment"]), "grade": grade_to_wire(grade)}


def grade_task(payload: dict) -> str:
    """The Dask task: grade one submission on this worker, in its sandbox. Returns JSON text
    (never raises: an exception's pickle would be an object of the worker's making)."""
    try:
        reply = _worker_reply(payload)
    except Exception as exc:  # noqa: BLE001 - reported as the grader's failure
        reply = {"ok": False, "error": f"{type(exc).__name__}: {printable(exc, 500)}"}
    return json.dumps(reply)


def probe_task(assignment: str) -> str:
    """What a worker would grade with: its secret's fingerprint, the lab's spec digest, the
    sandbox it gives student code. JSON text."""
    try:
        secret = secret_fingerprint(grading.load_secret(None))
    except ValueError as exc:
        secret = f"missing: {exc}"
    try:
        from importlib.metadata import version

        package = version("cobotlab")
    except Exception:  # noqa: BLE001
        package = "unknown"
    try:
        specs = spec_digest(assignment)
    except Exception as exc:  # noqa: BLE001 - no such lab here: the client says what to do
        specs = f"missing: {type(exc).__name__}: {exc}"
    return json.dumps({"fingerprint": secret, "specs": specs,
                       "sandbox": sandbox.mode(), "version": package})


# --------------------------------------------------------------------------- the trusted side


class ClusterGrader:
    """Grades submissions on the Dask cluster behind ``client`` (see the module docstring).

    :meth:`grade_notebook` has the signature of :func:`autograder.grading.grade_notebook`,
    so :func:`autograder.course.grade_course` calls it in place of a local sandbox.
    ``owned``: a cluster this object started (a dask-gateway cluster), shut down by
    :meth:`close`.
    """

    def __init__(self, client, address: str, owned=None, wait_workers_s: float = 300.0):
        self.client, self.address, self.owned = client, address, owned
        self.wait_workers_s = wait_workers_s
        self._lock = threading.Lock()
        self._live: set = set()
        self._recorded: dict[tuple, grading.SubmissionGrade] = {}
        self._run = uuid.uuid4().hex[:8]

    # -- before grading

    def slots(self) -> int:
        """Tasks the cluster runs at once now (its workers' threads), at least 1."""
        return max(1, sum(self.client.nthreads().values()))

    def check(self, assignment: str, secret: str) -> str:
        """Refuse a cluster whose workers would grade differently (another secret, another
        version of the lab, no secret); returns a note for the run's summary."""
        self.client.wait_for_workers(1, timeout=self.wait_workers_s)
        replies = self.client.run(probe_task, assignment)
        mine, specs = secret_fingerprint(secret), spec_digest(assignment)
        sandboxes = set()
        for worker, text in replies.items():
            try:
                got = json.loads(text) if isinstance(text, str) else {}
            except ValueError:
                got = {}
            if got.get("fingerprint") != mine:
                why = str(got.get("fingerprint", "no reply"))
                why = printable(why, 200) if why.startswith("missing") else "another secret"
                raise ValueError(
                    f"the worker {worker} does not hold this course's grading secret ({why}): "
                    f"give the workers ${grading.SECRET_ENV} from {grading.PRIVATE_DIR}/"
                    f"{grading.SECRET_FILE} (docs/instructors.md, Grading on a cluster)")
            theirs = str(got.get("specs", ""))
            if theirs.startswith("missing"):
                raise ValueError(
                    f"the worker {worker} cannot load the lab {assignment} "
                    f"({printable(theirs, 300)}): a course's own lab must reach the workers: "
                    f"mount a copy of the course's {registry.CONFIG_NAME}, lab folders and "
                    f"{registry.PRIVATE_DIR.as_posix()}/ on them and set "
                    f"${registry.COURSE_ENV} to it (docs/instructors.md, Grading on a cluster)")
            if theirs != specs:
                raise ValueError(f"the worker {worker} has another version of {assignment} "
                                 f"(cobotlab {printable(got.get('version'), 40)}): build "
                                 "the workers' image from the same release as this install")
            sandboxes.add(printable(got.get("sandbox"), 60))
        return (f"graded on the Dask cluster {printable(self.address, 200)} ({len(replies)} "
                f"worker(s) at the start, sandbox on the workers: {', '.join(sorted(sandboxes))})")

    # -- grading

    def grade_notebook(self, notebook_paths, assignment: str, student_id: str, secret: str,
                       nonce: str | None, limits: grading.Limits = grading.Limits(),
                       run_tests: bool = False) -> grading.SubmissionGrade:
        """Grade one submission on a worker; a failure raises (the caller's retry, then
        no score). ``secret`` is not sent: the reply's fingerprint must match it."""
        paths = [notebook_paths] if isinstance(notebook_paths, (str, Path)) else \
            list(notebook_paths)
        notebooks = []
        for path in paths:
            data = Path(path).read_bytes()   # frozen (or nbgrader's sanitized) copy
            if len(data) > MAX_NOTEBOOK_BYTES:
                raise grading.GraderError(f"{Path(path).name} is too large to ship")
            notebooks.append((Path(path).name, data))
        payload = {"assignment": assignment, "student_id": student_id, "nonce": nonce,
                   "limits": dataclasses.asdict(limits), "run_tests": run_tests,
                   "notebooks": notebooks}
        key = f"cobotlab-grade-{self._run}-{assignment}-{student_id}-{uuid.uuid4().hex[:8]}"
        text = self._wait(self.client.submit(grade_task, payload, key=key, pure=False))
        if not isinstance(text, str) or len(text) > MAX_REPLY_BYTES:
            raise grading.GraderError("the worker's reply is not text or is too large")
        try:
            reply = json.loads(text)
        except ValueError:
            raise grading.GraderError("the worker's reply is not JSON") from None
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            error = reply.get("error") if isinstance(reply, dict) else None
            raise grading.GraderError(f"on the cluster: {printable(error or 'no reply', 500)}")
        if reply.get("fingerprint") != secret_fingerprint(secret):
            raise grading.GraderError("the worker graded with another grading secret")
        if reply.get("specs") != spec_digest(assignment):
            raise grading.GraderError(f"the worker has another version of {assignment}")
        try:
            grade = grade_from_wire(reply.get("grade"), assignment, student_id,
                                    {name for name, _ in notebooks})
        except WireRefused as exc:
            raise grading.GraderError(f"the worker's reply was refused: {exc}") from None
        with self._lock:   # idempotent by student: the first validated reply stands
            return self._recorded.setdefault((assignment, student_id, nonce, run_tests),
                                             grade)

    def _wait(self, future):
        """The task's result; Ctrl-C (sandbox.stop_all) cancels it within POLL_S."""
        with self._lock:
            self._live.add(future)
        try:
            while True:
                if sandbox.stopping():
                    future.cancel()
                    raise sandbox.Interrupted("grading was interrupted")
                try:
                    return future.result(timeout=POLL_S)
                except TimeoutError:
                    continue
                except Exception as exc:  # noqa: BLE001 - lost workers, cancelled, ...
                    raise grading.GraderError(
                        f"the cluster did not grade it: {type(exc).__name__}: "
                        f"{printable(exc, 300)}") from None
        finally:
            with self._lock:
                self._live.discard(future)

    def close(self) -> None:
        """Cancel what is still queued, disconnect, shut down a cluster this started."""
        with self._lock:
            live = list(self._live)
        try:
            if live:
                self.client.cancel(live, force=True)
        finally:
            self.client.close()
            if self.owned is not None:
                self.owned.shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --------------------------------------------------------------------------- connecting


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def security_from(ca_file=None, cert=None, key=None):
    """Dask's TLS :class:`~distributed.security.Security` for a client: the files given,
    else Dask's configuration (``distributed.comm.tls.ca-file``, ``...client.cert``,
    ``...client.key``, or ``DASK_DISTRIBUTED__COMM__TLS__...``). Refuses to go without a CA
    and a client certificate."""
    from distributed.security import Security

    given = {k: v for k, v in (("tls_ca_file", ca_file), ("tls_client_cert", cert),
                               ("tls_client_key", key)) if v}
    security = Security(require_encryption=True, **given)
    if not security.tls_ca_file or not security.tls_client_cert:
        raise ValueError("a tls:// scheduler needs the cluster's CA certificate and a client "
                         "certificate signed by it: --tls-ca-file, --tls-cert (and --tls-key "
                         "unless the key is in the cert file), or Dask's configuration "
                         "distributed.comm.tls.ca-file / client.cert / client.key")
    return security


def connect(address: str, *, security=None, workers: int | None = None,
            wait_workers_s: float = 300.0) -> ClusterGrader:
    """A :class:`ClusterGrader` for ``address``:

    - ``tls://HOST:PORT``: a Dask scheduler with TLS (``security``: a
      :class:`distributed.security.Security`, default :func:`security_from` Dask's config);
    - ``gateway``: a new cluster from the dask-gateway Dask's configuration names
      (``gateway.address``, ``gateway.auth.type``; on a JupyterHub with dask-gateway these
      are set for you), scaled to ``workers`` and shut down after the run;
    - ``gateway://HOST:PORT/NAME`` (a gateway cluster's scheduler address) or
      ``gateway:NAME``: that existing gateway cluster, left running.

    ``tcp://`` and the other schemes are refused: an unauthenticated scheduler runs whatever
    anyone who reaches it sends.
    """
    address = address.strip()
    if address == "gateway" or address.startswith("gateway:"):
        return _connect_gateway(address, workers, wait_workers_s)
    parts = urlsplit(address if "://" in address else f"none://{address}")
    if parts.scheme == "tcp" or parts.scheme == "none":
        where = "on this machine" if _loopback(parts.hostname or "") else "on the network"
        raise ValueError(
            f"refusing the unauthenticated scheduler {printable(address, 200)} ({where}): a "
            "Dask scheduler runs any code a client sends it, so it must require TLS client "
            "certificates (tls://, `dask scheduler --tls-ca-file ... --tls-cert ... "
            "--tls-key ...`) or sit behind dask-gateway (--cluster gateway); on one machine "
            "use --workers instead")
    if parts.scheme != "tls":
        raise ValueError(f"--cluster {printable(address, 200)}: expected tls://HOST:PORT, "
                         "gateway, gateway:NAME or gateway://HOST:PORT/NAME")
    from distributed import Client

    security = security or security_from()
    if not getattr(security, "require_encryption", False) or not security.tls_ca_file:
        raise ValueError("the TLS security given requires no encryption or names no CA")
    client = Client(address, security=security, timeout=60, set_as_default=False)
    return ClusterGrader(client, address, wait_workers_s=wait_workers_s)


def _connect_gateway(address: str, workers: int | None, wait_workers_s: float):
    try:
        from dask_gateway import Gateway
    except ImportError:
        raise ValueError("--cluster gateway needs the dask-gateway client: pip install "
                         "'cobotlab[cluster]'") from None
    gateway = Gateway()   # address and authentication from Dask's configuration
    name = address.partition(":")[2].strip()
    if name.startswith("//"):   # a scheduler address: gateway://HOST:PORT/NAME
        name = urlsplit(address).path.strip("/")
    owned = None
    if name:
        cluster = gateway.connect(name)
    else:
        cluster = owned = gateway.new_cluster()
        cluster.scale(max(1, workers or 1))
    client = cluster.get_client(set_as_default=False)
    return ClusterGrader(client, f"gateway cluster {cluster.name}", owned=owned,
                         wait_workers_s=wait_workers_s)


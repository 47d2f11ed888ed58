"""Grade on a Dask cluster: ``cobotlab grade COURSE LAB --cluster ADDRESS``.

The execute stage of :func:`autograder.pipeline.pipeline.grade_course` (running untrusted
code) moves to the workers of a Dask distributed cluster, the engine JupyterHub-on-Kubernetes deployments
run beside the hub (dask-gateway); every other stage stays in this trusted process, which
draws the problems and scores. No scheduler or RPC layer of our own: Dask schedules, retries
and moves the data.

- **One task per frozen submission.** The task carries the frozen notebook's bytes (never a
  path on this machine), the assignment, the student id, the problems' inputs and the
  limits (:func:`task_payload`); on its worker it runs
  :func:`autograder.pipeline.run_submission.execute_notebook`, the same bubblewrap sandbox as a local run,
  and returns the :class:`~autograder.pipeline.execution.Execution` as one JSON text
  (:mod:`autograder.executions`).
- **The cluster never holds the secret.** Problems are drawn here; a task carries only the
  inputs of its own student's problems (a closed loop also what its loop flies by), never a
  tolerance, the secret or anything that draws another student's problems. The workers
  need no secret at all.
- **The trusted side validates, then scores.** :func:`autograder.executions.from_wire`
  rebuilds the execution only from a reply whose functions are this lab's, in order, with
  bounded counts, finite times, capped strings and values that pass the wire's checks; the
  score is computed here from it (:func:`autograder.pipeline.score.score_execution`). A reply that
  fails is the grader's failure (retried, then no score), never a student's grade.
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
import ipaddress
import json
import re
import shutil
import threading
import uuid
from pathlib import Path
from urllib.parse import urlsplit

from autograder import checks, executions, registry, sandbox
from autograder.freeze import printable
from autograder.pipeline.execution import Execution
from autograder.pipeline.problems import Problems
from autograder.pipeline.run_submission import execute_notebook
from autograder.pipeline.worker import GraderError, Limits

__all__ = ["ClusterGrader", "connect", "execute_task", "spec_digest", "task_payload"]

# The largest reply accepted (JSON text): every cell's captured output at its 4 KB caps.
MAX_REPLY_BYTES = 32 * 2**20
# The largest submission shipped to a worker (freeze caps one file at 20 MB).
MAX_NOTEBOOK_BYTES = 64 * 2**20
# How often a waiting thread looks for Ctrl-C (sandbox.stop_all) while its task runs.
POLL_S = 0.5


# --------------------------------------------------------------------------- the lab's version


def spec_digest(assignment: str) -> str:
    """The lab's graded functions, points, checks and weights, and the hash of its scoring
    and private spec files (:func:`autograder.registry.spec_hash`), hashed: a worker whose
    lab version differs would run other closed loops or stand-ins."""
    shape = [(s.name, s.points, [(c.name, c.weight) for c in s.checks])
             for s in checks.SPECS[assignment]]
    shape.append(registry.spec_hash(assignment))
    return hashlib.sha256(json.dumps(shape).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- on the worker


def _worker_reply(payload: dict) -> dict:
    # what a worker killed mid-task on this machine left (its finally never ran)
    sandbox.remove_stale_folders()
    folder = sandbox.private_folder("cobotlab-cluster-")
    try:
        paths = []
        for name, data in payload["notebooks"]:
            if not re.fullmatch(r"[^/\\\x00]{1,200}\.ipynb", name) or name.startswith("."):
                raise ValueError(f"unsafe notebook name {printable(name, 80)!r}")
            path = Path(folder) / name
            path.write_bytes(data)
            paths.append(path)
        limits = Limits(**payload["limits"])
        problems = executions.problems_from_wire(payload["problems"], payload["assignment"],
                                                 payload["student_id"])
        execution = execute_notebook(paths, problems, limits,
                                             run_tests=payload["run_tests"])
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {"ok": True, "specs": spec_digest(payload["assignment"]),
            "execution": executions.to_wire(execution)}


def execute_task(payload: dict) -> str:
    """The Dask task: run one submission on this worker, in its sandbox, on the problems'
    inputs it carries. Returns JSON text (never raises: an exception's pickle would be an
    object of the worker's making)."""
    try:
        reply = _worker_reply(payload)
    except Exception as exc:  # noqa: BLE001 - reported as the grader's failure
        reply = {"ok": False, "error": f"{type(exc).__name__}: {printable(exc, 500)}"}
    return json.dumps(reply)


def probe_task(assignment: str) -> str:
    """What a worker would run with: the lab's spec digest, the sandbox it gives student
    code, its cobotlab version. JSON text."""
    try:
        from importlib.metadata import version

        package = version("cobotlab")
    except Exception:  # noqa: BLE001
        package = "unknown"
    try:
        specs = spec_digest(assignment)
    except Exception as exc:  # noqa: BLE001 - no such lab here: the client says what to do
        specs = f"missing: {type(exc).__name__}: {exc}"
    return json.dumps({"specs": specs, "sandbox": sandbox.mode(), "version": package})


def task_payload(notebooks: list[tuple[str, bytes]], problems: Problems,
                 limits: Limits, run_tests: bool) -> dict:
    """What one task carries: the frozen notebooks' bytes, the problems' inputs (never
    their tolerances, nor the truth of a function graded in one call), the limits."""
    return {"assignment": problems.assignment, "student_id": problems.student_id,
            "problems": executions.problems_to_wire(problems),
            "limits": dataclasses.asdict(limits), "run_tests": run_tests,
            "notebooks": notebooks}


# --------------------------------------------------------------------------- the trusted side


class ClusterGrader:
    """Grades submissions on the Dask cluster behind ``client`` (see the module docstring).

    :meth:`execute_notebook` has the signature of
    :func:`autograder.pipeline.run_submission.execute_notebook`, so
    :func:`autograder.pipeline.pipeline.grade_course` calls it in place of a local sandbox.
    ``owned``: a cluster this object started (a dask-gateway cluster), shut down by
    :meth:`close`.
    """

    def __init__(self, client, address: str, owned=None, wait_workers_s: float = 300.0):
        self.client, self.address, self.owned = client, address, owned
        self.wait_workers_s = wait_workers_s
        self._lock = threading.Lock()
        self._live: set = set()
        self._recorded: dict[tuple, Execution] = {}
        self._run = uuid.uuid4().hex[:8]

    # -- before grading

    def slots(self) -> int:
        """Tasks the cluster runs at once now (its workers' threads), at least 1."""
        return max(1, sum(self.client.nthreads().values()))

    def check(self, assignment: str) -> str:
        """Refuse a cluster whose workers would run differently (another version of the lab,
        or without it); returns a note for the run's summary."""
        self.client.wait_for_workers(1, timeout=self.wait_workers_s)
        replies = self.client.run(probe_task, assignment)
        specs = spec_digest(assignment)
        sandboxes = set()
        for worker, text in replies.items():
            try:
                got = json.loads(text) if isinstance(text, str) else {}
            except ValueError:
                got = {}
            theirs = str(got.get("specs", "no reply"))
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

    # -- running

    def execute_notebook(self, notebook_paths, problems: Problems,
                         limits: Limits = Limits(),
                         run_tests: bool = False) -> Execution:
        """Run one submission on a worker (:func:`autograder.pipeline.run_submission.execute_notebook`
        there); a failure raises (the caller's retry, then no score). The task carries the
        problems' inputs, never the secret: this process scores what comes back."""
        paths = [notebook_paths] if isinstance(notebook_paths, (str, Path)) else \
            list(notebook_paths)
        notebooks = []
        for path in paths:
            data = Path(path).read_bytes()   # frozen (or nbgrader's sanitized) copy
            if len(data) > MAX_NOTEBOOK_BYTES:
                raise GraderError(f"{Path(path).name} is too large to ship")
            notebooks.append((Path(path).name, data))
        payload = task_payload(notebooks, problems, limits, run_tests)
        assignment, student_id = problems.assignment, problems.student_id
        key = f"cobotlab-grade-{self._run}-{assignment}-{student_id}-{uuid.uuid4().hex[:8]}"
        text = self._wait(self.client.submit(execute_task, payload, key=key, pure=False))
        if not isinstance(text, str) or len(text) > MAX_REPLY_BYTES:
            raise GraderError("the worker's reply is not text or is too large")
        try:
            reply = json.loads(text)
        except ValueError:
            raise GraderError("the worker's reply is not JSON") from None
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            error = reply.get("error") if isinstance(reply, dict) else None
            raise GraderError(f"on the cluster: {printable(error or 'no reply', 500)}")
        if reply.get("specs") != spec_digest(assignment):
            raise GraderError(f"the worker has another version of {assignment}")
        try:
            execution = executions.from_wire(reply.get("execution"), assignment, student_id,
                                             {name for name, _ in notebooks})
        except executions.ExecutionRefused as exc:
            raise GraderError(f"the worker's reply was refused: {exc}") from None
        with self._lock:   # idempotent by student: the first validated reply stands
            return self._recorded.setdefault((assignment, student_id, run_tests), execution)

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
                    raise GraderError(
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


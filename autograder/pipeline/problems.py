"""A student's hidden problems: drawn from the secret, never written down.

Problems are drawn from the secret seed, the assignment, the student id and the function name
only (:func:`problem_rng`, :func:`draw_problems`), so a regrade gives the same submission the
same problems and the same score. A run that asks for fresh problems mixes in a random nonce,
which reaches the disk (the run log, for replays) only after the workers are gone. Only the
inputs go to a worker; the truth stays in this process. :class:`DrawnProblems` is the draw
stage's read-only value: every student's :class:`Problems`.
"""

from __future__ import annotations

import hashlib
import hmac
import threading
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from autograder import checks


def problem_rng(secret: str, nonce: str | None, assignment: str, student_id: str,
                function: str) -> np.random.Generator:
    """The generator for one student's hidden problems of one function.

    HMAC-SHA256 keyed by the secret over the names, so students get different problems and
    a student cannot predict theirs. ``nonce`` None (or empty): the course's fixed problems,
    the same on every regrade; a nonce (fresh problems, on request) gives other problems,
    the same again whenever that nonce is replayed.
    """
    message = "\x1f".join([nonce or "", assignment, student_id, function]).encode()
    digest = hmac.new(secret.encode(), message, hashlib.sha256).digest()
    return np.random.default_rng(int.from_bytes(digest, "big"))


@dataclass(frozen=True)
class Problems:
    """One submission's hidden problems: ``trials[function]`` in the lab's order, truth
    included, and the public trials ``hidden_test(function)`` scores on (the kernel seeds);
    drawn on the trusted side (:class:`DrawnProblems`)."""

    assignment: str
    student_id: str
    trials: dict[str, list[checks.Trial]]
    kernel: KernelTrials

    def kernel_trials(self, name: str) -> list[checks.Trial]:
        return self.kernel.of(name)


class KernelTrials:
    """The public problems of :data:`checks.KERNEL_SEEDS` per function, drawn once for the
    class (they are the same for everyone) and when first asked for."""

    def __init__(self, assignment: str):
        self.specs = {s.name: s for s in specs_of(assignment)}
        self._drawn: dict[str, list[checks.Trial]] = {}
        self._lock = threading.Lock()

    def of(self, name: str) -> list[checks.Trial]:
        with self._lock:
            if name not in self._drawn:
                spec = self.specs[name]
                self._drawn[name] = [t for seed in checks.KERNEL_SEEDS
                                     for t in checks.public_trials(spec, seed)]
            return self._drawn[name]


class DrawnProblems:
    """Every submission's hidden problems of one run, drawn before any code runs (from the
    secret, the run's nonce, the assignment, the student id and the function name:
    :func:`problem_rng`), and read-only from then on: the draw stage's value, which the
    execute stage sends the inputs of and the score stage scores on."""

    def __init__(self, assignment: str, by_student: dict[str, Problems],
                 kernel: KernelTrials):
        self.assignment, self.kernel = assignment, kernel
        self._by_student = MappingProxyType(dict(by_student))

    def of(self, student_id: str) -> Problems:
        """The student's problems; KeyError naming the student when none were drawn."""
        try:
            return self._by_student[student_id]
        except KeyError:
            raise KeyError(f"no problems of {self.assignment} were drawn for "
                           f"{student_id!r}: it was not among this run's submissions") from None


def draw_all(assignment: str, secret: str, nonce: str | None,
             student_ids) -> DrawnProblems:
    """The hidden problems of each of ``student_ids`` (see :func:`draw_problems`), drawn now,
    all of them, with one set of public kernel-seed trials shared by all."""
    kernel = KernelTrials(assignment)
    return DrawnProblems(assignment, {sid: draw_problems(assignment, sid, secret, nonce, kernel)
                                      for sid in dict.fromkeys(student_ids)}, kernel)


def draw_problems(assignment: str, student_id: str, secret: str, nonce: str | None,
                  kernel: KernelTrials | None = None) -> Problems:
    """One student's hidden problems of ``assignment`` (see :func:`problem_rng`)."""
    trials = {spec.name: checks.make_trials(spec, problem_rng(secret, nonce, assignment,
                                                              student_id, spec.name))
              for spec in specs_of(assignment)}
    return Problems(assignment, student_id, trials, kernel or KernelTrials(assignment))


def specs_of(assignment: str):
    """The graded functions' specs of ``assignment``, in the lab's order; ValueError, naming
    the known assignments, when none is registered (the one place that says so)."""
    specs = checks.SPECS.get(assignment)
    if specs is None:
        raise ValueError(f"no graded functions are registered for assignment {assignment!r}; "
                         f"known assignments: {sorted(checks.SPECS)}")
    return specs

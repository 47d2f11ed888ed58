"""Nothing a worker sends can raise in the trusted process (issue 37, item 4).

A student's function may return anything the wire can carry, and student code in the worker
may write forged messages on the reply pipe. The trusted side decodes every value with
bounds (integers fit in 64 bits) and measures and scores any value without raising: a value
that cannot be measured fails its problem, with a message that says why. Checked here on
every graded function of every lab, closed loops included, without a sandbox; the same
values graded through the real sandboxed worker are tests/adversarial/huge_values.py.
"""

from __future__ import annotations

import json
import math
import os
import struct

import numpy as np
import pytest

from autograder import checks, executions
from autograder.inside import wire

# What a hostile (or merely confused) function returns instead of an answer.
HOSTILE = {
    "a 400-digit integer": 10**400,
    "a pose of 400-digit integers": [[10**400] * 4] * 4,
    "an object array": np.array([10**400, 1], dtype=object),
    "a string": "4x4 identity",
    "a dict": {"R": 1, "t": 2},
    "None": None,
    "a nested tuple": ((((),),),),
    "uint64 past int64": np.array([2**64 - 1], dtype=np.uint64),
    "NaN": math.nan,
}
SPECS = [spec for lab in sorted(checks.SPECS) for spec in checks.SPECS[lab]]


def test_integers_past_64_bits_are_refused_both_ways():
    for big in (2**63, -(2**63) - 1, 10**400):
        with pytest.raises(wire.WireError, match="64 bits"):
            wire.encode({"value": big})
        with pytest.raises(wire.WireError, match="64 bits"):
            wire.decode({"value": big})
    assert wire.decode(wire.encode({"v": 2**63 - 1}))["v"] == 2**63 - 1
    # uint64 beyond int64 would wrap round to a negative number as i8: it travels as f8
    back = wire.decode(json.loads(json.dumps(wire.encode(np.array([2**64 - 1], np.uint64)))))
    assert back.dtype == np.float64 and back[0] == float(2**64 - 1)


def test_a_forged_reply_with_a_huge_number_is_a_typed_wire_error():
    body = b'{"ok": true, "value": 1, "cpu_seconds": 1' + b"0" * 400 + b"}"
    r, w = os.pipe()
    os.write(w, struct.pack("<Q", len(body)) + body)
    with pytest.raises(wire.WireError, match="64 bits") as raised:
        wire.receive(r)
    assert not isinstance(raised.value, (wire.WireTimeout, wire.WireClosed, wire.WireTooLarge))
    os.close(w)
    with pytest.raises(wire.WireClosed):
        wire.receive(r)
    os.close(r)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_measuring_and_scoring_any_value_never_raises(spec):
    trials = checks.make_trials(spec, np.random.default_rng(7), 2)
    for what, value in HOSTILE.items():
        outcomes = [checks.run_trial(spec, trial,
                                     lambda args, limit, v=value: checks.TrialOutcome(value=v),
                                     spec.time_limit_s) for trial in trials]
        result = checks.score_function(spec, trials, outcomes)
        assert result.points == 0.0, (spec.name, what, result.summary())
        # the student is told why: a message, or (a number that is merely wrong) the checks
        assert result.errors or result.failed_checks, (spec.name, what)


def test_a_failure_of_the_caller_inside_a_closed_loop_is_not_the_students():
    spec = next(s for s in SPECS if s.drive is not None)
    trial = checks.make_trials(spec, np.random.default_rng(1), 1)[0]

    class WorkerDied(Exception):
        pass

    def call_once(args, limit):
        raise WorkerDied("the worker process stopped")

    with pytest.raises(WorkerDied):
        checks.run_trial(spec, trial, call_once, spec.time_limit_s)


def test_a_kept_or_cluster_execution_refuses_a_number_too_large_for_a_float():
    with pytest.raises(executions.ExecutionRefused, match="too large"):
        executions._number(10**400, "the seconds")

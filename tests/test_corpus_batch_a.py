"""The lab 0 adversarial corpus graded in one batch: the cases that fool or wedge nbgrader's
own kernel (it runs them too, for the cross-check).

The corpus is split between tests/test_corpus_batch_a.py and tests/test_corpus_batch_b.py so
that the two parts run in parallel; together they grade every notebook-layer case (the
course, host and layout layers go through the real flow in tests/test_grading_flow.py).
"""

from __future__ import annotations

from pathlib import Path

import course_kit as kit
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), "lab0_frames")


@pytest.mark.timeout(1200)
def test_the_cases_nbgrader_runs_too_graded_in_one_batch(released, tmp_path):
    names = kit.corpus_batch_parts()[0]
    assert len(names) >= 4
    # the reference started cold is batch b's (its forked run is graded here as there)
    kit.grade_corpus_batch(released, tmp_path, names, reference_cold=False)

"""The lab 0 adversarial corpus graded in one batch: every case nbgrader's kernel does not run.

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
def test_every_other_case_graded_in_one_batch(released, tmp_path):
    names = kit.corpus_batch_parts()[1]
    assert len(names) >= 10
    kit.grade_corpus_batch(released, tmp_path, names)

"""The readers of the adversarial corpus (issue 29, item 3): submissions that search the disk
and sys.path for reference source, run it under another name, and call it.

Each reader is first shown to work where the answer key is in reach (this process, a
checkout with solutions/, the specs and the source notebooks): it answers correctly. In the
grading worker (this checkout's editable install; tests/test_course_install.py repeats it in
a regular install) it must score exactly what the blank scores, and be flagged.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import course_kit as kit
import nbformat
import numpy as np
import pytest

from autograder import checks, sandbox
from autograder.pipeline.run_submission import grade_notebook
from autograder.pipeline.worker import Limits

ROOT = Path(__file__).resolve().parent.parent

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sandbox.capabilities().bwrap, reason="needs bubblewrap")]

READERS = {"reader_source_notebook": "invert_pose", "reader_answer_key": "fit_rigid",
           "reader_specs": "interaction_matrix"}
SECRET = "s" * 32
LIMITS = Limits(cell_timeout_s=20, load_timeout_s=120)


def _case(name):
    return kit.parse_case(kit.ADVERSARIAL / f"{name}.py")


def submission(tmp_path, cells: list[str], name: str, lab: str):
    """A notebook of ``cells`` (the lab's own cells are not what is tested here: its
    simulator cells would only cost time)."""
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    path = tmp_path / name / f"{lab}.ipynb"
    path.parent.mkdir(parents=True)
    nbformat.write(nb, path)
    return path


@pytest.mark.parametrize("name", sorted(READERS))
def test_the_reader_works_where_the_answer_key_is_in_reach(name, monkeypatch):
    monkeypatch.chdir(ROOT)   # a checkout: solutions/, the specs and labs/ are all here
    case, function = _case(name), READERS[name]
    namespace = {"np": np}
    exec(case["replace"][function], namespace)
    spec = checks.spec_for(function, case["lab"])
    trial = checks.public_trials(spec, 0)[-1]
    result = checks.score_function(spec, [trial], [checks.TrialOutcome(
        value=namespace[function](*trial.args))])
    assert result.fraction == 1.0, result.summary()


@pytest.mark.parametrize("name", sorted(READERS))
def test_the_reader_scores_the_blank_and_is_flagged_in_the_worker(tmp_path, name, monkeypatch):
    case, function = _case(name), READERS[name]
    lab = case["lab"]
    spec = checks.spec_for(function, lab)
    if spec.forbidden:
        # Code it builds at run time could call a forbidden routine: the static rule scores
        # it zero without running it. The worker's view is what is tested here, so it is
        # graded once more with nothing forbidden, and runs.
        path = submission(tmp_path, ["import numpy as np", case["replace"][function]],
                          "static", lab)
        ruled = grade_notebook([path], lab, "static", SECRET, None, LIMITS)
        by_name = {f.name: f for f in ruled.functions}
        assert by_name[function].points == 0.0 and by_name[function].forbidden, \
            by_name[function].summary()
        monkeypatch.setattr(checks, "SPECS", {lab: tuple(
            dataclasses.replace(s, forbidden=()) for s in checks.SPECS[lab])})
    graded = {}
    blank = [f"def {function}(*args):\n    raise NotImplementedError()"]
    for who, cells in (("blank", blank), (name, [case["replace"][function]])):
        path = submission(tmp_path, ["import numpy as np", *cells], who, lab)
        graded[who] = grade_notebook([path], lab, who, SECRET, None, LIMITS)
    reader, blank = graded[name], graded["blank"]
    by_name = {f.name: f for f in reader.functions}
    assert by_name[function].points == 0.0, by_name[function].summary()
    assert reader.score == blank.score, (reader.score, blank.score)
    for flag in case["flags"]:
        assert flag in reader.flags, (flag, reader.flags)
    assert "no answer key in reach" in " ".join(by_name[function].errors), \
        by_name[function].errors

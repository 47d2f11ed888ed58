"""The lab registry (autograder.registry): built-in and instructors' labs through one table,
each loaded on its own, so a broken lab breaks only itself and says which file to fix."""

from __future__ import annotations

import numpy as np
import pytest

from autograder import checks, practice, registry

SCORING = '''\
import numpy as np
from autograder.spec_types import Check, FunctionSpec, OutputError

def _measure(value, trial):
    value = np.asarray(value, dtype=float)
    if value.shape != (3,):
        raise OutputError(f"returned shape {value.shape}, expected (3,)")
    return {"error": float(np.linalg.norm(value - trial.truth)) * 1000.0}

DOUBLE = FunctionSpec(name="{fn}", points=1.0, n_trials=4, practice_trials=2, make_trial=None,
                      measure=_measure, checks=(Check("error", "mm", 1.0, ((1.0, 1.0),)),),
                      signature="{fn}(v: (3,)) -> (3,)", parameters="v")
SPECS = (DOUBLE,)
'''

SPEC = '''\
from dataclasses import replace
from autograder.registry import public_scoring
from autograder.spec_types import CodeMistake, Trial

scoring = public_scoring("{lab}")

def _trial(rng, index):
    v = rng.uniform(-1, 1, 3)
    return Trial(args=(v,), truth=2 * v, tol={{"error": 1e-6}}, label="random")

SPECS = (replace(scoring.DOUBLE, make_trial=_trial,
                 code_mistakes=(CodeMistake("it halves instead of doubling", lambda v: v / 2),)),)
ANSWERS = (_trial,)
'''


def write_lab(course, lab: str, fn: str = "double", spec: str | None = None,
              scoring: str | None = None, folder: str = "labs"):
    """A minimal instructor's lab in ``course``: notebook, public scoring, private spec."""
    course.mkdir(parents=True, exist_ok=True)
    (course / "cobotlab.toml").write_text(f'lab_folders = ["{folder}"]\n')
    lab_dir = course / folder / lab
    lab_dir.mkdir(parents=True)
    (lab_dir / f"{lab}.ipynb").write_text('{"cells": [], "metadata": {}, "nbformat": 4, '
                                          '"nbformat_minor": 5}')
    (lab_dir / "scoring.py").write_text(scoring if scoring is not None
                                        else SCORING.replace("{fn}", fn))
    private = course / ".cobotlab" / "specs"
    private.mkdir(parents=True, exist_ok=True)
    (private / f"{lab}.py").write_text(spec if spec is not None else SPEC.format(lab=lab))
    return lab_dir


@pytest.fixture
def course(tmp_path):
    yield tmp_path / "course"
    registry.use_course(None)


def test_an_instructors_lab_loads_checks_and_names_its_code_mistake(course):
    write_lab(course, "mylab")
    registry.use_course(course)
    assert "mylab" in checks.SCORING and "lab0_frames" in checks.SCORING
    assert [s.name for s in checks.SPECS["mylab"]] == ["double"]
    good = checks.evaluate(lambda v: 2 * v, "double", assignment="mylab")
    assert good.points == 1.0
    wrong = checks.evaluate(lambda v: v / 2, "double", assignment="mylab")
    assert wrong.points == 0.0
    assert any("it halves instead of doubling" in e for e in wrong.errors), wrong.errors
    # the practice data carries the mistake's answers: a student's copy names it too
    document = practice.build_practice("mylab")
    assert document["assignment"] == "mylab"


def test_a_broken_spec_breaks_only_its_own_lab(course):
    write_lab(course, "mylab", spec="import no_such_module_here\n")
    registry.use_course(course)
    with pytest.raises(registry.LabError) as err:
        checks.SPECS["mylab"]
    message = str(err.value)
    assert "mylab.py" in message and "(line 1)" in message and "ModuleNotFoundError" in message
    # every other lab still loads, checks and draws problems
    spec = checks.SPECS["lab0_frames"][0]
    assert checks.make_trials(spec, np.random.default_rng(0), 1)
    assert checks.evaluate(lambda T: np.linalg.inv(T), "invert_pose").points == \
        spec.points


def test_a_broken_public_scoring_does_not_stop_check_in_another_lab(course):
    write_lab(course, "mylab", scoring="raise RuntimeError('half written')\n")
    registry.use_course(course)
    with pytest.raises(registry.LabError, match="scoring.py .line 1.*half written"):
        checks.SCORING["mylab"]
    # a function found by name alone skips the broken lab rather than failing on it
    assert checks.evaluate(lambda T: np.linalg.inv(T), "invert_pose").points > 0


@pytest.mark.parametrize("case, expected", [
    ("graded twice", "double graded twice"),
    ("no make_trial", "has no make_trial"),
    ("other functions", "the two must list the same functions"),
])
def test_a_spec_that_does_not_fit_its_scoring_is_refused_with_the_fix(course, case, expected):
    spec = {"graded twice": SPEC.format(lab="mylab").replace(
                "SPECS = (replace(", "SPECS = (scoring.DOUBLE, replace(").replace(
                "),)),)", "),)))") ,
            "no make_trial": "from autograder.registry import public_scoring\n"
                             "SPECS = public_scoring('mylab').SPECS\n",
            "other functions": SPEC.format(lab="mylab").replace(
                "make_trial=_trial,", "name='triple', make_trial=_trial,")}[case]
    write_lab(course, "mylab", spec=spec)
    registry.use_course(course)
    with pytest.raises(registry.LabError, match=expected):
        registry.specs("mylab")


def test_two_labs_of_one_name_or_a_built_in_name_are_refused(course, tmp_path):
    write_lab(course, "mylab")
    other = course / "more" / "mylab"
    other.mkdir(parents=True)
    (other / "scoring.py").write_text(SCORING.replace("{fn}", "double"))
    (course / "cobotlab.toml").write_text('lab_folders = ["labs", "more"]\n')
    registry.use_course(course)
    with pytest.raises(registry.LabError, match="two labs are named mylab"):
        registry.all_labs()
    clash = tmp_path / "clash"
    write_lab(clash, "lab0_frames")
    registry.use_course(clash)
    with pytest.raises(registry.LabError, match="name of a built-in lab"):
        registry.all_labs()


def test_the_same_function_name_in_two_labs_stays_allowed(course):
    write_lab(course, "mylab", fn="per_axis_rmse")
    registry.use_course(course)
    spec = checks.spec_for("per_axis_rmse", "mylab")
    assert spec.make_trial is not None
    with pytest.raises(ValueError, match="graded in several labs"):
        checks.spec_for("per_axis_rmse")


def test_a_bad_config_names_the_file_and_the_fix(course):
    course.mkdir()
    (course / "cobotlab.toml").write_text("lab_folders = labs\n")
    registry.use_course(course)
    with pytest.raises(registry.LabError, match=r"cobotlab.toml: not valid TOML.*lab_folders"):
        registry.all_labs()
    (course / "cobotlab.toml").write_text('lab_folders = ["nowhere"]\n')
    registry.use_course(course)
    with pytest.raises(registry.LabError, match="nowhere does not exist"):
        registry.all_labs()
    (course / "cobotlab.toml").write_text('notebook_packages = ["no-such-distribution"]\n')
    registry.use_course(course)
    with pytest.raises(registry.LabError, match=r"cobotlab.toml: notebook_packages names "
                       r"'no-such-distribution', which is not installed.*pip install"):
        registry.notebook_packages()
    (course / "cobotlab.toml").write_text('labs = ["labs"]\n')
    registry.use_course(course)
    with pytest.raises(registry.LabError, match="unknown setting.*labs.*lab_folders"):
        registry.all_labs()


def test_the_spec_hash_follows_the_files_and_grade_warns_until_verified(course):
    write_lab(course, "mylab")
    registry.use_course(course)
    before = registry.spec_hash("mylab")
    assert "never verified" in registry.verification_note("mylab")
    record = registry.verification_path("mylab")
    assert record == course / ".cobotlab" / "verified" / "mylab.json"
    record.parent.mkdir(parents=True)
    record.write_text(f'{{"spec_hash": "{before}", "passed": true}}')
    assert registry.verification_note("mylab") is None
    spec = course / ".cobotlab" / "specs" / "mylab.py"
    spec.write_text(spec.read_text().replace("1e-6", "1e-5"))
    assert registry.spec_hash("mylab") != before
    assert "changed since it was last verified" in registry.verification_note("mylab")
    assert registry.verification_note("lab0_frames") is None   # the project verifies its own


def test_a_student_folder_finds_its_lab_from_the_scoring_beside_the_notebook(
        course, monkeypatch):
    lab_dir = write_lab(course, "mylab")
    (course / "cobotlab.toml").unlink()   # a student's download: no course around it
    registry.use_course(None)
    monkeypatch.chdir(lab_dir)
    assert "mylab" in registry.lab_names()
    assert not registry.private_available("mylab")  # no .cobotlab/specs beside the folder
    with pytest.raises(checks.InstructorOnly):
        checks.SPECS["mylab"]

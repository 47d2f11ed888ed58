"""`cobotlab labs verify`: the author's gate (issue 30, items 4 and 6).

Each test makes the skeleton lab with `cobotlab labs new` in a fresh course folder, breaks it
one way and checks that verify fails, names the file or the function, and says the fix,
without a traceback from inside the grader. The static checks run without the sandbox (the
test says so by making bubblewrap "unavailable", which verify reports as a failure of its
own); the statistical ones run the reference in the real bubblewrap worker. The walk-through
of docs/authoring.md (a passing lab from a wheel install, and the lab broken by a tight
tolerance and by a mistake equal to the reference) is in tests/test_course_install.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from autograder import registry, sandbox
from autograder.pipeline import worker
from cobotlab import cli
from cobotlab.authoring import new_lab
from cobotlab.verify import verify_lab

LAB = "gauge_offset"
needs_bwrap = pytest.mark.skipif(not sandbox.capabilities().bwrap,
                                 reason="verify runs the reference in bubblewrap")


@pytest.fixture
def lab(tmp_path):
    """(course folder, lab folder, private spec) of a fresh skeleton lab."""
    course = tmp_path / "course"
    new_lab(LAB, course)
    registry.use_course(course)
    yield course, course / "labs" / LAB, course / ".cobotlab" / "specs" / f"{LAB}.py"
    registry.use_course(None)


@pytest.fixture
def no_sandbox(monkeypatch):
    monkeypatch.setattr(worker, "sandbox_available", lambda: False)


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new))
    registry.use_course(registry.course_root())   # drop what was loaded before the edit


def _edit_cell(notebook: Path, grade_id: str, edit) -> None:
    nb = json.loads(notebook.read_text())
    (cell,) = [c for c in nb["cells"] if c["metadata"].get("nbgrader", {}).get("grade_id")
               == grade_id]
    edit(cell)
    notebook.write_text(json.dumps(nb, indent=1))


def _findings(**kwargs) -> dict[str, list[str]]:
    report = verify_lab(LAB, progress=False, **kwargs)
    found: dict[str, list[str]] = {}
    for f in report.findings:
        found.setdefault(f.check, []).append(f.message)
    return found


def _source(cell) -> str:
    return "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]


def test_without_bubblewrap_verify_fails_and_says_how_to_get_it(lab, no_sandbox):
    found = _findings(draws=10)
    assert list(found) == ["sandbox"], found   # the skeleton itself is clean
    assert "sudo apt-get install bubblewrap" in found["sandbox"][0]


def test_a_spec_that_fails_to_import_names_its_file_and_line(lab, no_sandbox, capsys):
    _, _, spec = lab
    _edit(spec, "BOX_SIDE_M = 0.5", "BOX_SIDE_M = 0.5 +")
    found = _findings(draws=10)
    assert list(found) == ["spec"], found
    assert str(spec) in found["spec"][0] and "line" in found["spec"][0]
    # The command: exit 1, the table's FAIL line, no traceback.
    assert cli.main(["labs", "verify", str(lab[1]), "--draws", "10"]) == 1
    out = capsys.readouterr()
    assert f"FAIL spec: {spec}" in out.out and "Traceback" not in out.out + out.err


@pytest.mark.parametrize("body, expected", [
    ("raise ZeroDivisionError('no stops')", "the generator raised on a first draw: "
                                            "ZeroDivisionError: no stops"),
    ("return Trial(args=(0, 0), truth=np.full(3, np.nan), tol={'offset': 1.0})",
     "the truth is NaN"),
    ("return Trial(args=(0, 0), truth=np.zeros(3), tol={'offset': float('nan')})",
     "are not finite positive numbers"),
    ("return _trial_mean_offset(np.random.default_rng(7), index)", "ignores its rng"),
    ("return _trial_mean_offset(np.random.default_rng(), index)",
     "the same rng gave other problems"),
], ids=["raises", "nan-truth", "nan-tolerance", "ignores-rng", "own-random-source"])
def test_a_broken_generator_is_named_with_its_file(lab, no_sandbox, body, expected):
    _, _, spec = lab
    _edit(spec, "SPECS = (MEAN_OFFSET,)", f"def _broken(rng, index):\n    {body}\n\n\n"
                                          "SPECS = (replace(MEAN_OFFSET, make_trial=_broken),)")
    found = _findings(draws=10)
    assert set(found) == {"generator", "sandbox"}, found
    (message,) = found["generator"]
    assert message.startswith("mean_offset: ") and expected in message, message
    assert str(spec) in message


def test_a_notebook_without_the_graded_function_or_any_solution_region(lab, no_sandbox):
    _, folder, _ = lab
    notebook = folder / f"{LAB}.ipynb"

    def rename(cell):
        cell["source"] = _source(cell).replace("def mean_offset(", "def mean_offsets(")
    _edit_cell(notebook, "mean_offset", rename)
    found = _findings(draws=10)
    assert any("no solution cell defines mean_offset" in m for m in found["solution region"])

    def no_region(cell):
        cell["source"] = "\n".join(line for line in _source(cell).splitlines()
                                   if "SOLUTION" not in line)
    _edit_cell(notebook, "mean_offset", no_region)
    found = _findings(draws=10)
    assert any("no cell holds a ### BEGIN SOLUTION" in m for m in found["solution region"])
    assert "reference" not in found   # nothing to run, so no statistics


def test_parameters_points_and_outputs_must_match_the_spec(lab, no_sandbox):
    _, folder, _ = lab
    notebook = folder / f"{LAB}.ipynb"

    def other_order(cell):
        cell["source"] = _source(cell).replace("def mean_offset(measured, commanded)",
                                               "def mean_offset(commanded, measured=None)")
    _edit_cell(notebook, "mean_offset", other_order)

    def three_points_and_an_output(cell):
        cell["metadata"]["nbgrader"]["points"] = 3
        cell["outputs"] = [{"output_type": "stream", "name": "stdout", "text": "2 / 2\n"}]
    _edit_cell(notebook, "test_mean_offset", three_points_and_an_output)
    found = _findings(draws=10)
    (parameters,) = found["parameters"]
    assert "def mean_offset(commanded, measured=None) but the spec says (measured, " \
        "commanded)" in parameters
    assert "test_mean_offset is worth 3 points, the spec 2" in found["points"][0]
    assert "hold outputs; clear them" in found["outputs"][0]


def test_a_function_graded_twice_and_a_test_cell_without_a_spec(lab, no_sandbox):
    course, folder, spec = lab
    _edit(folder / "scoring.py", "SPECS = (MEAN_OFFSET,)", "SPECS = (MEAN_OFFSET, MEAN_OFFSET)")
    found = _findings(draws=10)
    assert list(found) == ["spec"], found
    assert "mean_offset" in found["spec"][0] and "twice" in found["spec"][0]


def test_a_forbidden_routine_that_names_nothing(lab, no_sandbox):
    _, folder, _ = lab
    _edit(folder / "scoring.py", 'parameters="measured, commanded",',
          'parameters="measured, commanded", forbidden=("numpy.meen",),')
    found = _findings(draws=10)
    assert "'numpy.meen' names nothing importable" in found["forbidden"][0]


@needs_bwrap
def test_a_hidden_problem_equal_to_a_practice_one_is_refused(lab):
    """A generator choosing among a handful of fixed problems repeats check()'s practice
    problems in the hidden set, where their answers are known."""
    _, _, spec = lab
    _edit(spec, "SPECS = (MEAN_OFFSET,)", "def _few(rng, index):\n"
                                          "    return _trial_mean_offset(np.random.default_rng("
                                          "int(rng.integers(3))), index)\n\n\n"
                                          "SPECS = (replace(MEAN_OFFSET, make_trial=_few),)")
    found = _findings(draws=20)
    assert "a hidden problem equals a practice problem" in found["practice"][0]
    assert "draw from a wider range" in found["practice"][0]


@needs_bwrap
def test_a_reference_that_needs_a_package_outside_the_allow_list_fails_in_the_sandbox(lab):
    """The reference imports a library that is installed here but not on the grader's
    allow list: verify finds it where the students' code would, and names the setting."""
    course, folder, _ = lab
    notebook = folder / f"{LAB}.ipynb"

    def import_pytest(cell):
        cell["source"] = "import pytest\n" + _source(cell)
    _edit_cell(notebook, "imports", import_pytest)
    found = _findings(draws=5)
    assert "raised while loading in the sandbox" in found["reference"][0]
    assert "pytest" in found["reference"][0] and "notebook_packages" in found["reference"][0]
    # With the package on the course's list the worker imports it.
    (course / "cobotlab.toml").write_text('lab_folders = ["labs"]\n'
                                          'notebook_packages = ["pytest"]\n')
    registry.use_course(course)
    found = _findings(draws=5)
    assert "reference" not in found, found


@pytest.mark.parametrize("builtin", registry.builtin_names())
def test_every_built_in_lab_agrees_with_its_spec(builtin):
    """The built-in labs pass the same static gate: each graded def takes the spec's
    parameters, each test cell is worth the spec's points and calls check(), outputs are
    clear, the release is clean, forbidden routines exist."""
    from cobotlab import verify

    specs = registry.specs(builtin)
    findings = verify._static(registry.find_lab(builtin), specs) + verify._forbidden(specs)
    assert findings == [], findings


def test_a_closed_loop_problem_is_told_apart_by_its_set_up():
    """ibvs_velocity's problems have no arguments (the loop calls the law): its set-up,
    in the truth, is what differs between students."""
    from cobotlab import verify

    (spec,) = [s for s in registry.specs("lab3_servoing") if s.name == "ibvs_velocity"]
    assert spec.drive is not None
    assert verify._generator("lab3_servoing", spec) == []


def test_course_init_with_a_broken_lab_names_it_and_writes_nothing_of_it(lab, capsys):
    """A generator that raises while drawing the practice problems: the lab is skipped with
    one line naming its spec (issue 40: a broken draft never blocks the other labs, which
    tests/test_lab_lifecycle.py checks)."""
    course, _, spec = lab
    _edit(spec, "n = int(rng.integers(5, 41))", "n = int(rng.integers(5, 41)) / 0")
    assert cli.main(["course", "init", str(course)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"cobotlab: skipped lab {LAB}: ") and str(spec) in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (course / "source" / LAB).exists()
    assert (course / "source" / "lab0_frames" / "lab0_frames.ipynb").is_file()


# --------------------------------------------------------------------------- what an author sees
# (issue 38, items 1 and 4): trivial answers, each mistake's share of problems, the
# tolerances in the check's unit, and the worst problem as a notebook cell.


@needs_bwrap
def test_the_skeleton_shows_trivial_answers_tolerances_and_its_worst_problem(lab, capsys):
    import ast

    report = verify_lab(LAB, draws=30, progress=False)
    # 30 draws cannot show a mistake's 99 %: that is the only finding
    assert {f.check for f in report.findings} == {"draws"}, report.findings
    (row,) = report.functions
    # no trivial answer earns credit on the skeleton: its offsets are 5 to 50 mm, its
    # tolerances a few mm; the best one's interval is given
    best = row["trivial"][0]
    assert best["draws"] == 30 and best["mean"] <= 0.05 and best["low"] <= best["mean"] \
        <= best["high"]
    assert {"zeros", "(0, 0, 1)", "truth of another problem"} <= \
        {t["answer"] for t in row["trivial"]}
    # the tolerance range, in the check's unit, against a trivial answer's typical error
    (tol,) = row["tolerances"]
    assert tol["check"] == "offset" and tol["unit"] == "mm"
    assert 6 * 0.2 / 40 ** 0.5 <= tol["low"] <= tol["high"] <= 6 * 2.0 / 5 ** 0.5
    assert tol["high"] < 5.0 <= tol["trivial_error"]
    assert report.warnings == []
    # the wrong sign loses every problem, not only every draw; the reference none
    variants = {v["variant"]: v for v in row["variants"]}
    assert variants["reference"]["problems_lost"] == 0
    (mistake,) = [v for v in variants.values() if not v["correct"]]
    assert mistake["problems"] == 30 * 12 == mistake["problems_lost"]
    assert row["worst_problem"]["check"] == "offset"
    # mistake families (issue 52): an offset in mm, a plain vector, takes the unit, sign and
    # sum families, each losing every draw; no pose, so no inverse; no reference in the
    # skeleton's spec, so nothing for the input side to call on swapped inputs
    families = {(f["family"], f["mistake"]): f for f in row["families"]}
    assert len(families) == len(row["families"])
    for key in (("units m/mm", "millimetres"), ("units m/mm", "metres"), ("sign", "sign"),
                ("sum for mean", "sum for mean")):
        f = families[key]
        assert (f["status"], f["draws"], f["lost"], f["share"]) == ("applies", 30, 30, 1.0)
        assert f["problems"] == 30 * 12 and f["low"] < 1.0 == f["high"]
    assert families[("inverse/transpose", "inverse pose")]["status"] == "does not apply"
    assert families[("swapped arguments", "swapped arguments")]["status"] == "no reference"

    assert cli.main(["labs", "verify", LAB, "--draws", "30", "--worst"]) == 1
    out = capsys.readouterr().out
    assert "trivial answers: mean share of the function's points" in out
    assert "tolerances over the draws" in out and "problems lost" in out
    table = out.split("mistake families: ", 1)[1]
    assert "mean_offset              units m/mm             millimetres" in table
    assert "HOLE" not in table
    assert "mean_offset              does not apply: " in table and "(inverse pose)" in table
    saved = json.loads((lab[0] / ".cobotlab" / "verified" / f"{LAB}.json").read_text())
    assert saved["functions"][0]["families"] == json.loads(json.dumps(row["families"]))
    cell = out.split("# ---- cell ----\n", 1)[1]
    ast.parse(cell)   # pastes into a notebook as it is
    # and, run beside the reference, it rebuilds the worst problem: full credit, no error
    namespace: dict = {}
    exec("import numpy as np\n"   # noqa: S102 - our own cell and the skeleton's reference
         "def mean_offset(measured, commanded):\n"
         "    return np.mean(np.asarray(measured) - np.asarray(commanded), axis=0)\n" + cell,
         namespace)
    assert "mean_offset: 2 / 2 points" in capsys.readouterr().out


@needs_bwrap
def test_a_tolerance_as_large_as_the_answer_fails_the_trivial_gate(lab):
    """Tolerances of metres on an offset of millimetres (a tolerance in the wrong unit):
    answering zeros earns full credit, which verify refuses, naming the answer and the
    check, and the tolerance table warns in metres."""
    _, _, spec = lab
    _edit(spec, "tol_mm = 6.0 * sigma * 1000.0 / math.sqrt(n)",
          "tol_mm = 6.0 * sigma * 1e6 / math.sqrt(n)")
    report = verify_lab(LAB, draws=20, progress=False)
    # one finding for the check, naming the best trivial answer and counting the others
    (trivial,) = [f.message for f in report.findings if f.check == "trivial"]
    assert trivial.startswith("mean_offset: the trivial answer ") and \
        "earns 100.0% of its points on average" in trivial, trivial
    assert "credited by the check 'offset'" in trivial and "more above it" in trivial
    (row,) = report.functions
    (zeros,) = [t for t in row["trivial"] if t["answer"] == "zeros"]
    assert zeros["mean"] == 1.0 and zeros["check"] == "offset" and zeros["draws"] == 20
    (warning,) = [w for w in report.warnings if w.check == "tolerance"]
    assert "check 'offset' reaches" in warning.message
    assert " m)" in warning.message   # millimetres past a metre are shown in metres too
    # the families see the hole too: the offset in metres (a thousandth of the truth) and
    # any sign are within metres of tolerance; the offset in millimetres x1000 is not
    holes = {w.message.split("(", 1)[1].split(")", 1)[0] for w in report.warnings
             if w.check == "family"}
    assert {"metres", "sign"} <= holes and "millimetres" not in holes, report.warnings
    families = {f["mistake"]: f for f in row["families"]}
    assert families["metres"]["lost"] == 0 and families["millimetres"]["share"] == 1.0

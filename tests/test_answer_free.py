"""Students' copies hold no code that computes an answer, and check() shows the same table.

``check()`` scores on practice data (autograder/practice.py) with the public scoring
(autograder/scoring/); the generators and answer functions (autograder/specs/) stay on the
instructor's side. Here:

* the practice data `course init` writes beside each lab's notebook, loaded back, holds
  exactly the problems the private generators draw, with their code mistakes' answers and
  stand-in tables;
* for every graded function of every lab, the notebook's solution and each correct variant
  and classic mistake of the fairness benchmark get the same points, per-check verdicts and
  errors from ``check()`` on that file as the grader's in-memory scoring on the generators
  (with the analytic interaction matrix of before as IBVS's stand-in, and the reference law
  run inside the loop as before);
* no solution region of a source notebook and no private ``ANSWERS`` function, normalised
  through ``ast``, appears in the student wheel or in ``cobotlab labs student``'s output;
* nor a near copy of one: no function there holds half or more of such a function's
  statements (robots/perception.py once shipped lab 5's RANSAC plane fit with two of its
  lines changed, which the exact search could not see);
* and both searches find a renamed copy planted on purpose.
"""

from __future__ import annotations

import copy
import math
import shutil
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import checks, forbidden, practice, registry
from autograder.specs import lab3_servoing as lab3

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))
sys.path.insert(0, str(TESTS.parent / "benchmarks"))
import answer_leaks  # noqa: E402
import grading_fairness as fairness  # noqa: E402

LABS = sorted(checks.SCORING)


@pytest.fixture(scope="module")
def practice_dir(tmp_path_factory) -> Path:
    """Every lab's practice file as `course init` wrote it beside the lab's notebook (what a
    release carries), gathered in one folder. The run's one `course init`
    (course_kit.initialized_master) writes them with practice.save_practice of
    build_practice, as write_practice does: drawing them again here cost 8.5 s of CPU."""
    course = kit.initialized_master()
    folder = tmp_path_factory.mktemp("practice")
    for lab in LABS:
        name = practice.practice_file_name(lab)
        shutil.copyfile(course / "source" / lab / name, folder / name)
    return folder


# --------------------------------------------------------------------------- the data


def _same_value(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype \
            and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(map(_same_value, a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(
            _same_value(a[k], b[k]) for k in a)
    return type(a) is type(b) and (a == b or (a != a and b != b))


@pytest.mark.parametrize("lab", LABS)
def test_practice_file_holds_the_generators_problems(lab, practice_dir, monkeypatch):
    monkeypatch.setenv(practice.ENV_DIR, str(practice_dir))
    loaded = practice.load_practice(lab)
    assert loaded.source == str(practice_dir / practice.practice_file_name(lab))
    assert loaded.seeds == sorted(checks.PUBLIC_SEEDS + checks.KERNEL_SEEDS)
    for spec in checks.SPECS[lab]:
        for seed in loaded.seeds:
            drawn = checks.public_trials(spec, seed)
            read = loaded.trials(spec.name, seed)
            assert len(read) == len(drawn) == (spec.practice_trials or spec.n_trials)
            for a, b in zip(drawn, read):
                assert _same_value(a.args, b.args), (spec.name, seed, a.label)
                truth = a.truth
                if spec.drive is not None:  # the loop's reference is part of the truth
                    assert "first_twist" in truth
                assert _same_value(truth, b.truth), (spec.name, seed)
                assert (a.tol, a.label, a.all_or_nothing, a.raises) == \
                    (b.tol, b.label, b.all_or_nothing, b.raises)
                assert _same_value(practice.precomputed_mistakes(spec, a), b.mistakes)
                tables = spec.substitutes(a.args) if spec.substitutes and not spec.drive \
                    else None
                assert _same_value(tables, b.substitutes)


def test_a_student_install_without_the_file_is_told_what_to_fetch(tmp_path, monkeypatch):
    monkeypatch.delenv(practice.ENV_DIR, raising=False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(registry, "private_available", lambda name: False)
    with pytest.raises(practice.PracticeDataError) as err:
        checks.evaluate(lambda T: T, "invert_pose", assignment="lab0_frames")
    message = str(err.value)
    assert practice.practice_file_name("lab0_frames") in message
    assert "download the whole lab folder" in message


def test_a_damaged_file_is_refused_as_data(tmp_path, monkeypatch):
    import gzip
    import json

    monkeypatch.setenv(practice.ENV_DIR, str(tmp_path))
    path = practice.write_practice("lab0_frames", tmp_path)
    document = json.loads(gzip.decompress(path.read_bytes()))
    trial = document["functions"]["invert_pose"]["0"][0]
    trial["args"] = {"__pickle__": "Y29zCnN5c3RlbQ=="}  # not a wire type: never unpickled
    path.write_bytes(gzip.compress(json.dumps(document).encode()))
    with pytest.raises(practice.PracticeDataError, match="damaged"):
        practice.practice_trials("lab0_frames", "invert_pose", [0])


def test_the_student_side_imports_no_private_module(practice_dir):
    """Importing what a notebook imports, then check() and hidden_test() on the practice
    file, never imports autograder.specs, even where it could be imported."""
    import os
    import subprocess

    code = ("import sys, autograder.checks, autograder.scoring, autograder.practice, "
            "autograder.synthetic, autograder.datasets, robots, sim_backends\n"
            "from autograder.checks import check, hidden_test\n"
            "from robots import geometry as geo\n"
            "def invert_pose(T):\n"
            "    R, t = T[:3, :3], T[:3, 3]\n"
            "    out = geo.make_pose(R.T, -R.T @ t)\n"
            "    return out\n"
            "check(invert_pose, assignment='lab0_frames')\n"
            "hidden_test(invert_pose, assignment='lab0_frames')\n"
            "print(sorted(m for m in sys.modules if m.startswith('autograder.specs')))")
    env = {**os.environ, practice.ENV_DIR: str(practice_dir)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=TESTS.parent, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "invert_pose: 3 / 3 points" in done.stdout, done.stdout
    assert done.stdout.strip().endswith("[]"), done.stdout


# --------------------------------------------------------------------------- the same table


def _analytic_ibvs_substitutes(args) -> dict:
    """Before: IBVS's stand-in answered with the analytic interaction matrix."""
    s, _, Z, _ = args
    s, Z = np.asarray(s, dtype=float), np.asarray(Z, dtype=float)
    return {"interaction_matrix": [((s[:, 0], s[:, 1], Z),
                                    lab3._true_interaction(s[:, 0], s[:, 1], Z))]}


def _drive_with_the_law_inside(call, trial):
    """Before: the closed loop ran the reference law on its own first features."""
    truth = {k: v for k, v in trial.truth.items() if k != "first_twist"}
    shadow = replace(trial, truth=truth)

    def spy(s, s_star, Z, gain):
        if "first_twist" not in truth:
            truth["first_twist"] = lab3._reference_ibvs(s, s_star, Z, gain)
        return call(s, s_star, Z, gain)

    return lab3.IBVS_VELOCITY.drive(spy, shadow)


_DRAWN: dict[tuple, list] = {}


def _generated(spec, seed: int) -> list:
    """``checks.public_trials(spec, seed)`` drawn by the generator once per function and
    seed, each caller given its own deep copy: every variant of a function met the same
    problems, drawn again each time (lab 5: 2.7 s of CPU of its table's 20)."""
    key = (spec.make_trial, spec.name, int(seed))   # the generator: lab 1 and 4 share a name
    if key not in _DRAWN:
        _DRAWN[key] = checks.public_trials(spec, seed)
    return copy.deepcopy(_DRAWN[key])


def _before(spec, func, seeds) -> checks.FunctionResult:
    """The grader's scoring of before: generators, spec-side mistakes and stand-ins."""
    if spec.drive is not None:
        spec = replace(spec, substitutes=_analytic_ibvs_substitutes,
                       drive=_drive_with_the_law_inside)
    trials = [t for s in seeds for t in _generated(spec, s)]
    with forbidden.Tripwire(spec.forbidden, ()) as tripwire:
        outcomes = [checks._call_in_process(func, t, spec) for t in trials]
    used = set(tripwire.hits) | set(checks._static_forbidden(func, spec, ()))
    if used:
        return checks.forbidden_result(spec, used)
    return checks.score_function(spec, trials, outcomes)


def _close(a: float, b: float) -> bool:
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b or (math.isnan(a) and math.isnan(b))
    return abs(a - b) <= max(1e-12, 1e-9 * max(abs(a), abs(b)))


def _assert_same(before: checks.FunctionResult, after: checks.FunctionResult, what: str):
    assert after.points == before.points, (what, before.summary(), after.summary())
    assert (after.n_problems, after.n_failed, after.forbidden) == \
        (before.n_problems, before.n_failed, before.forbidden), what
    assert after.errors == before.errors, what
    assert after.error_counts == before.error_counts, what
    assert [c.name for c in after.checks] == [c.name for c in before.checks], what
    for b, a in zip(before.checks, after.checks):
        assert (a.n_full, a.n_trials, a.credit, a.n_voided) == \
            (b.n_full, b.n_trials, b.credit, b.n_voided), (what, b.name)
        for field in ("worst_error", "median_error", "tolerance"):
            assert _close(getattr(a, field), getattr(b, field)), \
                (what, b.name, field, getattr(b, field), getattr(a, field))


def _seed_sets(k: int) -> tuple[tuple[int, ...], ...]:
    """The seed sets variant ``k`` of a function's table is compared on. Every seed's
    problems go through the same encoding and the same scoring, and each seed's problems
    are compared with the generator's one by one (args with their dtypes, truths,
    tolerances, labels, mistakes, stand-ins: test_practice_file_holds_the_generators_problems),
    so one seed shows what the scoring does with a variant's answers: the notebook solution
    (k = 0) meets every public and kernel seed, every other variant one public seed, taken
    in turn (variant k the k-th, cyclically), so that a function's variants meet all three.
    Every variant on every public seed cost 29 s more of CPU (the file: 96 against 67 s)
    and reached no line of autograder/ the turns do not (traced on all six labs); with
    COBOTLAB_FULL_CORPUS=1 (benchmarks/adversarial_corpus.py, row ``practice``) every
    variant meets every public seed, as before."""
    if k == 0:
        return checks.PUBLIC_SEEDS, checks.KERNEL_SEEDS
    if kit.full_corpus():
        return (checks.PUBLIC_SEEDS,)
    return ((checks.PUBLIC_SEEDS[k % len(checks.PUBLIC_SEEDS)],),)


@pytest.mark.slow
@pytest.mark.parametrize("lab", LABS)
def test_check_on_practice_data_gives_the_same_table(lab, practice_dir, monkeypatch):
    monkeypatch.setenv(practice.ENV_DIR, str(practice_dir))
    np.seterr(all="ignore")  # the mistakes divide by zero on purpose
    table = fairness.variants(lab)
    seen = 0
    for spec in checks.SPECS[lab]:
        assert table[spec.name][0].name == "notebook solution"
        for k, variant in enumerate(table[spec.name]):
            for seeds in _seed_sets(k):
                what = f"{lab}.{spec.name} ({variant.name}) on seeds {seeds}"
                before = _before(spec, variant.func, seeds)
                after = checks.evaluate(variant.func, spec.name, seeds, lab, reference=True)
                _assert_same(before, after, what)
                seen += 1
        assert practice.load_practice(lab).source.startswith(str(practice_dir))
    assert seen >= 5 * len(checks.SPECS[lab])


# --------------------------------------------------------------------------- no answer code


@pytest.fixture(scope="module")
def needles():
    found = answer_leaks.answer_functions()
    # every graded function of every lab has its solution among them
    names = {n.origin.rsplit("def ", 1)[1] for n in found}
    for lab, specs in checks.SCORING.items():
        for spec in specs:
            assert spec.name in names, f"{lab}.{spec.name}: no solution region found"
    return found


def test_the_leak_search_finds_a_renamed_copy(needles, tmp_path):
    planted = tmp_path / "innocent.py"
    planted.write_text('''
import numpy as onp


def helper_matrix(u: "array", v, depth) -> "array":
    """Nothing to see here."""
    # a comment
    M = onp.zeros((len(u), 2, 6))
    M[:, 0, 0], M[:, 0, 2], M[:, 0, 3], M[:, 0, 4], M[:, 0, 5] = -1 / depth, u / depth, u * v, -(1 + u * u), v
    M[:, 1, 1], M[:, 1, 2], M[:, 1, 3], M[:, 1, 4], M[:, 1, 5] = -1 / depth, v / depth, 1 + v * v, -u * v, -u
    return M.reshape(-1, 6)


def unrelated(a, b):
    return a + b
''')
    findings = answer_leaks.find_answers([planted], needles)
    assert len(findings) == 1 and "_true_interaction" in findings[0], findings


@pytest.fixture(scope="module")
def references():
    """The statements of every solution region's and private answer's function defs."""
    found = answer_leaks.reference_statements()
    # every graded function's solution is among them, with statements to compare
    names = {r.origin.rsplit("def ", 1)[1] for r in found if r.forms}
    for lab, specs in checks.SCORING.items():
        for spec in specs:
            assert spec.name in names, f"{lab}.{spec.name}: no solution statements found"
    return found


def test_the_near_copy_search_finds_a_copy_with_two_lines_changed(references, needles,
                                                                  tmp_path):
    """Lab 5's RANSAC plane fit renamed, commented, its NaN filter left out and its normal
    normalised in place: the exact search misses it, the statement search does not."""
    planted = tmp_path / "innocent.py"
    planted.write_text('''
import numpy


def dominant_surface(cloud, tolerance, rounds=200, seed=1):
    """Nothing to see here."""
    xyz = numpy.asarray(cloud, dtype=float).reshape(-1, 3)
    gen = numpy.random.default_rng(seed)
    winner = None
    for _ in range(rounds):
        p, q, r = xyz[gen.choice(len(xyz), 3, replace=False)]
        axis = numpy.cross(q - p, r - p)
        if numpy.linalg.norm(axis) < 1e-12:
            continue
        axis /= numpy.linalg.norm(axis)  # unit length
        close = numpy.abs((xyz - p) @ axis) < tolerance
        if winner is None or close.sum() > winner.sum():
            winner = close
    middle = xyz[winner].mean(axis=0)
    up = numpy.linalg.svd(xyz[winner] - middle, full_matrices=False)[2][2]
    if up @ middle > 0:
        up = -up
    return middle, up


def unrelated(points, k):
    pts = numpy.asarray(points, dtype=float).reshape(-1, 3)
    for _ in range(k):
        pts = pts - pts.mean(axis=0)
    return pts
''')
    assert answer_leaks.find_answers([planted], needles) == []
    findings = answer_leaks.find_near_copies([planted], references)
    assert findings and all("def dominant_surface holds" in f for f in findings), findings
    assert any("lab5_depth.ipynb" in f and "def fit_plane_ransac" in f for f in findings)


@pytest.fixture(scope="module")
def unpacked_wheel(tmp_path_factory) -> Path:
    """The student wheel, built from a copy of the sources and unpacked."""
    from test_student_install import _build_wheel

    wheel = _build_wheel()
    names = zipfile.ZipFile(wheel).namelist()
    assert not any(n.startswith("autograder/specs/") for n in names), names
    assert any(n.startswith("autograder/scoring/") for n in names)
    unpacked = tmp_path_factory.mktemp("wheel")
    zipfile.ZipFile(wheel).extractall(unpacked)
    return unpacked


def test_the_student_wheel_holds_no_answer_code(needles, unpacked_wheel):
    assert answer_leaks.find_answers([unpacked_wheel], needles) == []


def test_the_student_wheel_holds_no_near_copy_of_an_answer(references, unpacked_wheel):
    """No function a student receives holds half or more of a solution's (or private
    answer's) statements: the functions a lab grades stay out of the library, which passes
    the students' own functions in where it needs them (robots/labkit)."""
    assert answer_leaks.find_near_copies([unpacked_wheel], references) == []


def test_the_student_labs_hold_no_answer_code_and_carry_practice_data(needles, references,
                                                                      tmp_path):
    from cobotlab.labs import write_student_labs

    written = write_student_labs(tmp_path / "labs")
    assert {p.parent.name for p in written} == set(LABS)
    for lab in LABS:
        assert (tmp_path / "labs" / lab / practice.practice_file_name(lab)).is_file()
    assert answer_leaks.find_answers([tmp_path / "labs"], needles) == []
    assert answer_leaks.find_near_copies([tmp_path / "labs"], references) == []


@pytest.mark.parametrize("which", ["worker", "kernel"])
def test_the_grading_views_hold_no_answer_code(needles, which):
    """What the grading worker and nbgrader's kernel may read of cobotlab (the allow list of
    autograder/views.py): no solution region, no private answer function. The third-party
    libraries in the view are not searched: none of them holds a lab's answers."""
    from autograder import views

    view = views.worker_view() if which == "worker" else views.kernel_view()
    own = [str(Path(__import__(name).__file__).parent)
           for name in ("robots", "sim_backends", "autograder")]
    shown = [p for p in view.paths() if any(p == d or p.startswith(d + "/") for d in own)]
    assert any(p.endswith("/autograder/inside") for p in shown), shown   # the view was read
    assert not any("/specs" in p or p.endswith(("course.py", "secret.py", "/pipeline")) for p in shown)
    assert answer_leaks.find_answers(shown, needles) == []

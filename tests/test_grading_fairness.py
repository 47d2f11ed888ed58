"""Fair hidden grades: correct code never loses credit, classic mistakes always do.

A fast slice of benchmarks/grading_fairness.py (which runs >= 10,000 draws per function):
a few dozen hidden draws, drawn as the grader draws them, of the functions whose problems
or weights were fixed for fairness, every mistake being one of the spec's code mistakes; plus
the engine's statistics (autograder/fairness.py), the degenerate-input problems of
``fit_rigid``, the number of hidden problems against ``check()``'s, and the weights of the
checks.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from autograder import checks, fairness

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import grading_fairness as benchmark  # noqa: E402


@pytest.mark.parametrize("assignment,function,draws", [
    ("lab0_frames", "pose_from_rotvec", 10),
    ("lab1_flange", "fit_rigid", 12),
    ("lab4_stereo", "frame_from_three_points", 10),
    ("lab4_stereo", "reproject", 30),
    ("lab5_depth", "backproject", 10),
    ("lab5_depth", "base_T_cam_from_flanges", 10),
    ("lab5_depth", "rectangle_pose", 10),
])
def test_correct_code_keeps_full_credit_and_each_mistake_loses_some(assignment, function, draws):
    result = benchmark.run_function((assignment, function, 0, draws))
    spec = checks.spec_for(function, assignment)
    assert sum(not s.correct for s in result["stats"].values()) == len(spec.code_mistakes)
    for name, s in result["stats"].items():
        assert s.seen == draws
        if s.correct:
            assert s.lost == 0, f"correct {function} ({name}) lost credit: " \
                                f"{s.first_loss.describe()}"
            assert s.margin < 1.0, (name, s.margin)
        else:
            assert s.lost == draws, f"{function} mistake {name!r} kept full credit on " \
                                    f"{draws - s.lost}/{draws} draws"
            assert s.first_loss.draw == 0 and s.first_loss.describe().startswith(
                "draw student000000 ")


def test_every_code_mistake_has_a_table_name():
    """The benchmark's rows name each spec mistake briefly (docs/benchmarks/grading_fairness.md),
    and no two rows of a function share a name."""
    for lab, specs in checks.SPECS.items():
        for spec in specs:
            for m in spec.code_mistakes:
                assert m.func.__qualname__ in benchmark.SHORT_NAMES, (lab, spec.name, m.label)
            names = [benchmark.short_name(m) for m in spec.code_mistakes]
            assert len(set(names)) == len(names), (lab, spec.name, names)


def test_mistakes_are_scored_on_the_first_draws_only_and_parts_merge():
    first = benchmark.run_function(("lab0_frames", "invert_pose", 0, 3, 2))
    second = benchmark.run_function(("lab0_frames", "invert_pose", 3, 5, 2))
    merged = benchmark._merge([second, first])["stats"]
    for name, s in merged.items():
        assert s.seen == (5 if s.correct else 2), name
        assert s.lost == (0 if s.correct else 2), name
        assert s.correct or s.first_loss.student == "student000000"


def test_clopper_pearson_and_the_draws_a_rate_needs():
    low, high = fairness.clopper_pearson(0, 10_000)
    assert low == 0.0 and high == pytest.approx(3.69e-4, rel=0.01)
    low, high = fairness.clopper_pearson(1000, 1000)
    assert high == 1.0 and low == pytest.approx(0.99632, abs=1e-4)
    n = fairness.draws_for_rate(1e-3)
    assert n == 3688
    assert fairness.clopper_pearson(0, n)[1] < 1e-3 <= fairness.clopper_pearson(0, n - 1)[1]
    assert fairness.draws_for_rate(1e-4) == pytest.approx(36_887, abs=2)


def test_a_losing_draw_names_its_worst_check():
    spec = checks.spec_for("fit_rigid", "lab1_flange")

    def rng_of(student):
        return benchmark.problem_rng("lab1_flange", student, "fit_rigid")

    def transposed(src, dst):
        T = benchmark._kabsch(src, dst)
        T[:3, :3] = T[:3, :3].T
        return T

    stats = fairness.score_draws(spec, "lab1_flange", range(4, 6),
                                 {"transposed": fairness.in_process(transposed)}, rng_of)
    loss = stats["transposed"].first_loss
    assert (stats["transposed"].seen, stats["transposed"].lost, loss.draw) == (2, 2, 4)
    assert loss.check == "mapping" and loss.error > loss.tolerance and loss.unit == "mm"
    assert loss.describe().startswith("draw student000004 (")
    assert "check mapping" in loss.describe() and "mm noise' problem" in loss.describe()


def test_hidden_problems_are_at_least_as_many_as_checks():
    for lab, specs in checks.SPECS.items():
        for spec in specs:
            shown = len(checks.PUBLIC_SEEDS) * (spec.practice_trials or spec.n_trials)
            assert spec.n_trials >= shown, f"{lab}.{spec.name}: {spec.n_trials} hidden < {shown}"
            assert len(checks.public_trials(spec, 0)) == (spec.practice_trials or spec.n_trials)


def _fit_rigid_trials(seed: int = 3):
    spec = checks.spec_for("fit_rigid", "lab1_flange")
    return spec, checks.make_trials(spec, np.random.default_rng(seed))


def test_fit_rigid_hidden_problems_include_collinear_and_too_few_points():
    spec, trials = _fit_rigid_trials()
    degenerate = [t for t in trials if t.raises]
    assert {t.raises for t in degenerate} == {"ValueError"}
    assert any("collinear" in t.label for t in degenerate)
    assert any(len(t.args[0]) < 3 for t in degenerate)
    for t in degenerate:
        if len(t.args[0]) >= 3:  # collinear, to rounding: rank 1 once centred
            centred = t.args[0] - t.args[0].mean(axis=0)
            s = np.linalg.svd(centred, compute_uv=False)
            assert s[1] < 1e-12 * s[0]
    planar = [t for t in trials if t.label.startswith("planar")]
    assert len(planar) >= 9


def test_degenerate_problems_score_the_exception_and_only_there():
    spec, trials = _fit_rigid_trials()
    table = {v.name: v.func for v in benchmark.variants("lab1_flange")["fit_rigid"]}

    def score(func):
        return checks.score_function(spec, trials,
                                     [checks._call_in_process(func, t, spec) for t in trials])

    assert score(table["notebook solution"]).points == spec.points
    unchecked = score(table["no degenerate-input check"])
    share = sum(1 for t in trials if t.raises) / len(trials)
    assert unchecked.points == pytest.approx(spec.points * (1 - share), abs=0.01)
    assert any("expected ValueError" in e for e in unchecked.errors)

    def always_raises(src, dst):
        raise ValueError("no")

    # raising on every input is no method: the degenerate problems, edge cases, count only
    # when an ordinary problem is right too (issue 38: no trivial answer earns credit)
    raising = score(always_raises)
    assert raising.points == 0
    assert any("count only when the answer is right on at least one ordinary problem" in e
               for e in raising.errors), raising.errors

    def wrong_exception(src, dst):
        if len(src) < 3 or np.linalg.matrix_rank(np.asarray(src) - np.mean(src, 0)) < 2:
            raise RuntimeError("degenerate")
        return table["notebook solution"](src, dst)

    assert score(wrong_exception).points == pytest.approx(spec.points * (1 - share), abs=0.01)


def test_pose_checks_weigh_what_the_function_teaches():
    """Copying the given translation earns nothing: it counts only with the rotation right
    (Check.requires), and the identity's right answers to zero and tiny rotations are edge
    cases that count only when an ordinary rotation is right too."""
    def identity_rotation(rvec, t):
        T = np.eye(4)
        T[:3, 3] = t
        return T

    def frame_origin_only(p_origin, p_x, p_xy):
        T = np.eye(4)
        T[:3, 3] = p_origin
        return T

    spec = checks.spec_for("pose_from_rotvec", "lab0_frames")
    trials = [t for s in checks.PUBLIC_SEEDS for t in checks.public_trials(spec, s)]
    # the identity is the right rotation for a zero and a tiny rotation vector
    right = sum(t.label in ("zero rotation", "tiny rotation") for t in trials) / len(trials)
    rotvec = checks.evaluate(identity_rotation, "pose_from_rotvec", assignment="lab0_frames")
    assert right > 0 and rotvec.points == 0, rotvec.summary()
    frame = checks.evaluate(frame_origin_only, "frame_from_three_points",
                            assignment="lab4_stereo")
    assert frame.points == 0, frame.summary()


def test_the_fairness_run_takes_a_course_lab_and_leaves_the_projects_table_alone(
        tmp_path, monkeypatch, capsys):
    from autograder import registry
    from cobotlab.authoring import new_lab

    course = tmp_path / "course"
    new_lab("gauge", course)
    monkeypatch.chdir(course)   # found as a user finds it: the course folder's cobotlab.toml
    registry.use_course(None)
    before = benchmark.RESULTS_MD.read_bytes()
    try:
        assert benchmark.main(["--labs", "gauge", "--draws", "40", "--mistake-draws", "40"]) == 0
    finally:
        registry.use_course(None)
    out = capsys.readouterr().out
    assert "+ notebook solution" in out and "0/40" in out
    assert "- the offset has the wrong sign" in out and "40/40" in out
    assert "is a course's own lab" in out
    assert benchmark.RESULTS_MD.read_bytes() == before

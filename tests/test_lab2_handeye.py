"""Lab 2 (AX = XB eye-in-hand): the notebook runs, its tolerances separate right from wrong,
and the real nbgrader cycle grades a reference, a blank and a subtly wrong student.

About 2 minutes on 2 cores: the notebook drives the PyBullet sim (about 15 s a run), and each
of the three submissions runs through nbgrader once and through the independent grader once.
"""

from __future__ import annotations

from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import checks
from autograder.pipeline.pipeline import grade_course
from autograder.secret import load_secret
from autograder.specs import lab2_handeye as spec
from robots import geometry as geo
from solutions import handeye

ASSIGNMENT = "lab2_handeye"
FUNCTIONS = ("motions", "tsai_lenz", "axes_ls", "rotation_residual", "translation_residual")
POINTS = {"motions": 3.0, "tsai_lenz": 4.0, "axes_ls": 4.0, "rotation_residual": 2.0,
          "translation_residual": 2.0}

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), ASSIGNMENT)


@pytest.fixture(scope="module")
def solutions() -> dict[str, str]:
    return kit.solution_sources(ASSIGNMENT, FUNCTIONS)


def _compile(sources: dict[str, str]) -> dict:
    """The notebook's solution functions, defined as the notebook's imports cell would."""
    namespace = {"np": np, "geo": geo}
    for source in sources.values():
        exec(compile(source, "<solution>", "exec"), namespace)
    return namespace


# Subtly wrong, as students write them: B with the inverse on the wrong side, and an X returned
# inverted (cam_T_flange instead of flange_T_cam).
WRONG = {
    "motions": ("C[i] @ geo.invert(C[j])", "geo.invert(C[i]) @ C[j]"),
    "axes_ls": ("return geo.make_pose(R_X, t_X)", "return geo.invert(geo.make_pose(R_X, t_X))"),
}


def _wrong_sources(solutions: dict[str, str]) -> dict[str, str]:
    out = dict(solutions)
    for name, (old, new) in WRONG.items():
        assert old in out[name], f"the {name} solution no longer contains {old!r}"
        out[name] = out[name].replace(old, new)
    return out


# --------------------------------------------------------------------------- the notebook


def _strategy_errors(text: str, strategy: str) -> tuple[float, float, float, float]:
    """(rotation deg, translation mm) at n=3 and at n=15 as the strategy cell prints them."""
    line = text.split(f"Tsai-Lenz, {strategy:>11}: ", 1)[1].splitlines()[0]
    numbers = [float(v) for v in line.replace("n=3", "").replace("n=15", "").replace(
        "deg", "").replace("mm", "").replace("/", " ").replace(",", " ").split()]
    return tuple(numbers)


def test_source_notebook_runs_with_solutions_and_hidden_tests():
    nb = kit.execute_source(ASSIGNMENT, timeout_s=180)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)
    text = kit.output_text(nb)
    for name in FUNCTIONS:
        assert f"{name}: {POINTS[name]:g} / {POINTS[name]:g} points" in text, name
    assert "pybullet build time" not in text
    # The question after the strategy figure says: nearly equal at n = 3, apart at n = 15.
    consecutive = _strategy_errors(text, "consecutive")
    everything = _strategy_errors(text, "all")
    assert abs(consecutive[0] / everything[0] - 1.0) < 0.15, (consecutive, everything)
    assert everything[2] < 0.8 * consecutive[2], (consecutive, everything)
    assert "(closed_chain.svg)" in kit.source_notebook(ASSIGNMENT).read_text()
    assert (kit.source_notebook(ASSIGNMENT).parent / "closed_chain.svg").is_file()
    # the released notebook never calls the instructor's reference solvers
    source = kit.source_notebook(ASSIGNMENT).read_text()
    assert "from solutions" not in source and "import solutions" not in source
    assert "opencv_baseline" not in source


def test_release_has_no_solution_hidden_tests_or_secret(released, solutions):
    kit.assert_release_clean(released, ASSIGNMENT, len(FUNCTIONS), (
        "C[i] @ geo.invert(C[j])",
        "np.sqrt(4.0 - P @ P)",
        "np.linalg.svd(M)",
        "Ak[:3, :3] @ R_X - R_X @ Bk[:3, :3]",
    ))
    # The closed-chain diagram the markdown shows travels with the notebook.
    assert (released / "release" / ASSIGNMENT / "closed_chain.svg").is_file()


# --------------------------------------------------------------------------- the tolerances


def test_notebook_and_reference_solvers_earn_full_marks_on_many_problems(solutions):
    """A correct method passes over many seeds: the notebook's own solutions and the
    instructor's reference solvers (solutions.handeye) on the very same problems. Five
    seeds (30 problems per solver) here; the long version is benchmarks/grading_fairness.py,
    where both reference solvers and the notebook's solutions are correct variants scored
    on thousands of hidden draws (docs/benchmarks/grading_fairness.md), every pose count
    among them. Fifteen seeds here cost about 6 s more of CPU for a few more pose counts
    (7, 9 and 13 poses), which that benchmark draws thousands of times."""
    ns = _compile(solutions)
    seeds = range(200, 205)  # 30 problems per solver
    for name in FUNCTIONS:
        result = checks.evaluate(ns[name], name, seeds=seeds)
        assert result.fraction == 1.0, result.summary()
    for name, ref in (("tsai_lenz", handeye.solve_tsai), ("axes_ls", handeye.solve_axes_ls)):
        result = checks.evaluate(ref, name, seeds=seeds)
        assert result.fraction == 1.0, result.summary()


def test_wrong_methods_do_not_earn_the_marks(solutions):
    ns = _compile(solutions)
    seeds = range(300, 306)
    # Inverted X, A and B swapped, and a solver fed inverse motions all fail.
    tsai = ns["tsai_lenz"]
    for wrong in (lambda A, B: geo.invert(tsai(A, B)),
                  lambda A, B: tsai(B, A),
                  lambda A, B: tsai(geo.invert(A), B)):
        result = checks.evaluate(wrong, "tsai_lenz", seeds=seeds)
        assert result.fraction < 0.1, result.summary()
    # Skipping the projection onto SO(3): the noisy 9-parameter fit is not a rotation.
    source = solutions["axes_ls"].replace("R_X = U @ D @ Vt", "R_X = M")
    assert checks.evaluate(_compile({"axes_ls": source})["axes_ls"], "axes_ls",
                           seeds=seeds).fraction < 0.1
    # Motions: the inverse on the wrong side of B loses B; ignoring the strategy (always
    # consecutive pairs) loses the "all" half of the problems.
    wrong_b = _compile(_wrong_sources(solutions))["motions"]
    assert checks.evaluate(wrong_b, "motions", seeds=seeds).fraction == pytest.approx(0.5)
    always_consecutive = lambda F, C, strategy: ns["motions"](F, C, "consecutive")  # noqa: E731
    assert checks.evaluate(always_consecutive, "motions", seeds=seeds).fraction == \
        pytest.approx(0.5)
    # Residuals: a sum for the mean, a norm for its square, the wrong product order.
    for fn, edit in (("rotation_residual", ("np.mean", "np.sum")),
                     ("rotation_residual", ("R_X @ Bk[:3, :3]", "Bk[:3, :3] @ R_X")),
                     ("translation_residual", ("np.sum((", "np.sqrt(np.sum((")),
                     ("translation_residual", ("np.mean", "np.sum"))):
        source = solutions[fn].replace(*edit)
        if edit[1].startswith("np.sqrt"):
            source = source.replace("** 2)", "** 2))", 1)
        assert source != solutions[fn]
        result = checks.evaluate(_compile({fn: source})[fn], fn, seeds=seeds)
        assert result.fraction == 0.0, (edit, result.summary())


def test_tolerance_comes_from_the_noise():
    """Noise-free problems get a zero tolerance; more noise, a proportionally wider one."""
    from autograder import synthetic

    quiet = synthetic.make_hand_eye(5, n_poses=8)
    A, _ = spec.motion_pairs_truth(quiet.base_T_flange, quiet.cam_T_target, "all")
    assert spec.solver_tolerances(quiet, A) == {"rotation": spec.FLOOR, "translation": spec.FLOOR}
    noise = synthetic.NoiseModel(robot_rot_deg=0.02, robot_trans_mm=0.2, cam_rot_deg=0.1,
                                 cam_trans_mm=0.5)
    noisy = synthetic.make_hand_eye(5, n_poses=8, noise=noise)
    louder = synthetic.make_hand_eye(5, n_poses=8, noise=synthetic.NoiseModel(
        robot_rot_deg=0.04, robot_trans_mm=0.4, cam_rot_deg=0.2, cam_trans_mm=1.0))
    A, _ = spec.motion_pairs_truth(noisy.base_T_flange, noisy.cam_T_target, "all")
    t1, t2 = spec.solver_tolerances(noisy, A), spec.solver_tolerances(louder, A)
    assert t2["rotation"] == pytest.approx(2 * t1["rotation"], rel=1e-2)
    assert t2["translation"] == pytest.approx(2 * t1["translation"], rel=1e-2)


def test_ill_conditioned_motion_sets_are_drawn_again():
    """Motions about one axis leave R_X's turn about that axis unknown: such a set is refused
    by its geometry alone; the hidden problems drawn are well conditioned, reproducible from
    their stream, and the identity earns nothing on any of them."""
    from dataclasses import replace

    from autograder import synthetic
    from autograder.outcomes import TrialOutcome

    p = synthetic.make_hand_eye(3, n_poses=8, noise=spec._noise(np.random.default_rng(3)))
    trial, _ = spec.draw_solver_problem(np.random.default_rng(3))
    about_z = np.array([geo.make_pose(geo.rotation_from_rotvec([0.0, 0.0, 0.4 * k]),
                                      [0.1 * k, 0.0, 0.0]) for k in range(8)])
    parallel = replace(p, base_T_flange=about_z)
    info = spec.motion_information(parallel.base_T_flange)
    assert info.rotation_gain > 1e3 * spec.MAX_ROTATION_GAIN
    assert not spec.tests_the_solver(trial, parallel)
    for seed in range(12):
        trial = spec._trial_solver(np.random.default_rng(seed), 0)
        again = spec._trial_solver(np.random.default_rng(seed), 0)
        assert np.array_equal(trial.truth, again.truth) and trial.tol == again.tol
        assert trial.tol["rotation"] <= spec.ROT_K * np.hypot(0.05, 0.3) * spec.MAX_ROTATION_GAIN
        identity = checks.score_function(spec.TSAI_LENZ, [trial],
                                         [TrialOutcome(value=np.eye(4))], hints=False)
        assert identity.points == 0.0, (seed, trial.label, identity.summary())
        reference = handeye.solve_tsai(*trial.args)
        assert geo.rotation_error_deg(reference, trial.truth) < trial.tol["rotation"]


# --------------------------------------------------------------------------- full cycle


def test_full_cycle_reference_blank_and_subtly_wrong(released, solutions, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    kit.submit(course, ASSIGNMENT, "ref", replace=solutions)
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace=_wrong_sources(solutions))
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    assert [r["student_id"] for r in rows] == ["blank", "ref", "wrong"]
    grades = kit.read_grades(course)
    assert float(grades["ref"]["score"]) == 15.0 and float(grades["ref"]["max_score"]) == 15.0
    assert float(grades["blank"]["score"]) == 0.0
    # motions: A right, B wrong (1.5 of 3); axes_ls: an inverted X, whose only credit is a
    # stray half band on rotation when R_X is near the identity (rotation is half of its 4
    # points, so at most 1.0 even if that happened on every hidden problem: the problems are
    # fresh each run); the rest right (4 + 2 + 2).
    wrong = float(grades["wrong"]["score"])
    assert 9.5 <= wrong <= 10.5, grades["wrong"]
    assert all(grades[s]["flags"] == "" for s in grades), {s: g["flags"] for s, g in grades.items()}
    feedback = (course / "feedback_cobotlab" / "wrong" / ASSIGNMENT / "feedback.html").read_text()
    assert "motions" in feedback and " deg" in feedback and " mm" in feedback
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        text = path.read_text()
        assert secret not in text and "hidden_test" not in text, path

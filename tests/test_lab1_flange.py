"""Lab 1 (camera intrinsics and flange calibration): notebook, grading specs, nbgrader cycle.

The source notebook runs top to bottom in sim; its solutions agree with ``solutions.registration``;
the specs give the reference full marks and wrong methods less; the released notebook holds no
solution, hidden test or secret; and the real nbgrader cycle grades a reference, a blank and a
subtly wrong student full / zero / partial.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import checks, synthetic
from autograder.datasets import load_aubo_flange_capture
from autograder.pipeline.pipeline import grade_course
from autograder.secret import load_secret
from robots import geometry as geo
from solutions import registration as reg

ASSIGNMENT = "lab1_flange"
FUNCTIONS = ("fit_rigid", "per_point_residuals", "per_axis_rmse")
MAX_SCORE = 8.0

pytestmark = pytest.mark.slow


# --------------------------------------------------------------------------- helpers


def _evaluate(func, name: str) -> checks.FunctionResult:
    """Score ``func`` as lab 1's ``name`` on the public seeds (lab 4 also grades a
    per_axis_rmse, so the assignment is named)."""
    return checks.evaluate(func, name, assignment=ASSIGNMENT)


def _solutions() -> dict[str, str]:
    return kit.solution_sources(ASSIGNMENT, FUNCTIONS)


def _notebook_functions(sources: dict[str, str]) -> dict:
    """The notebook's solution cells as functions (they only need numpy)."""
    namespace = {"np": np}
    for source in sources.values():
        exec(source, namespace)  # noqa: S102 - our own notebook's solution code
    return {name: namespace[name] for name in FUNCTIONS}


def _wrong_sources(solutions: dict[str, str]) -> dict[str, str]:
    """A subtly wrong student: SVD of the raw (uncentred) covariance, RMSE along the dst axes."""
    fit = solutions["fit_rigid"].replace("src_c, dst_c = src - src_mean, dst - dst_mean",
                                         "src_c, dst_c = src, dst")
    rmse = solutions["per_axis_rmse"].replace("along_src = residuals @ R ",
                                              "along_src = residuals ")
    assert fit != solutions["fit_rigid"] and rmse != solutions["per_axis_rmse"]
    return {"fit_rigid": fit, "per_axis_rmse": rmse}


def _no_reflection_fix(src, dst):
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    U, _, Vt = np.linalg.svd((src - src.mean(0)).T @ (dst - dst.mean(0)))
    R = Vt.T @ U.T  # may be a mirror image
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = dst.mean(0) - R @ src.mean(0)
    return T


REFERENCE = {
    "fit_rigid": reg.fit_rigid,
    "per_point_residuals": lambda T, s, d: np.linalg.norm(reg.residuals(T, s, d), axis=1),
    "per_axis_rmse": lambda T, s, d: reg.per_axis_rmse(T, s, d, expressed_in="src"),
}


# --------------------------------------------------------------------------- specs and solutions


@pytest.mark.parametrize("name", FUNCTIONS)
def test_reference_earns_full_marks_on_public_and_kernel_seeds(name):
    for seeds in (checks.PUBLIC_SEEDS, checks.KERNEL_SEEDS, (11, 12, 13)):
        result = checks.evaluate(REFERENCE[name], name, seeds, assignment=ASSIGNMENT,
                                 reference=True)
        assert result.fraction == 1.0, result.summary()


def test_wrong_methods_lose_credit():
    # No reflection fix: a mirror image on some planar problems -> partial credit.
    naive = _evaluate(_no_reflection_fix, "fit_rigid")
    assert 0.0 < naive.fraction < 1.0, naive.summary()
    assert any("proper rotation" in e for e in naive.errors)
    wrong = _notebook_functions(_wrong_sources(_solutions()) | {
        k: v for k, v in _solutions().items() if k == "per_point_residuals"})
    assert _evaluate(wrong["fit_rigid"], "fit_rigid").fraction == 0.0
    assert _evaluate(wrong["per_axis_rmse"], "per_axis_rmse").fraction == 0.0
    no_translation = _evaluate(
        lambda T, s, d: np.linalg.norm(s @ T[:3, :3].T - d, axis=1), "per_point_residuals")
    assert no_translation.fraction == 0.0
    bad_shape = _evaluate(lambda T, s, d: np.zeros(4), "per_axis_rmse")
    assert bad_shape.fraction == 0.0 and "shape" in bad_shape.errors[0]


def test_notebook_solutions_agree_with_reference():
    mine = _notebook_functions(_solutions())
    for seed in range(5):
        p = synthetic.make_flange(seed, n_points=12, noise_mm=1.0, depth_noise_mm=3.0,
                                  fixed_orientation=seed % 2 == 0, n_outliers=1)
        T = mine["fit_rigid"](p.cam_points, p.base_points)
        assert np.allclose(T, reg.fit_rigid(p.cam_points, p.base_points), atol=1e-10)
        for name in ("per_point_residuals", "per_axis_rmse"):
            assert np.allclose(mine[name](T, p.cam_points, p.base_points),
                               REFERENCE[name](T, p.cam_points, p.base_points), atol=1e-12)
    line = np.outer(np.linspace(0.0, 0.3, 3), [1.0, -0.5, 0.2])
    with pytest.raises(ValueError, match="collinear"):
        mine["fit_rigid"](line, line + 0.1)
    with pytest.raises(ValueError, match="shape"):
        mine["fit_rigid"](np.zeros((5, 3)), np.zeros((4, 3)))


def test_real_capture_facts_the_notebook_tells():
    cam, base = load_aubo_flange_capture()
    T = reg.fit_rigid(cam, base)
    norms = np.linalg.norm(reg.residuals(T, cam, base), axis=1)
    assert int(np.argmax(norms)) == 45 and 0.011 < norms[45] < 0.013
    keep = np.arange(len(cam)) != 45
    T_clean = reg.fit_rigid(cam[keep], base[keep])
    rmse = reg.per_axis_rmse(T_clean, cam[keep], base[keep], expressed_in="src")
    assert rmse[2] > 3.0 * max(rmse[0], rmse[1]), rmse  # the error lives along depth
    # A fixed orientation hides a marker offset: zero residuals, a translation off by R p.
    offset = np.array([0.03, 0.0, 0.01])
    p = synthetic.make_flange(7, n_points=15, fixed_orientation=True, marker_offset_m=offset)
    T = reg.fit_rigid(p.cam_points, p.base_points)
    assert np.abs(reg.residuals(T, p.cam_points, p.base_points)).max() < 1e-9
    assert geo.translation_error(T, p.base_T_cam_true) == pytest.approx(np.linalg.norm(offset))


# --------------------------------------------------------------------------- notebook + cycle


@pytest.fixture
def clean_results():
    """The source notebook saves into lab1_results/ beside it; remove what the test made."""
    results = kit.source_notebook(ASSIGNMENT).parent / "lab1_results"
    existed = results.exists()
    yield
    if not existed:
        shutil.rmtree(results, ignore_errors=True)


def test_source_notebook_runs_with_solutions_and_hidden_tests(clean_results):
    nb = kit.execute_source(ASSIGNMENT, timeout_s=180)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)
    text = kit.output_text(nb)
    assert "worst pose 45" in text and "views with the whole board" in text
    assert "fit_rigid refused" in text and "collinear" in text
    assert "pybullet build time" not in text


def test_simulator_starts_without_the_pybullet_banner():
    """PyBullet prints its build time on stderr when it loads; Jupyter shows that in red."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", "import robots\n"
                           "with robots.connect('sim', arm='panda', seed=0) as cell:\n"
                           "    print('connected', cell.robot.name)"],
                          capture_output=True, text=True, timeout=120, check=True)
    assert "connected" in done.stdout
    assert "pybullet build time" not in done.stdout + done.stderr, done.stderr


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), ASSIGNMENT)


def test_release_has_no_solution_hidden_tests_or_secret(released):
    kit.assert_release_clean(released, ASSIGNMENT, len(FUNCTIONS), (
        "np.diag([1.0, 1.0, d])",
        "dst_mean - R @ src_mean",
        "along_src = residuals",
        "np.linalg.norm(residuals, axis=1)",
    ))


def test_full_cycle_reference_blank_and_subtly_wrong(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    solutions = _solutions()
    kit.submit(course, ASSIGNMENT, "ref", replace=solutions)
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace=solutions | _wrong_sources(solutions))
    # `cobotlab grade`'s way: nbgrader's autograde, its cells run by the grader's worker
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    assert [r["student_id"] for r in rows] == ["blank", "ref", "wrong"]
    grades = kit.read_grades(course)
    assert float(grades["ref"]["max_score"]) == MAX_SCORE
    assert float(grades["ref"]["score"]) == MAX_SCORE, grades["ref"]
    assert float(grades["blank"]["score"]) == 0.0
    # fit_rigid lost (its length check still raises ValueError on the 2-point problem, but
    # an edge case counts only when an ordinary problem is right: 0), per_axis_rmse (2)
    # lost, per_point_residuals (2) kept
    assert float(grades["wrong"]["score"]) == pytest.approx(2.0)
    assert all(g["flags"] == "" for g in grades.values()), grades  # the cross-check agrees
    feedback = (course / "feedback_cobotlab" / "wrong" / ASSIGNMENT / "feedback.html").read_text()
    assert "mapping" in feedback and " mm" in feedback
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        text = path.read_text()
        assert secret not in text and "hidden_test" not in text, path


# --------------------------------------------------------------------------- the lab's helpers


def test_view_plan_pivots_about_the_board_centre():
    from robots.labkit import lab1

    pivot = np.array([0.0, 0.0, 0.5])
    T = lab1.turned_about(pivot, [20.0, -10.0, 5.0])
    assert np.allclose(geo.transform_points(T, pivot), pivot)       # the pivot stays put
    assert geo.rotation_error_deg(T, np.eye(4)) == pytest.approx(np.linalg.norm([20, -10, 5]))
    home = geo.make_pose(np.diag([1.0, -1.0, -1.0]), [0.4, 0.0, 0.5])
    views = lab1.plan_views(home, [(0, 0), (20, 0)], [(0.25, (9, -12))])
    assert len(views) == 3
    # An untilted view is the home pose raised 15 cm along the flange axis (z points down here).
    assert np.allclose(views[0][:3, 3], [0.4, 0.0, 0.65])
    # Tilted views pivot about the point 0.5 m ahead of the raised flange: it stays in place.
    ahead = geo.transform_points(views[0], pivot)
    assert np.allclose(geo.transform_points(views[1], pivot), ahead, atol=1e-12)
    assert geo.rotation_error_deg(views[1], views[0]) == pytest.approx(20.0)

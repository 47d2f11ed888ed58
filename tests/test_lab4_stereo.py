"""Lab 4 (stereo single-shot hand-to-eye) on the real nbgrader cycle.

The source notebook runs with its solutions; the release holds no solution, hidden test or
secret; a reference, a blank and a subtly wrong student (a flipped world frame and a Q
reprojection divided by the wrong homogeneous coordinate) get full, zero and partial marks.
nbgrader's own autograde runs on the reference only (it re-executes the whole sim notebook,
about 40 s a student here); every student goes through the independent grader.
"""

from __future__ import annotations

from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import checks
from autograder.pipeline.pipeline import grade_course
from autograder.secret import load_secret
from robots import geometry as geo
from solutions import registration as reg

ASSIGNMENT = "lab4_stereo"
FUNCTIONS = ("frame_from_three_points", "reproject", "hand_to_eye_from_three_points",
             "per_axis_rmse")
MAX_SCORE = 10.0

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), ASSIGNMENT)


def _solutions() -> dict[str, str]:
    return kit.solution_sources(ASSIGNMENT, FUNCTIONS)


def _wrong() -> dict[str, str]:
    s = _solutions()
    wrong = {
        # left-handed construction: z = (p_xy - o) x x, a frame turned half a turn about x
        "frame_from_three_points": s["frame_from_three_points"].replace(
            "np.cross(x, np.asarray(p_xy, dtype=float) - o)",
            "np.cross(np.asarray(p_xy, dtype=float) - o, x)"),
        # divides by Z instead of W
        "reproject": s["reproject"].replace("np.array([X, Y, Z]) / W", "np.array([X, Y, Z]) / Z"),
    }
    assert all(wrong[k] != s[k] for k in wrong), "the wrong edits must change the solutions"
    return wrong


def _namespace(sources: dict[str, str]) -> dict:
    ns = {"np": np}
    for name in FUNCTIONS:
        exec(sources[name], ns)  # noqa: S102 - our own reference cells
    return ns


# --------------------------------------------------------------------------- specs


def test_spec_passes_the_reference_solutions_and_fails_wrong_ones():
    ns = _namespace(_solutions())
    for name in FUNCTIONS:
        spec = checks.spec_for(name, ASSIGNMENT)
        trials = [t for s in range(6) for t in checks.public_trials(spec, s)]
        result = checks.score_function(spec, trials,
                                       [checks._call_in_process(ns[name], t) for t in trials])
        assert result.fraction == 1.0, result.summary()
    bad = _namespace({**_solutions(), **_wrong()})
    for name in ("frame_from_three_points", "reproject"):
        spec = checks.spec_for(name, ASSIGNMENT)
        trials = checks.public_trials(spec, 0)
        result = checks.score_function(spec, trials,
                                       [checks._call_in_process(bad[name], t) for t in trials])
        assert result.fraction <= 0.5, result.summary()
    # The flip is the same on both sides of the chain, so it cancels in base_T_cam.
    spec = checks.spec_for("hand_to_eye_from_three_points", ASSIGNMENT)
    trials = checks.public_trials(spec, 0)
    outcomes = [checks._call_in_process(bad["hand_to_eye_from_three_points"], t) for t in trials]
    assert checks.score_function(spec, trials, outcomes).fraction == 1.0


def test_notebook_solutions_agree_with_the_instructor_references():
    ns = _namespace(_solutions())
    rng = np.random.default_rng(5)
    for _ in range(20):
        p = rng.normal(size=(3, 3))
        np.testing.assert_allclose(ns["frame_from_three_points"](*p),
                                   reg.frame_from_three_points(*p), atol=1e-12)
        T = geo.make_pose(geo.project_to_so3(rng.normal(size=(3, 3)) + 3 * np.eye(3)),
                          rng.normal(size=3))
        c, b = rng.normal(size=(12, 3)), rng.normal(size=(12, 3))
        np.testing.assert_allclose(ns["per_axis_rmse"](T, c, b),
                                   reg.per_axis_rmse(T, c, b, expressed_in="src"), atol=1e-12)


# --------------------------------------------------------------------------- notebooks


# Both engines: the text's table gives each engine's numbers. This is also the suite's lab on
# PyBullet (the other labs run on the default engine, MuJoCo, which paid for it: lab 4 there
# takes about 10 s, on PyBullet about 23 s, and labs 1-3 got 23 s faster with the default).
@pytest.mark.parametrize("engine", ["mujoco", "pybullet"])
def test_source_notebook_runs_with_solutions_and_hidden_tests(engine, monkeypatch):
    pytest.importorskip(engine, reason=f"the {engine} engine is not installed")
    monkeypatch.setenv("COBOTLAB_SIM_ENGINE", engine)   # the kernel inherits it
    nb = kit.execute_source(ASSIGNMENT, timeout_s=180)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)
    text = kit.output_text(nb, "\n")
    assert "20 views seen by both cameras" in text
    assert "pybullet build time" not in text
    # What the text says about these outputs: Q's (cx - cx')/Tx is zero with the default
    # rectification and not without it; on both engines the calibration's check points are
    # worst along camera x, from a tilt mostly about camera y; the stereo points' worst axis
    # and the tilt's size are each engine's, as section 7's table gives them.
    stereo_worst, tilt_range = SECTION_7_TABLE[engine]
    assert "Q[3, 3] = 0:" in text and "flags=0 instead: Q[3, 3] = 0 " not in text
    check_rmse = _vector_after(text, "per-axis RMSE on 12 check points (mm, camera x y z):")
    stereo_rmse = _vector_after(text, "stereo error of all 48 corners (mm RMS, camera x y z):")
    tilt = _vector_after(text, "rotation error of base_T_cam as a rotation vector, camera axes (deg):")
    assert np.argmax(check_rmse) == 0, (engine, check_rmse)
    assert np.argmax(stereo_rmse) == stereo_worst, (engine, stereo_rmse)
    assert np.argmax(np.abs(tilt)) == 1 and tilt_range[0] < abs(tilt[1]) < tilt_range[1], \
        (engine, tilt)
    import nbformat

    markdown = " ".join(" ".join(c.source.split()) for c in nbformat.read(
        kit.source_notebook(ASSIGNMENT), as_version=4).cells if c.cell_type == "markdown")
    assert "On both, the calibration's error on the check points comes out largest along the " \
        "camera's $x$ axis" in markdown
    assert "tilt the triangle's frame, mostly about the camera's $y$ axis" in markdown
    assert "| MuJoCo (the default) | 0.5 / 1.9 / 1.1 |" in markdown
    assert "| PyBullet | 2.2 / 0.9 / 4.1 |" in markdown


# Section 7's table for SEED = 2: the stereo points' worst camera axis (depth on PyBullet; y on
# MuJoCo, whose calibration leaves the left c_y a pixel off) and the tilt about camera y (deg).
SECTION_7_TABLE = {"pybullet": (2, (1.0, 4.0)), "mujoco": (1, (0.1, 1.0))}


def _vector_after(text: str, label: str) -> np.ndarray:
    """The numbers printed as [a b c] after ``label``."""
    numbers = text.split(label, 1)[1].split("[", 1)[1].split("]", 1)[0]
    return np.array([float(v) for v in numbers.split()])


def test_release_has_no_solution_hidden_tests_or_secret(released):
    kit.assert_release_clean(released, ASSIGNMENT, len(FUNCTIONS), (
        "[X, Y, Z]) / W",
        "np.cross(x, np.asarray(p_xy",
        "base_T_world @ world_T_cam",
        "along_cam = residuals @ R",
        "solutions",
    ))


# --------------------------------------------------------------------------- full cycle


def test_full_cycle_reference_blank_and_subtly_wrong(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    kit.submit(course, ASSIGNMENT, "ref", replace=_solutions())
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "wrong", replace={**_solutions(), **_wrong()})
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    grades = {r["student_id"]: r for r in rows}
    assert set(grades) == {"ref", "blank", "wrong"}
    assert grades["ref"]["score"] == MAX_SCORE and grades["ref"]["max_score"] == MAX_SCORE
    assert grades["blank"]["score"] == 0.0
    # frame: translation right, rotation 180 deg off (0 of 3: the translation counts only
    # with the rotation right, Check.requires); reproject 0 of 3; hand_to_eye is scored
    # with the true frames (2); per_axis_rmse untouched (2)
    assert grades["wrong"]["score"] == pytest.approx(4.0)
    assert grades["ref"]["flags"] == "", grades["ref"]
    # only nbgrader's missing cross-check (not run on them), nothing suspicious
    assert all(not f.startswith("suspicious") for s in grades for f in grades[s]["flags"].split(";"))
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        assert secret not in path.read_text(), path
    feedback = (course / "feedback_cobotlab" / "wrong" / ASSIGNMENT / "feedback.html").read_text()
    assert "reproject" in feedback and " mm" in feedback


# --------------------------------------------------------------------------- the lab's helpers


def test_find_corners_on_a_drawn_chessboard():
    from robots.labkit import lab4

    square = 30
    board = (np.indices((7, 9)).sum(axis=0) % 2 * 255).astype(np.uint8)   # 9 x 7 squares
    image = np.kron(board, np.ones((square, square), np.uint8))
    image = np.pad(image, 40, constant_values=255)
    rgb = np.repeat(image[:, :, None], 3, axis=2)
    corners = lab4.find_corners(rgb, (8, 6))
    assert corners.shape == (48, 2)
    # Inner corners sit on the grid lines, 40 px margin + k squares.
    grid = 40 + square * np.arange(1, 9)
    assert np.all(np.min(np.abs(corners[:, :1] - grid[None, :] + 0.5), axis=1) < 1.0)
    assert lab4.find_corners(np.full_like(rgb, 128), (8, 6)) is None

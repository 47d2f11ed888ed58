"""Lab 3 (visual servoing to chess pieces): grading specs, notebook, nbgrader cycle.

The specs give the reference full marks and the issue's subtly wrong students less (IBVS with
the gain's sign flipped, an interaction matrix with a sign error in one row, a depth read from
one pixel); the source notebook runs top to bottom in sim and moves the pawn e2 -> e4; the
release holds no solution, hidden test or secret; the real nbgrader cycle grades a reference,
a blank and two subtly wrong students full / zero / partial.
"""

from __future__ import annotations

from pathlib import Path

import course_kit as kit
import numpy as np
import pytest

from autograder import checks
from autograder.pipeline.pipeline import grade_course
from autograder.pipeline.run_submission import grade_notebook
from autograder.pipeline.worker import Limits
from autograder.secret import load_secret
from solutions import servoing as S

ASSIGNMENT = "lab3_servoing"
FUNCTIONS = ("piece_position", "interaction_matrix", "ibvs_velocity")
MAX_SCORE = 10.0

pytestmark = pytest.mark.slow


def _solutions() -> dict[str, str]:
    return kit.solution_sources(ASSIGNMENT, FUNCTIONS)


def _functions(sources: dict[str, str]) -> dict:
    """The notebook's solution cells as functions (they need only numpy)."""
    namespace = {"np": np}
    for name in FUNCTIONS:  # interaction_matrix before ibvs_velocity uses it
        exec(sources[name], namespace)  # noqa: S102 - our own notebook's solution code
    return {name: namespace[name] for name in FUNCTIONS}


def _flipped_gain(solutions):
    src = solutions["ibvs_velocity"].replace("return -gain * np.linalg.pinv",
                                             "return gain * np.linalg.pinv")
    assert src != solutions["ibvs_velocity"]
    return {"ibvs_velocity": src}


def _wrong_row(solutions):
    # The y row's wx entry written -(1 + y^2): one sign error, in the rotation block.
    src = solutions["interaction_matrix"].replace("y / Z, 1 + y * y, -x * y",
                                                  "y / Z, -(1 + y * y), -x * y")
    assert src != solutions["interaction_matrix"]
    return {"interaction_matrix": src}


# --------------------------------------------------------------------------- specs


REFERENCE = {
    "interaction_matrix": lambda x, y, Z: S.interaction_matrix(np.column_stack([x, y]), Z),
    "ibvs_velocity": lambda s, s_star, Z, gain: S.ibvs_velocity(s, s_star, Z, gain),
}


@pytest.mark.parametrize("name", FUNCTIONS)
def test_reference_and_notebook_solutions_earn_full_marks(name):
    mine = _functions(_solutions())
    candidates = [mine[name]] + ([REFERENCE[name]] if name in REFERENCE else [])
    for func in candidates:
        for seeds in (checks.PUBLIC_SEEDS, checks.KERNEL_SEEDS, (21, 22, 23)):
            # the adapters in REFERENCE call the reference solvers: the instructor's self-check
            result = checks.evaluate(func, name, seeds, reference=func is not mine[name])
            assert result.fraction == 1.0, result.summary()


def test_subtly_wrong_methods_lose_credit():
    solutions = _solutions()
    flipped = _functions(solutions | _flipped_gain(solutions))
    result = checks.evaluate(flipped["ibvs_velocity"], "ibvs_velocity")
    assert result.fraction == 0.0, result.summary()

    wrong = _functions(solutions | _wrong_row(solutions))
    result = checks.evaluate(wrong["interaction_matrix"], "interaction_matrix")
    assert result.fraction == 0.5, result.summary()
    assert result.failed_checks == ["rotation"]
    # one bug costs once: the law that calls the wrong matrix is scored with the true one
    result = checks.evaluate(wrong["ibvs_velocity"], "ibvs_velocity")
    assert result.fraction == 1.0, result.summary()
    assert wrong["interaction_matrix"] is not None  # put back after the check
    assert checks.evaluate(wrong["interaction_matrix"], "interaction_matrix").fraction == 0.5

    def one_pixel(depth, uv, K):  # no window: a depth hole at the pixel gives NaN
        u, v = np.rint(uv).astype(int)
        Z = depth[v, u]
        return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])

    result = checks.evaluate(one_pixel, "piece_position")
    assert 0.0 < result.fraction < 1.0, result.summary()
    assert any("NaN" in e for e in result.errors)

    def swapped(depth, uv, K):  # depth[u, v]: row and column mixed up
        u, v = np.rint(uv).astype(int)
        Z = np.nanmedian(depth[u - 2:u + 3, v - 2:v + 3])
        return np.array([(uv[0] - K[0, 2]) * Z / K[0, 0], (uv[1] - K[1, 2]) * Z / K[1, 1], Z])

    assert checks.evaluate(swapped, "piece_position").fraction < 0.5


def test_closed_loop_grading_is_robust_to_bad_laws():
    # A law that stands still, one that returns NaN, a wrong shape, one that raises: all zero,
    # with the reason in the feedback, and the loop always ends.
    for law, reason in [(lambda s, ss, Z, g: np.zeros(6), None),
                        (lambda s, ss, Z, g: np.full(6, np.nan), "NaN"),
                        (lambda s, ss, Z, g: np.zeros(3), "shape"),
                        (lambda s, ss, Z, g: 1 / 0, "ZeroDivisionError")]:
        result = checks.evaluate(law, "ibvs_velocity")
        assert result.fraction == 0.0, result.summary()
        if reason:
            assert any(reason in e for e in result.errors), result.errors


def test_interaction_matrix_truth_is_the_projection_derivative():
    # The spec's finite differences agree with the analytic matrix to 1e-8 of its scale, and
    # the 1e-6 full-credit band is far below a sign slip (order 1).
    spec = checks.spec_for("interaction_matrix", ASSIGNMENT)
    for trial in checks.public_trials(spec, 0):
        x, y, Z = trial.args
        L = REFERENCE["interaction_matrix"](x, y, Z)
        assert np.abs(L - trial.truth).max() < 1e-2 * trial.tol["rotation"]


# --------------------------------------------------------------------------- notebook + cycle


def test_source_notebook_runs_with_solutions_and_hidden_tests():
    nb = kit.execute_source(ASSIGNMENT, timeout_s=180)
    hidden = [c for c in nb.cells if "BEGIN HIDDEN TESTS" in c.source]
    assert len(hidden) == len(FUNCTIONS)
    text = kit.output_text(nb)
    assert "32 pieces found on 32 squares; 32 agree with the truth" in text
    assert "e2 empty: True; on e4: white pawn" in text
    assert "IBVS, gain sign flipped" in text and "wrong calibration (5 mm, 2 deg)" in text
    assert "pybullet build time" not in text
    lever = text.split("camera to pawn top at the end of the closed loop: d = ")[1].split(" m")[0]
    source = nbformat_cells(kit.source_notebook(ASSIGNMENT))
    quoted = [c.replace("$", "") for c in source if "camera-to-pawn distance" in c]
    assert len(quoted) == 2 and all(f"{lever} m" in c for c in quoted), (lever, quoted)
    assert "0.25 m" not in "".join(quoted) and "0.3 m" not in "".join(quoted)
    # The feature tracks are drawn in pixels, with the commanded velocity beside them.
    figures = [o for c in nb.cells if "plot_servo_runs" in c.source for o in c.outputs
               if "image/png" in o.get("data", {})]
    assert len(figures) == 2


def nbformat_cells(path) -> list[str]:
    """The markdown sources of a notebook."""
    import nbformat

    return [c.source for c in nbformat.read(path, as_version=4).cells if c.cell_type == "markdown"]


@pytest.fixture(scope="module")
def released(tmp_path_factory) -> Path:
    return kit.released_course(tmp_path_factory.mktemp("course"), ASSIGNMENT)


def test_release_has_no_solution_hidden_tests_or_secret(released):
    kit.assert_release_clean(released, ASSIGNMENT, len(FUNCTIONS), (
        "np.linalg.pinv(L) @ (s - s_star)",
        "-(1 + x * x), y])",
        "Z = float(np.median(valid))",
        "pick_and_place(",
    ))


def test_full_cycle_reference_blank_and_subtly_wrong(released, tmp_path):
    course = kit.fresh_course(released, tmp_path)
    solutions = _solutions()
    kit.submit(course, ASSIGNMENT, "ref", replace=solutions)
    kit.submit(course, ASSIGNMENT, "blank")
    kit.submit(course, ASSIGNMENT, "flipped_gain", replace=solutions | _flipped_gain(solutions))
    kit.submit(course, ASSIGNMENT, "wrong_row", replace=solutions | _wrong_row(solutions))
    # nbgrader's cross-check from the grader's own run of each notebook
    rows = grade_course(course, ASSIGNMENT, workers=2, run_nbgrader=True, quiet=True)
    assert [r["student_id"] for r in rows] == ["blank", "flipped_gain", "ref", "wrong_row"]
    grades = kit.read_grades(course)
    assert float(grades["ref"]["max_score"]) == MAX_SCORE
    assert float(grades["ref"]["score"]) == MAX_SCORE, grades["ref"]
    assert grades["ref"]["flags"] == "", grades["ref"]
    assert float(grades["blank"]["score"]) == 0.0
    # ibvs_velocity (4 of 10) lost: the law diverges from every hidden offset
    assert float(grades["flipped_gain"]["score"]) == pytest.approx(6.0)
    # interaction_matrix: rotation block wrong (2 of 4 lost), and only there: the IBVS
    # built on it is scored with the true matrix (one bug costs once)
    assert float(grades["wrong_row"]["score"]) == pytest.approx(MAX_SCORE - 2.0), grades["wrong_row"]
    feedback = (course / "feedback_cobotlab" / "flipped_gain" / ASSIGNMENT /
                "feedback.html").read_text()
    assert "position" in feedback and " mm" in feedback
    secret = load_secret(course)
    for path in [course / "grades.csv", *(course / "feedback_cobotlab").rglob("*.html")]:
        text = path.read_text()
        assert secret not in text and "hidden_test" not in text, path


# --------------------------------------------------------------------------- closed loop, isolated


def _notebook(tmp_path: Path, name: str, cells: list[str]) -> Path:
    import nbformat

    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    path = tmp_path / f"{name}.ipynb"
    nbformat.write(nb, path)
    return path


def test_independent_grader_drives_the_law_in_its_worker(tmp_path):
    """The closed loop runs in the grader, calling the student's law in the limited worker:
    the reference earns full marks there; a law that hangs, crawls or behaves only on the
    first call earns what it earned and no more, and the loop's time budget holds."""
    solutions = _solutions()
    head = "import numpy as np\nimport time\n"
    base = [head, solutions["interaction_matrix"]]
    laws = {
        "ref": solutions["ibvs_velocity"],
        "hangs": "def ibvs_velocity(s, s_star, Z, gain):\n    while True:\n        pass\n",
        "crawls": "def ibvs_velocity(s, s_star, Z, gain):\n    time.sleep(0.5)\n"
                  "    return np.zeros(6)\n",
        "first_call_only": solutions["ibvs_velocity"].replace("def ibvs_velocity", "def _law")
        + "\ncalls = []\ndef ibvs_velocity(s, s_star, Z, gain):\n    calls.append(1)\n"
          "    return _law(s, s_star, Z, gain) if len(calls) % 80 == 1 else np.zeros(6)\n",
    }
    limits = Limits(call_timeout_s=3, cell_timeout_s=5, load_timeout_s=30)
    scores = {}
    for name, law in laws.items():
        path = _notebook(tmp_path, name, base + [law])
        started = __import__("time").monotonic()
        grade = grade_notebook([path], ASSIGNMENT, name, "s" * 32, "nonce", limits)
        elapsed = __import__("time").monotonic() - started
        scores[name] = {f.name: f for f in grade.functions}
        assert elapsed < 30, (name, elapsed)
    assert scores["ref"]["ibvs_velocity"].fraction == 1.0, scores["ref"]["ibvs_velocity"].summary()
    assert scores["ref"]["interaction_matrix"].fraction == 1.0
    for name in ("hangs", "crawls"):
        result = scores[name]["ibvs_velocity"]
        assert result.points == 0.0 and any("timed out" in e for e in result.errors), \
            result.summary()
        assert scores[name]["interaction_matrix"].fraction == 1.0  # one hang costs one function
    # The first twist right, then nothing: the velocity check only (0.3 of 4 points) at most.
    assert scores["first_call_only"]["ibvs_velocity"].points <= 0.3 * 4.0 + 1e-9


# --------------------------------------------------------------------------- the lab's helpers


def test_find_tops_finds_a_raised_block_on_the_board():
    from robots.interfaces import Intrinsics
    from robots.labkit import lab3

    intrinsics = Intrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    depth = np.full((240, 320), 0.5)                 # the board plane, 0.5 m below the camera
    depth[100:111, 200:211] = 0.47                   # a 3 cm tall piece: its top is a plateau
    depth[50, 50] = 0.49                             # one noisy pixel: not a piece
    depth[150:160, 40:50] = np.nan                   # a hole in the depth image
    cam_T_chess = np.diag([1.0, -1.0, -1.0, 1.0])    # chess z points at the camera
    cam_T_chess[2, 3] = 0.5
    tops = lab3.find_tops(depth, cam_T_chess, intrinsics)
    assert tops.shape == (1, 2)
    assert np.allclose(tops[0], [205.0, 105.0])
    assert np.allclose(lab3.to_pixels([[0.0, 0.0], [0.1, -0.1]], intrinsics.K),
                       [[160.0, 120.0], [190.0, 90.0]])

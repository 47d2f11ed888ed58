"""The grading engine without nbgrader: scoring bands, seeds, the wire format and the worker.

Real worker processes, real limits; each test well under a few seconds.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest

from autograder import checks
from autograder.inside import wire
from autograder.outcomes import Failed, Place
from autograder.pipeline.cells import extract_code, scan_for_tampering
from autograder.pipeline.notebook_runner import NotebookRunner
from autograder.pipeline.problems import problem_rng
from autograder.pipeline.run_submission import grade_notebook
from autograder.pipeline.worker import (
    Limits,
    Worker,
    WorkerFailure,
    WorkerSetup,
    _reported_failure,
    sandbox_available,
)
from autograder.secret import SECRET_ENV, create_secret, load_secret
from robots import geometry as geo
from solutions.registration import fit_rigid

SECRET = "s" * 40
LIMITS = Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=30)


def _notebook(tmp_path, *cells, name="nb.ipynb"):
    nb = {"cells": [{"cell_type": "code", "metadata": {}, "outputs": [], "source": c}
                    for c in cells], "metadata": {}, "nbformat": 4, "nbformat_minor": 5}
    path = tmp_path / name
    path.write_text(json.dumps(nb))
    return path


REFERENCE = """
import numpy as np
def invert_pose(T):
    out = np.eye(4); out[:3, :3] = T[:3, :3].T; out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
def compose_chain(poses):
    out = np.eye(4)
    for T in poses:
        out = out @ T
    return out
def pose_from_rotvec(r, t):
    th = np.linalg.norm(r); T = np.eye(4); T[:3, 3] = t
    if th > 0:
        x, y, z = r / th; K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        T[:3, :3] = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    return T
"""


# --------------------------------------------------------------------------- scoring


def _reference(name):
    namespace = {}
    exec(REFERENCE, namespace)
    return namespace[name]


def test_reference_functions_get_full_marks_on_public_seeds():
    for name in ("invert_pose", "compose_chain", "pose_from_rotvec"):
        assert checks.evaluate(_reference(name), name).fraction == 1.0, name


def test_check_zeroes_a_call_of_the_library_routine_the_lab_teaches():
    # robots.geometry does exactly what lab 0 asks for: calling it earns nothing, and says why
    for func, name, routine in [(geo.invert, "invert_pose", "robots.geometry.invert"),
                                (lambda p: geo.compose(*p), "compose_chain",
                                 "robots.geometry.compose"),
                                (geo.pose_from_rotvec, "pose_from_rotvec",
                                 "robots.geometry.pose_from_rotvec")]:
        result = checks.evaluate(func, name)
        assert result.points == 0 and routine in result.errors[0], (name, result.errors)


def test_wrong_methods_get_partial_or_zero_with_reasons():
    def forgets_rotation(T):
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = T[:3, :3].T, -T[:3, 3]
        return out

    result = checks.evaluate(forgets_rotation, "invert_pose")
    assert result.fraction == 0.5 and result.failed_checks == ["translation"]
    assert checks.evaluate(lambda T: np.eye(4), "invert_pose").points == 0
    backwards = _reference("compose_chain")
    # reversed order is right only on one-pose chains, an edge case that counts only when a
    # longer chain is right too
    assert checks.evaluate(lambda p: backwards(p[::-1]), "compose_chain").points == 0
    # float32 arithmetic lands in the half-credit band, not full marks
    invert = _reference("invert_pose")
    single = checks.evaluate(lambda T: invert(T).astype(np.float32), "invert_pose")
    assert 0.4 < single.fraction < 1.0


def test_trivial_answer_gets_nothing_even_on_edge_cases():
    assert checks.evaluate(lambda r, t: np.eye(4), "pose_from_rotvec").points == 0


@pytest.mark.parametrize("bad, why", [
    (np.full((4, 4), np.nan), "NaN"), (np.eye(3), "shape"), ("eye", "str"),
    (np.zeros((4, 4)), "last row"), ([[1, 2], [3]], "list")])
def test_unusable_outputs_score_zero_and_say_why(bad, why):
    result = checks.evaluate(lambda T: bad, "invert_pose")
    assert result.points == 0 and result.errors


def test_noise_derived_tolerance_passes_reference_and_fails_wrong_methods():
    spec = checks.spec_for("fit_rigid")
    rng = np.random.default_rng(7)
    trials = [t for _ in range(6) for t in checks.make_trials(spec, rng)]
    ref = checks.score_function(spec, trials, [checks._call_in_process(fit_rigid, t)
                                               for t in trials])
    assert ref.fraction == 1.0, ref.summary()

    def no_centroid(src, dst):  # SVD of the raw cross-covariance: a classic slip
        # (with the reflection fix: the slip is the centring, and a reflection has no unique
        # nearest rotation for project_to_so3 to return)
        U, _, Vt = np.linalg.svd(src.T @ dst)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ D @ U.T
        return geo.make_pose(R, dst.mean(0) - R @ src.mean(0))

    wrong = checks.score_function(spec, trials, [checks._call_in_process(no_centroid, t)
                                                 for t in trials])
    # full credit on none of the 108 problems; within the half-credit band (2 x tol) on a
    # rare one at most
    assert wrong.checks[0].n_full == 0 and wrong.fraction < 0.01, wrong.summary()


def test_check_prints_the_score(capsys):
    checks.check(_reference("invert_pose"), "invert_pose")
    assert "invert_pose: 3 / 3 points" in capsys.readouterr().out
    with pytest.raises(ValueError, match="no graded function"):
        checks.check(_reference("invert_pose"), "not_a_function")


# --------------------------------------------------------------------------- seeds and secret


def test_problem_rng_is_per_student_per_run_and_reproducible():
    a = problem_rng(SECRET, "n1", "lab0_frames", "alice", "invert_pose").random(3)
    again = problem_rng(SECRET, "n1", "lab0_frames", "alice", "invert_pose").random(3)
    assert np.array_equal(a, again)
    for other in [(SECRET, "n1", "lab0_frames", "bob", "invert_pose"),
                  (SECRET, "n2", "lab0_frames", "alice", "invert_pose"),
                  ("t" * 40, "n1", "lab0_frames", "alice", "invert_pose")]:
        assert not np.array_equal(a, problem_rng(*other).random(3))


def test_secret_from_env_or_course_file(tmp_path, monkeypatch):
    monkeypatch.delenv(SECRET_ENV, raising=False)
    with pytest.raises(ValueError, match="grading secret"):
        load_secret(tmp_path)
    path = create_secret(tmp_path)
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    assert load_secret(tmp_path) == path.read_text().strip()
    monkeypatch.setenv(SECRET_ENV, "e" * 20)
    assert load_secret(tmp_path) == "e" * 20


# --------------------------------------------------------------------------- wire format


def test_wire_round_trip_and_forged_messages(tmp_path):
    value = {"a": np.arange(6.0).reshape(2, 3), "b": (1, "x", [True, None]), "c": 2.5}
    back = wire.decode(json.loads(json.dumps(wire.encode(value))))
    assert np.array_equal(back["a"], value["a"]) and back["b"] == (1, "x", [True, None])
    for forged in [{"__nd__": "AAAA", "dtype": "O", "shape": [1]},
                   {"__nd__": "AAAAAAAAAAA=", "dtype": "f8", "shape": [5]},
                   {"__nd__": "", "dtype": "f8", "shape": [10**9]},
                   {"__nd__": "", "dtype": "f8", "shape": [-1]}]:
        with pytest.raises(wire.WireError):
            wire.decode(forged)
    r, w = os.pipe()
    os.write(w, struct.pack("<Q", 2**40))
    with pytest.raises(wire.WireError, match="exceeds"):
        wire.receive(r)
    os.close(r), os.close(w)


# --------------------------------------------------------------------------- the worker


def test_extract_code_skips_hidden_tests_and_magics(tmp_path):
    path = _notebook(tmp_path, "%matplotlib inline\nx = 1", "### BEGIN HIDDEN TESTS\nboom",
                     "%%bash\nls", "!pip install x\ny = 2")
    cells, notes = extract_code(path)
    assert len(cells) == 2 and "boom" not in "".join(cells) and "pip" not in "".join(cells)
    bad = tmp_path / "bad.ipynb"
    bad.write_text("{not json")
    cells, notes = extract_code(bad)
    assert cells == [] and "unreadable" in notes[0]


def test_reference_notebook_full_marks_through_the_worker(tmp_path):
    grade = grade_notebook(_notebook(tmp_path, REFERENCE), "lab0_frames", "alice",
                                   SECRET, "n", LIMITS)
    assert grade.score == grade.max_score == 10.0 and grade.flags == []


def test_worker_sees_no_secret_no_course_and_cannot_stop_the_grader(tmp_path, monkeypatch):
    monkeypatch.setenv(SECRET_ENV, SECRET)
    course = tmp_path / "course"
    create_secret(course)
    probe = """
import os
def env():
    return sorted(os.environ)
def cwd():
    return os.getcwd()
def secret():
    return open(SECRET_PATH).read()
def kill_parent():
    import signal
    os.kill(os.getppid(), signal.SIGKILL)
    return 1
def hog():
    return len(bytearray(8 * 1024**3))
""".replace("SECRET_PATH", repr(str(course / ".cobotlab" / "secret")))
    with Worker([probe], LIMITS) as worker:
        names = worker.call("env", (), 3).value
        assert SECRET_ENV not in names and "PATH" in names
        assert not worker.call("cwd", (), 3).value.startswith(str(course))
        if sandbox_available():
            # the course is not in the sandbox at all
            assert "FileNotFoundError" in worker.call("secret", (), 3).error
        assert "MemoryError" in worker.call("hog", (), 3).error
        try:
            worker.call("kill_parent", (), 3)
        except WorkerFailure:
            pass  # it may only kill itself
    assert os.getpid() > 0  # still here


def test_viewer_cells_run_in_the_worker_without_building_a_widget():
    # What the labs' viewer cells do (lab 0's, lab 2's loop of estimates, lab 3's bare `view`)
    cell = """
from robots.viewer import WorkcellViewer
view = WorkcellViewer(object(), frame_length=0.05)
for name in ("a", "b"):
    view.show_estimate("cam", None, parent="flange", label=name)
panel = view.with_jog_panel()
view.plot.camera = [0, 0, 0]
view.objects["frame cam"].model_matrix
view.close()
import sys
def what_was_built():
    return [repr(view), repr(panel), "k3d" in sys.modules, "ipywidgets" in sys.modules]
"""
    with Worker([cell], LIMITS) as worker:
        shown, panel, k3d_loaded, widgets_loaded = worker.call("what_was_built", (), 3).value
    assert "not drawn while grading" in shown and "not drawn while grading" in panel
    assert not k3d_loaded and not widgets_loaded


def test_mangled_and_renamed_notebooks_are_graded_by_name(tmp_path):
    other = _notebook(tmp_path, "import numpy as np\ndef invert_pose(T):\n    return np.eye(4)",
                      name="renamed_copy.ipynb")
    main = _notebook(tmp_path, REFERENCE, name="lab0_frames.ipynb")
    grade = grade_notebook([other, main], "lab0_frames", "bob", SECRET, "n", LIMITS)
    assert grade.score == 10.0


def test_tampering_patterns_are_flagged():
    flags = scan_for_tampering([
        "get_ipython().set_custom_exc((Exception,), f)", "sys.modules['numpy'] = x",
        "np.allclose = lambda *a: True", "os.environ['X']"])
    assert {"suspicious_exception_handler", "suspicious_sys_modules", "suspicious_numpy_patch",
            "suspicious_secret_probe"} <= set(flags)
    assert scan_for_tampering(["from autograder.checks import check\nx = np.eye(4)"]) == []


def test_a_name_graded_by_two_labs_resolves_by_folder_or_assignment(tmp_path, monkeypatch):
    labs = [lab for lab, group in checks.SPECS.items() if any(s.name == "per_axis_rmse" for s in group)]
    if len(labs) < 2:
        pytest.skip("no function name is graded by two labs yet")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="several labs"):
        checks.spec_for("per_axis_rmse")
    for lab in labs:
        assert checks.spec_for("per_axis_rmse", lab) in checks.SPECS[lab]
        (tmp_path / lab).mkdir()
        monkeypatch.chdir(tmp_path / lab)
        assert checks.spec_for("per_axis_rmse") in checks.SPECS[lab]
    with pytest.raises(ValueError, match="unknown assignment"):
        checks.spec_for("per_axis_rmse", "lab9")


def test_forbidden_routines_zero_the_function_that_reaches_them_only(tmp_path):
    import course_kit as kit

    case = kit.parse_case(kit.ADVERSARIAL / "calibrate_hand_eye.py")
    assert case["lab"] == "lab2_handeye"
    cells = ["import numpy as np", case["replace"]["tsai_lenz"], case["replace"]["axes_ls"],
             # comparing with OpenCV in a cell of its own is fine: no graded function uses it
             "import cv2\ncompare = cv2.calibrateHandEye", "def motions(*a):\n    return 1"]
    nb = _notebook(tmp_path, *cells)
    grade = grade_notebook(nb, "lab2_handeye", "eve", SECRET, "n", LIMITS)
    by_name = {f.name: f for f in grade.functions}
    assert by_name["tsai_lenz"].points == 0 and by_name["axes_ls"].points == 0
    assert "cv2.calibrateHandEye" in by_name["tsai_lenz"].errors[0]
    assert "forbidden:cv2.calibrateHandEye" in grade.flags
    assert not any("calibrateHandEye" in e for e in by_name["motions"].errors)
    # and lab 0's reference code is clean of its own rule
    assert not [f for f in grade_notebook(_notebook(tmp_path, REFERENCE, name="r.ipynb"),
                                                  "lab0_frames", "a", SECRET, "n", LIMITS).flags
                if f.startswith("forbidden")]


# Student code runs in the worker's own process, so it can switch the worker's tripwire off
# (here through the garbage collector): the worker then reports no call at all.
SILENCE_TRIPWIRE = """
import gc
for _kind in [o for o in gc.get_objects() if isinstance(o, type) and o.__name__ == "Tripwire"]:
    _kind.__enter__ = lambda self: self
    _kind.__exit__ = lambda self, *exc: False
"""
# Lab 5's graded names bound, without a def, to objects that call the library: an instance of
# a class with __call__ (robots.perception.point_cloud) and a functools.partial of a helper
# (cv2.solvePnP, a C routine). With the tripwire on, the worker would see both calls.
LAB5_BOUND = """
import functools
import cv2
import numpy as np
from robots import perception
from robots.interfaces import Intrinsics

class _Backproject:
    def __call__(self, depth_raw, K, depth_scale):
        h, w = np.shape(depth_raw)
        camera = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h)
        return perception.point_cloud(np.asarray(depth_raw, float) * depth_scale, camera)

backproject = _Backproject()

def _pnp(corners_px, width_m, height_m, K):
    w, h = width_m / 2, height_m / 2
    square = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]])
    _, rvec, tvec = cv2.solvePnP(square, np.asarray(corners_px, float), np.asarray(K, float),
                                 None, flags=cv2.SOLVEPNP_IPPE)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    return T

rectangle_pose = functools.partial(_pnp)
"""


def test_what_is_bound_to_a_graded_name_is_scanned_whatever_the_worker_reports(tmp_path):
    # Before the scan followed assignments to the graded name, this earned 4 of 4 unflagged.
    grade = grade_notebook(_notebook(tmp_path, SILENCE_TRIPWIRE, LAB5_BOUND),
                                   "lab5_depth", "eve", SECRET, "n", LIMITS)
    by_name = {f.name: f for f in grade.functions}
    assert by_name["backproject"].points == 0 and by_name["rectangle_pose"].points == 0
    assert by_name["backproject"].forbidden == ("robots.perception.point_cloud",)
    assert by_name["rectangle_pose"].forbidden == ("cv2.solvePnP",)
    assert {"forbidden:robots.perception.point_cloud", "forbidden:cv2.solvePnP"} <= \
        set(grade.flags)


# An honest lab 0 notebook that compares its answers with the library's, in cells of its own
# and in a helper no graded function calls, under the same local names its functions use.
COMPARED = """
import cv2
import threading
from robots import geometry as geo
T = geo.pose_from_rotvec(np.array([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0]))
out = geo.invert(T)
checked = []
def compare(poses):
    checked.append(np.abs(compose_chain(poses) - geo.compose(*poses)).max())
    checked.append(np.abs(invert_pose(poses[0]) - vars(geo)["invert"](poses[0])).max())
compare([T, out])
R = cv2.Rodrigues(np.array([0.1, 0.2, 0.3]))[0]
worker = threading.Thread(target=lambda: checked.append(geo.invert(T)))
worker.start()
worker.join()
"""


def test_the_forbidden_routines_used_outside_the_graded_functions_cost_nothing(tmp_path):
    grade = grade_notebook(_notebook(tmp_path, REFERENCE, COMPARED), "lab0_frames",
                                   "a", SECRET, "n", LIMITS)
    assert grade.score == 10.0 and not [f for f in grade.flags if f.startswith("forbidden")], \
        (grade.flags, [f.errors[:1] for f in grade.functions])


def test_without_bubblewrap_the_rlimits_fallback_still_grades_and_says_so(tmp_path):
    import subprocess
    import sys

    path = _notebook(tmp_path, REFERENCE)
    script = ("from autograder.pipeline.run_submission import grade_notebook\n"
              "from autograder.pipeline.worker import Limits\n"
              f"g = grade_notebook({str(path)!r}, 'lab0_frames', 'a', {SECRET!r}, 'n',\n"
              "    Limits(cell_timeout_s=5, call_timeout_s=3, load_timeout_s=30))\n"
              "print(g.score, g.flags)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, COBOTLAB_SANDBOX="rlimits"))
    assert done.stdout.strip() == "10.0 ['sandbox:rlimits_only']", done.stdout + done.stderr


def test_check_lets_the_reference_solver_be_itself_but_not_a_student_that_calls_it():
    # The instructor's self-check scores the reference with evaluate(): the reference is the
    # answer key, it does not call it. A student function that calls it earns nothing.
    assert checks.evaluate(fit_rigid, "fit_rigid", assignment="lab1_flange").fraction == 1.0

    def student_fit_rigid(model_points, base_points):
        return fit_rigid(model_points, base_points)

    result = checks.evaluate(student_fit_rigid, "fit_rigid", assignment="lab1_flange")
    assert result.points == 0 and "solutions" in result.errors[0]


# --------------------------------------------------------------------------- time limits

BURN = """
import time
def burn(cpu_s):
    start = time.process_time()
    while time.process_time() - start < cpu_s:
        pass
"""


def test_a_worker_that_dies_late_is_reloaded_for_the_next_function(tmp_path):
    # The load budget counts the seconds spent loading, not the seconds since grading began:
    # after invert_pose's trials (0.25 s a call: well over the budget in all) the worker
    # dies in compose_chain, and pose_from_rotvec still gets a freshly loaded worker within
    # a 1.25 s load budget (a load is about 0.25 s). Quarter-second burns: the proportions
    # are the test, and each burn's CPU is spent on every trial and again on the reload.
    slow_invert = REFERENCE.replace("def invert_pose(T):\n",
                                    "def invert_pose(T):\n    burn(0.25)\n")
    dies = "\nimport os\ndef compose_chain(poses):\n    os.kill(os.getpid(), 9)\n"
    limits = Limits(cell_timeout_s=2, call_timeout_s=2, load_timeout_s=1.25)
    grade = grade_notebook(_notebook(tmp_path, BURN, "burn(0.25)", slow_invert + dies),
                                   "lab0_frames", "carol", SECRET, "n", limits)
    points = {f.name: f.points for f in grade.functions}
    assert points == {"invert_pose": 3.0, "compose_chain": 0.0, "pose_from_rotvec": 4.0}, \
        (points, grade.notes)


def test_a_stand_in_answers_the_expected_call_and_leaves_the_rest_to_the_student():
    from autograder.inside import standin

    def own(x, y):
        return x - y

    namespace = {"f": own}
    table = [((np.array([1.0, 2.0]), 3.0), np.array([42.0]))]
    with standin.substituted(namespace, {"f": table, "g": [((1.0,), 7.0)]}):
        assert namespace["f"](np.array([1.0, 2.0]), 3.0)[0] == 42.0      # the expected call
        assert namespace["f"]([[1.0, 2.0]], np.float32(3.0))[0] == 42.0  # reshaped, same values
        assert np.allclose(namespace["f"](np.array([1.0, 2.0]), 4.0), [-3.0, -2.0])  # own
        assert namespace["g"](1.0) == 7.0
        with pytest.raises(NameError):
            namespace["g"](2.0)   # no function of the student's to fall back on
    assert namespace == {"f": own}


def test_one_bug_costs_once_in_the_worker_too(tmp_path):
    # lab 4: hand_to_eye_from_three_points built on a frame_from_three_points that forgets
    # the origin (an error that does not cancel in the chain) is scored with the true frames;
    # the frame itself still loses its translation credit.
    import course_kit as kit

    names = ("frame_from_three_points", "reproject", "hand_to_eye_from_three_points",
             "per_axis_rmse")
    sources = kit.solution_sources("lab4_stereo", names)
    wrong_frame = sources["frame_from_three_points"].replace("T[:3, 3] = o", "pass")
    assert wrong_frame != sources["frame_from_three_points"]
    cells = ["import numpy as np", wrong_frame, sources["hand_to_eye_from_three_points"]]
    own = {}
    exec("\n".join(cells), own)  # noqa: S102 - our own test code
    spec = checks.spec_for("hand_to_eye_from_three_points", "lab4_stereo")
    trial = checks.public_trials(spec, 3)[-1]
    alone = spec.measure(own["hand_to_eye_from_three_points"](*trial.args), trial)
    assert alone["mapping"] > 10 * trial.tol["mapping"]  # without the stand-in it is wrong
    assert checks.evaluate(own["hand_to_eye_from_three_points"],
                           "hand_to_eye_from_three_points").fraction == 1.0  # in check() too
    grade = grade_notebook(_notebook(tmp_path, *cells), "lab4_stereo", "dan", SECRET,
                                   "n", LIMITS)
    result = {f.name: f for f in grade.functions}
    assert result["hand_to_eye_from_three_points"].fraction == 1.0, \
        result["hand_to_eye_from_three_points"].summary()
    assert result["frame_from_three_points"].fraction < 1.0


# --------------------------------------------------------------------------- check()'s words


def test_check_names_the_classic_mistake_behind_a_wrong_answer(capsys):
    checks.check(lambda T: T.copy(), "invert_pose")   # a_T_b back where b_T_a was asked
    # the spec's own code mistake for it, in its words
    assert "it is the given pose itself, not its inverse" in capsys.readouterr().out
    checks.check(_reference("invert_pose"), "invert_pose")   # right: no hint
    assert "classic mistake" not in capsys.readouterr().out
    rotvec = _reference("pose_from_rotvec")

    def millimetres(r, t):
        T = rotvec(r, t)
        T[:3, 3] *= 1000.0
        return T

    checks.check(millimetres, "pose_from_rotvec")
    # the spec's own code mistake for it, in its words
    assert "its translation is in millimetres: t is given in metres" in \
        capsys.readouterr().out

    def inverse(r, t):
        return np.linalg.inv(rotvec(r, t))

    checks.check(inverse, "pose_from_rotvec")
    assert "inverse of the expected pose" in capsys.readouterr().out

    def reversed_chain(poses):
        out = np.eye(4)
        for T in poses:
            out = T @ out
        return out

    checks.check(reversed_chain, "compose_chain")
    assert "multiplied in reverse order" in capsys.readouterr().out


def test_a_check_voided_by_an_edge_case_says_so_instead_of_reading_as_a_contradiction():
    spec = checks.spec_for("pose_from_rotvec", "lab0_frames")
    trials = [t for s in checks.PUBLIC_SEEDS for t in checks.public_trials(spec, s)
              if t.all_or_nothing]
    assert trials, "lab 0 has all-or-nothing edge cases (zero rotations)"

    def wrong_translation(trial):
        T = np.array(trial.truth, dtype=float)
        T[:3, 3] += 0.5
        return checks.TrialOutcome(value=T)

    result = checks.score_function(spec, trials, [wrong_translation(t) for t in trials])
    rotation = next(c for c in result.checks if c.name == "rotation")
    assert rotation.n_voided == len(trials) and rotation.worst_error < 1e-9
    assert "within the tolerance but counted as failed: another check failed there" \
        in result.summary()


def test_check_shows_a_table_in_jupyter_and_returns_nothing():
    result = checks.evaluate(_reference("invert_pose"), "invert_pose")
    page = checks._html_report(result)
    assert "<table>" in page and "invert_pose: 3 / 3 points" in page
    assert checks.check(_reference("invert_pose"), "invert_pose") is None


# invert_pose whose behaviour is keyed on its input, so that single calls and a batch meet
# each problem with the same behaviour: it answers, raises, returns what is not an array, or
# reaches the routine the lab forbids; with LOOPS or DIES some problems time out or kill
# the worker.
KEYED = """
import os
import numpy as np
from robots import geometry
LOOPS = DIES = False
def invert_pose(T):
    kind = int(abs(T[0, 3]) * 1e6) % 6
    if kind == 0:
        raise ValueError("keyed")
    if kind == 1:
        return {"not": "an array"}
    if kind == 2:
        return geometry.invert(T)
    if kind == 3 and LOOPS:
        while True:
            pass
    if kind == 4 and DIES:
        os.kill(os.getpid(), 9)
    out = np.eye(4); out[:3, :3] = T[:3, :3].T; out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
"""


def _seen(outcome) -> tuple:
    import re

    # how a killed worker's end reads ("killed", "exit code 137") depends on whether
    # bubblewrap had noticed its child's death before the grader stopped it: a race of
    # the two processes, not of the calls
    error = outcome.error and re.sub(r"worker process stopped \([^;]*;", "worker process "
                                     "stopped (...;", outcome.error)
    value = outcome.value
    value = np.round(np.asarray(value, float), 12).tolist() if isinstance(value, list) \
        else value
    failure = outcome.failure
    return (repr(value), error,
            None if failure is None else (failure.kind, failure.cause, failure.limit_s))


@pytest.mark.parametrize("misbehaves", ["", "LOOPS = True", "DIES = True"])
def test_a_batch_of_calls_gives_what_single_calls_give(misbehaves, monkeypatch):
    """`labs verify` makes a draw's problems in one round trip; values, errors, failures,
    skips and the tripwire's findings are those of one call each, and a batch that meets a
    time-out or a dead worker is made again call by call."""
    spec = checks.SPECS["lab0_frames"][0]
    # a looping call is stopped by its CPU timer: a quarter second (the others take
    # microseconds), spent on every call that loops, batched and single
    limits = Limits(cell_timeout_s=5, call_timeout_s=0.25, load_timeout_s=30)
    cells = [KEYED, misbehaves]
    singles = []
    monkeypatch.setattr(Worker, "call", lambda self, *a, _call=Worker.call,
                        **k: singles.append(a[0]) or _call(self, *a, **k))
    kinds = set()
    for seed in range(2):
        trials = checks.make_trials(spec, np.random.default_rng(seed))
        kinds |= {int(abs(t.args[0][0, 3]) * 1e6) % 6 for t in trials}
        seen = {}
        for batch in (False, True):
            singles.clear()
            runner = NotebookRunner(cells, limits, setup=WorkerSetup(cpu_s=600),
                                    batch_calls=batch)
            try:
                outcomes, tripped = runner.run(spec, trials)
            finally:
                runner.close()
            seen[batch] = ([_seen(o) for o in outcomes], tripped)
            if batch and not misbehaves:
                assert singles == [], "the batch was made call by call"
            if batch and misbehaves:
                assert singles, "a batch that met a time-out or death must be made again"
        assert seen[True] == seen[False], (misbehaves, seed)
        results, tripped = seen[False]
        errors = {r[2][0] for r in results if r[2] is not None}
        if not misbehaves:
            assert "robots.geometry.invert" in tripped and Failed.RAISED in errors
        else:
            assert ({Failed.TIMED_OUT, Failed.SKIPPED} if "LOOPS" in misbehaves
                    else {Failed.WORKER_STOPPED, Failed.SKIPPED}) <= errors, errors
    assert {0, 2, 3, 4, 5} <= kinds


@pytest.mark.parametrize("claimed, place", [
    ([3, 7], (3, 7)), ((0, 1), (0, 1)),
    (None, None), ("cell 3, line 7", None), ([3], None), ([3, 7, 1], None),
    ([-1, 7], None), ([3, 0], None), ([True, 7], None), ([3.0, 7], None),
    ([10**9, 7], None), ([3, 10**9], None)])
def test_a_workers_claimed_place_is_typed_or_nothing(claimed, place):
    """A failure's place is the worker's ``[cell, line]``, never read out of its words; a
    claim that is no place (the worker is untrusted) leaves the failure without one."""
    reply = {"ok": False, "error": "ValueError: x", "failure": "raised",
             "exception": "ValueError", "place": claimed}
    failure = _reported_failure(reply)
    assert failure.place == (None if place is None else Place(*place))
    with pytest.raises(ValueError, match="Place.line"):
        Place(3, 0)


def test_the_worker_reports_the_place_of_a_cell_it_ran_and_no_other():
    """The place is looked up from the cells the worker compiled: a "<cell ...>" file name
    the student's code makes up itself gives no place; and the reply holds no place in
    words (the grader writes them from the place)."""
    from autograder.inside import worker

    namespace: dict = {}
    exec(compile("def f():\n    x = 1\n    raise ValueError('no')", worker._cell_file(3),
                 "exec"), namespace)
    made_up = compile("raise KeyError('k')", "<cell forged>", "exec")
    for call, place in ((namespace["f"], [3, 3]), (lambda: exec(made_up, {}), None)):
        try:
            call()
        except Exception as exc:  # noqa: BLE001 - the test's own raise
            reply = worker._failure(exc)
        assert reply["place"] == place and "where" not in reply
        assert "cell" not in reply["error"]
        assert (reply["exception"], reply["message"]) == (
            ("ValueError", "no") if place else ("KeyError", "'k'"))

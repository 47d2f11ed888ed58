"""The class `benchmarks/grading.py` grades, per lab, built deterministically from a seed.

Kinds of submission (every one made from the released notebook, as a student hands it in):

* ``reference``: each graded function holds the notebook's solution region;
* ``mistake``: the reference with one graded function holding a classic mistake, written as
  exact text edits of that function's reference cell (:data:`MISTAKES`). An edit whose text
  is not found exactly once raises :class:`MistakeDoesNotApply`, so a changed notebook can
  never silently turn a "mistake" into the reference;
* ``blank``: the released notebook as is (every graded function ``raise NotImplementedError()``);
* ``partly blank``: some graded functions left as released, the others the reference;
* ``hostile``: one case of the adversarial corpus (``tests/adversarial``, ``layer: notebook``),
  its replaced functions moved onto the lab's own (as ``tests/test_adversarial_labs.py`` does).

:func:`check_scores` then says, as warning lines, where a grade makes no sense.
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import course_kit as kit  # noqa: E402
from test_adversarial_labs import _retarget  # noqa: E402

from autograder import checks  # noqa: E402
from autograder.course import LABS_DIR  # noqa: E402

# The hostile submission: cheap on every lab (no sleeps, no hangs), so it measures the cost
# of a hostile notebook, not a time limit; it may earn nothing (`earned: 0`) on any lab.
HOSTILE_CASE = "numpy_patch"


class MistakeDoesNotApply(ValueError):
    """A mistake's text is not in the reference cell (exactly once): the notebook changed."""


@dataclass(frozen=True)
class Mistake:
    function: str
    name: str
    why: str                                 # why it is a classic
    edits: tuple[tuple[str, str], ...]       # (text in the reference cell, its replacement)

    def apply(self, reference: str) -> str:
        source = reference
        for old, new in self.edits:
            found = source.count(old)
            if found != 1:
                raise MistakeDoesNotApply(
                    f"mistake {self.name!r} of {self.function}: {old!r} is in the reference "
                    f"cell {found} times, not once; the notebook's solution changed, so update "
                    f"this mistake in {Path(__file__).name}")
            source = source.replace(old, new)
        compile(source, f"<mistake {self.name!r} of {self.function}>", "exec")
        return source


def _m(function: str, name: str, why: str, *edits: tuple[str, str]) -> Mistake:
    return Mistake(function, name, why, tuple(edits))


# Per lab: classic mistakes, each one that benchmarks/grading_fairness.py shows loses credit
# on every hidden draw (docs/benchmarks/grading_fairness.md).
MISTAKES: dict[str, list[Mistake]] = {
    "lab0_frames": [
        _m("invert_pose", "t negated only (-t, not -R^T t)",
           "the inverse's translation is not rotated into the new frame",
           ("b_T_a[:3, 3] = -R.T @ t", "b_T_a[:3, 3] = -t")),
        _m("invert_pose", "R not transposed", "the inverse keeps R instead of R^T",
           ("b_T_a[:3, :3] = R.T", "b_T_a[:3, :3] = R")),
        _m("compose_chain", "reversed multiplication order",
           "a_T_b @ b_T_c written as b_T_c @ a_T_b (frames composed right to left)",
           ("out = out @ T", "out = T @ out")),
        _m("pose_from_rotvec", "skew matrix transposed (rotation transposed)",
           "the sign convention of [k]x mixed up: R^T, the rotation by -theta",
           ("K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])",
            "K = np.array([[0.0, kz, -ky], [-kz, 0.0, kx], [ky, -kx, 0.0]])")),
        _m("pose_from_rotvec", "translation in mm",
           "millimetres for metres, as robot pendants display them",
           ("T[:3, 3] = np.asarray(t, dtype=float).reshape(3)",
            "T[:3, 3] = np.asarray(t, dtype=float).reshape(3) * 1000.0")),
    ],
    "lab1_flange": [
        _m("fit_rigid", "no reflection fix",
           "Kabsch without the det(V U^T) sign: a reflection on noisy or planar points",
           ("R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T", "R = Vt.T @ U.T")),
        _m("fit_rigid", "transposed rotation", "R^T returned: src_T_dst's rotation",
           ("dst_T_src[:3, :3] = R\n", "dst_T_src[:3, :3] = R.T\n")),
        _m("per_point_residuals", "R not transposed (row vectors)",
           "points as rows need src @ R^T; src @ R rotates the other way",
           ("residuals = src @ R.T + t - dst", "residuals = src @ R + t - dst")),
        _m("per_point_residuals", "in mm", "millimetres for metres",
           ("return np.linalg.norm(residuals, axis=1)",
            "return np.linalg.norm(residuals, axis=1) * 1000.0")),
        _m("per_axis_rmse", "along the dst (base) axes",
           "the residuals not rotated into the frame the question asks for",
           ("along_src = residuals @ R", "along_src = residuals")),
    ],
    "lab2_handeye": [
        _m("motions", "B = inv(C_i) C_j (inverse on the wrong side)",
           "the camera's motion written like the robot's, though C is cam_T_target",
           ("B = np.array([C[i] @ geo.invert(C[j]) for i, j in pairs])",
            "B = np.array([geo.invert(C[i]) @ C[j] for i, j in pairs])")),
        _m("tsai_lenz", "inverse X (cam_T_flange)",
           "the hand-eye classic: the calibration returned the wrong way round",
           ("return geo.make_pose(R_X, t_X)", "return geo.invert(geo.make_pose(R_X, t_X))")),
        _m("axes_ls", "swapped A / B (omega_B = R omega_A)",
           "the rotation axes fitted the wrong way: R_X^T, then t_X from it",
           ("np.linalg.lstsq(omega_B, omega_A, rcond=None)",
            "np.linalg.lstsq(omega_A, omega_B, rcond=None)")),
        _m("rotation_residual", "R_X transposed", "X's rotation read transposed",
           ("R_X = X[:3, :3]\n", "R_X = X[:3, :3].T\n")),
        _m("translation_residual", "sum, not mean", "the mean of the formula taken as a sum",
           ("return float(np.mean(", "return float(np.sum(")),
    ],
    "lab3_servoing": [
        _m("interaction_matrix", "rows stacked x..., y...",
           "the x rows of all points, then the y rows, not interleaved as s is",
           ("L[0::2] = ", "L[:len(x)] = "), ("L[1::2] = ", "L[len(x):] = ")),
        _m("interaction_matrix", "rotation columns' sign flipped",
           "the textbook's other sign convention for the angular velocity",
           ("x * y, -(1 + x * x), y]", "-x * y, 1 + x * x, -y]"),
           ("1 + y * y, -x * y, -x]", "-(1 + y * y), x * y, x]")),
        _m("ibvs_velocity", "gain sign flipped", "v = +gain pinv(L) e: the error grows",
           ("return -gain * np.linalg.pinv(L)", "return gain * np.linalg.pinv(L)")),
        _m("ibvs_velocity", "L^T instead of pinv(L)", "the transpose taken for the inverse",
           ("np.linalg.pinv(L)", "L.T")),
        _m("piece_position", "depth in mm", "the RealSense's Z16 units (mm) kept",
           ("return np.array([X, Y, Z])", "return np.array([X, Y, Z]) * 1000.0")),
    ],
    "lab4_stereo": [
        _m("reproject", "divided by Z, not W", "the homogeneous coordinate confused with depth",
           ("return np.array([X, Y, Z]) / W", "return np.array([X, Y, Z]) / Z")),
        _m("reproject", "disparity sign flipped", "d = x_right - x_left, not x_left - x_right",
           ("np.array([u, v, d, 1.0])", "np.array([u, v, -d, 1.0])")),
        _m("frame_from_three_points", "cross product order swapped",
           "z = (p_xy - o) x x: p_xy ends up on the -y side",
           ("z = np.cross(x, np.asarray(p_xy, dtype=float) - o)",
            "z = np.cross(np.asarray(p_xy, dtype=float) - o, x)")),
        _m("hand_to_eye_from_three_points", "inverse forgotten (cam_T_world used)",
           "base_T_world @ cam_T_world: the camera's frame pose not inverted",
           ("return base_T_world @ world_T_cam", "return base_T_world @ cam_T_world")),
        _m("per_axis_rmse", "along the base axes",
           "the residuals not rotated into the camera frame",
           ("along_cam = residuals @ R\n", "along_cam = residuals\n")),
    ],
    "lab5_depth": [
        _m("backproject", "depth in millimetres", "the Z16 units kept: depth_scale ignored",
           (" * float(depth_scale)", "")),
        _m("backproject", "u and v swapped", "the row index used as x",
           ("u, v = np.meshgrid(np.arange(w), np.arange(h))",
            "v, u = np.meshgrid(np.arange(w), np.arange(h))")),
        _m("fit_plane_ransac", "no outlier rejection", "least squares through every point",
           ("for _ in range(iterations):", "for _ in range(0):"),
           ("centre = pts[best].mean(axis=0)\n", "best = slice(None)\n    centre = pts.mean(axis=0)\n")),
        _m("fit_flange_circle", "algebraic fit unrefined", "the Kasa fit's bias on a partial arc",
           ("for _ in range(50):", "for _ in range(0):")),
        _m("fit_flange_circle", "normal away from the camera", "the sign of the SVD normal kept",
           ("    if n @ c0 > 0:\n        n = -n\n", "")),
        _m("base_T_cam_from_flanges", "cam_T_base returned", "the registration the wrong way round",
           ("    return T\n", "    return np.linalg.inv(T)\n")),
        _m("rectangle_pose", "width and height swapped", "width_m taken along the left edge",
           ("w, hh = width_m / 2, height_m / 2", "w, hh = height_m / 2, width_m / 2")),
    ],
}


def reference_cells(lab: str) -> dict[str, str]:
    """grade id -> the source notebook's solution cell, solution markers removed."""
    nb = json.loads((LABS_DIR / lab / f"{lab}.ipynb").read_text())
    names = {s.name for s in checks.SPECS[lab]}
    out = {}
    for cell in nb["cells"]:
        gid = cell["metadata"].get("nbgrader", {}).get("grade_id")
        if gid in names:
            out[gid] = "".join(line for line in "".join(cell["source"]).splitlines(True)
                               if "### BEGIN SOLUTION" not in line
                               and "### END SOLUTION" not in line)
    return out


def mistaken_cells(lab: str) -> dict[str, str]:
    """Mistake name -> its function's cell: every mistake of ``lab`` applied (and checked)."""
    reference = reference_cells(lab)
    return {m.name: m.apply(reference[m.function]) for m in MISTAKES[lab]}


@dataclass
class Submission:
    student: str
    kind: str                           # reference, mistake, blank, partly blank, hostile
    detail: str = ""                    # the mistake, the blank functions or the case
    blank: list[str] = field(default_factory=list)    # functions left as released
    mistake_function: str | None = None
    max_points: float = 0.0             # what its non-blank functions allow
    earned: float | None = None         # hostile: what its case may earn at most
    flags: list[str] = field(default_factory=list)    # hostile: flags its case must raise

    def as_dict(self) -> dict:
        return asdict(self)


def composition(n: int, n_mistakes: int) -> dict[str, int]:
    """How many of each kind in a class of ``n`` (at least one reference)."""
    hostile = 1
    blank = max(1, round(0.07 * n))
    partly = max(1, round(0.10 * n))
    mistakes = max(0, min(max(n_mistakes, round(0.30 * n)), n - 1 - hostile - blank - partly))
    reference = n - hostile - blank - partly - mistakes
    if reference < 1:
        raise ValueError(f"a class of {n} is too small for every kind of submission")
    return {"reference": reference, "mistake": mistakes, "blank": blank,
            "partly blank": partly, "hostile": hostile}


def build_class(course: Path, lab: str, n: int, seed: int = 0) -> list[Submission]:
    """Release ``lab`` in ``course`` and hand in ``n`` seeded submissions (submitted/)."""
    kit.nbgrader(course, "generate_assignment", lab)
    specs = checks.SPECS[lab]
    names = [s.name for s in specs]
    points = {s.name: float(s.points) for s in specs}
    total = sum(points.values())
    reference = reference_cells(lab)
    missing = set(names) - set(reference)
    if missing:
        raise ValueError(f"{lab}: no solution cell for {sorted(missing)}")
    mistakes = MISTAKES[lab]
    if len(mistakes) < 3:
        raise ValueError(f"{lab}: at least 3 classic mistakes are needed")
    cells = mistaken_cells(lab)    # every mistake applied, so a stale one fails here
    case = kit.parse_case(kit.ADVERSARIAL / f"{HOSTILE_CASE}.py")
    if case["layer"] != "notebook" or case["layout"] or case["student"]:
        raise ValueError(f"{HOSTILE_CASE} must be a plain notebook-layer case")

    rng = np.random.default_rng(seed)
    counts = composition(n, len(mistakes))
    order = rng.permutation(len(mistakes))
    kinds = [k for k, c in counts.items() for _ in range(c)]
    ids = [f"s{i:03d}" for i in rng.permutation(n)]
    subs, m_next = [], 0
    for sid, kind in zip(ids, kinds):
        if kind == "reference":
            subs.append(Submission(sid, kind, max_points=total))
            kit.submit(course, lab, sid, replace=dict(reference))
        elif kind == "mistake":
            m = mistakes[order[m_next % len(mistakes)]]
            m_next += 1
            subs.append(Submission(sid, kind, m.name, mistake_function=m.function,
                                   max_points=total))
            kit.submit(course, lab, sid, replace={**reference, m.function: cells[m.name]})
        elif kind == "blank":
            subs.append(Submission(sid, kind, "all", blank=list(names), max_points=0.0))
            kit.submit(course, lab, sid)
        elif kind == "partly blank":
            k = int(rng.integers(1, len(names)))
            blank = sorted(rng.choice(names, size=k, replace=False).tolist(), key=names.index)
            kept = {f: reference[f] for f in names if f not in blank}
            subs.append(Submission(sid, kind, ", ".join(blank), blank=blank,
                                   max_points=sum(points[f] for f in kept)))
            kit.submit(course, lab, sid, replace=kept)
        else:
            replace = _retarget(case, tuple(names))
            # its bound holds on the lab it is written for; elsewhere the constants its
            # functions return may earn honest partial credit (lab 2's solvers: np.eye(4))
            subs.append(Submission(sid, kind, HOSTILE_CASE,
                                   blank=[f for f in names if f not in replace],
                                   max_points=total,
                                   earned=case["earned"] if case["lab"] == lab else None,
                                   flags=[f for f in case["flags"]
                                          if f.startswith("suspicious_")]))
            kit.submit(course, lab, sid, replace=replace, extra=case["extra"],
                       mangle=case["mangle"])
    return sorted(subs, key=lambda s: s.student)


def describe(lab: str, subs: list[Submission]) -> str:
    """One line per kind: how many, and which mistakes, blanks and case."""
    lines = [f"{lab}: a class of {len(subs)}"]
    for kind in ("reference", "mistake", "blank", "partly blank", "hostile"):
        mine = [s for s in subs if s.kind == kind]
        details: dict[str, int] = {}
        for s in mine:
            key = f"{s.mistake_function}: {s.detail}" if kind == "mistake" else s.detail
            if key:
                details[key] = details.get(key, 0) + 1
        extra = "; ".join(f"{k} x{v}" for k, v in details.items())
        lines.append(f"  {len(mine):3d} {kind}" + (f" ({extra})" if extra else ""))
    return "\n".join(lines)


def check_scores(subs: list[Submission], rows: list[dict], grades: dict | None = None,
                 label: str = "") -> list[str]:
    """Warnings (empty: all is as expected) for grades that make no sense: a reference below
    full marks, a mistake at full marks (or its mistaken function at full points, from the
    captured ``grades``: student id -> SubmissionGrade), a blank above what its non-blank
    functions allow, the hostile case at full marks, above what its case may earn (on its
    own lab), with points for a function it left blank or full points for one that returns
    a constant, or without its flags; a submission with no row or no score."""
    out = []
    by_id = {r["student_id"]: r for r in rows}
    eps = 1e-9
    for s in subs:
        row = by_id.get(s.student)
        where = f"{label}: {s.student} ({s.kind}{', ' + s.detail if s.detail else ''})"
        if row is None:
            out.append(f"{where} has no row")
            continue
        if row["score"] in ("", None):
            out.append(f"{where} was not graded (flags: {row.get('flags', '')})")
            continue
        score, full = float(row["score"]), float(row["max_score"])
        if s.kind == "reference" and score < full - eps:
            out.append(f"{where}: a reference scored {score:g} / {full:g}")
        elif s.kind == "mistake":
            if score >= full - eps:
                out.append(f"{where}: a mistake scored full marks, {score:g} / {full:g}")
            grade = (grades or {}).get(s.student)
            for f in getattr(grade, "functions", []):
                if f.name == s.mistake_function and f.points >= f.max_points - eps:
                    out.append(f"{where}: the mistaken {f.name} scored full points "
                               f"({f.points:g} / {f.max_points:g})")
        elif s.kind in ("blank", "partly blank") and score > s.max_points + eps:
            out.append(f"{where}: scored {score:g}, more than its non-blank functions allow "
                       f"({s.max_points:g})")
        elif s.kind == "hostile":
            if s.earned is not None and score > s.earned + eps:
                out.append(f"{where}: scored {score:g}, more than its case may earn "
                           f"({s.earned:g})")
            if score >= full - eps:
                out.append(f"{where}: the hostile submission scored full marks")
            grade = (grades or {}).get(s.student)
            for f in getattr(grade, "functions", []):
                if f.name in s.blank and f.points > eps:
                    out.append(f"{where}: its blank {f.name} scored {f.points:g}")
                elif f.name not in s.blank and f.points >= f.max_points - eps:
                    out.append(f"{where}: its constant {f.name} scored full points "
                               f"({f.points:g} / {f.max_points:g})")
            flags = str(row.get("flags", "")).split(";")
            for wanted in s.flags:
                if not any(f.startswith(wanted) for f in flags):
                    out.append(f"{where}: flag {wanted} missing (flags: {row.get('flags')})")
    return out

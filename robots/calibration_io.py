"""Calibration results on disk: one small, human-readable YAML file per result.

    save_calibration("flange_T_cam.yaml", X, parent="flange", child="cam", method="park",
                     n_samples=15, residuals={"rotation_deg": 0.05, "translation_m": 0.0004})
    result = load_calibration("flange_T_cam.yaml")   # result.pose is X, bit for bit

The file holds ``parent_T_child``: the pose of the child frame in the parent frame (it maps
child coordinates to parent coordinates), as a translation in metres, a ``quat_xyzw`` and a
3x3 rotation matrix. The matrix and translation are authoritative; the quaternion is there
for tools that want one and is checked against the matrix on load, so a hand-edited file
that no longer agrees with itself is refused rather than silently half-used. Floats are
written with ``repr`` precision (PyYAML does this for Python floats), so float64 values
round-trip exactly.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from robots.geometry import (
    as_pose,
    make_pose,
    pose_from_quat_xyzw,
    quat_xyzw_from_pose,
    rotation_error_deg,
)

__all__ = ["CalibrationResult", "save_calibration", "load_calibration"]

FORMAT = "cobotlab-calibration/1"
# The stored quaternion is printed at full precision, so it agrees with the matrix to ~1e-15;
# anything beyond this means one of them was edited by hand.
QUAT_MATRIX_TOL_DEG = 1e-6


@dataclass(eq=False)
class CalibrationResult:
    """A calibrated pose ``parent_T_child`` (4, 4) with how it was obtained.

    ``residuals`` maps names to numbers (or lists of numbers), e.g. ``{"rotation_deg": 0.05,
    "translation_m": 4e-4}``; ``date`` is ISO 8601; ``robot_id`` / ``camera_id`` identify the
    hardware (serial numbers or names), empty if unknown.
    """

    pose: np.ndarray
    parent: str
    child: str
    method: str
    n_samples: int
    residuals: dict
    date: str
    robot_id: str = ""
    camera_id: str = ""

    @property
    def translation(self) -> np.ndarray:
        """Translation in metres, (3,)."""
        return self.pose[:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray:
        """Rotation matrix, (3, 3)."""
        return self.pose[:3, :3].copy()

    @property
    def quat_xyzw(self) -> np.ndarray:
        """Unit quaternion (x, y, z, w), w >= 0."""
        return quat_xyzw_from_pose(self.pose)[0]

    @property
    def name(self) -> str:
        """The conventional variable name, e.g. ``flange_T_cam``."""
        return f"{self.parent}_T_{self.child}"

    def save(self, path) -> Path:
        """Write this result to ``path`` (see :func:`save_calibration`)."""
        save_calibration(
            path,
            self.pose,
            self.parent,
            self.child,
            self.method,
            self.n_samples,
            self.residuals,
            self.robot_id,
            self.camera_id,
            date=self.date,
        )
        return Path(path)

    def __eq__(self, other) -> bool:
        if not isinstance(other, CalibrationResult):
            return NotImplemented
        return bool(np.array_equal(self.pose, other.pose)) and (
            self.parent,
            self.child,
            self.method,
            self.n_samples,
            self.residuals,
            self.date,
            self.robot_id,
            self.camera_id,
        ) == (
            other.parent,
            other.child,
            other.method,
            other.n_samples,
            other.residuals,
            other.date,
            other.robot_id,
            other.camera_id,
        )


def _frame_name(value, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(
            f"{what} must be a non-empty frame name such as 'flange' or 'cam', got {value!r}"
        )
    return value


def _is_count(n) -> bool:
    """Whether ``n`` is a non-negative whole number (an int, or a float such as 15.0)."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, float, np.integer, np.floating)):
        return False
    return bool(np.isfinite(n)) and int(n) == n and n >= 0


def _plain_residuals(residuals: Mapping) -> dict:
    """Residuals as plain Python floats/lists (YAML cannot write numpy scalars), finite only."""
    if not isinstance(residuals, Mapping):
        raise ValueError(
            f"residuals must be a dict of name -> number, got {type(residuals).__name__}"
        )
    out = {}
    for key, value in residuals.items():
        if not isinstance(key, str):
            raise ValueError(f"residual names must be strings, got {key!r}")
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"residual {key!r} must be a number or a list of numbers, got "
                             f"{value!r}") from None
        if arr.ndim > 1:
            raise ValueError(
                f"residual {key!r} must be a number or a list of numbers, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(
                f"residual {key!r} is not finite ({value!r}); the calibration failed, "
                "fix it before saving"
            )
        out[key] = float(arr) if arr.ndim == 0 else [float(v) for v in arr]
    return out


def save_calibration(
    path,
    pose,
    parent: str,
    child: str,
    method: str,
    n_samples: int,
    residuals: Mapping,
    robot_id: str = "",
    camera_id: str = "",
    date: str | None = None,
) -> CalibrationResult:
    """Write ``parent_T_child`` (4, 4, metres) and its metadata to a YAML file at ``path``.

    ``method`` names the solver (e.g. "tsai", "park", "daniilidis"), ``n_samples`` the number
    of pose pairs used, ``residuals`` its error measures (finite numbers). ``date`` defaults
    to now (UTC, ISO 8601). Returns the :class:`CalibrationResult` that was written.
    """
    import yaml

    pose = as_pose(pose, f"{parent}_T_{child}")
    parent, child = _frame_name(parent, "parent"), _frame_name(child, "child")
    if not _is_count(n_samples):
        raise ValueError(f"n_samples must be a non-negative whole number, got {n_samples!r}")
    result = CalibrationResult(
        pose=pose,
        parent=parent,
        child=child,
        method=str(method),
        n_samples=int(n_samples),
        residuals=_plain_residuals(residuals),
        date=date or datetime.now(timezone.utc).isoformat(timespec="seconds"),
        robot_id=str(robot_id),
        camera_id=str(camera_id),
    )
    doc = {
        "format": FORMAT,
        "name": result.name,
        "parent": parent,
        "child": child,
        "translation_m": [float(v) for v in pose[:3, 3]],
        "quat_xyzw": [float(v) for v in result.quat_xyzw],
        "matrix": [[float(v) for v in row] for row in pose[:3, :3]],
        "method": result.method,
        "n_samples": result.n_samples,
        "residuals": result.residuals,
        "date": result.date,
        "robot_id": result.robot_id,
        "camera_id": result.camera_id,
    }
    header = (
        f"# cobotlab calibration result: {result.name} maps {child} coordinates to {parent} "
        "coordinates.\n# translation in metres; matrix is authoritative, quat_xyzw must agree.\n"
    )
    text = header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200)
    path = _as_path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a directory; give a file name such as "
                         f"{path / (result.name + '.yaml')}")
    path.write_text(text)
    return result


def _as_path(path) -> Path:
    if isinstance(path, (str, Path)) or hasattr(path, "__fspath__"):
        return Path(path)
    raise ValueError(f"path must be a file path (str or pathlib.Path), got "
                     f"{type(path).__name__}: {path!r}")


_REQUIRED = ("parent", "child", "translation_m", "quat_xyzw", "matrix", "method", "n_samples",
             "residuals", "date")
_RESAVE = "re-save the result with robots.save_calibration (or fix the file by hand)"


def _read_text(path: Path) -> str:
    """The file's text; clear errors for a missing file, a directory or a binary file."""
    if path.is_dir():
        inside = sorted(p.name for p in path.glob("*.yaml"))[:5]
        hint = f" (it holds {', '.join(inside)})" if inside else ""
        raise ValueError(f"{path} is a directory, not a calibration file{hint}; pass the path of "
                         "the YAML file itself")
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such calibration file (looked in "
                                f"{path.resolve().parent}); check the name and the working "
                                "directory, or save one with robots.save_calibration")
    data = path.read_bytes()
    if b"\0" in data:
        offset = data.index(b"\0")
        raise ValueError(f"{path} is a binary file (a NUL byte at offset {offset}), "
                         "not a calibration file: those are YAML text written by "
                         "robots.save_calibration")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data[:err.start].count(b"\n") + 1
        raise ValueError(f"{path}, line {line}: not UTF-8 text (byte {data[err.start]:#04x}); a "
                         f"binary or wrongly encoded file, not a calibration file: {_RESAVE}"
                         ) from None


def _parse_yaml(path: Path, text: str):
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"{path}, line {mark.line + 1}, column {mark.column + 1}" if mark else str(path)
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        bad_line = text.splitlines()[mark.line] if mark and mark.line < len(text.splitlines()) \
            else ""
        if mark and "\t" in bad_line[:mark.column + 1]:
            fix = ("a tab character: YAML indents with spaces only, so replace the tabs with "
                   "spaces")
        elif mark and not text[mark.index:].strip():
            fix = f"the file ends in the middle of a value: it looks truncated; {_RESAVE}"
        else:
            fix = f"not valid YAML ({problem}); {_RESAVE}"
        raise ValueError(f"{where}: {fix}") from None


def _key_line(text: str, key: str) -> str:
    """", line N" of the top-level ``key:`` in the file's text, or "" if it is not found."""
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith(f"{key}:"):
            return f", line {number}"
    return ""


def load_calibration(path) -> CalibrationResult:
    """Read a file written by :func:`save_calibration`; the pose comes back bit for bit equal.

    Raises ValueError, naming the file, the line where one is known and the fix, if the file
    is a directory, binary, not valid YAML (tabs, truncated), a field is missing or malformed,
    the matrix is not a rotation, or the quaternion disagrees with the matrix;
    FileNotFoundError if there is no such file.
    """
    path = _as_path(path)
    text = _read_text(path)
    doc = _parse_yaml(path, text)
    if doc is None:
        what = "is empty" if not text.strip() else "holds only comments"
        raise ValueError(f"{path} {what} (truncated?); {_RESAVE}")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{path} is not a cobotlab calibration file (format: {FORMAT!r} "
                         "missing); load files written by robots.save_calibration")
    missing = [k for k in _REQUIRED if k not in doc]
    if missing:
        lines = len(text.splitlines())
        raise ValueError(f"{path} is missing {missing} (it has {sorted(doc)} and ends at line "
                         f"{lines}); the file may be truncated or hand-edited: {_RESAVE}")

    def field_error(key: str, message: str) -> ValueError:
        return ValueError(f"{path}{_key_line(text, key)}: {message}")

    try:
        t = np.asarray(doc["translation_m"], dtype=float)
    except (TypeError, ValueError):
        raise field_error("translation_m", f"translation_m must be 3 numbers (metres), got "
                          f"{doc['translation_m']!r}") from None
    try:
        R = np.asarray(doc["matrix"], dtype=float)
    except (TypeError, ValueError):
        raise field_error("matrix", f"matrix must be 3 rows of 3 numbers, got "
                          f"{doc['matrix']!r}") from None
    if t.shape != (3,) or R.shape != (3, 3):
        raise ValueError(
            f"{path}: translation_m must have 3 numbers and matrix 3x3 rows, "
            f"got shapes {t.shape} and {R.shape}"
        )
    try:
        pose = as_pose(make_pose(R, t), f"{path.name} matrix")
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error
    try:
        quat_pose = pose_from_quat_xyzw(doc["quat_xyzw"])
    except ValueError as error:
        raise field_error("quat_xyzw", str(error)) from None
    disagreement = rotation_error_deg(quat_pose, pose)
    if disagreement > QUAT_MATRIX_TOL_DEG:
        raise ValueError(
            f"{path}: quat_xyzw and matrix disagree by {disagreement:.3g} deg; the matrix is "
            "authoritative, so fix or delete the edited quaternion (re-save the result)"
        )
    n_samples = doc["n_samples"]
    if not _is_count(n_samples):
        raise field_error("n_samples", f"n_samples must be a non-negative whole number, got "
                          f"{n_samples!r}")
    try:
        residuals = _plain_residuals(doc["residuals"] or {})
        parent = _frame_name(doc["parent"], "parent")
        child = _frame_name(doc["child"], "child")
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    return CalibrationResult(
        pose=pose,
        parent=parent,
        child=child,
        method=str(doc["method"]),
        n_samples=int(n_samples),
        residuals=residuals,
        date=str(doc["date"]),
        robot_id=str(doc.get("robot_id") or ""),
        camera_id=str(doc.get("camera_id") or ""),
    )

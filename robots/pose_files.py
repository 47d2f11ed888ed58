"""Read the robot poses and camera intrinsics that other calibration tools write.

Robot poses, one per view, come as

- one text or CSV file for all views, a row per view: 16 numbers (a 4 x 4 matrix, row-major),
  12 (its top 3 x 4), 6 (translation + rotation vector, i.e. theta-u) or 7 (translation +
  quaternion). A header row may name the columns (``x,y,z,qx,qy,qz,qw``, ``tx ty tz rx ry
  rz``, ``x,y,z,qw,qx,qy,qz``): then the names decide the layout and the quaternion's order;
- a folder of YAML or JSON files, one per view, in name order (numbers as numbers): a mapping with a 4 x 4
  ``matrix`` (or ``pose``, ``T``), or ``translation``/``position`` plus ``rotation`` (3 x 3),
  ``rotvec``/``theta_u``, ``quat_xyzw``/``quat_wxyz``, or ``quaternion`` as ``{x, y, z, w}``
  (order named) or a list (order unknown); or ViSP's ``vpPoseVector`` file (``data``: the
  six values t, theta-u).

What a file often leaves unsaid (metres or millimetres, radians or degrees, the quaternion's
order, ``base_T_flange`` or its inverse) is a ``PoseConvention``; ``robots.pose_import``
decides it from the data and the camera's view of the board, or takes it from flags.
Intrinsics come from an OpenCV FileStorage (YAML or XML: ``camera_matrix`` and
``distortion_coefficients``), a ROS ``camera_info`` YAML, or numbers (``intrinsics_from``).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from robots.geometry import as_poses
from robots.interfaces import Intrinsics

__all__ = ["PoseConvention", "PoseTable", "in_natural_order", "read_intrinsics",
           "intrinsics_from", "read_poses", "to_base_T_flange"]

LENGTH_UNITS = ("m", "mm")
ANGLE_UNITS = ("rad", "deg")
QUAT_ORDERS = ("xyzw", "wxyz")
DIRECTIONS = ("base_T_flange", "flange_T_base")
POSE_SUFFIXES = (".yaml", ".yml", ".json")


@dataclass(frozen=True)
class PoseTable:
    """Robot poses as a file gives them, before any convention is applied.

    ``layout``: ``matrix`` (``rotations`` (n, 3, 3)), ``rotvec`` ((n, 3), theta-u) or
    ``quat`` ((n, 4) in file order). ``translations`` (n, 3) in the file's unit.
    ``quat_order``: ``xyzw``/``wxyz`` when the file names it, else None. ``names``: where
    each view came from (``file:line`` or the file name), for messages."""

    layout: str
    translations: np.ndarray
    rotations: np.ndarray
    names: tuple
    source: str
    quat_order: str | None = None

    def __len__(self) -> int:
        return len(self.translations)


@dataclass(frozen=True)
class PoseConvention:
    """How to read a ``PoseTable``: ``length_unit`` (m, mm), ``angle_unit`` (rad, deg: rotation
    vectors only), ``quat_order`` (xyzw, wxyz: quaternions only), ``direction``
    (``base_T_flange``, or ``flange_T_base`` when the file holds the inverse)."""

    length_unit: str = "m"
    angle_unit: str = "rad"
    quat_order: str = "xyzw"
    direction: str = "base_T_flange"


def to_base_T_flange(table: PoseTable, convention: PoseConvention) -> np.ndarray:
    """The table's poses as ``base_T_flange`` (n, 4, 4), metres. ``ValueError`` names the view
    whose rotation is not one (a quaternion far from unit norm, a matrix not orthonormal)."""
    t = table.translations * (1e-3 if convention.length_unit == "mm" else 1.0)
    if table.layout == "matrix":
        R = table.rotations
    elif table.layout == "rotvec":
        vectors = table.rotations * (np.pi / 180 if convention.angle_unit == "deg" else 1.0)
        R = Rotation.from_rotvec(vectors).as_matrix()
    else:
        q = table.rotations if convention.quat_order == "xyzw" else np.roll(table.rotations, -1,
                                                                           axis=1)
        norms = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1) > 1e-3)
        if len(bad):
            raise ValueError(f"{table.source}: the quaternion of {table.names[bad[0]]} has norm "
                             f"{norms[bad[0]]:.4g}, not 1; is the column layout right (x y z "
                             "then four quaternion numbers)?")
        R = Rotation.from_quat(q).as_matrix()
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T = as_poses(T, f"{table.source} poses")
    if convention.direction == "flange_T_base":
        from robots.geometry import invert

        T = invert(T)
    return T


# --------------------------------------------------------------------------- poses


def in_natural_order(paths) -> list[Path]:
    """``paths`` sorted by name with runs of digits compared as numbers, so ``image-2`` comes
    before ``image-10`` (ViSP numbers its files 1, 2, ..., 10 without zeros)."""
    def key(path):
        return [(0, int(part), "") if part.isdigit() else (1, 0, part)
                for part in re.split(r"(\d+)", Path(path).name) if part]

    return sorted((Path(p) for p in paths), key=key)


_HEADER_LAYOUTS = {
    # column names (lower case, in file order) -> (layout, quaternion order)
    ("x", "y", "z", "qx", "qy", "qz", "qw"): ("quat", "xyzw"),
    ("x", "y", "z", "qw", "qx", "qy", "qz"): ("quat", "wxyz"),
    ("x", "y", "z", "rx", "ry", "rz"): ("rotvec", None),
    ("x", "y", "z", "tux", "tuy", "tuz"): ("rotvec", None),
}
_COUNT_LAYOUTS = {16: "matrix", 12: "matrix", 6: "rotvec", 7: "quat"}


def _header_layout(names: list[str]):
    """(layout, quaternion order) named by a header row, or None when it names no layout."""
    clean = tuple(re.sub(r"^(position_|translation_|pos_|rot_|q_|t)", "", n) if n not in
                  ("tux", "tuy", "tuz") else n for n in names)
    clean = tuple({"w": "qw"}.get(n, n) for n in clean)
    # drop a leading index or name column (view, id, image)
    if clean and clean[0] in ("view", "id", "index", "image", "name", "frame"):
        clean = clean[1:]
    return _HEADER_LAYOUTS.get(clean)


def _split(line: str) -> list[str]:
    return [v for v in re.split(r"[,;\s]+", line.strip()) if v]


def _rows_from_text(path: Path):
    """(numbers per view row, their names, the header's (layout, order) or None)."""
    rows, names, header = [], [], None
    for number, line in enumerate(path.read_text().splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = _split(text)
        try:
            values = [float(v) for v in parts]
        except ValueError:
            if not rows and header is None:
                header = _header_layout([p.lower() for p in parts])
                if header is None:
                    raise ValueError(
                        f"{path}:{number}: a header naming no layout I know: {text[:60]!r}; "
                        "name the columns x,y,z,qx,qy,qz,qw or x,y,z,qw,qx,qy,qz (quaternion) "
                        "or x,y,z,rx,ry,rz (rotation vector), or remove the header") from None
                if parts[0].lower() in ("view", "id", "index", "image", "name", "frame"):
                    header = header + (True,)
                continue
            raise ValueError(f"{path}:{number}: not a list of numbers: {text[:60]!r}") from None
        rows.append(values)
        names.append(f"{path.name}:{number}")
    return rows, names, header


def _table_from_rows(rows, names, source: str, layout=None, quat_order=None) -> PoseTable:
    counts = {len(r) for r in rows}
    if len(counts) != 1:
        raise ValueError(f"{source}: rows of {sorted(counts)} numbers; every view needs the same "
                         "layout (16: a 4 x 4 matrix, 12: its 3 x 4 top, 6: x y z + rotation "
                         "vector, 7: x y z + quaternion)")
    count = counts.pop()
    if layout is None:
        if count not in _COUNT_LAYOUTS:
            raise ValueError(
                f"{source}: {count} numbers per view, expected 16 (a 4 x 4 matrix, row-major), "
                "12 (its 3 x 4 top), 6 (x y z + rotation vector / theta-u) or 7 (x y z + "
                "quaternion)")
        layout = _COUNT_LAYOUTS[count]
    values = np.array(rows, dtype=float)
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0])
        raise ValueError(f"{source}: {names[bad]} holds NaN or inf; remove that view (and its "
                         "image)")
    if layout == "matrix":
        if count == 16:
            bottom = values[:, 12:]
            off = np.flatnonzero(~np.all(np.isclose(bottom, [0, 0, 0, 1], atol=1e-6), axis=1))
            if len(off):
                raise ValueError(f"{source}: {names[off[0]]} does not end in 0 0 0 1; is the "
                                 "matrix stored column-major (transposed)?")
        M = values[:, :12].reshape(-1, 3, 4)
        return PoseTable("matrix", M[:, :, 3], M[:, :, :3], tuple(names), source)
    return PoseTable(layout, values[:, :3], values[:, 3:], tuple(names), source, quat_order)


def _numbers(value, what: str, count: int, source: str) -> list[float]:
    if isinstance(value, dict):
        keys = {"x", "y", "z", "w"} if count == 4 else {"x", "y", "z"}
        if set(value) >= keys:
            return [float(value[k]) for k in ("x", "y", "z", "w")[:count]]
    flat = np.asarray(value, dtype=float).ravel()
    if flat.size != count:
        raise ValueError(f"{source}: {what} has {flat.size} numbers, expected {count}")
    return flat.tolist()


def _row_from_mapping(data, source: str):
    """(numbers, layout, quaternion order or None) of one per-view YAML/JSON mapping."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a mapping of pose fields, got "
                         f"{type(data).__name__}")
    keys = {k.lower(): v for k, v in data.items()}
    for name in ("matrix", "pose", "t", "base_t_flange", "transform"):
        if name in keys:
            return _numbers(keys[name], name, 16, source), "matrix", None
    if "data" in keys and "translation" not in keys:  # ViSP vpPoseVector: t then theta-u
        return _numbers(keys["data"], "data", 6, source), "rotvec", None
    t = next((keys[k] for k in ("translation", "position", "xyz") if k in keys), None)
    if t is None:
        raise ValueError(f"{source}: no pose found; give 'matrix' (4 x 4), or 'translation' with "
                         "'rotation' (3 x 3), 'rotvec', 'quat_xyzw', 'quat_wxyz' or 'quaternion'")
    t = _numbers(t, "translation", 3, source)
    if "rotation" in keys and np.asarray(keys["rotation"], dtype=object).size == 9:
        R = np.asarray(keys["rotation"], dtype=float).reshape(3, 3)
        return np.vstack([np.hstack([R, np.reshape(t, (3, 1))]), [0, 0, 0, 1]]).ravel().tolist(), \
            "matrix", None
    for name in ("rotvec", "rotation_vector", "theta_u", "thetau", "tu", "rvec"):
        if name in keys:
            return t + _numbers(keys[name], name, 3, source), "rotvec", None
    for name, order in (("quat_xyzw", "xyzw"), ("quat_wxyz", "wxyz")):
        if name in keys:
            return t + _numbers(keys[name], name, 4, source), "quat", order
    for name in ("quaternion", "orientation", "rotation", "quat"):
        if name in keys:
            named = isinstance(keys[name], dict)
            return t + _numbers(keys[name], name, 4, source), "quat", "xyzw" if named else None
    raise ValueError(f"{source}: a translation but no rotation; add 'rotation' (3 x 3), "
                     "'rotvec', 'quat_xyzw', 'quat_wxyz' or 'quaternion'")


def _load_mapping(path: Path):
    import yaml

    text = path.read_text()
    if path.suffix.lower() == ".json":
        return json.loads(text)
    # ViSP and OpenCV write a "%YAML:1.0" line that PyYAML does not take
    return yaml.safe_load(re.sub(r"^%YAML:1\.0\s*\n", "", text))


def read_poses(path) -> PoseTable:
    """Read the robot poses of every view from ``path``: a text/CSV file (a row per view) or a
    folder of YAML/JSON files (one per view, sorted by name); see the module docstring.

    Returns a ``PoseTable`` in the file's own units and conventions; ``ValueError`` names the
    file (and line) and says what was expected."""
    path = Path(path)
    if path.is_dir():
        files = in_natural_order(p for p in path.iterdir() if p.suffix.lower() in POSE_SUFFIXES)
        if not files:
            raise ValueError(f"{path} holds no .yaml, .yml or .json pose files")
        rows, layouts, orders = [], set(), set()
        for f in files:
            values, layout, order = _row_from_mapping(_load_mapping(f), str(f))
            rows.append(values)
            layouts.add(layout)
            orders.add(order)
        if len(layouts) != 1 or len(orders) != 1:
            raise ValueError(f"{path}: the files mix pose layouts ({sorted(layouts)}); keep one")
        return _table_from_rows(rows, [f.name for f in files], str(path), layouts.pop(),
                                orders.pop())
    if not path.is_file():
        raise FileNotFoundError(f"no pose file or folder at {path}")
    if path.suffix.lower() in POSE_SUFFIXES:
        data = _load_mapping(path)
        items = data.get("poses", data.get("views")) if isinstance(data, dict) else data
        if not isinstance(items, list):
            raise ValueError(f"{path}: expected a list of poses (or a mapping with 'poses'); "
                             "for one file per view, give the folder")
        parsed = [_row_from_mapping(item, f"{path}[{k}]") for k, item in enumerate(items)]
        layouts = {p[1] for p in parsed}
        if len(layouts) != 1:
            raise ValueError(f"{path}: the poses mix layouts ({sorted(layouts)}); keep one")
        return _table_from_rows([p[0] for p in parsed], [f"{path.name}[{k}]" for k in
                                                        range(len(parsed))], str(path),
                                layouts.pop(), parsed[0][2])
    rows, names, header = _rows_from_text(path)
    if not rows:
        raise ValueError(f"{path} holds no poses")
    layout = order = None
    if header is not None:
        layout, order = header[:2]
        if len(header) == 3:  # a leading view-name column
            rows = [r[1:] for r in rows]
    return _table_from_rows(rows, names, str(path), layout, order)


# --------------------------------------------------------------------------- intrinsics


def intrinsics_from(fx, fy, cx, cy, width: int, height: int, dist=()) -> Intrinsics:
    """``Intrinsics`` from numbers (pixels); ``dist`` OpenCV's k1 k2 p1 p2 [k3 ...] (missing
    ones 0). ``ValueError`` names a focal length or centre that is not a positive number."""
    values = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
    for name, v in values.items():
        if v is None or not np.isfinite(float(v)) or float(v) <= 0:
            raise ValueError(f"--{name} must be a positive number of pixels, got {v!r}")
    d = np.zeros(5)
    given = np.asarray(dist, dtype=float).ravel()
    if given.size > 5:
        if np.any(given[5:] != 0):
            raise ValueError(f"distortion has {given.size} coefficients; cobotlab's camera "
                             "model keeps OpenCV's first five (k1 k2 p1 p2 k3)")
        given = given[:5]
    if not np.all(np.isfinite(given)):
        raise ValueError("the distortion coefficients hold NaN or inf")
    d[:given.size] = given
    return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height), d)


def _opencv_storage(path: Path):
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        def matrix(*names):
            for name in names:
                node = fs.getNode(name)
                if not node.empty():
                    return node.mat()
            return None

        def number(*names):
            for name in names:
                node = fs.getNode(name)
                if not node.empty():
                    return node.real()
            return None

        K = matrix("camera_matrix", "cameraMatrix", "K", "intrinsics")
        dist = matrix("distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
        size = (number("image_width", "width"), number("image_height", "height"))
    finally:
        fs.release()
    return K, dist, size


def read_intrinsics(path, image_size=None) -> Intrinsics:
    """The camera's intrinsics from an OpenCV FileStorage (YAML with ``%YAML:1.0`` or XML:
    ``camera_matrix``, ``distortion_coefficients``, ``image_width``/``image_height``) or a ROS
    ``camera_info`` YAML (``camera_matrix: {data: [...]}``, ``distortion_coefficients``,
    ``image_width``, ``image_height``). ``image_size`` (width, height) stands in when the file
    has none, and must agree with it when it has."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no intrinsics file at {path}")
    text = path.read_text()
    if path.suffix.lower() == ".xml" or text.lstrip().startswith("%YAML:1.0"):
        K, dist, size = _opencv_storage(path)
    else:
        data = yaml.safe_load(text)
        if not isinstance(data, dict):
            raise ValueError(f"{path}: not a camera_info or OpenCV calibration file")

        def field(*names):
            for name in names:
                if name in data:
                    value = data[name]
                    return value["data"] if isinstance(value, dict) and "data" in value else value
            return None

        K = field("camera_matrix", "K", "k")
        dist = field("distortion_coefficients", "D", "d")
        size = (data.get("image_width", data.get("width")),
                data.get("image_height", data.get("height")))
    if K is None or np.asarray(K, dtype=float).size != 9:
        raise ValueError(f"{path}: no 3 x 3 camera_matrix found (OpenCV: camera_matrix; ROS "
                         "camera_info: camera_matrix.data or K)")
    K = np.asarray(K, dtype=float).reshape(3, 3)
    if not (K[0, 1] == 0 and np.allclose(K[2], [0, 0, 1])):
        raise ValueError(f"{path}: camera_matrix {K.tolist()} is not [[fx 0 cx] [0 fy cy] "
                         "[0 0 1]]")
    if size[0] is None or size[1] is None or not size[0]:
        if image_size is None:
            raise ValueError(f"{path} gives no image size; give the images too")
        size = image_size
    elif image_size is not None and tuple(int(v) for v in size) != tuple(image_size):
        raise ValueError(f"{path} is for {int(size[0])} x {int(size[1])} images but the images "
                         f"are {image_size[0]} x {image_size[1]}: a calibration of another "
                         "resolution does not apply")
    return intrinsics_from(K[0, 0], K[1, 1], K[0, 2], K[1, 2], int(size[0]), int(size[1]),
                           () if dist is None else dist)

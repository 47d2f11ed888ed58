"""Calibration-target images and the textured meshes that put them in the simulation.

Every target is drawn by OpenCV/numpy at a whole number of texels per feature (so corners
fall exactly on texel edges), saved as a PNG in a cache folder, and shown on a thin slab
mesh written here as an .obj with explicit texture coordinates. Writing the mesh ourselves
gives full control of the UV mapping; PyBullet's built-in boxes map textures per face in ways
that are easy to get mirrored.

Frames
------
* The *print frame* of an image: origin at the image's top-left outer edge, x to the right
  along the image, y down the image, z into the board (the printed face looks along -z).
* Each target has its own *target frame*, the one OpenCV's detectors report, given as
  ``print_T_target``:

  - chessboard: origin at the first inner corner, x along a row of inner corners, y down the
    columns, z into the board: OpenCV's ``objp = (col * s, row * s, 0)`` convention, so
    ``solvePnP(objp, findChessboardCorners(...))`` returns ``cam_T_target``.
  - ChArUco: ``cv2.aruco.CharucoBoard``'s own frame: origin at the board's top-left outer
    corner (inside the white margin), x right, y down, z into the board.
  - single ArUco marker: OpenCV's marker frame: origin at the marker centre, x right, y UP,
    z OUT of the board (towards the viewer); corners listed TL, TR, BR, BL.
  - asymmetric circle grid: the centre of the first circle, x right, y down, z into the board,
    OpenCV's ``((2 j + i % 2) s, i s, 0)`` layout for ``findCirclesGrid(..., ASYMMETRIC)``.

The mesh file is written in the target frame, so a PyBullet body made from it has its link
frame exactly on the target frame: the body's pose IS ``world_T_target``.

Edge softness: TinyRenderer samples textures nearest-neighbour and does no antialiasing, so
perfectly sharp squares alias into jagged edges and detected corners scatter by about 0.2 px.
Each texture is therefore drawn fine (default 0.2 mm texels) and blurred by a Gaussian of
``blur`` metres (default 0.6 mm, like a slightly soft print seen through a real lens); the
blurred ramps keep edge positions to a few hundredths of a pixel at 0.3-1 m. Measured: corner
reprojection error 0.05 px mean with the blur, 0.27 px without.

Measured in PyBullet 3.2.6: TinyRenderer maps texture coordinate v = 1 to the image's top
row (the OBJ convention) and culls back faces, hence a closed slab rather than a single quad.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from robots.geometry import invert, make_pose, transform_points

__all__ = [
    "ARUCO_DICT",
    "Target",
    "aruco_marker",
    "cache_dir",
    "charuco",
    "chessboard",
    "circle_grid",
    "write_textured_slab",
]

ARUCO_DICT = cv2.aruco.DICT_5X5_100

# Print frame -> OpenCV single-marker frame: y up and z out of the board.
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])


@dataclass
class Target:
    """A printable calibration target at true scale.

    image : (H, W, 3) uint8 RGB texture.
    size : (width, height) of the printed image in metres (including its white margin).
    print_T_target : (4, 4) target frame in the print frame (see the module docstring).
    object_points : (N, 3) feature points in the target frame, metres, in detector order
        (chessboard corners, ChArUco corner ids, marker corners TL TR BR BL, circle centres).
    kind : "chessboard", "charuco", "aruco" or "circles".
    pattern_size : what the OpenCV detector wants ((cols, rows) of inner corners / circles),
        or None.
    board : the ``cv2.aruco.CharucoBoard`` (ChArUco only).
    dictionary : the ArUco dictionary id (ChArUco and ArUco), marker_ids: ids on the target.
    """

    kind: str
    image: np.ndarray
    size: tuple[float, float]
    print_T_target: np.ndarray
    object_points: np.ndarray
    pattern_size: tuple[int, int] | None = None
    board: object = None
    dictionary: int | None = None
    marker_ids: tuple[int, ...] = ()
    params: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        """A short content hash, used to name cached files."""
        h = hashlib.sha1(self.image.tobytes())
        h.update(np.asarray(self.size, float).tobytes())
        h.update(self.print_T_target.tobytes())
        return f"{self.kind}_{h.hexdigest()[:12]}"

    @property
    def centre(self) -> np.ndarray:
        """Centre (3,) of the printed image in the target frame, metres: where to aim a camera
        or put a goal over the target."""
        w, h = self.size
        return (invert(self.print_T_target) @ np.array([w / 2, h / 2, 0.0, 1.0]))[:3]


def cache_dir() -> Path:
    """Folder for generated PNG/OBJ files: $COBOTLAB_CACHE, else ~/.cache/cobotlab/textures,
    else a temporary folder when the home directory is not writable."""
    env = os.environ.get("COBOTLAB_CACHE")
    candidates = [Path(env)] if env else []
    candidates += [Path.home() / ".cache" / "cobotlab" / "textures",
                   Path(tempfile.gettempdir()) / "cobotlab_textures"]
    for d in candidates:
        try:
            d.mkdir(parents=True, exist_ok=True)
            if os.access(d, os.W_OK):
                return d
        except OSError:
            continue
    raise OSError(f"no writable cache folder among {candidates}; set COBOTLAB_CACHE")


def _positive(name, x):
    if not (np.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a positive number, got {x!r}")


def _count(name, n, minimum):
    if int(n) != n or n < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}")


def _finish(gray: np.ndarray, texel: float, blur: float) -> np.ndarray:
    """Blur by ``blur`` metres (see the module docstring) and return an RGB texture."""
    if not (np.isfinite(blur) and blur >= 0):
        raise ValueError(f"blur must be >= 0 metres, got {blur!r}")
    if blur > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), blur / texel, borderType=cv2.BORDER_REPLICATE)
    return np.repeat(gray[..., None], 3, axis=2)


def _per(name, length, texel):
    """Whole number of texels across ``length`` metres, so features sit on texel edges."""
    _positive("texel", texel)
    return max(4, round(length / texel))


# --------------------------------------------------------------------------- targets


def chessboard(squares=(9, 7), square=0.039, margin=None, texel=2e-4, blur=6e-4) -> Target:
    """A chessboard of ``squares = (along x, along y)`` squares of side ``square`` metres.

    It has ``(squares[0] - 1) x (squares[1] - 1)`` inner corners (the default 9x7 board of
    39 mm squares gives OpenCV's pattern_size (8, 6)). ``margin`` is the white border in
    metres (default one square, the quiet zone the detector needs). The top-left square is
    black. With both square counts odd the board looks the same turned 180 degrees, so the
    detector's corner order can start at either end; see ``canonical_chessboard_order`` in
    the tests for the usual fix. ``texel`` and ``blur`` (metres): see the module docstring.
    """
    nx, ny = squares
    _count("squares[0]", nx, 2)
    _count("squares[1]", ny, 2)
    _positive("square", square)
    s = _per("square", square, texel)
    margin = square if margin is None else margin
    m = round(margin / square * s)
    img = np.full((ny * s + 2 * m, nx * s + 2 * m), 255, np.uint8)
    for r in range(ny):
        for c in range(nx):
            if (r + c) % 2 == 0:
                img[m + r * s:m + (r + 1) * s, m + c * s:m + (c + 1) * s] = 0
    texel = square / s
    origin = (m + s) * texel  # first inner corner, from the top-left edge
    cols, rows = nx - 1, ny - 1
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    objp = np.stack([j.ravel() * square, i.ravel() * square, np.zeros(cols * rows)], axis=1)
    return Target(
        kind="chessboard",
        image=_finish(img, texel, blur),
        size=(img.shape[1] * texel, img.shape[0] * texel),
        print_T_target=make_pose(t=[origin, origin, 0.0]),
        object_points=objp,
        pattern_size=(cols, rows),
        params={"squares": (nx, ny), "square": square, "margin": m * texel},
    )


def charuco(squares=(7, 5), square=0.04, marker=0.03, dictionary=ARUCO_DICT, margin=None,
            texel=2e-4, blur=6e-4) -> Target:
    """A ChArUco board (``cv2.aruco.CharucoBoard``) with OpenCV's own board frame.

    ``squares`` is (along x, along y); ``marker`` is the ArUco side in metres (< square).
    ``object_points`` are the ChArUco corners in id order (``board.getChessboardCorners()``).
    """
    nx, ny = squares
    _count("squares[0]", nx, 3)
    _count("squares[1]", ny, 3)
    _positive("square", square)
    _positive("marker", marker)
    if marker >= square:
        raise ValueError(f"marker ({marker} m) must be smaller than square ({square} m)")
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    board = cv2.aruco.CharucoBoard((nx, ny), square, marker, d)
    s = _per("square", square, texel)
    m = round((square / 2 if margin is None else margin) / square * s)
    inner = board.generateImage((nx * s, ny * s), marginSize=0, borderBits=1)
    img = cv2.copyMakeBorder(inner, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    texel = square / s
    return Target(
        kind="charuco",
        image=_finish(img, texel, blur),
        size=(img.shape[1] * texel, img.shape[0] * texel),
        print_T_target=make_pose(t=[m * texel, m * texel, 0.0]),
        object_points=np.asarray(board.getChessboardCorners(), dtype=float),
        pattern_size=(nx, ny),
        board=board,
        dictionary=dictionary,
        marker_ids=tuple(int(i) for i in board.getIds().ravel()),
        params={"squares": (nx, ny), "square": square, "marker": marker},
    )


def aruco_marker(marker_id=0, size=0.05, dictionary=ARUCO_DICT, margin=None,
                 texel=2e-4, blur=6e-4) -> Target:
    """One ArUco marker of side ``size`` metres with a white quiet zone (default 1/4 side).

    The target frame is OpenCV's marker frame (centre, x right, y up, z out of the board), so
    ``solvePnP(object_points, corners, ..., flags=cv2.SOLVEPNP_IPPE_SQUARE)`` gives it.
    """
    _positive("size", size)
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    n_ids = d.bytesList.shape[0]
    if not (0 <= int(marker_id) < n_ids):
        raise ValueError(f"marker_id must be in [0, {n_ids}) for this dictionary, got {marker_id}")
    bits = d.markerSize + 2  # payload plus the black border
    px = bits * max(1, round(size / bits / texel))
    img = cv2.aruco.generateImageMarker(d, int(marker_id), px, borderBits=1)
    m = round((size / 4 if margin is None else margin) / size * px)
    img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    texel = size / px
    half = size / 2
    centre = (m + px / 2) * texel
    print_T_target = make_pose(_FLIP_YZ, [centre, centre, 0.0])
    objp = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
    return Target(
        kind="aruco",
        image=_finish(img, texel, blur),
        size=(img.shape[1] * texel, img.shape[0] * texel),
        print_T_target=print_T_target,
        object_points=objp,
        dictionary=dictionary,
        marker_ids=(int(marker_id),),
        params={"size": size, "marker_id": int(marker_id)},
    )


def circle_grid(pattern=(4, 11), spacing=0.02, diameter=None, texel=2e-4, blur=6e-4) -> Target:
    """An asymmetric circle grid for ``cv2.findCirclesGrid(..., CALIB_CB_ASYMMETRIC_GRID)``.

    ``pattern = (circles per row, rows)``; circle (row i, column j) sits at
    ``((2 j + i % 2) * spacing, i * spacing)``, OpenCV's layout. Diameter defaults to 0.7 of
    the spacing. Circles are drawn with sub-texel antialiasing.
    """
    cols, rows = pattern
    _count("pattern[0]", cols, 2)
    _count("pattern[1]", rows, 3)
    _positive("spacing", spacing)
    diameter = 0.7 * spacing if diameter is None else diameter
    _positive("diameter", diameter)
    if diameter >= 1.4 * spacing:
        raise ValueError("circles overlap: use diameter < 1.4 * spacing")
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    objp = np.stack([(2 * j + i % 2).ravel() * spacing, i.ravel() * spacing,
                     np.zeros(rows * cols)], axis=1)
    px_per_m = 1.0 / texel
    margin = 1.5 * spacing
    width = objp[:, 0].max() + 2 * margin
    height = objp[:, 1].max() + 2 * margin
    W, H = round(width * px_per_m), round(height * px_per_m)
    img = np.full((H, W), 255, np.uint8)
    shift = 4  # cv2.circle's fixed-point bits: centres to 1/16 texel
    for x, y, _ in objp:
        # Continuous print coordinate x (m) is texel-edge based; OpenCV pixel centres sit at +0.5.
        cx = ((x + margin) * px_per_m - 0.5) * (1 << shift)
        cy = ((y + margin) * px_per_m - 0.5) * (1 << shift)
        r = diameter / 2 * px_per_m * (1 << shift)
        cv2.circle(img, (round(cx), round(cy)), round(r), 0, -1, cv2.LINE_AA, shift)
    return Target(
        kind="circles",
        image=_finish(img, 1.0 / px_per_m, blur),
        size=(W / px_per_m, H / px_per_m),
        print_T_target=make_pose(t=[margin, margin, 0.0]),
        object_points=objp,
        pattern_size=(cols, rows),
        params={"spacing": spacing, "diameter": diameter},
    )


# --------------------------------------------------------------------------- meshes


def write_textured_slab(target: Target, thickness: float = 0.003) -> tuple[Path, Path]:
    """Write the target's PNG and a closed slab .obj (in the target frame); return both paths.

    The printed face is the print frame's z = 0 plane, facing -z; the slab extends
    ``thickness`` metres into the board (+z of the print frame). Its other five faces sample
    a white texel of the margin, so the board reads as a white plate from every side.
    Files are named by content hash and reused.
    """
    _positive("thickness", thickness)
    folder = cache_dir()
    name = f"{target.key}_{round(thickness * 1e6)}um"
    png, obj = folder / f"{target.key}.png", folder / f"{name}.obj"
    if not png.exists():
        tmp = png.with_suffix(".tmp.png")
        cv2.imwrite(str(tmp), cv2.cvtColor(target.image, cv2.COLOR_RGB2BGR))
        os.replace(tmp, png)  # atomic: parallel test workers never read half a file
    if not obj.exists():
        tmp = obj.with_suffix(".tmp")
        tmp.write_text(_slab_obj(target, thickness))
        os.replace(tmp, obj)
    return png, obj


def _slab_obj(target: Target, thickness: float) -> str:
    w, h = target.size
    H, W = target.image.shape[:2]
    # Print-frame corners: 0..3 on the printed face (z = 0), 4..7 on the back (z = thickness).
    xy = [(0, 0), (w, 0), (w, h), (0, h)]
    corners = np.array([(x, y, 0.0) for x, y in xy] + [(x, y, thickness) for x, y in xy])
    target_T_print = np.linalg.inv(target.print_T_target)
    verts = transform_points(target_T_print, corners)
    R = target_T_print[:3, :3]
    # v = 1 is the image's top row (measured, see module docstring).
    uv_face = [(0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0)]
    white = (0.5 / W, 1.0 - 0.5 / H)  # centre of the top-left margin texel
    lines = ["# cobotlab calibration target slab, target-frame coordinates in metres"]
    lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in verts]
    lines += [f"vt {u:.9f} {v:.9f}" for u, v in uv_face + [white]]
    normals = {"front": (0, 0, -1), "back": (0, 0, 1), "top": (0, -1, 0), "bottom": (0, 1, 0),
               "left": (-1, 0, 0), "right": (1, 0, 0)}
    names = list(normals)
    lines += ["vn {:.9f} {:.9f} {:.9f}".format(*(R @ np.asarray(n, float)))
              for n in normals.values()]
    # Quads as vertex lists, wound counter-clockwise seen from outside (in the print frame,
    # which is right-handed with z into the board).
    quads = {
        "front": [0, 3, 2, 1],
        "back": [4, 5, 6, 7],
        "top": [0, 1, 5, 4],
        "bottom": [3, 7, 6, 2],
        "left": [0, 4, 7, 3],
        "right": [1, 2, 6, 5],
    }
    for face, q in quads.items():
        n = names.index(face) + 1
        if face == "front":
            t = [k + 1 for k in q]  # corner k uses uv_face[k]
        else:
            t = [5] * 4
        a, b, c, d = q
        ta, tb, tc, td = t
        lines.append(f"f {a + 1}/{ta}/{n} {b + 1}/{tb}/{n} {c + 1}/{tc}/{n}")
        lines.append(f"f {a + 1}/{ta}/{n} {c + 1}/{tc}/{n} {d + 1}/{td}/{n}")
    return "\n".join(lines) + "\n"

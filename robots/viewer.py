"""A live 3-D view of a workcell in the notebook: the arm, the camera, the board and the frames.

    from robots import connect
    from robots.viewer import WorkcellViewer
    cell = connect("sim", arm="panda", mount="eye_in_hand")
    view = WorkcellViewer(cell)
    view.show_estimate("cam", my_flange_T_cam, parent="flange")   # dashed, beside the truth
    view.with_jog_panel()          # last line of a cell: the view and a jog panel side by side

What it draws
-------------
* the cell's geometry as the backend describes it (``Workcell.visual_scene()``): in sim the
  arm's links at their current joints, the tool, the table, the calibration board (with its
  printed pattern) and the chess pieces; a real robot describes none, and the view then holds
  the frames alone;
* frames as red / green / blue arrows for x / y / z: ``base``, ``flange``, ``cam`` (with the
  camera's viewing frustum, its top edge marked by a small triangle: the image's "up"),
  ``target`` and, in the chess scene, ``world`` (the a1 corner). Solid arrows are the truth
  (the simulator's, students never get it on a real robot); estimates given to
  :meth:`WorkcellViewer.show_estimate` are dashed, with their own label.

Rendering happens in the student's browser (WebGL, through the ``k3d`` Jupyter widget and the
kernel's own connection), so the server needs no GPU and no extra port: it works in JupyterLab,
JupyterHub, VS Code and Colab alike. The scene lives in Python as ``k3d`` objects, one per
shape and frame, each placed by its ``model_matrix`` (the ``base_T_x`` pose, the robot base is
the scene's origin, metres); :meth:`WorkcellViewer.update` re-reads the poses and sends only
those that changed. The view updates after every move of the robot (``Robot.move_listeners``,
at most every ``MIN_REDRAW_S``, so a loop that moves the robot animates it live), on a timer
between cells (``refresh_s``: it catches what moved otherwise, such as a piece that fell),
and whenever :meth:`update` is called.

``VisualShape`` / ``ShapePart`` / ``VisualScene`` are what a backend returns from
``Workcell.visual_scene()``: plain data, so ``robots`` never imports a backend (DESIGN.md).
"""

from __future__ import annotations

import html
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from robots.geometry import as_pose, compose, transform_points
from robots.interfaces import Robot, RobotDisconnectedError, Workcell
from robots.jog import RefreshTimer, jog_panel

__all__ = [
    "ShapePart",
    "VisualScene",
    "VisualShape",
    "WorkcellViewer",
    "tessellate",
]

PRIMITIVES = ("box", "cylinder", "capsule", "sphere")
AXIS_COLOURS = (0xE41A1C, 0x2CA02C, 0x1F5FD1)  # x, y, z: red, green, blue
FRUSTUM_COLOUR = 0x6A3D9A
LABEL_COLOUR = 0x222222
ESTIMATE_COLOURS = (0xFF7F0E, 0x17BECF, 0xBCBD22, 0xE377C2)  # labels of successive estimates
_SEGMENTS = 20  # around a cylinder, a capsule or a sphere
_POSE_TOL = 1e-7  # a pose that changed less than this (m, or rotation entries) is not resent
# Loose bodies (pieces) settle by fractions of a millimetre while the world steps under a move;
# resending every piece after every arm move would cost more than the move.
_LOOSE_POSE_TOL = 2e-4
MIN_REDRAW_S = 0.1  # after a move, redraw at most this often: a servo loop moves at 20-50 Hz


# --------------------------------------------------------------------------- scene data


@dataclass(frozen=True)
class ShapePart:
    """One visual piece of a rigid body, in the body's frame (metres).

    ``kind`` is "box" (``size`` = full x, y, z extents), "cylinder" or "capsule" (``size`` =
    radius, length of the straight part, along z), "sphere" (``size`` = radius,) or "mesh"
    (``vertices`` (n, 3) and ``triangles`` (m, 3) int; ``uvs`` (n, 2) and ``texture_png`` (PNG
    bytes) for a printed pattern). ``body_T_part`` places the part, ``rgba`` colours it
    (0..1; alpha below 1 draws it translucent).
    """

    kind: str
    size: tuple = ()
    body_T_part: np.ndarray = field(default_factory=lambda: np.eye(4))
    rgba: tuple = (0.7, 0.7, 0.7, 1.0)
    vertices: np.ndarray | None = None
    triangles: np.ndarray | None = None
    uvs: np.ndarray | None = None
    texture_png: bytes | None = None


@dataclass(frozen=True)
class VisualShape:
    """A rigid body (or one link of the arm) to draw: its parts, and where it is now.

    ``name`` is unique and stable for the life of the cell ("arm/panda_link3", "board",
    "piece 12: white pawn"); ``group`` says what it is: "arm", "tool", "table", "board",
    "target" (a target carried by the flange), "piece" or "object". ``base_T_body`` is the
    body frame in the robot base frame (metres).
    """

    name: str
    group: str
    base_T_body: np.ndarray
    parts: tuple[ShapePart, ...]


@dataclass(frozen=True)
class VisualScene:
    """What ``Workcell.visual_scene()`` returns: every shape at its pose now, and the TRUE
    poses of the named frames in the robot base frame (``frames["cam"]`` is ``base_T_cam``;
    names "flange", "cam", "target", "world", "tcp"). Read-only: built fresh by each call."""

    shapes: tuple[VisualShape, ...]
    frames: dict


# --------------------------------------------------------------------------- tessellation


def _lathe(profile: Sequence[tuple[float, float]], segments: int = _SEGMENTS):
    """Vertices and triangles of a surface of revolution about z from (radius, z) points."""
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    vertices = np.concatenate([np.column_stack([r * ring, np.full(segments, z)])
                               for r, z in profile])
    triangles = []
    for k in range(len(profile) - 1):
        a, b = k * segments, (k + 1) * segments
        for i in range(segments):
            j = (i + 1) % segments
            triangles += [(a + i, a + j, b + j), (a + i, b + j, b + i)]
    return vertices, np.array(triangles, dtype=np.uint32)


def _arc(radius: float, z_centre: float, start: float, stop: float, steps: int):
    """(radius, z) points of a quarter or half circle in the r-z plane (angles from +z)."""
    return [(radius * math.sin(a), z_centre + radius * math.cos(a))
            for a in np.linspace(start, stop, steps)]


def tessellate(part: ShapePart) -> tuple[np.ndarray, np.ndarray]:
    """Triangles for a part in the part's own frame: ``(vertices (n, 3), triangles (m, 3))``.

    Primitives follow PyBullet's and URDF's conventions: centred on the frame, cylinders and
    capsules along z. A mesh part is returned as it is.
    """
    if part.kind == "mesh":
        return np.asarray(part.vertices, float), np.asarray(part.triangles, np.uint32)
    size = [float(s) for s in part.size]
    if part.kind == "box":
        half = np.asarray(size[:3]) / 2
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
        faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
                 (1, 5, 7, 3)]
        triangles = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
        return corners, np.array(triangles, dtype=np.uint32)
    if part.kind == "cylinder":
        r, half = size[0], size[1] / 2
        return _lathe([(0.0, -half), (r, -half), (r, half), (0.0, half)])
    if part.kind == "capsule":
        r, half = size[0], size[1] / 2
        return _lathe(_arc(r, -half, math.pi, math.pi / 2, 6) + _arc(r, half, math.pi / 2, 0, 6))
    if part.kind == "sphere":
        return _lathe(_arc(size[0], 0.0, math.pi, 0.0, 10))
    raise ValueError(f"unknown shape kind {part.kind!r}; expected one of {PRIMITIVES} or 'mesh'")


def _packed(rgba) -> int:
    r, g, b = (int(round(255 * min(max(float(c), 0.0), 1.0))) for c in rgba[:3])
    return (r << 16) | (g << 8) | b


def _matrix(T: np.ndarray) -> np.ndarray:
    return np.asarray(T, dtype=np.float32)


def _frame_segments(length: float, dashed: bool):
    """Vertices, segment indices and per-vertex colours of an x/y/z triad (frame coordinates)."""
    vertices, colours = [], []
    for axis in range(3):
        if dashed:
            edges = np.linspace(0.0, length, 12)  # 6 dashes with gaps between
            pairs = list(zip(edges[0::2], edges[1::2]))
        else:
            pairs = [(0.0, length)]
        for a, b in pairs:
            for s in (a, b):
                v = np.zeros(3)
                v[axis] = s
                vertices.append(v)
                colours.append(AXIS_COLOURS[axis])
    indices = np.arange(len(vertices), dtype=np.uint32).reshape(-1, 2)
    return np.array(vertices, dtype=np.float32), indices, colours


def _frustum_segments(intrinsics, depth: float):
    """Camera-frame lines of the viewing pyramid to ``depth`` metres, and an "up" triangle."""
    i = intrinsics
    corners_px = [(0, 0), (i.width, 0), (i.width, i.height), (0, i.height)]
    corners = [np.array([(u - i.cx) / i.fx * depth, (v - i.cy) / i.fy * depth, depth])
               for u, v in corners_px]
    top_mid = (corners[0] + corners[1]) / 2
    apex = top_mid + np.array([0.0, -0.25 * abs(corners[0][1] - corners[3][1]) / 2, 0.0])
    points = [np.zeros(3), *corners, apex]
    segments = [(0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (2, 3), (3, 4), (4, 1)]
    # The triangle on the image's top edge: image y points down, so "up" is camera -y.
    left = corners[0] + (corners[1] - corners[0]) * 0.35
    right = corners[0] + (corners[1] - corners[0]) * 0.65
    points += [left, right]
    segments += [(6, 5), (5, 7)]
    return (np.array(points, dtype=np.float32), np.array(segments, dtype=np.uint32))


# --------------------------------------------------------------------------- the viewer


def _k3d():
    try:
        import k3d
    except ModuleNotFoundError:
        raise ImportError(
            "the 3-D view needs k3d; install it with `pip install 'cobotlab[course]'` "
            "(or `pip install 'k3d>=3.1,<4'`)"
        ) from None
    return k3d


def _robot_and_cell(cell) -> tuple[Robot, Workcell | None]:
    if isinstance(cell, Workcell):
        return cell.robot, cell
    if isinstance(cell, Robot):
        return cell, None
    raise ValueError(
        f"expected a robots.Workcell (from robots.connect) or a Robot, got {type(cell).__name__}"
    )


@dataclass
class _Estimate:
    label: str
    parent: str
    parent_T_frame: np.ndarray
    colour: int


class WorkcellViewer:
    """A ``k3d`` 3-D view of a workcell that follows the robot. Display it as a cell's last line.

    ``cell`` is a Workcell (or a Robot: frames only). ``frame_length`` (m) is the arrow length
    of the frames (the base gets twice that), ``frustum_depth`` (m) the depth to which the
    camera's viewing pyramid is drawn, ``height`` the widget's height in pixels.
    The view redraws after every move of the robot, at most every ``min_redraw_s`` seconds
    (a robot move listener), and ``refresh_s`` (seconds; None: off) re-reads the poses on a
    timer on the notebook's event loop, between cells and never during one. :meth:`close`
    stops both.

    Attributes for tests and the curious: ``plot`` (the ``k3d.plot.Plot`` widget),
    ``objects`` (name -> k3d object: a shape's name, "frame <name>", "estimate <label>",
    "frustum", "label frame <name>", "label estimate <label>"), :meth:`pose` (the ``base_T_x`` an object is drawn at).
    """

    def __init__(self, cell, frame_length: float = 0.08, frustum_depth: float = 0.12,
                 height: int = 480, refresh_s: float | None = 0.5):
        k3d = _k3d()
        self._k3d = k3d
        self.robot, self.cell = _robot_and_cell(cell)
        for name, value in (("frame_length", frame_length), ("frustum_depth", frustum_depth)):
            if not (math.isfinite(float(value)) and float(value) > 0):
                raise ValueError(f"{name} must be a positive number of metres, got {value!r}")
        self.frame_length = float(frame_length)
        self.frustum_depth = float(frustum_depth)
        self.objects: dict[str, object] = {}
        self._drawn: dict[str, np.ndarray] = {}  # name -> base_T_x last sent
        self._estimates: dict[str, _Estimate] = {}
        self._shape_objects: dict[str, list[str]] = {}  # shape name -> its k3d objects' names
        self._tolerance: dict[str, float] = {}  # name -> smallest change worth resending
        self._timer = RefreshTimer(self._refresh_once)
        self.min_redraw_s = MIN_REDRAW_S
        self._last_update = -math.inf
        self.plot = k3d.plot(height=int(height), grid_visible=False, axes_helper=0,
                             camera_auto_fit=False, menu_visibility=False,
                             background_color=0xFFFFFF, camera_up_axis="z")
        scene = self._read_scene()
        self._has_truth = scene is not None
        for shape in () if scene is None else scene.shapes:
            self._add_shape(shape)
        self._add_frame("base", 2 * self.frame_length, np.eye(4))
        frames = self._true_frames(scene)
        for name, T in frames.items():
            self._add_frame(name, self.frame_length, T)
            if name == "cam" and self.cell is not None and self.cell.camera is not None:
                self._add_frustum(T)
        self._legend = k3d.text2d(self._legend_text(self._has_truth), position=(0.01, 0.01),
                                  reference_point="lt", size=0.8, color=LABEL_COLOUR,
                                  label_box=False, is_html=True, name="legend")
        self.plot += self._legend
        self._place_camera(scene, frames)
        self.robot.move_listeners.append(self._robot_moved)
        if refresh_s is not None:
            self.start_auto_refresh(refresh_s)

    # ----- reading the cell

    def _read_scene(self):
        if self.cell is None:
            return None
        return self.cell.visual_scene()

    def _true_frames(self, scene) -> dict[str, np.ndarray]:
        """Frames drawn solid: the backend's truth, else what the robot reports."""
        frames = {} if scene is None else {k: as_pose(v, k) for k, v in scene.frames.items()}
        if "flange" not in frames:
            frames["flange"] = self.robot.flange_pose()
        return frames

    # ----- building

    def _add(self, name: str, obj, base_T_x) -> None:
        obj.model_matrix = _matrix(base_T_x)
        self.plot += obj
        self.objects[name] = obj
        self._drawn[name] = np.array(base_T_x, dtype=float)

    def _add_shape(self, shape: VisualShape) -> None:
        loose = shape.group in ("piece", "object")
        plain = [p for p in shape.parts if p.texture_png is None and p.rgba[3] > 0]
        textured = [p for p in shape.parts if p.texture_png is not None and p.rgba[3] > 0]
        if plain:
            vertices, triangles, colours, offset = [], [], [], 0
            for part in plain:
                v, t = tessellate(part)
                v = transform_points(part.body_T_part, v)
                vertices.append(v)
                triangles.append(t + offset)
                colours += [_packed(part.rgba)] * len(v)
                offset += len(v)
            opacity = min(p.rgba[3] for p in plain)
            mesh = self._k3d.mesh(np.concatenate(vertices).astype(np.float32),
                                  np.concatenate(triangles).astype(np.uint32),
                                  colors=colours, opacity=float(opacity), side="double",
                                  flat_shading=True, name=shape.name)
            self._add(shape.name, mesh, shape.base_T_body)
            self._shape_objects.setdefault(shape.name, []).append(shape.name)
            if loose:
                self._tolerance[shape.name] = _LOOSE_POSE_TOL
        for k, part in enumerate(textured):
            v, t = tessellate(part)
            v = transform_points(part.body_T_part, v)
            name = shape.name if not plain and k == 0 else f"{shape.name} [{k}]"
            mesh = self._k3d.mesh(v.astype(np.float32), t.astype(np.uint32),
                                  uvs=np.asarray(part.uvs, np.float32), texture=part.texture_png,
                                  texture_file_format="png", side="double", flat_shading=True,
                                  color=0xFFFFFF, name=name)
            self._add(name, mesh, shape.base_T_body)
            self._shape_objects.setdefault(shape.name, []).append(name)

    def _add_frame(self, name: str, length: float, base_T_x, dashed: bool = False,
                   label: str | None = None, label_colour: int = LABEL_COLOUR) -> None:
        vertices, indices, colours = _frame_segments(length, dashed)
        key = f"{'estimate' if dashed else 'frame'} {name}"
        lines = self._k3d.lines(vertices, indices, indices_type="segment", colors=colours,
                                shader="mesh", width=0.003 if dashed else 0.004, name=key)
        self._add(key, lines, base_T_x)
        # A sprite drawn in the WebGL scene itself (k3d's HTML text overlays do not show in
        # every front end), sized in metres.
        text = self._k3d.texture_text(label or name,
                                      position=self._label_position(base_T_x, length),
                                      color=label_colour, font_weight=600, font_face="sans-serif",
                                      size=0.1, name=f"label {key}")
        self.plot += text
        self.objects[f"label {key}"] = text

    def _add_frustum(self, base_T_cam) -> None:
        points, segments = _frustum_segments(self.cell.camera.intrinsics, self.frustum_depth)
        frustum = self._k3d.lines(points, segments, indices_type="segment", color=FRUSTUM_COLOUR,
                                  shader="simple", width=1.0, name="frustum")
        self._add("frustum", frustum, base_T_cam)

    def _label_position(self, base_T_x, length: float) -> list[float]:
        T = np.asarray(base_T_x, float)
        # Beyond the tip of the x arrow: frames that share an origin region rarely share an
        # x direction (the wrist camera's x runs along the flange's y), so labels part.
        return [float(c) for c in T[:3, 3] + 1.3 * length * T[:3, 0]]

    def _legend_text(self, has_truth: bool) -> str:
        lines = ["frames: <b style='color:#e41a1c'>x</b> <b style='color:#2ca02c'>y</b> "
                 "<b style='color:#1f5fd1'>z</b>"]
        lines.append("solid: the simulator's truth" if has_truth else "solid: what the robot reports")
        if self._estimates:
            lines.append("dashed: " + ", ".join(html.escape(e.label)
                                                for e in self._estimates.values()))
        return "<br>".join(lines)

    def _place_camera(self, scene, frames) -> None:
        """Look at the work area from the front left, a little above, as a visitor would."""
        points = [np.zeros(3)] + [T[:3, 3] for T in frames.values()]
        if scene is not None:
            points += [s.base_T_body[:3, 3] for s in scene.shapes if s.group != "table"]
        points = np.array(points)
        centre = (points.min(axis=0) + points.max(axis=0)) / 2
        extent = max(float(np.ptp(points, axis=0).max()), 0.3)
        eye = centre + extent * np.array([0.9, 1.0, 0.6])
        self.plot.camera = [*eye, *centre, 0.0, 0.0, 1.0]

    # ----- estimates

    def show_estimate(self, frame: str, pose, parent: str = "base",
                      label: str | None = None) -> None:
        """Draw an estimated frame dashed, next to the truth: ``parent_T_frame = pose`` (4, 4).

        ``parent`` is "base" (``pose`` is ``base_T_frame``) or "flange" (``pose`` is
        ``flange_T_frame``, e.g. a hand-eye result ``flange_T_cam``: drawn at the robot's
        reported flange pose times it, so it follows the arm). ``label`` defaults to
        "<frame> (estimate)"; showing the same label again moves that estimate.
        """
        if parent not in ("base", "flange"):
            raise ValueError(f"parent must be 'base' or 'flange', got {parent!r}")
        pose = as_pose(pose, f"{parent}_T_{frame}")
        label = label or f"{frame} (estimate)"
        known = self._estimates.get(label)
        colour = known.colour if known else ESTIMATE_COLOURS[
            len(self._estimates) % len(ESTIMATE_COLOURS)]
        self._estimates[label] = _Estimate(label, parent, pose, colour)
        base_T_x = self._estimate_pose(self._estimates[label])
        if known is None:
            self._add_frame(label, self.frame_length, base_T_x, dashed=True, label=label,
                            label_colour=colour)
        else:
            self._move(f"estimate {label}", base_T_x, self.frame_length)
        self._legend.text = self._legend_text(self._has_truth)

    def _estimate_pose(self, estimate: _Estimate) -> np.ndarray:
        if estimate.parent == "flange":
            return compose(self.robot.flange_pose(), estimate.parent_T_frame)
        return estimate.parent_T_frame

    # ----- updating

    def _move(self, name: str, base_T_x, length: float | None = None) -> bool:
        T = np.asarray(base_T_x, float)
        if np.abs(T - self._drawn[name]).max() <= self._tolerance.get(name, _POSE_TOL):
            return False
        self.objects[name].model_matrix = _matrix(T)
        self._drawn[name] = T.copy()
        label = self.objects.get(f"label {name}")
        if label is not None and length is not None:
            label.position = self._label_position(T, length)
        return True

    def update(self) -> int:
        """Re-read every pose and move what moved; returns how many objects were moved.

        Returns 0 (and leaves the view as it was) once the robot is disconnected.
        """
        if self.robot.closed:
            return 0
        self._last_update = time.monotonic()
        try:
            scene = self._read_scene()
            frames = self._true_frames(scene)
            estimates = {k: self._estimate_pose(e) for k, e in self._estimates.items()}
        except RobotDisconnectedError:
            return 0
        moved = 0
        for shape in () if scene is None else scene.shapes:
            for name in self._shape_objects.get(shape.name, ()):
                moved += self._move(name, shape.base_T_body)
        for name, T in frames.items():
            if f"frame {name}" in self._drawn:
                moved += self._move(f"frame {name}", T, self.frame_length)
            if name == "cam" and "frustum" in self._drawn:
                moved += self._move("frustum", T)
        for label, T in estimates.items():
            moved += self._move(f"estimate {label}", T, self.frame_length)
        return moved

    def _robot_moved(self) -> None:
        if time.monotonic() - self._last_update >= self.min_redraw_s:
            self.update()

    def pose(self, name: str) -> np.ndarray:
        """The ``base_T_x`` (4, 4) that object ``name`` is drawn at, read back from the widget."""
        return np.asarray(self.objects[name].model_matrix, dtype=float)

    # ----- beside the jog panel

    def with_jog_panel(self, panel=None, **options):
        """The view and a jog panel side by side (an ipywidgets HBox); the view redraws after
        every jog, as after any move of the robot. ``panel`` is an existing :class:`~robots.jog.JogPanel`, or None to build one
        with ``options`` (see :func:`robots.jog.jog_panel`)."""
        if panel is None:
            panel = jog_panel(self.cell if self.cell is not None else self.robot, **options)
        import ipywidgets

        self.jog_panel = panel
        # The panel keeps its natural width (its buttons must not be squeezed), the view takes
        # the rest, and on a narrow page the panel wraps below the view.
        self.plot.layout.flex = "1 1 420px"
        self.plot.layout.min_width = "320px"
        panel.widget.layout.flex = "0 0 auto"
        return ipywidgets.HBox([self.plot, panel.widget], layout=ipywidgets.Layout(
            flex_flow="row wrap", align_items="flex-start"))

    # ----- display and timer

    def _repr_mimebundle_(self, **kwargs):
        return self.plot._repr_mimebundle_(**kwargs)

    def save_html(self, path) -> str:
        """Write the view as a standalone HTML page (the k3d library inlined: it opens offline,
        in any browser with WebGL); returns the path."""
        with open(path, "w", encoding="utf-8") as f:
            f.write(self.plot.get_snapshot())
        return str(path)

    @property
    def auto_refresh_running(self) -> bool:
        return self._timer.running

    def start_auto_refresh(self, period_s: float = 0.5) -> bool:
        """Call :meth:`update` every ``period_s`` seconds on the running event loop (False and
        nothing started outside one, as in a plain script). Stops once the robot is closed."""
        return self._timer.start(period_s)

    def _refresh_once(self) -> bool:
        if self.robot.closed:
            return False
        self.update()
        return True

    def stop_auto_refresh(self) -> None:
        self._timer.stop()

    def close(self) -> None:
        """Stop following the robot and close the widget (the robot stays connected)."""
        self.stop_auto_refresh()
        if self._robot_moved in self.robot.move_listeners:
            self.robot.move_listeners.remove(self._robot_moved)
        self.plot.close()

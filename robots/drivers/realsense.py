"""Intel RealSense depth camera (D400 series) behind the :class:`~robots.interfaces.Camera` interface.

Uses Intel's ``pyrealsense2`` (pip, in the ``real`` extra; on Linux it also needs the Debian
package ``libusb-1.0-0``). It streams colour (RGB8) and depth (Z16), aligns depth to the colour
camera with ``rs.align(rs.stream.color)``, so ``Frame.depth[v, u]`` is the distance along the
colour camera's optical axis for colour pixel ``(u, v)``, and converts depth units to metres with
the depth sensor's own scale (``get_depth_scale()``, typically 0.001 m per unit on a D435).

Intrinsics come from the colour stream profile (``as_video_stream_profile().get_intrinsics()``):
``fx, fy, ppx, ppy`` map to our ``fx, fy, cx, cy``. RealSense and OpenCV agree on pixel centres
(``ppx`` is the principal point in the same pixel-centre-at-integer convention), so no half-pixel
shift is applied. Distortion: the colour stream of a D400 reports "Inverse Brown-Conrady" (or
"Brown-Conrady") with ``coeffs = [k1, k2, p1, p2, k3]``, which is OpenCV's order, so the coefficients
are passed through unchanged. Models with a different layout (Kannala-Brandt fisheye "ftheta")
are refused with a ValueError instead of being silently mis-read.

Every depth pixel without a measurement (raw value 0) becomes NaN, as ``Frame`` documents.

Usage, alone or next to any robot driver::

    from robots.drivers.realsense import open_realsense
    cam = open_realsense(width=640, height=480, fps=30)
    frame = cam.capture()            # Frame(rgb uint8 HxWx3, depth float32 metres HxW)
    cam.close()

    connect("ur", host="192.168.1.10", camera="realsense")   # the drivers call open_realsense
"""

from __future__ import annotations

import importlib
import time

import numpy as np

from robots.backends import BackendNotAvailableError
from robots.interfaces import Camera, Frame, Intrinsics, RobotDisconnectedError

__all__ = [
    "RealSenseCamera",
    "RealSenseError",
    "camera_from_option",
    "frame_from_rs",
    "intrinsics_from_rs",
    "open_realsense",
]

# Distortion models whose coefficients are (k1, k2, p1, p2, k3) like OpenCV's.
_BROWN_MODELS = ("none", "brown_conrady", "inverse_brown_conrady", "modified_brown_conrady")


class RealSenseError(RuntimeError):
    """The camera is missing, busy, or stopped delivering frames."""


def _import_rs(rs=None):
    """The pyrealsense2 module (or the one passed in), with a fix-it message if missing."""
    if rs is not None:
        return rs
    try:
        return importlib.import_module("pyrealsense2")
    except ImportError as error:
        hint = (
            "install the Debian package with `sudo apt-get install libusb-1.0-0`"
            if "libusb" in str(error)
            else "install it with `pip install cobotlab[real]` (or `pip install pyrealsense2`)"
        )
        raise BackendNotAvailableError(
            f"the RealSense camera needs pyrealsense2: {error}; {hint}"
        ) from error


def intrinsics_from_rs(rs_intrinsics) -> Intrinsics:
    """Convert a ``pyrealsense2.intrinsics`` (from a video stream profile) to :class:`Intrinsics`.

    ``fx, fy, ppx, ppy`` are in pixels; ``coeffs`` are taken as OpenCV's ``(k1, k2, p1, p2, k3)``
    for the Brown-Conrady family. Raises ValueError for a model with another layout.
    """
    model = str(rs_intrinsics.model).rsplit(".", 1)[-1].lower()
    if model not in _BROWN_MODELS:
        raise ValueError(
            f"RealSense distortion model {model!r} is not OpenCV's (k1, k2, p1, p2, k3); "
            "use the colour stream (Brown-Conrady) rather than a fisheye stream"
        )
    return Intrinsics(
        fx=rs_intrinsics.fx,
        fy=rs_intrinsics.fy,
        cx=rs_intrinsics.ppx,
        cy=rs_intrinsics.ppy,
        width=rs_intrinsics.width,
        height=rs_intrinsics.height,
        dist=list(rs_intrinsics.coeffs)[:5],
    )


def frame_from_rs(frameset, align, depth_scale: float, name: str = "realsense") -> Frame:
    """Align one ``pyrealsense2.composite_frame`` to colour and convert it to a :class:`Frame`.

    ``align`` is an ``rs.align(rs.stream.color)``; ``depth_scale`` is metres per depth unit.
    Depth zeros (no measurement) become NaN. The timestamp is the colour frame's, in seconds
    (RealSense reports milliseconds; its clock domain is the device's or the host's, see
    ``get_frame_timestamp_domain``).
    """
    aligned = align.process(frameset)
    color = aligned.get_color_frame()
    depth = aligned.get_depth_frame()
    if not color:
        raise RealSenseError("the frameset holds no colour frame; is the colour stream enabled?")
    rgb = np.asanyarray(color.get_data())
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise RealSenseError(
            f"colour frame has shape {rgb.shape} and dtype {rgb.dtype}; stream it as RGB8"
        )
    depth_m = None
    if depth:
        raw = np.asanyarray(depth.get_data())
        depth_m = raw.astype(np.float32) * np.float32(depth_scale)
        depth_m[raw == 0] = np.nan
    return Frame(rgb.copy(), depth_m, color.get_timestamp() / 1000.0, name)


class RealSenseCamera(Camera):
    """A RealSense camera streaming RGB8 colour and, optionally, Z16 depth aligned to colour.

    Build it with :func:`open_realsense`. ``capture()`` waits up to ``timeout_s`` for the next
    frameset and returns a :class:`Frame`; ``depth_scale`` is metres per raw depth unit.
    ``source`` is anything with ``wait_for_frames(timeout_ms)`` and ``stop()`` (an
    ``rs.pipeline`` on a real camera; a syncer over a ``software_device`` in the tests).
    """

    def __init__(
        self,
        source,
        intrinsics: Intrinsics,
        depth_scale: float | None,
        rs=None,
        name: str = "realsense",
        timeout_s: float = 2.0,
        serial: str | None = None,
    ):
        super().__init__(name, intrinsics)
        self._rs = _import_rs(rs)
        self._source = source
        self._align = self._rs.align(self._rs.stream.color)
        self.depth_scale = None if depth_scale is None else float(depth_scale)
        self.timeout_s = float(timeout_s)
        self.serial = serial
        self._closed = False

    def capture(self) -> Frame:
        if self._closed:
            raise RobotDisconnectedError(
                f"camera {self.name!r} is closed; open it again with open_realsense()"
            )
        try:
            frameset = self._source.wait_for_frames(int(self.timeout_s * 1000))
        except RuntimeError as error:  # pyrealsense2 raises RuntimeError on timeout
            raise RealSenseError(
                f"no frame from the RealSense within {self.timeout_s:.1f} s ({error}); check the "
                "USB 3 cable (a USB 2 port cannot carry colour and depth at this size)"
            ) from error
        frame = frame_from_rs(frameset, self._align, self.depth_scale or 0.0, self.name)
        if frame.depth is not None and self.depth_scale is None:
            raise RealSenseError("got a depth frame but the depth scale is unknown")
        if (frame.width, frame.height) != self.intrinsics.size:
            raise RealSenseError(
                f"frame is {frame.width}x{frame.height} but the intrinsics are for "
                f"{self.intrinsics.width}x{self.intrinsics.height}"
            )
        return frame

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._source.stop()
        except RuntimeError:  # already stopped (pyrealsense2 says so with RuntimeError)
            pass


def open_realsense(
    serial: str | None = None,
    width: int = 640,
    height: int = 480,
    fps: int = 30,
    depth: bool = True,
    name: str = "realsense",
    timeout_s: float = 2.0,
    rs=None,
) -> RealSenseCamera:
    """Start a RealSense camera and return it as a :class:`RealSenseCamera`.

    ``serial`` picks one camera when several are plugged in (``rs-enumerate-devices -s`` lists
    them); ``width`` x ``height`` at ``fps`` must be a mode the camera offers for both colour and
    depth (640x480 at 30 fps works on every D400). With ``depth=False`` only colour streams and
    ``Frame.depth`` is None. Raises RealSenseError if no camera answers.
    """
    rs = _import_rs(rs)
    for value, what in ((width, "width"), (height, "height"), (fps, "fps")):
        if isinstance(value, bool) or int(value) != value or int(value) <= 0:
            raise ValueError(f"{what} must be a positive whole number, got {value!r}")
    serials = [d.get_info(rs.camera_info.serial_number) for d in rs.context().query_devices()]
    if not serials or (serial is not None and str(serial) not in serials):
        found = f"found {serials}" if serials else "found none"
        raise RealSenseError(
            f"no RealSense camera{'' if serial is None else f' with serial {serial}'} ({found}); "
            "plug it into a USB 3 port (blue), check `rs-enumerate-devices`, and on Linux install "
            "Intel's udev rules so a normal user may open it"
        )
    pipeline = rs.pipeline()
    config = rs.config()
    if serial is not None:
        config.enable_device(str(serial))
    config.enable_stream(rs.stream.color, int(width), int(height), rs.format.rgb8, int(fps))
    if depth:
        config.enable_stream(rs.stream.depth, int(width), int(height), rs.format.z16, int(fps))
    try:
        profile = pipeline.start(config)
    except RuntimeError as error:
        which = f"serial {serial}" if serial else "any camera"
        raise RealSenseError(
            f"could not start the RealSense ({which}, {width}x{height} at {fps} fps): {error}. "
            "Check it is plugged into a USB 3 port, not open in another program (realsense-viewer), "
            "and that the mode exists (rs-enumerate-devices)"
        ) from error
    try:
        color_profile = profile.get_stream(rs.stream.color).as_video_stream_profile()
        intrinsics = intrinsics_from_rs(color_profile.get_intrinsics())
        depth_scale = profile.get_device().first_depth_sensor().get_depth_scale() if depth else None
        device_serial = profile.get_device().get_info(rs.camera_info.serial_number)
        camera = RealSenseCamera(
            pipeline, intrinsics, depth_scale, rs=rs, name=name, timeout_s=timeout_s,
            serial=device_serial,
        )
        # Auto-exposure needs a few frames to settle; the first ones are often dark.
        deadline = time.monotonic() + 2.0
        for _ in range(5):
            if time.monotonic() > deadline:
                break
            pipeline.wait_for_frames(int(timeout_s * 1000))
    except BaseException:
        pipeline.stop()
        raise
    return camera


def camera_from_option(camera, camera_options=None) -> Camera | None:
    """Resolve a driver's ``camera=`` option: None, "realsense", or a ready :class:`Camera`.

    ``camera_options`` (a dict) go to :func:`open_realsense`, e.g. ``{"serial": "0123"}``.
    """
    if camera is None or isinstance(camera, Camera):
        if camera_options:
            raise ValueError("camera_options given but camera is not 'realsense'")
        return camera
    if camera == "realsense":
        return open_realsense(**dict(camera_options or {}))
    raise ValueError(
        f"camera must be None, 'realsense' or a robots.Camera, got {camera!r}"
    )

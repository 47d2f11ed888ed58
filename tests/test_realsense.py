"""RealSense camera (robots/drivers/realsense.py) fed through pyrealsense2's own software_device.

No hardware: a software device with a colour and a depth sensor of known intrinsics receives
synthetic frames; a syncer groups them and the camera class aligns and converts them exactly as
it does for a pipeline on a real D400.
"""

import numpy as np
import pytest

from robots import Camera, Frame, RobotDisconnectedError
from robots.drivers import realsense

rs = pytest.importorskip(
    "pyrealsense2",
    reason="pyrealsense2 not installed (pip install pyrealsense2; it needs apt libusb-1.0-0)",
    exc_type=ImportError,
)

W, H = 64, 48


def rs_intrinsics(fx, fy, cx, cy, coeffs=(0, 0, 0, 0, 0), model=None, width=W, height=H):
    i = rs.intrinsics()
    i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = width, height, fx, fy, cx, cy
    i.coeffs = list(coeffs)
    i.model = rs.distortion.brown_conrady if model is None else model
    return i


class SoftwareRig:
    """A software_device with depth and colour sensors feeding a syncer.

    ``source`` has ``wait_for_frames`` / ``stop`` like an ``rs.pipeline``.
    """

    def __init__(self, color_intr, depth_intr, depth_units=0.001):
        self.device = rs.software_device()
        self.depth_sensor = self.device.add_sensor("Depth")
        self.color_sensor = self.device.add_sensor("Color")
        self.depth_profile = self.depth_sensor.add_video_stream(
            self._stream(rs.stream.depth, rs.format.z16, 2, depth_intr, uid=0)
        )
        self.color_profile = self.color_sensor.add_video_stream(
            self._stream(rs.stream.color, rs.format.rgb8, 3, color_intr, uid=1)
        )
        self.depth_sensor.add_read_only_option(rs.option.depth_units, depth_units)
        identity = rs.extrinsics()
        identity.rotation, identity.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0]
        self.depth_profile.register_extrinsics_to(self.color_profile, identity)
        self.device.create_matcher(rs.matchers.dlr_c)  # the D400 matcher: depth + colour
        self.syncer = rs.syncer(8)
        for sensor, profile in (
            (self.depth_sensor, self.depth_profile),
            (self.color_sensor, self.color_profile),
        ):
            sensor.open(profile)
            sensor.start(self.syncer)
        self.count = 0
        self.timestamps_ms = []
        self.ready = []
        self.stopped = False

    @staticmethod
    def _stream(kind, fmt, bpp, intrinsics, uid):
        s = rs.video_stream()
        s.type, s.index, s.uid, s.width, s.height, s.fps, s.bpp, s.fmt = (
            kind, 0, uid, intrinsics.width, intrinsics.height, 30, bpp, fmt
        )
        s.intrinsics = intrinsics
        return s

    def _push(self, sensor, profile, pixels, bpp, timestamp_ms):
        f = rs.software_video_frame()
        f.pixels, f.stride, f.bpp = np.ascontiguousarray(pixels), pixels.shape[1] * bpp, bpp
        f.timestamp, f.frame_number = timestamp_ms, self.count
        f.domain = rs.timestamp_domain.hardware_clock
        f.profile = profile.as_video_stream_profile()
        sensor.on_video_frame(f)

    def push(self, rgb, depth_raw):
        """Feed the same colour/depth pair until the syncer emits it as one frameset.

        The syncer pairs by timestamp only once it has seen a stream's frames arrive in order,
        so the very first frames come out alone; repeating the pair is what a live camera does.
        """
        for _ in range(8):
            t = 33.0 * self.count
            self.timestamps_ms.append(t)
            self._push(self.depth_sensor, self.depth_profile, depth_raw, 2, t)
            self._push(self.color_sensor, self.color_profile, rgb, 3, t)
            self.count += 1
            fs = self.syncer.wait_for_frames(1000)  # one frameset per pair, like a live stream
            if fs.get_depth_frame() and fs.get_color_frame():
                self.ready.append(fs)
                return
        raise AssertionError("the syncer never paired colour with depth")

    # the pipeline-like face the camera sees
    def wait_for_frames(self, timeout_ms=5000):
        if not self.ready:
            raise RuntimeError("Frame did not arrive in time!")  # pyrealsense2's own words
        return self.ready.pop(0)

    def stop(self):
        self.stopped = True
        for sensor in (self.depth_sensor, self.color_sensor):
            sensor.stop()
            sensor.close()


def make_camera(rig, depth_units=0.001):
    color_intr = rig.color_profile.as_video_stream_profile().get_intrinsics()
    scale = rig.depth_sensor.as_depth_sensor().get_depth_scale()
    assert scale == pytest.approx(depth_units)
    return realsense.RealSenseCamera(rig, realsense.intrinsics_from_rs(color_intr), scale, rs=rs)


def test_intrinsics_and_distortion_come_from_the_colour_profile():
    coeffs = (0.11, -0.05, 0.001, -0.002, 0.013)
    rig = SoftwareRig(
        rs_intrinsics(60.0, 61.0, 32.25, 23.75, coeffs, rs.distortion.inverse_brown_conrady),
        rs_intrinsics(50.0, 50.0, 31.5, 23.5),
    )
    cam = make_camera(rig)
    k = cam.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (60.0, 61.0, 32.25, 23.75, W, H)
    np.testing.assert_allclose(k.dist, coeffs, atol=1e-7)  # k1, k2, p1, p2, k3: OpenCV's order
    np.testing.assert_allclose(k.K, [[60, 0, 32.25], [0, 61, 23.75], [0, 0, 1]])
    cam.close()
    assert rig.stopped


def test_fisheye_model_is_refused():
    fisheye = rs_intrinsics(60, 60, 32, 24, (0.1, 0.01, 0, 0, 0), rs.distortion.kannala_brandt4)
    with pytest.raises(ValueError, match="kannala_brandt4"):
        realsense.intrinsics_from_rs(fisheye)


@pytest.mark.parametrize("depth_units", [0.001, 0.0001])
def test_capture_gives_rgb_and_depth_in_metres(depth_units):
    same = rs_intrinsics(55.0, 55.0, 31.5, 23.5)
    rig = SoftwareRig(same, same, depth_units=depth_units)
    cam = make_camera(rig, depth_units)
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    depth_raw = np.full((H, W), round(0.75 / depth_units), np.uint16)
    depth_raw[:4, :] = 0  # no measurement
    rig.push(rgb, depth_raw)
    frame = cam.capture()
    assert isinstance(frame, Frame)
    assert frame.rgb.dtype == np.uint8 and frame.rgb.shape == (H, W, 3)
    np.testing.assert_array_equal(frame.rgb, rgb)
    assert frame.depth.dtype == np.float32 and frame.depth.shape == (H, W)
    assert np.all(np.isnan(frame.depth[:4]))
    measured = frame.depth[4:]
    # rs.align splats each depth pixel onto colour pixels with rounding, which leaves a few
    # single-pixel holes even for identical cameras; those must be NaN, never a wrong depth.
    valid = ~np.isnan(measured)
    assert valid.mean() > 0.9
    np.testing.assert_allclose(measured[valid], 0.75, rtol=1e-6)
    assert min(abs(frame.timestamp - t / 1000.0) for t in rig.timestamps_ms) < 1e-9
    cam.close()
    with pytest.raises(RobotDisconnectedError):
        cam.capture()


def test_depth_is_aligned_to_the_colour_camera():
    # Different focal lengths and principal points: colour column u_c sees the ray of depth
    # column u_d = cx_d + fx_d * (u_c - cx_c) / fx_c (zero extrinsics, no distortion).
    color = rs_intrinsics(40.0, 40.0, 31.5, 23.5)
    depth = rs_intrinsics(60.0, 60.0, 30.0, 24.0)
    rig = SoftwareRig(color, depth)
    cam = make_camera(rig)
    columns = np.arange(W)
    depth_raw = np.tile((1000 + 10 * columns).astype(np.uint16), (H, 1))  # 1.00 m + 1 cm/column
    rig.push(np.zeros((H, W, 3), np.uint8), depth_raw)
    frame = cam.capture()
    row = frame.depth[H // 2]
    assert frame.depth.shape == (H, W)
    u_d = 30.0 + 60.0 * (columns - 31.5) / 40.0
    inside = (u_d > 1) & (u_d < W - 2)
    expected = 1.0 + 0.01 * u_d[inside]
    # One depth column is 1 cm: the aligned value may come from either neighbour.
    assert np.nanmax(np.abs(row[inside] - expected)) <= 0.0101
    # The raw image would be off by up to 16 columns at the edges; alignment really ran.
    assert np.abs(row[inside] - (1.0 + 0.01 * columns[inside])).max() > 0.1
    # Colour pixels whose ray leaves the narrower depth view get no depth.
    assert np.all(np.isnan(row[~inside][[0, -1]]))
    cam.close()


def test_open_realsense_without_a_camera_says_what_to_check():
    ctx = rs.context()
    if len(ctx.query_devices()) > 0:
        pytest.skip("a RealSense is plugged in; this checks the no-camera message")
    with pytest.raises(realsense.RealSenseError, match="USB 3"):
        realsense.open_realsense(width=640, height=480, fps=30)
    with pytest.raises(ValueError, match="width"):
        realsense.open_realsense(width=0)


def test_camera_option_resolution():
    assert realsense.camera_from_option(None) is None

    class Dummy(Camera):
        def capture(self):
            raise NotImplementedError

    from robots import Intrinsics

    cam = Dummy("d", Intrinsics(500, 500, 319.5, 239.5, 640, 480))
    assert realsense.camera_from_option(cam) is cam
    with pytest.raises(ValueError, match="realsense"):
        realsense.camera_from_option("kinect")
    with pytest.raises(ValueError, match="camera_options"):
        realsense.camera_from_option(None, {"serial": "1"})


@pytest.mark.parametrize("depth_units", [0.001, 0.0001])   # a D435's default, a D405's
def test_lab5_finds_the_flange_centre_in_a_realsense_capture(depth_units):
    # Lab 5's pipeline (its reference functions, robots.labkit.lab5) on a frame that went through
    # pyrealsense2 as Z16 with the sensor's depth units, aligned like a live D400's: a 63 mm
    # flange face 0.45 m away, tilted, in front of the wrist 6.5 mm behind it and a far wall,
    # with the D435's depth noise. The centre comes back to well under a millimetre.
    import course_kit as kit

    from robots.geometry import compose, make_pose, pose_from_rotvec
    from robots.labkit import lab5

    w, h, f = 320, 240, 300.0
    same = rs_intrinsics(f, f, 159.5, 119.5, width=w, height=h)
    rig = SoftwareRig(same, same, depth_units=depth_units)
    cam = make_camera(rig, depth_units)
    cam_T_face = compose(make_pose(t=[0.02, -0.01, 0.45]), pose_from_rotvec([0.25, -0.2, 0.0]))
    radius = 0.0315
    c = cam_T_face[:3, 3]
    n = cam_T_face[:3, 2] if cam_T_face[:3, 2] @ c < 0 else -cam_T_face[:3, 2]   # to the camera
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(uu - 159.5) / f, (vv - 119.5) / f, np.ones((h, w))], axis=-1)
    depth = np.full((h, w), 0.9)                                     # the wall
    for offset, reach in ((0.0065, 2.0 * radius), (0.0, radius)):    # wrist, then the face
        plane_c = c - offset * n                                     # behind: away from us
        hit = rays * ((plane_c @ n) / (rays @ n))[..., None]
        inside = np.linalg.norm(hit - plane_c, axis=2) < reach
        depth = np.where(inside, hit[..., 2], depth)
    rng = np.random.default_rng(5)
    depth = depth + rng.normal(0.0, 0.00358 * depth ** 2)             # sigma_z = k z^2, D435
    raw = np.round(depth / depth_units).astype(np.uint16)
    rig.push(np.full((h, w, 3), 128, np.uint8), raw)
    frame = cam.capture()
    cam.close()

    ns = {"np": np}
    names = ("backproject", "fit_plane_ransac", "fit_flange_circle")
    for source in kit.solution_sources("lab5_depth", names).values():
        exec(source, ns)  # noqa: S102 - the lab's own reference cells
    z16 = lab5.to_z16(frame.depth, cam.depth_scale)
    view = lab5.measure_flange(z16, cam.intrinsics.K, cam.depth_scale, radius,
                               *(ns[name] for name in names))
    assert np.linalg.norm(view.centre - c) < 0.8e-3, view.centre - c
    assert np.degrees(np.arccos(min(1.0, view.normal @ n))) < 1.0

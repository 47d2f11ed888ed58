"""cobotlab's hardware-abstraction layer: one API for the simulated and the real robot cell.

    from robots import connect
    with connect("sim", arm="panda", mount="eye_in_hand", seed=0) as cell:
        cell.robot.move_to(T)
        frame = cell.camera.capture()

Importing ``robots`` is light: it never imports a backend (pybullet, robot SDKs) or OpenCV;
those load when first used.
"""

from robots.backends import (
    BackendNotAvailableError,
    available_backends,
    connect,
    register_backend,
)
from robots.interfaces import (
    Camera,
    Frame,
    Gripper,
    Intrinsics,
    Pointer,
    Robot,
    RobotDisconnectedError,
    SafetyError,
    SuctionCup,
    Tool,
    UnreachableError,
    Workcell,
)
from robots.safety import Safety

# These modules import tqdm/yaml (and OpenCV inside functions); load them on first use.
_LAZY = {
    "Capture": "robots.capture",
    "Detection": "robots.capture",
    "capture_pose_pairs": "robots.capture",
    "save_capture": "robots.capture",
    "load_capture": "robots.capture",
    "CalibrationResult": "robots.calibration_io",
    "save_calibration": "robots.calibration_io",
    "load_calibration": "robots.calibration_io",
}

__all__ = [
    "BackendNotAvailableError",
    "Camera",
    "Frame",
    "Gripper",
    "Intrinsics",
    "Pointer",
    "Robot",
    "RobotDisconnectedError",
    "Safety",
    "SafetyError",
    "SuctionCup",
    "Tool",
    "UnreachableError",
    "Workcell",
    "available_backends",
    "connect",
    "register_backend",
    # loaded on first use (see _LAZY)
    "Capture",
    "Detection",
    "capture_pose_pairs",
    "save_capture",
    "load_capture",
    "CalibrationResult",
    "save_calibration",
    "load_calibration",
]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'robots' has no attribute {name!r}")

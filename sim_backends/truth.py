"""The ground truth of a simulated workcell, the same type for every engine.

``base_T_pybullet`` is the pose of the engine's own world frame in the robot's base frame
(the name dates from the first engine; the MuJoCo engine's world frame is placed the same
way, so it holds the same pose there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robots.geometry import compose
from sim_backends import textures
from sim_backends.flanges import FlangeSpec

__all__ = ["SimTruth"]


@dataclass
class SimTruth:
    """Ground truth of a simulated workcell (instructors and tests only; see module docstring).

    ``base_T_cam`` is set for a fixed camera (eye-to-hand) and ``flange_T_cam`` for a camera on
    the flange (eye-in-hand); the other is None. ``nominal_*`` is the mount a naive user would
    assume (the design values, before ``mount_error``). ``pieces`` is live: read it again after
    the arm moves a piece. ``flange`` is the arm's ISO 9409-1 flange (its face, radius
    ``flange.radius`` m, is centred on tool0 with normal +z); ``base_T_rectangle`` and
    ``rectangle_size`` (width, height) m the rectangle mark, None without one.
    """

    mount: str
    base_T_cam: np.ndarray | None
    flange_T_cam: np.ndarray | None
    nominal_base_T_cam: np.ndarray | None
    nominal_flange_T_cam: np.ndarray | None
    base_T_board: np.ndarray | None
    base_T_world: np.ndarray
    flange_T_marker: np.ndarray | None
    base_T_pybullet: np.ndarray
    cam_T_right: np.ndarray | None = None
    base_T_overview_cam: np.ndarray | None = None
    encoder_offsets: np.ndarray | None = None
    board: textures.Target | None = None
    flange_target: textures.Target | None = None
    flange: FlangeSpec | None = None
    base_T_rectangle: np.ndarray | None = None
    rectangle_size: tuple[float, float] | None = None
    _chess: object = field(default=None, repr=False)  # a scene.ChessSet (PyBullet)
    _arm: object = field(default=None, repr=False)

    @property
    def pieces(self) -> dict:
        """Square name -> ``PieceTruth(kind, colour, base_T_piece)`` read from the live sim.

        Empty outside the chess scene. A piece that is lifted or off the board is keyed
        ``"lifted:<body id>"``.
        """
        if self._chess is None:
            return {}
        return self._chess.pieces(self.base_T_pybullet)

    def base_T_flange(self) -> np.ndarray:
        """The TRUE flange pose now (the robot's ``flange_pose()`` adds encoder errors)."""
        return self._arm.true_flange_pose()

    def base_T_cam_now(self) -> np.ndarray:
        """Where the main camera is now, in the base frame (either mount)."""
        if self.base_T_cam is not None:
            return self.base_T_cam.copy()
        return compose(self.base_T_flange(), self.flange_T_cam)

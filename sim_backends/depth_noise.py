"""What a RealSense D4xx stereo camera does to a perfect depth image.

:class:`RealSenseDepthModel` turns the simulator's exact z depth into what a D435 streams
(Z16 aligned to colour, converted to metres as ``robots.drivers.realsense`` does), so that
code which works on the simulator meets the real camera's failure modes:

1. **Range.** Nothing closer than ``min_z`` (the stereo matcher searches a fixed number of
   disparities) or farther than ``max_z``.
2. **Dropouts at depth edges.** Where depth jumps (disparity changes by more than
   ``edge_jump_px`` between neighbouring pixels: an occluding contour, where the left and
   right imagers see different things) the matcher fails or returns flying pixels that the
   left-right check removes; every pixel within ``edge_dropout_px`` of such a jump is NaN.
3. **Dropouts at grazing angles.** A surface seen at more than ``max_incidence_deg`` from its
   normal has no matchable texture left: NaN.
4. **Noise growing with the square of distance.** Stereo measures disparity ``d = f B / z``
   with an RMS error of ``subpixel`` pixels, so the depth RMS error is
   ``sigma_z = z**2 * subpixel / (f B)`` (Intel, Grunnet-Jepsen, Sweetser, Woodfill, "Tuning
   depth cameras for best performance", rev. 2.0, "Depth RMS error" formula,
   https://dev.intelrealsense.com/docs/tuning-depth-cameras-for-best-performance). Gaussian,
   independent per pixel (the real error is spatially correlated; the per-pixel RMS is
   right).
5. **Quantisation.** Z16 carries whole multiples of the depth unit (``depth_unit``, the D400
   default depth scale 0.001 m), converted to float32 metres as ``raw * depth_scale``; the
   step is 1 mm.

Defaults are a D435 at its recommended 848 x 480 depth resolution (same paper: "D435:
848x480"): baseline 50 mm and depth field of view 87 deg horizontal (Intel RealSense D400
series product family datasheet), so ``f = 424 / tan(43.5 deg) = 446.8`` px; ``subpixel``
0.08, the paper's typical RMS subpixel on a well-textured target. That gives
``sigma_z = 0.00358 z**2`` (1/m): 0.9 mm at 0.5 m, 3.6 mm at 1 m, 14 mm at 2 m (0.7 %, within
the datasheet's "<= 2 % at 2 m" RMS error). ``min_z`` is ``f B / 126`` (the D4 ASIC's
126-disparity search): 0.18 m at 848 x 480; the datasheet's Min-Z of ~0.28 m is at
1280 x 720, where f is larger. ``max_z`` 10 m is the datasheet's nominal maximum (its ideal
range ends near 3 m, where this model's noise is already 32 mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

__all__ = ["D435_DEPTH_FOCAL_PX", "RealSenseDepthModel", "depth_model_from"]

# D435 depth imager at 848 x 480 with an 87 deg horizontal field of view, pixels.
D435_DEPTH_FOCAL_PX = 424.0 / math.tan(math.radians(87.0) / 2)
D4_DISPARITY_SEARCH_PX = 126


@dataclass(frozen=True)
class RealSenseDepthModel:
    """D4xx depth artefacts applied to an exact depth image (see the module docstring).

    Lengths in metres, angles in degrees. ``depth_focal_px`` and ``baseline_m`` describe the
    stereo pair (not the colour camera the depth is aligned to); ``subpixel`` is the RMS
    disparity error in its pixels; ``depth_unit`` the Z16 step (None or 0: no quantisation);
    ``min_z``/``max_z`` the valid range (None for ``min_z``: the 126-disparity limit);
    ``edge_jump_px`` the disparity jump (depth-imager pixels) that counts as a depth edge and
    ``edge_dropout_px`` how many image pixels either side of it are lost (0: none);
    ``max_incidence_deg`` the steepest view of a surface that still gives depth (90: all).
    """

    subpixel: float = 0.08
    baseline_m: float = 0.050
    depth_focal_px: float = D435_DEPTH_FOCAL_PX
    depth_unit: float | None = 0.001
    min_z: float | None = None
    max_z: float = 10.0
    edge_jump_px: float = 1.0
    edge_dropout_px: int = 2
    max_incidence_deg: float = 75.0

    def __post_init__(self):
        for name in ("subpixel", "baseline_m", "depth_focal_px", "max_z", "edge_jump_px",
                     "max_incidence_deg"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x >= 0):
                raise ValueError(f"RealSenseDepthModel.{name} must be finite and >= 0, got {x!r}")
        if self.baseline_m <= 0 or self.depth_focal_px <= 0:
            raise ValueError("RealSenseDepthModel needs baseline_m > 0 and depth_focal_px > 0")
        if self.depth_unit is not None and not (math.isfinite(self.depth_unit)
                                                and self.depth_unit >= 0):
            raise ValueError(f"depth_unit must be >= 0 metres or None, got {self.depth_unit!r}")
        if self.min_z is not None and not (math.isfinite(self.min_z) and self.min_z >= 0):
            raise ValueError(f"min_z must be >= 0 metres or None, got {self.min_z!r}")
        if not (isinstance(self.edge_dropout_px, (int, np.integer)) and self.edge_dropout_px >= 0):
            raise ValueError(f"edge_dropout_px must be an integer >= 0, got "
                             f"{self.edge_dropout_px!r}")
        if self.max_incidence_deg > 90:
            raise ValueError("max_incidence_deg must be at most 90")

    @property
    def focal_baseline(self) -> float:
        """``f B`` in pixel metres: disparity (px) = focal_baseline / z (m)."""
        return self.depth_focal_px * self.baseline_m

    @property
    def sigma_coefficient(self) -> float:
        """k in ``sigma_z = k z**2`` (1/m)."""
        return self.subpixel / self.focal_baseline

    @property
    def min_range(self) -> float:
        """Nearest valid depth (m): ``min_z``, or the 126-disparity limit ``f B / 126``."""
        if self.min_z is not None:
            return float(self.min_z)
        return self.focal_baseline / D4_DISPARITY_SEARCH_PX

    def sigma_z(self, z) -> np.ndarray:
        """Depth RMS error (m) at depth ``z`` (m), before quantisation."""
        z = np.asarray(z, dtype=float)
        return self.sigma_coefficient * z * z

    def dropout_mask(self, depth, K) -> np.ndarray:
        """(H, W) bool: pixels the camera returns no depth for, from the EXACT depth image
        (m, NaN = nothing there) and the 3x3 pixel K it is aligned to: out of range, near a
        depth edge, or seen at a grazing angle."""
        z = np.asarray(depth, dtype=np.float64)
        empty = ~np.isfinite(z)
        lost = empty | (z < self.min_range) | (z > self.max_z)
        if self.edge_dropout_px > 0:
            lost |= self._near_edges(z, empty)
        if self.max_incidence_deg < 90:
            lost |= self._grazing(z, np.asarray(K, dtype=float))
        return lost

    def apply(self, depth, K, rng: np.random.Generator) -> np.ndarray:
        """The depth image (H, W) float32 metres, NaN = no data, that a D4xx would stream for
        the exact ``depth`` (m) seen through pixel matrix ``K``; noise drawn from ``rng``."""
        z = np.asarray(depth, dtype=np.float64)
        lost = self.dropout_mask(z, K)
        noisy = z + rng.standard_normal(z.shape) * self.sigma_z(np.nan_to_num(z))
        if self.depth_unit:
            with np.errstate(invalid="ignore"):
                raw = np.rint(noisy / self.depth_unit)
            lost |= ~(raw >= 1) | (raw > np.iinfo(np.uint16).max)  # Z16: 0 means "no data"
            raw = np.where(lost, 0, raw).astype(np.uint16)
            out = raw.astype(np.float32) * np.float32(self.depth_unit)  # as the driver does
        else:
            lost |= ~(noisy > 0)
            out = noisy.astype(np.float32)
        out[lost] = np.nan
        return out

    # ----------------------------------------------------------------- internals

    def _near_edges(self, z, empty) -> np.ndarray:
        # Disparity, 0 where nothing was drawn (infinitely far): a silhouette is an edge too.
        with np.errstate(divide="ignore", invalid="ignore"):
            disp = np.where(empty | (z <= 0), 0.0, self.focal_baseline / z)
        edge = np.zeros(z.shape, bool)
        jump_x = np.abs(np.diff(disp, axis=1)) > self.edge_jump_px
        jump_y = np.abs(np.diff(disp, axis=0)) > self.edge_jump_px
        edge[:, 1:] |= jump_x
        edge[:, :-1] |= jump_x
        edge[1:, :] |= jump_y
        edge[:-1, :] |= jump_y
        edge &= ~empty
        if self.edge_dropout_px > 1:
            size = 2 * (self.edge_dropout_px - 1) + 1
            edge = cv2.dilate(edge.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
        return edge

    def _grazing(self, z, K) -> np.ndarray:
        # The surface normal from central differences of the back-projected points,
        # n = d/du x d/dv, against the pixel's ray r: steep where |n.r| / (|n| |r|) is below
        # cos(max_incidence_deg). A neighbour across an edge gives a wild normal, but those
        # pixels are edge dropouts already; the border rows and columns (no central
        # difference) and holes (NaN) never count as steep. Written per component with
        # in-place arithmetic: the (H, W, 3) arrays and np.cross cost twice the time (lab 5
        # applies this to every frame), for the same floating-point operations in the same
        # order, so the same mask bit for bit (tests/test_sim_depth_flange.py).
        H, W = z.shape
        steep = np.zeros((H, W), dtype=bool)
        if H < 3 or W < 3:
            return steep
        rx = ((np.arange(W, dtype=float) - K[0, 2]) / K[0, 0])[None, :]
        ry = ((np.arange(H, dtype=float) - K[1, 2]) / K[1, 1])[:, None]
        x, y = rx * z, ry * z
        ax, ay, az = (a[1:-1, 2:] - a[1:-1, :-2] for a in (x, y, z))   # along u
        bx, by, bz = (a[2:, 1:-1] - a[:-2, 1:-1] for a in (x, y, z))   # along v
        nx = ay * bz
        nx -= az * by
        ny = az * bx
        ny -= ax * bz
        nz = ax * by
        nz -= ay * bx
        rx, ry = rx[:, 1:-1], ry[1:-1, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = nx * rx
            cos += ny * ry
            cos += nz
            np.abs(cos, out=cos)
            for n in (nx, ny, nz):
                n *= n
            nx += ny
            nx += nz
            np.sqrt(nx, out=nx)
            nx *= np.sqrt((rx * rx + ry * ry) + 1.0)
            cos /= nx
        steep[1:-1, 1:-1] = cos < math.cos(math.radians(self.max_incidence_deg))
        return steep


def depth_model_from(spec) -> RealSenseDepthModel | None:
    """A :class:`RealSenseDepthModel` from None/False (off), True or "d435"/"realsense" (the
    defaults), a dict of fields, or a model as is."""
    if spec is None or spec is False:
        return None
    if spec is True or (isinstance(spec, str) and spec.lower() in ("d435", "realsense")):
        return RealSenseDepthModel()
    if isinstance(spec, RealSenseDepthModel):
        return spec
    if isinstance(spec, dict):
        known = {f.name for f in fields(RealSenseDepthModel)}
        unknown = sorted(set(spec) - known)
        if unknown:
            raise ValueError(f"unknown depth_model field(s) {unknown}; known: {sorted(known)}")
        return RealSenseDepthModel(**spec)
    raise ValueError("depth_model must be None, 'd435', a dict of RealSenseDepthModel fields "
                     f"or a sim_backends.depth_noise.RealSenseDepthModel, got {spec!r}")

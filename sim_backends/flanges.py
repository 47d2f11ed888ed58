"""ISO 9409-1 tool-mounting flanges of the simulated arms (data only, no PyBullet).

The flange face is what a depth camera sees of a bare arm: a flat disc of the flange's outer
diameter, centred on tool0 (the flange frame) with its normal along tool0 +z, standing
``FLANGE_PROUD_M`` proud of the wrist housing behind it so its rim is a clean step in depth.
The arm URDFs (``urdf/generate_urdfs.py``) and the Panda's render model (``arms.py``) draw
it from this table; lab 5 and its tests read the radius from here (``cell.truth.flange``).

ISO 9409-1 sizes are named ``ISO 9409-1-<d1>-<n>-<thread>``: ``d1`` the pitch circle of the
screw holes. The outer diameter ``D`` and the centring bore ``d2`` (H7) per size, from the
standard's table as reproduced by graspmonkey.de, "ISO 9409-1: The interface between robot
and tool" (https://graspmonkey.de/en/blogs/news/iso-9409-1-die-schnittstelle-zwischen-
roboter-und-werkzeug), (D, d1, d2) in mm: (40, 31.5, 20), (50, 40, 25), (63, 50, 31.5),
(80, 63, 40), (100, 80, 50). Every row has D = 1.26 d1 and d2 = d1 / 1.6 (one and two steps
of the R10 preferred-number series); size 20, which that table does not list, is taken on
the same series: D = 25, d2 = 12.5 mm (an extrapolation, not a quoted value).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["FLANGE_PROUD_M", "FLANGES", "FlangeSpec", "flange_face_obj"]

# How far the flange face stands out of the wrist housing, m. The UR tool flange's outer
# ring is 6.5 mm high above the wrist cover (TAMS, Univ. Hamburg, ur5_flange.scad /
# ur10_flange.scad, "outer flange height 6.5", drawn from UR's drawings). The same step is
# used on every arm: it exceeds the plane thresholds a flange fit uses (a few mm) at any
# depth noise the camera models, so the face's rim is a depth edge, as on the real flange.
FLANGE_PROUD_M = 0.0065


@dataclass(frozen=True)
class FlangeSpec:
    """One arm's ISO 9409-1 flange. Lengths in metres.

    ``designation`` is the ISO 9409-1 name; ``outer_diameter`` (D) the diameter of the flat
    face a depth camera sees; ``pitch_diameter`` (d1) the screw-hole circle;
    ``centring_diameter`` (d2) the H7 centring bore (not drawn: the face is a solid disc);
    ``verified`` False where no maker's document was found and the size is an assumption
    (see ``source``).
    """

    designation: str
    outer_diameter: float
    pitch_diameter: float
    centring_diameter: float
    source: str
    verified: bool = True

    @property
    def radius(self) -> float:
        """Radius (m) of the flange face, half the outer diameter."""
        return self.outer_diameter / 2


_ISO_50 = dict(designation="ISO 9409-1-50-4-M6", outer_diameter=0.063, pitch_diameter=0.050,
               centring_diameter=0.0315)

FLANGES: dict[str, FlangeSpec] = {
    # Franka's manuals name the Panda's flange "DIN ISO 9409-1-A50" (as quoted in a Panda
    # setup guide: "Mount the end effector to the Arm's ISO 9409-1-A50 flange", and in a
    # Franka Hand holder derived from Franka's mesh: "outer rim (diam. 63, the flange
    # diameter)"). Not the 31.5-4-M5 size some third-party tables list for Franka arms.
    "panda": FlangeSpec(**_ISO_50, source="Franka Panda manual: DIN ISO 9409-1-A50; D 63 mm "
                        "per the ISO table and Franka's link8 mesh rim"),
    # UR e-Series: ISO 9409-1-50-4-M6 (graspmonkey.de table above, "Universal Robots: UR3e,
    # UR5e, UR10e, UR16e"); D 63, d1 50, d2 31.5 mm also in TAMS ur5_flange.scad.
    "ur5e": FlangeSpec(**_ISO_50, source="UR e-Series: ISO 9409-1-50-4-M6 (graspmonkey.de; "
                       "TAMS ur5_flange.scad)"),
    "ur10e": FlangeSpec(**_ISO_50, source="UR e-Series: ISO 9409-1-50-4-M6 (graspmonkey.de; "
                        "TAMS ur10_flange.scad)"),
    # No Aubo document with the flange size was found. Aubo's i-series copies the UR layout
    # (same DH structure, 5 kg class); the 5-10 kg cobots all use ISO 9409-1-50-4-M6, so that
    # size is assumed. Check the arm's manual before trusting it on a real Aubo-i5.
    "aubo_i5": FlangeSpec(**_ISO_50, source="ASSUMED (no Aubo data sheet found): the UR-class "
                          "ISO 9409-1-50-4-M6", verified=False),
    # No Denso document with the flange size was found. The smallest ISO 9409-1 size, 20
    # (4 x M3, as on KUKA's 3 kg KR 3 AGILUS), fits the 0.5 kg COBOTTA's wrist; D and d2 are
    # the R10 extrapolation in the module docstring. Check the COBOTTA manual.
    "cobotta": FlangeSpec("ISO 9409-1-20-4-M3", 0.025, 0.020, 0.0125,
                          source="ASSUMED (no Denso data sheet found): ISO 9409-1-20-4-M3, "
                          "D 25 mm on the R10 series", verified=False),
}


def _face_obj_text(radius: float, depth: float, sides: int) -> str:
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    lines = [f"# ISO 9409-1 flange face: radius {radius} m, {depth} m deep (sim_backends.flanges)"]
    lines += [f"v {x:.7f} {y:.7f} 0" for x, y in ring]
    lines += [f"v {x:.7f} {y:.7f} {-depth:.7f}" for x, y in ring]
    lines += ["v 0 0 0", f"v 0 0 {-depth:.7f}"]
    lines += ["vn 0 0 1", "vn 0 0 -1"] + [f"vn {np.cos(t):.7f} {np.sin(t):.7f} 0" for t in a]
    top, bottom = 2 * sides + 1, 2 * sides + 2
    for k in range(sides):
        i, j = k + 1, (k + 1) % sides + 1  # OBJ indices are 1-based
        ni, nj = k + 3, (k + 1) % sides + 3
        lines += [f"f {top}//1 {i}//1 {j}//1", f"f {bottom}//2 {j + sides}//2 {i + sides}//2",
                  f"f {i}//{ni} {i + sides}//{ni} {j + sides}//{nj}",
                  f"f {i}//{ni} {j + sides}//{nj} {j}//{nj}"]
    return "\n".join(lines) + "\n"


def flange_face_obj(arm: str, sides: int = 128) -> Path:
    """Path of an OBJ mesh of ``arm``'s flange face, written to the texture cache if needed.

    The disc's face is the mesh's xy plane (normal +z), radius ``FLANGES[arm].radius``,
    ``FLANGE_PROUD_M`` deep. A mesh, not a URDF cylinder: TinyRenderer draws a cylinder's
    cap up to 1 mm nearer than its true plane (measured: a 63 mm cap at 0.45 m read
    0.13-1.0 mm near), which would bias every flange fit; with 128 sides the polygon's rim is
    within 0.01 mm of the circle.
    """
    from sim_backends.textures import cache_dir

    spec = FLANGES[arm]
    text = _face_obj_text(spec.radius, FLANGE_PROUD_M, sides)
    path = cache_dir() / f"flange_face_{round(spec.outer_diameter * 1e4)}.obj"
    if not path.exists() or path.read_text() != text:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")  # atomic: parallel workers share it
        tmp.write_text(text)
        os.replace(tmp, path)
    return path

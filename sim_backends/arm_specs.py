"""The five arms' models, engine-neutral: URDF, joints, limits, home pose, reach.

``ARM_SPECS[name]`` (an :class:`ArmSpec`) is what every simulator engine builds an arm from,
and ``render_urdf`` the URDF it draws (the arm's own plus its ISO 9409-1 flange face). The
frames each arm's ``flange_pose`` reports are described in ``sim_backends.arms``. The Panda's
model comes from ``pybullet_data`` (inside the PyBullet wheel); without PyBullet its path
names a folder that does not exist, and an engine that needs it says so.
"""

from __future__ import annotations

import importlib.util
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ARM_NAMES", "ARM_SPECS", "ArmSpec", "portable_urdf", "render_portable_urdf", "render_urdf"]


def _pybullet_data_dir() -> Path:
    found = importlib.util.find_spec("pybullet_data")
    if found is None or not found.submodule_search_locations:
        return Path("pybullet_data-not-installed")
    return Path(list(found.submodule_search_locations)[0])


URDF_DIR = Path(__file__).resolve().parent / "urdf"
DEG = np.pi / 180

@dataclass(frozen=True)
class ArmSpec:
    """Static description of one arm model. Angles in rad, speeds in rad/s, lengths in m."""

    name: str
    urdf: Path
    joint_names: tuple[str, ...]
    flange_link: str
    joint_limits: np.ndarray  # (n, 2), the maker's published limits
    velocity_limits: np.ndarray  # (n,)
    home: np.ndarray  # (n,) a tidy start configuration, flange above the table, tool down
    reach: float  # published reach, m
    base_T_mount: np.ndarray = field(default_factory=lambda: np.eye(4))  # mounting face in base
    other_joints: dict[str, float] = field(default_factory=dict)  # held fixed (Panda fingers)
    hand_links: tuple[str, ...] = ()  # built-in hand, hidden when another tool is mounted

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)


def _write_if_changed(path: Path, text: str) -> Path:
    if not path.exists() or path.read_text() != text:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")  # atomic: parallel workers share it
        tmp.write_text(text)
        os.replace(tmp, path)
    return path


def _with_flange_face(text: str, link: str, arm: str, material: str) -> str:
    """URDF text with the arm's ISO 9409-1 flange face (``sim_backends.flanges``) added to
    ``link`` as a visual (its face on the link's xy plane): visual only, so kinematics,
    collisions and tool mounting are untouched."""
    from sim_backends.flanges import flange_face_obj

    found = re.search(rf'<link name="{link}"\s*(/>|>.*?</link>)', text, re.S)
    if found is None:
        raise RuntimeError(f"URDF of {arm}: no link {link!r} to put the flange face on")
    face = (f'<visual><origin rpy="0 0 0" xyz="0 0 0"/><geometry>'
            f'<mesh filename="{flange_face_obj(arm).as_posix()}"/></geometry>'
            f'<material name="{material}"/></visual>')
    body = found.group(0)
    if body.endswith("/>"):
        drawn = f'<link name="{link}">{face}</link>'
    else:
        drawn = body[:-len("</link>")] + face + "</link>"
    return text[:found.start()] + drawn + text[found.end():]


def render_urdf(spec: ArmSpec) -> Path:
    """The URDF the simulator draws ``spec``'s arm from: its own, plus the flange face.

    Written into the texture cache (meshes need absolute paths there). The Panda's is
    pybullet_data's with its collision meshes drawn as the visuals: the visual meshes carry
    ~100k triangles, and TinyRenderer's time goes almost all into them; drawn with the
    (coarser, same-shaped) collision meshes a 640 x 480 RGB-D frame renders ~35 % faster.
    The Panda's link7 mesh ends in a flat face on panda_link8's xy plane whose rounded rim
    (63-70 mm across) has no clean edge in depth, so link7 is drawn ``FLANGE_PROUD_M``
    further back along its axis (``generate_urdfs.py`` does the same for the other arms'
    last links). Kinematics and collisions are untouched.
    """
    from sim_backends.flanges import FLANGE_PROUD_M
    from sim_backends.textures import cache_dir

    if spec.name != "panda":
        return _drawn(spec.urdf, spec, "render")
    source = spec.urdf
    meshes = (source.parent / "meshes" / "collision").as_posix()
    text = source.read_text()
    link7 = re.search(r'<link name="panda_link7">.*?</link>', text, re.S)
    if link7 is None:
        raise RuntimeError(f"{source}: no panda_link7")
    drawn7 = link7.group(0).replace(
        "<visual>", f'<visual>\n      <origin rpy="0 0 0" xyz="0 0 {-FLANGE_PROUD_M}"/>', 1)
    text = text[:link7.start()] + drawn7 + text[link7.end():]
    text = _with_flange_face(text, "panda_link8", "panda", "panda_white")
    text = text.replace("package://meshes/visual/", meshes + "/")
    text = text.replace("package://meshes/collision/", meshes + "/")
    return _write_if_changed(cache_dir() / "panda_light.urdf", text)


def _drawn(urdf: Path, spec: ArmSpec, suffix: str) -> Path:
    """A generated URDF (``generate_urdfs.py``) with the flange face, in the texture cache."""
    from sim_backends.textures import cache_dir

    text = _with_flange_face(urdf.read_text(), spec.flange_link, spec.name, "flange")
    text = text.replace('<material name="accent">', '<material name="flange"><color rgba='
                        '"0.62 0.63 0.66 1"/></material>\n  <material name="accent">', 1)
    return _write_if_changed(cache_dir() / f"{spec.name}_{suffix}.urdf", text)


def portable_urdf(spec: ArmSpec) -> Path:
    """The arm's URDF generated in ``sim_backends/urdf`` (kinematics only, cylinders for
    links): the same file as ``spec.urdf`` for every arm but the Panda, whose ``spec.urdf`` is
    pybullet_data's (meshes, the Franka Hand) and whose generated copy has the same joints
    and flange without the hand. What an engine without pybullet_data builds from."""
    return URDF_DIR / f"{spec.name}.urdf"


def render_portable_urdf(spec: ArmSpec) -> Path:
    """``portable_urdf`` with the arm's flange face drawn (as ``render_urdf`` adds it)."""
    return _drawn(portable_urdf(spec), spec, "portable_render")


def _limits(lo_hi) -> np.ndarray:
    return np.array(lo_hi, dtype=float)


_SIX = tuple(f"joint_{k}" for k in range(1, 7))
_AUBO_MOUNT = np.eye(4)
_AUBO_MOUNT[2, 3] = -0.0235

ARM_SPECS: dict[str, ArmSpec] = {
    # Franka Panda datasheet limits (tighter than pybullet_data's URDF).
    "panda": ArmSpec(
        "panda", _pybullet_data_dir() / "franka_panda" / "panda.urdf",
        tuple(f"panda_joint{k}" for k in range(1, 8)), "panda_link8",
        _limits([(-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
                 (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)]),
        np.array([2.175] * 4 + [2.61] * 3),
        np.array([0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]),
        0.855,
        other_joints={"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04},
        hand_links=("panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_grasptarget"),
    ),
    "ur5e": ArmSpec(
        "ur5e", URDF_DIR / "ur5e.urdf", _SIX, "tool0",
        _limits([(-2 * np.pi, 2 * np.pi)] * 6), np.full(6, 180 * DEG),
        np.array([0.0, -1.570796, 1.570796, -1.570796, -1.570796, 0.0]), 0.850),
    "ur10e": ArmSpec(
        "ur10e", URDF_DIR / "ur10e.urdf", _SIX, "tool0",
        _limits([(-2 * np.pi, 2 * np.pi)] * 6), np.array([120 * DEG] * 2 + [180 * DEG] * 4),
        np.array([0.0, -1.570796, 1.570796, -1.570796, -1.570796, 0.0]), 1.300),
    "aubo_i5": ArmSpec(
        "aubo_i5", URDF_DIR / "aubo_i5.urdf", _SIX, "tool0",
        _limits([(-175 * DEG, 175 * DEG)] * 6), np.array([150 * DEG] * 3 + [180 * DEG] * 3),
        np.array([0.0, -0.26179, 1.74532, 0.436, 1.5708, 0.0]), 0.8865, base_T_mount=_AUBO_MOUNT),
    "cobotta": ArmSpec(
        "cobotta", URDF_DIR / "cobotta.urdf", _SIX, "tool0",
        _limits([(-2.617994, 2.617994), (-1.047198, 1.745329), (0.3141593, 2.443461),
                 (-2.96706, 2.96706), (-1.658063, 2.356194), (-2.96706, 2.96706)]),
        np.array([0.40317105721069, 0.392175482923126, 0.725707902979242, 0.739146938219599,
                  0.739146938219599, 1.1093312725676]),
        np.array([0.0, 0.3, 1.6, 0.0, 1.2, 0.0]), 0.342),
}
ARM_NAMES = tuple(ARM_SPECS)


def _as_q(q, n: int, name: str) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) (one angle per joint, rad), got {q.shape}")
    bad = np.flatnonzero(~np.isfinite(q))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is {q[bad[0]]}; joint angles must be finite radians")
    return q


def _as_speed(speed, unit: str) -> float:
    speed = float(speed)
    if not np.isfinite(speed) or speed <= 0:
        raise ValueError(f"speed must be a positive number of {unit}, got {speed}")
    return speed

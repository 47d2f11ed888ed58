"""Write the simplified arm URDFs in this folder from the makers' published kinematics.

Run ``python sim_backends/urdf/generate_urdfs.py`` after changing a number below; the URDFs
are checked in, so the simulator never runs this. Only the kinematics must be exact: the
geometry is plain cylinders along the links (cheap to render, roughly the right size) and the
inertias are those of the cylinders.

Frame conventions (what the simulated controller reports, see ``sim_backends.arms``):

* UR5e / UR10e: the root link is ``base``, the frame the UR controller (teach pendant, RTDE
  ``actual_TCP_pose`` with a zero TCP) reports poses in. ROS's ``base_link`` is ``base``
  rotated 180 deg about z; it is added as a child link for reference. ``tool0`` is the DH frame
  6, i.e. the flange pose the controller reports with a zero TCP.
* Aubo-i5: the root link is ``base``, Aubo's DH frame 0 (d1 = 98.5 mm below the shoulder
  axis, J2). ROS's aubo_description ``base_link`` (the mounting face) is 23.5 mm below it
  (its shoulder joint sits 122 mm up); it is added as a child link. ``tool0`` is DH frame 6.
* Cobotta (CVR038): the root link is ``base_link`` of Denso's denso_cobotta_descriptions (base
  mounting face, on the J1 axis); ``tool0`` is the J6 link frame (the mechanical interface).

A DH row (a, alpha, d, theta_offset) is standard (distal) DH: ``T = Rz(q + offset) Tz(d)
Tx(a) Rx(alpha)``. URDF link k is DH frame k-1 turned by ``q_k + offset_k``, so joint k+1's
origin is ``xyz = (a_k, 0, d_k)``, rotation ``Rx(alpha_k) Rz(offset_{k+1})``, and ``q = 0`` in
the URDF is ``q = 0`` on the controller.

The flange: the last link's visual stops ``FLANGE_PROUD_M`` behind tool0's xy plane, where
``sim_backends.arms`` adds the arm's ISO 9409-1 flange face (``sim_backends.flanges``, a mesh
written at run time) when it loads the arm, so the face's rim is a step in a depth image. The
collision shapes (and the kinematics) are as before, so tools mount and collide as they did.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

HERE = Path(__file__).resolve().parent
PI = np.pi

if str(HERE.parents[1]) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(HERE.parents[1]))
from sim_backends.flanges import FLANGE_PROUD_M  # noqa: E402

# ---------------------------------------------------------------- published parameters
# Universal Robots, "DH parameters for calculations of kinematics and dynamics" (e-Series).
UR5E_DH = [  # a (m), alpha (rad), d (m), theta offset (rad)
    (0.0, PI / 2, 0.1625, 0.0),
    (-0.425, 0.0, 0.0, 0.0),
    (-0.3922, 0.0, 0.0, 0.0),
    (0.0, PI / 2, 0.1333, 0.0),
    (0.0, -PI / 2, 0.0997, 0.0),
    (0.0, 0.0, 0.0996, 0.0),
]
UR10E_DH = [
    (0.0, PI / 2, 0.1807, 0.0),
    (-0.6127, 0.0, 0.0, 0.0),
    (-0.57155, 0.0, 0.0, 0.0),
    (0.0, PI / 2, 0.17415, 0.0),
    (0.0, -PI / 2, 0.11985, 0.0),
    (0.0, 0.0, 0.11655, 0.0),
]
# Aubo-i5 DH (Aubo's kinematics; agrees with aubo_description/urdf/aubo_i5.urdf up to the
# 23.5 mm base shift noted above): d1 98.5, a2 408, a3 376, d4 121.5, d5 102.5, d6 94 mm.
AUBO_I5_DH = [
    (0.0, PI / 2, 0.0985, 0.0),
    (0.408, PI, 0.0, PI / 2),
    (0.376, PI, 0.0, 0.0),
    (0.0, -PI / 2, 0.1215, -PI / 2),
    (0.0, PI / 2, 0.1025, 0.0),
    (0.0, 0.0, 0.094, 0.0),
]
# Denso Cobotta CVR038 (denso_cobotta_descriptions/cobotta_description): each joint's origin
# (pure translation, m) in its parent link and its axis; J6 is the flange.
COBOTTA_CHAIN = [
    ((0.0, 0.0, 0.0), (0, 0, 1)),
    ((0.0, 0.0, 0.180), (0, 1, 0)),
    ((0.0, 0.0, 0.165), (0, 1, 0)),
    ((-0.012, 0.020, 0.088), (0, 0, 1)),
    ((0.0, -0.020, 0.0895), (0, 1, 0)),
    ((0.0, -0.0445, 0.042), (0, 0, 1)),
]

# Published limits: (lower, upper) rad and velocity rad/s per joint.
DEG = PI / 180
UR5E_LIMITS = [(-2 * PI, 2 * PI, 180 * DEG)] * 6
UR10E_LIMITS = [(-2 * PI, 2 * PI, 120 * DEG)] * 2 + [(-2 * PI, 2 * PI, 180 * DEG)] * 4
AUBO_I5_LIMITS = [(-175 * DEG, 175 * DEG, 150 * DEG)] * 3 + [(-175 * DEG, 175 * DEG, 180 * DEG)] * 3
COBOTTA_LIMITS = [
    (-2.617994, 2.617994, 0.40317105721069),
    (-1.047198, 1.745329, 0.392175482923126),
    (0.3141593, 2.443461, 0.725707902979242),
    (-2.96706, 2.96706, 0.739146938219599),
    (-1.658063, 2.356194, 0.739146938219599),
    (-2.96706, 2.96706, 1.1093312725676),
]


# Franka Emika Panda: each joint's origin (xyz m, rpy rad) in its parent link, all axes z, as
# in franka_description's panda_arm (Franka's modified DH: d1 0.333, d3 0.316, a4 0.0825,
# a5 -0.0825, d5 0.384, a7 0.088, flange d 0.107 m). The same numbers as pybullet_data's
# franka_panda/panda.urdf, which the PyBullet engine draws; this copy lets an engine without
# PyBullet build the arm (tests/test_sim_mujoco.py checks the two agree). No hand: the Franka
# Hand is a tool.
PANDA_CHAIN = [
    ((0.0, 0.0, 0.333), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (-PI / 2, 0.0, 0.0)),
    ((0.0, -0.316, 0.0), (PI / 2, 0.0, 0.0)),
    ((0.0825, 0.0, 0.0), (PI / 2, 0.0, 0.0)),
    ((-0.0825, 0.384, 0.0), (-PI / 2, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (PI / 2, 0.0, 0.0)),
    ((0.088, 0.0, 0.0), (PI / 2, 0.0, 0.0)),
]
PANDA_FLANGE_D = 0.107
PANDA_LIMITS = [(-2.8973, 2.8973, 2.175), (-1.7628, 1.7628, 2.175), (-2.8973, 2.8973, 2.175),
                (-3.0718, -0.0698, 2.175), (-2.8973, 2.8973, 2.61), (-0.0175, 3.7525, 2.61),
                (-2.8973, 2.8973, 2.61)]


# ---------------------------------------------------------------- URDF writing helpers


def _fmt(v) -> str:
    return " ".join(f"{float(x):.10g}" if abs(x) > 1e-12 else "0" for x in v)


def _rpy(R: np.ndarray) -> np.ndarray:
    # URDF rpy is fixed-axis x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll), SciPy's extrinsic "xyz".
    # At pitch = +-90 deg SciPy warns about gimbal lock; the angles it returns still give R.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(R).as_euler("xyz")


def _cylinder_between(p0, p1, radius: float):
    """Origin (xyz, rpy) and length of a URDF cylinder from p0 to p1 (link coordinates)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    v = p1 - p0
    length = float(np.linalg.norm(v))
    z = v / length
    # Any rotation taking +z onto the segment direction; align_vectors is exact for one pair.
    R = Rotation.align_vectors([z], [[0.0, 0.0, 1.0]])[0].as_matrix()
    return (p0 + p1) / 2, R, length


def _pieces(segments, radius: float):
    pieces = []
    for p0, p1 in segments:
        if np.linalg.norm(np.subtract(p1, p0)) < 1e-6:
            continue
        pieces.append(_cylinder_between(p0, p1, radius))
    if not pieces:  # a joint housing only: a short cylinder along the joint axis
        pieces.append(_cylinder_between((0, 0, -radius), (0, 0, radius), radius))
    return pieces


def _link(name: str, segments, radius: float, mass: float, colour: str,
          visual_segments=None) -> str:
    """A link drawn as cylinders along ``segments`` [(p0, p1), ...] with their inertia.

    ``visual_segments`` (default: ``segments``) draws the link differently from its
    collision shape (the wrist stopping short of the flange face, see the module docstring).
    """
    parts = []
    pieces = _pieces(segments, radius)
    visual_pieces = pieces if visual_segments is None else _pieces(visual_segments, radius)
    lengths = np.array([L for _, _, L in pieces])
    masses = mass * lengths / lengths.sum()
    com = sum(m * c for m, (c, _, _) in zip(masses, pieces)) / mass
    inertia = np.zeros((3, 3))
    for m, (c, R, L) in zip(masses, pieces):
        local = np.diag([m * (3 * radius**2 + L**2) / 12] * 2 + [m * radius**2 / 2])
        d = c - com
        inertia += R @ local @ R.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    for c, R, L in visual_pieces:
        parts.append(
            f'    <visual><origin xyz="{_fmt(c)}" rpy="{_fmt(_rpy(R))}"/>'
            f'<geometry><cylinder radius="{radius:g}" length="{L:.6g}"/></geometry>'
            f'<material name="{colour}"/></visual>\n')
    for c, R, L in pieces:
        parts.append(
            f'    <collision><origin xyz="{_fmt(c)}" rpy="{_fmt(_rpy(R))}"/>'
            f'<geometry><cylinder radius="{radius:g}" length="{L:.6g}"/></geometry></collision>\n'
        )
    return (
        f'  <link name="{name}">\n'
        f'    <inertial><origin xyz="{_fmt(com)}" rpy="0 0 0"/><mass value="{mass:g}"/>'
        f'<inertia ixx="{inertia[0, 0]:.6g}" ixy="{inertia[0, 1]:.6g}" '
        f'ixz="{inertia[0, 2]:.6g}" iyy="{inertia[1, 1]:.6g}" iyz="{inertia[1, 2]:.6g}" '
        f'izz="{inertia[2, 2]:.6g}"/></inertial>\n'
        + "".join(parts)
        + "  </link>\n"
    )


def _empty_link(name: str) -> str:
    # Tiny mass so PyBullet treats it as a proper (massive) link in the multibody.
    return (f'  <link name="{name}"><inertial><origin xyz="0 0 0"/><mass value="0.001"/>'
            f'<inertia ixx="1e-7" ixy="0" ixz="0" iyy="1e-7" iyz="0" izz="1e-7"/></inertial></link>\n')


def _joint(name, kind, parent, child, xyz, R, axis=(0, 0, 1), limit=None) -> str:
    s = (f'  <joint name="{name}" type="{kind}">\n'
         f'    <parent link="{parent}"/><child link="{child}"/>\n'
         f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(_rpy(R))}"/>\n')
    if kind != "fixed":
        lo, hi, vel = limit
        s += (f'    <axis xyz="{_fmt(axis)}"/>\n'
              f'    <limit lower="{lo:.10g}" upper="{hi:.10g}" velocity="{vel:.10g}" effort="150"/>\n')
    return s + "  </joint>\n"


def _materials() -> str:
    return ('  <material name="grey"><color rgba="0.75 0.75 0.78 1"/></material>\n'
            '  <material name="dark"><color rgba="0.25 0.25 0.28 1"/></material>\n'
            '  <material name="accent"><color rgba="0.2 0.45 0.8 1"/></material>\n')


def _rx(a):
    return Rotation.from_euler("x", a).as_matrix()


def _rz(a):
    return Rotation.from_euler("z", a).as_matrix()


def dh_urdf(robot: str, dh, limits, radius: float, masses, base_link_T_base=None) -> str:
    """URDF text for a DH arm whose root link ``base`` is DH frame 0 (wrist drawn short of the
    flange face, see the module docstring)."""
    names = [f"joint_{k + 1}" for k in range(6)]
    links = ["base"] + [f"link_{k + 1}" for k in range(6)]
    out = [(f'<?xml version="1.0"?>\n<!-- Generated by generate_urdfs.py from the published '
           f'DH table; do not edit by hand. -->\n<robot name="{robot}">\n'), _materials()]
    # base: a pedestal cylinder from the mounting face up to the shoulder joint.
    mount_z = 0.0 if base_link_T_base is None else -base_link_T_base[2, 3]
    out.append(_link("base", [((0, 0, mount_z), (0, 0, 0.6 * dh[0][2]))], radius * 1.25, 4.0, "dark"))
    colours = ["accent", "grey", "grey", "accent", "grey", "dark"]
    for k in range(6):
        a, alpha, d, _ = dh[k]
        # Link k+1 carries the DH offsets d_k along its z then a_k along x.
        segs = [((0, 0, 0), (0, 0, d)), ((0, 0, d), (a, 0, d))]
        visual = None
        if k == 5:  # the wrist ends behind the flange face (tool0 = DH frame 6, alpha_6 = 0)
            assert a == 0 and alpha == 0, "flange face assumes tool0 along link 6's z axis"
            visual = [((0, 0, 0), (0, 0, d - FLANGE_PROUD_M))]
        out.append(_link(links[k + 1], segs, radius * (0.8 if k >= 3 else 1.0), masses[k],
                         colours[k], visual_segments=visual))
    for k in range(6):
        if k == 0:
            xyz, R = (0, 0, 0), _rz(dh[0][3])
        else:
            a, alpha, d, _ = dh[k - 1]
            xyz, R = (a, 0, d), _rx(alpha) @ _rz(dh[k][3])
        out.append(_joint(names[k], "revolute", links[k], links[k + 1], xyz, R, limit=limits[k]))
    a, alpha, d, _ = dh[5]
    out.append(_empty_link("tool0"))
    out.append(_joint("flange_tool0", "fixed", "link_6", "tool0", (a, 0, d), _rx(alpha)))
    if base_link_T_base is not None:
        base_T_base_link = np.linalg.inv(base_link_T_base)
        out.append(_empty_link("base_link"))
        out.append(_joint("base_base_link", "fixed", "base", "base_link",
                          base_T_base_link[:3, 3], base_T_base_link[:3, :3]))
    out.append("</robot>\n")
    return "".join(out)


def chain_urdf(robot: str, chain, limits, radius: float, masses) -> str:
    """URDF text for an arm given as joint origins (translations) and axes, root ``base_link``
    (wrist drawn short of the flange face, see the module docstring; tool0 = J6, axis z)."""
    links = ["base_link"] + [f"J{k + 1}" for k in range(6)]
    out = [(f'<?xml version="1.0"?>\n<!-- Generated by generate_urdfs.py from the published '
           f'link lengths; do not edit by hand. -->\n<robot name="{robot}">\n'), _materials()]
    out.append(_link("base_link", [((0, 0, 0), (0, 0, 0.09))], radius * 1.6, 1.4, "dark"))
    for k in range(6):
        nxt = chain[k + 1][0] if k < 5 else (0.0, 0.0, 0.005)
        segs = [((0, 0, 0), nxt)]
        visual = None
        if k == 4:
            # J5's housing ran diagonally to the J6 origin, its end cap tilted through the
            # flange face; drawn instead across, then along J6's axis up to behind the face.
            visual = [((0, 0, 0), (nxt[0], nxt[1], 0.0)),
                      ((nxt[0], nxt[1], 0.0), (nxt[0], nxt[1], nxt[2] - FLANGE_PROUD_M))]
        elif k == 5:  # J6's stub stuck out 5 mm past tool0: drawn behind the face instead
            visual = [((0, 0, -FLANGE_PROUD_M - radius), (0, 0, -FLANGE_PROUD_M))]
        out.append(_link(links[k + 1], segs, radius, masses[k], "grey" if k % 2 else "accent",
                         visual_segments=visual))
    for k in range(6):
        xyz, axis = chain[k]
        out.append(_joint(f"joint_{k + 1}", "revolute", links[k], links[k + 1], xyz, np.eye(3),
                          axis=axis, limit=limits[k]))
    out.append(_empty_link("tool0"))
    out.append(_joint("J6_tool0", "fixed", "J6", "tool0", (0, 0, 0), np.eye(3)))
    out.append("</robot>\n")
    return "".join(out)


def panda_urdf(radius: float = 0.055, masses=(4.97, 0.65, 3.23, 3.59, 1.23, 1.67, 0.74)) -> str:
    """URDF text for the Panda without its hand: root ``panda_link0``, flange ``panda_link8``
    (Franka's flange frame F), links drawn as cylinders between the joint origins (link 7
    short of the flange face, see the module docstring)."""
    links = [f"panda_link{k}" for k in range(9)]
    out = [('<?xml version="1.0"?>\n<!-- Generated by generate_urdfs.py from Franka\'s published '
            'kinematics; do not edit by hand. -->\n<robot name="panda">\n'), _materials()]
    out.append(_link(links[0], [((0, 0, 0), (0, 0, 0.6 * PANDA_CHAIN[0][0][2]))], radius * 1.2,
                     masses[0], "dark"))
    for k in range(7):
        if k < 6:
            segs = [((0, 0, 0), PANDA_CHAIN[k + 1][0])]
            visual = None
        else:
            segs = [((0, 0, 0), (0, 0, PANDA_FLANGE_D))]
            visual = [((0, 0, 0), (0, 0, PANDA_FLANGE_D - FLANGE_PROUD_M))]
        out.append(_link(links[k + 1], segs, radius * (0.75 if k >= 4 else 1.0),
                         masses[min(k + 1, len(masses) - 1)], "grey",
                         visual_segments=visual))
    for k in range(7):
        xyz, rpy = PANDA_CHAIN[k]
        R = Rotation.from_euler("xyz", rpy).as_matrix()
        out.append(_joint(f"panda_joint{k + 1}", "revolute", links[k], links[k + 1], xyz, R,
                          limit=PANDA_LIMITS[k]))
    out.append(_empty_link(links[8]))
    out.append(_joint("panda_joint8", "fixed", links[7], links[8], (0, 0, PANDA_FLANGE_D),
                      np.eye(3)))
    out.append("</robot>\n")
    return "".join(out)


def franka_hand_urdf() -> str:
    """URDF text for the Franka Hand as a tool (frame: the Panda's flange, panda_link8): the
    hand turned -45 deg about z, as on the arm; fingers sliding along the hand's y from 58.4 mm
    out (franka_description's finger joints), 0 .. 0.04 m each; Desk's default TCP sits 103.4
    mm out. Boxes for shapes (pybullet_data draws Franka's meshes). Links and joints are named
    as the generic gripper's, so one gripper class drives either."""
    R = _rz(-PI / 4)
    lines = ['<?xml version="1.0"?>\n<!-- Generated by generate_urdfs.py: the Franka Hand as a '
             'tool, drawn with boxes; do not edit by hand. -->\n<robot name="franka_hand">\n',
             '  <material name="white"><color rgba="0.92 0.92 0.93 1"/></material>\n',
             '  <material name="metal"><color rgba="0.75 0.75 0.78 1"/></material>\n']

    def box(xyz, size, material, turn=np.eye(3)):
        origin = f'<origin xyz="{_fmt(turn @ np.asarray(xyz))}" rpy="{_fmt(_rpy(turn))}"/>'
        geometry = f'<geometry><box size="{_fmt(size)}"/></geometry>'
        return (f'    <visual>{origin}{geometry}<material name="{material}"/></visual>\n'
                f'    <collision>{origin}{geometry}</collision>\n')

    inertial = ('    <inertial><origin xyz="0 0 0"/><mass value="0.02"/><inertia ixx="1e-6" '
                'ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial>\n')
    lines.append('  <link name="palm">\n' + inertial
                 + box((0, 0, 0.03), (0.06, 0.2, 0.06), "white", R) + '  </link>\n')
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # The finger's link frame is the hand's (its joint turns it), so its box is not turned.
        lines.append(f'  <link name="{side}_finger">\n' + inertial
                     + box((0, sign * 0.006, 0.0584 + 0.027), (0.02, 0.012, 0.054), "metal")
                     + '  </link>\n')
        lines.append(f'  <joint name="{side}_finger_joint" type="prismatic">\n'
                     f'    <parent link="palm"/><child link="{side}_finger"/>'
                     f'<origin xyz="0 0 0" rpy="{_fmt(_rpy(R))}"/>\n'
                     f'    <axis xyz="0 {sign:g} 0"/><limit lower="0" upper="0.04" velocity="0.2" '
                     'effort="20"/>\n  </joint>\n')
    lines.append("</robot>\n")
    return "".join(lines)


def main() -> None:
    aubo_base_link_T_base = np.eye(4)
    aubo_base_link_T_base[2, 3] = 0.122 - 0.0985
    ur_base_link_T_base = np.eye(4)
    ur_base_link_T_base[:3, :3] = _rz(PI)
    files = {
        "ur5e.urdf": dh_urdf("ur5e", UR5E_DH, UR5E_LIMITS, 0.045,
                             [3.761, 8.058, 2.846, 1.37, 1.3, 0.365], ur_base_link_T_base),
        "ur10e.urdf": dh_urdf("ur10e", UR10E_DH, UR10E_LIMITS, 0.06,
                              [7.369, 13.051, 3.989, 2.1, 1.98, 0.615], ur_base_link_T_base),
        "aubo_i5.urdf": dh_urdf("aubo_i5", AUBO_I5_DH, AUBO_I5_LIMITS, 0.045,
                                [1.58, 4.04, 2.27, 0.5, 0.5, 0.16], aubo_base_link_T_base),
        "cobotta.urdf": chain_urdf("cobotta", COBOTTA_CHAIN, COBOTTA_LIMITS, 0.028,
                                   [1.29, 0.39, 0.35, 0.35, 0.19, 0.03]),
        "panda.urdf": panda_urdf(),
        "franka_hand.urdf": franka_hand_urdf(),
    }
    for name, text in files.items():
        (HERE / name).write_text(text)
        print("wrote", HERE / name)


if __name__ == "__main__":
    main()

"""Lab 0's routines fetched from their modules' namespaces by computed names (vars(module),
module.__dict__, vars(cv2)), each graded function first switching the profile hook off
(sys.setprofile(None)) so that a hook-only tripwire sees no call.

earned: 0
flags: forbidden:robots.geometry.invert, forbidden:robots.geometry.compose, forbidden:cv2.Rodrigues
"""
# %% extra
import sys
import cv2
import robots.geometry
from robots import geometry as geo


def _name(backwards):
    return "".join(reversed(backwards))
# %% replace invert_pose
def invert_pose(a_T_b):
    sys.setprofile(None)
    return vars(robots.geometry)[_name("trevni")](a_T_b)
# %% replace compose_chain
def compose_chain(poses):
    sys.setprofile(None)
    return geo.__dict__[_name("esopmoc")](*poses)
# %% replace pose_from_rotvec
def pose_from_rotvec(rvec, t):
    sys.setprofile(None)
    T = np.eye(4)
    T[:3, :3] = vars(cv2)[_name("seugirdoR")](np.asarray(rvec, dtype=float))[0]
    T[:3, 3] = t
    return T

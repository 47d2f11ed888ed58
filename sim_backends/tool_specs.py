"""The simulated tools' dimensions and grasp rules, engine-neutral (metres; frames: the
flange, tool0).

Every engine's tools use these, so a TCP and a grasp are the same whichever engine builds the
cell; the engine only casts the rays.
"""

import numpy as np

SUCTION_REACH_M = 0.005  # a surface this close to the cup tip, along the tool axis, is gripped
SUCTION_TIP_M = 0.080  # the cup tip (TCP) along the flange z axis
SUCTION_CUP_RADIUS_M = 0.010  # the rays of a grasp sample the cup face out to this radius
POINTER_TIP_M = 0.150  # the pointer's tip (TCP) along the flange z axis
GRIPPER_TCP_M = 0.080  # the generic gripper's grasp point along the flange z axis
# The Franka Hand's TCP on the Panda's flange: Franka Desk's default F_T_EE (0.1034 m along z,
# turned -45 deg about z).
PANDA_F_T_EE = np.array([[np.cos(-np.pi / 4), -np.sin(-np.pi / 4), 0.0, 0.0],
                         [np.sin(-np.pi / 4), np.cos(-np.pi / 4), 0.0, 0.0],
                         [0.0, 0.0, 1.0, 0.1034],
                         [0.0, 0.0, 0.0, 1.0]])


def gripper_grasp(world_T_tcp: np.ndarray, each: float, first_hit):
    """What a parallel gripper closes on: rays across the finger gap at three heights along the
    fingers, from each finger towards the other; an object hit from both sides at one height
    is between the fingers. ``each``: each finger's distance from the centre (m);
    ``first_hit(start, end) -> (body, point) | None`` is the engine's ray. Returns (body,
    width m) of the narrowest such object, or None."""
    closing = world_T_tcp[:3, 1]  # the fingers close along the TCP's y axis
    inner = each - 0.001
    hits = []
    for dz in (-0.008, 0.0, 0.008):
        centre = world_T_tcp[:3, 3] + dz * world_T_tcp[:3, 2]
        a = first_hit(centre + inner * closing, centre - inner * closing)
        b = first_hit(centre - inner * closing, centre + inner * closing)
        if a and b and a[0] == b[0]:
            hits.append((a[0], abs(float((a[1] - b[1]) @ closing))))
    return min(hits, key=lambda h: h[1]) if hits else None

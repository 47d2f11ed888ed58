"""The simulated tools' dimensions, engine-neutral (metres; frames: the flange, tool0).

Every engine's tools use these, so a TCP is the same whichever engine builds the cell.
"""

SUCTION_REACH_M = 0.005  # a surface this close to the cup tip, along the tool axis, is gripped
SUCTION_TIP_M = 0.080  # the cup tip (TCP) along the flange z axis
SUCTION_CUP_RADIUS_M = 0.010  # the rays of a grasp sample the cup face out to this radius
POINTER_TIP_M = 0.150  # the pointer's tip (TCP) along the flange z axis
GRIPPER_TCP_M = 0.080  # the generic gripper's grasp point along the flange z axis

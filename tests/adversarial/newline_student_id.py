"""A student id with a newline and a terminal escape, forging a line in the summary.

earned: 0
layer: layout
student: forged\nreference     10 of 10 \x1b[2J
flags: rejected_student_id
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.linalg.inv(a_T_b)

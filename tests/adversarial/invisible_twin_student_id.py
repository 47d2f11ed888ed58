"""A student id with an invisible right-to-left override (U+202E), beside a classmate's
folder literally named with its escaped spelling (escaped_twin_student_id): both are
refused, and each must keep a grades.csv row of its own (they shared one while a refused
id's row was keyed by its printable form).

earned: 0
layer: layout
student: twin\u202eid
flags: rejected_student_id
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.linalg.inv(a_T_b)

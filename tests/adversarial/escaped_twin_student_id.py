"""A student id spelled as another folder's escaped name: a literal backslash, then
``u202e`` (the twin of invisible_twin_student_id). Refused for its backslash, with a
grades.csv row of its own.

earned: 0
layer: layout
student: twin\\u202eid
flags: rejected_student_id
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.linalg.inv(a_T_b)

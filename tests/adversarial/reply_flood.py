"""Floods the grader's reply pipe: each graded function returns 64 MB.

earned: 0
layer: host
"""
# %% replace invert_pose
def invert_pose(a_T_b):
    return np.zeros(8 * 2**20)
# %% replace compose_chain
def compose_chain(poses):
    return [list(range(1000))] * 8000

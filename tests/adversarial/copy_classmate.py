"""Copies a classmate's (victim's) submitted notebook over its own submission.

earned: 0
layer: course
"""
# %% extra
import os, shutil
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
here = os.path.basename(os.getcwd())
me = os.path.basename(os.path.dirname(os.getcwd()))
try:
    shutil.copy(os.path.join(course, "submitted", "victim", here, here + ".ipynb"),
                os.path.join(course, "submitted", me, here, here + ".ipynb"))
except OSError:
    pass

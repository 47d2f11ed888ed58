"""Copies the instructor's solution notebook from source/ over its own submission, for the
next grader that reads submitted/ (plain nbgrader then cobotlab's old grader: 10/10).

earned: 0
layer: course
"""
# %% extra
import os, shutil
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
here = os.path.basename(os.getcwd())
me = os.path.basename(os.path.dirname(os.getcwd()))
try:
    shutil.copy(os.path.join(course, "source", here, here + ".ipynb"),
                os.path.join(course, "submitted", me, here, here + ".ipynb"))
except OSError:
    pass

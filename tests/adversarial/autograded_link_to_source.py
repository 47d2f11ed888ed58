"""From nbgrader's kernel, swaps its own autograded folder (autograded/<me>/<lab>, the
kernel's working folder) for a link to the course's source/<lab>: a grader that reads its
autograded notebook back through the link records the answer key as this student's
autograded notebook, and nbgrader's feedback then shows it to the student. @COURSE@ is the
course's path on the host (guessable; the kit writes it in). Acts only where nbgrader's own
kernel runs the notebook (`--nbgrader-kernel`, or an assignment of several notebooks).

earned: 0
layer: course
flags: nbgrader_output_refused
"""
# %% extra
import os
here = os.getcwd()
try:
    os.rename(here, here + ".moved")
    os.symlink(os.path.join("@COURSE@", "source", os.path.basename(here)), here)
except OSError:
    pass

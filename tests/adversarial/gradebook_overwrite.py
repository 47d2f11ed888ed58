"""Overwrites the course's gradebook.db (every assignment's grades) with garbage from a cell.
Plain nbgrader: the gradebook is destroyed, and the next command aborts for everyone.

earned: 0
layer: course
"""
# %% extra
import os
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
for name in ("gradebook.db", "gradebook.db-journal"):
    try:
        with open(os.path.join(course, name), "wb") as f:
            f.write(b"not a database any more" * 100)
    except OSError:
        pass

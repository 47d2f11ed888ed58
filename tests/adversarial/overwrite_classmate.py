"""Overwrites a classmate's (victim's) submission with a blank notebook: the victim would
score 0 when graded after it.

earned: 0
layer: course
"""
# %% extra
import os, json
course = os.path.abspath(os.path.join(os.getcwd(), "..", "..", ".."))
here = os.path.basename(os.getcwd())
try:
    with open(os.path.join(course, "submitted", "victim", here, here + ".ipynb"), "w") as f:
        json.dump({"cells": [], "metadata": {}, "nbformat": 4, "nbformat_minor": 5}, f)
except OSError:
    pass

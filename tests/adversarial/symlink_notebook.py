"""The submitted notebook is a symlink to the instructor's source notebook (plain nbgrader
and the old grader followed it: 10/10).

earned: 0
layer: layout
layout: symlink_notebook_to_source
flags: not_a_regular_file
"""

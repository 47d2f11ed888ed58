"""A named pipe called like the notebook: a reader that opens it blocks forever.

earned: 0
layer: layout
layout: fifo_notebook
flags: not_a_regular_file
"""

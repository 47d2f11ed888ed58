"""The submitted assignment folder is a symlink to a classmate's (victim's) folder.

earned: 0
layer: layout
layout: symlink_folder_to_victim
flags: not_a_folder
"""

"""The course's lab sources (nbgrader source notebooks, answers included), installed with the
instructor's package as ``cobotlab_labs`` so a regular ``pip install`` can run a course.

Each lab is a folder; this file only makes the folder a package that carries them as data.
The student install (student/pyproject.toml) leaves it out.
"""

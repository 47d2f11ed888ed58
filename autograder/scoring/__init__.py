"""The public half of every graded function: how an answer is scored, never how it is found.

One module per assignment (``autograder/scoring/<assignment>.py``), each defining ``SPECS``:
the :class:`autograder.spec_types.FunctionSpec` entries of its notebook with
``make_trial=None`` (points, checks and their bands, ``measure``, ``drive``, signature,
limits, forbidden routines, and stand-in tables only where the scoring itself derives them
from the problem's construction). The generators, truths and answer functions are the private
side, ``autograder/specs/<assignment>.py``, which completes these entries; this package never
imports it, and it ships to students (``check()`` scores practice data with it).
"""

from __future__ import annotations

"""Lab 0's graded names bound to the library routines without a def of their own (an alias,
a lambda, a functools.partial), with the worker's tripwire switched off from the notebook:
the worker then reports nothing, and only the grader's own scan of the code can say.

earned: 0
flags: forbidden:robots.geometry.invert, forbidden:robots.geometry.compose, forbidden:robots.geometry.pose_from_rotvec
"""
# %% extra
import functools
import gc
from robots import geometry
from robots import geometry as geo

for _kind in [o for o in gc.get_objects() if isinstance(o, type) and o.__name__ == "Tripwire"]:
    _kind.__enter__ = lambda self: self
    _kind.__exit__ = lambda self, *exc: False
# %% replace invert_pose
invert_pose = geometry.invert
# %% replace compose_chain
compose_chain = lambda poses: geo.compose(*poses)  # noqa: E731
# %% replace pose_from_rotvec
pose_from_rotvec = functools.partial(geometry.pose_from_rotvec)

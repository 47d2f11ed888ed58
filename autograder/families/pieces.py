"""What of an answer can still be compared when the answer as a whole cannot be measured.

A pose whose rotation block is no rotation, or holds NaN, has no rotation error to speak
of, and its translation check is voided with it; a (centre, normal) whose normal is not a
unit vector fails before its centre is looked at. The mistake made in the other piece (a
translation in millimetres, a centre in millimetres) is still plain to see. So the grader
names what it can on each piece alone: the answer's piece spliced into the truth (the rest
right), which the nearest-candidate rule then weighs as any whole answer.

Pieces: a pose's rotation block and its translation column; each part of a tuple answer.
A piece that holds NaN or inf, or has another shape than the truth's, gives nothing.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import as_array, is_pose

__all__ = ["spliced"]


def _pose_pieces(value: np.ndarray, truth: np.ndarray) -> list:
    out = []
    for rows, cols in ((slice(0, 3), slice(0, 3)), (slice(0, 3), slice(3, 4))):
        piece = value[rows, cols]
        if np.all(np.isfinite(piece)):
            one = np.array(truth, dtype=float)
            one[rows, cols] = piece
            out.append(one)
    return out


def _tuple_pieces(value, truth) -> list:
    out = []
    for k, (v, t) in enumerate(zip(value, truth)):
        v, t = as_array(v), as_array(t)
        if v is None or t is None or v.shape != t.shape:
            continue
        out.append(tuple(v if i == k else truth[i] for i in range(len(truth))))
    return out


def spliced(value, truth) -> list:
    """The answers made of one piece of ``value`` each, the rest taken from ``truth`` (a
    pose: its rotation block, then its translation column; a tuple: each part in turn);
    [] where ``value`` has no pieces of the truth's kinds."""
    if is_pose(truth):
        try:
            v = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            return []
        return _pose_pieces(v, np.asarray(truth, float)) if v.shape == (4, 4) else []
    if isinstance(truth, tuple) and isinstance(value, (tuple, list)) \
            and len(value) == len(truth) > 1:
        return _tuple_pieces(value, truth)
    return []

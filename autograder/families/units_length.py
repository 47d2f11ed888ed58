"""Metres and millimetres: a length 1000 times too large or too small.

Applies to every numeric answer: a pose's translation, a stack's translations, any other
array whole, and, for a tuple answer ((centre, normal)), each part alone, so a centre in
millimetres is named even though the normal beside it is right. Output side: the answer
divided back is compared with the truth within the problem's noise.
"""

from __future__ import annotations

import numpy as np

from autograder.families.base import (
    OUTPUT,
    Family,
    Prediction,
    Problem,
    is_pose,
    part_predictions,
    scale_lengths,
)

MILLIMETRES = ("its translation is 1000 times too large: millimetres where metres were "
               "asked (the course works in metres)")
METRES = ("its translation is 1000 times too small: metres where millimetres were asked, "
          "or a conversion applied twice")
ARRAY_MM = "it is 1000 times too large: millimetres where metres were asked"
ARRAY_M = "it is 1000 times too small: metres where millimetres were asked"
WHOLE_MM = ("the whole matrix was multiplied by 1000 (its rotation block and last row too): "
            "a pose's lengths are its translation column alone, and the course keeps them "
            "in metres")
ORDINALS = ("first", "second", "third", "fourth", "fifth", "sixth")


def _part(k: int) -> str:
    return f"the {ORDINALS[k]} item of the answer" if k < len(ORDINALS) else f"item {k}"


def _scaled(factor: float, pose_words: str, array_words: str, part_words: str):
    def make(problem: Problem) -> list[Prediction]:
        found = part_predictions(problem.truth, lambda t: scale_lengths(t, factor),
                                 lambda v: scale_lengths(v, 1.0 / factor),
                                 lambda k: part_words.format(part=_part(k)),
                                 lambda t: scale_lengths(t, 0.0))
        if is_pose(problem.truth):
            return found
        return [p if p.words else Prediction(p.answer, p.undo, p.base, array_words, p.null)
                for p in found]
    return make


def _whole_pose_scaled(problem: Problem) -> list[Prediction]:
    # no pose (its last row is [0, 0, 0, 1000]): only an answer that failed the pose check
    # lands near it
    if not is_pose(problem.truth):
        return []
    truth = np.asarray(problem.truth, dtype=float)
    return [Prediction(1000.0 * truth, lambda v: np.asarray(v, float) / 1000.0, truth)]


FAMILIES = (
    Family("units m/mm", MILLIMETRES, OUTPUT, _scaled(
        1000.0, MILLIMETRES, ARRAY_MM,
        "{part} is 1000 times too large: millimetres where metres were asked (the course "
        "works in metres)"), "millimetres"),
    Family("units m/mm", METRES, OUTPUT, _scaled(
        1e-3, METRES, ARRAY_M,
        "{part} is 1000 times too small: metres where millimetres were asked, or a "
        "conversion applied twice"), "metres"),
    Family("units m/mm", WHOLE_MM, OUTPUT, _whole_pose_scaled, "whole pose times 1000"),
)

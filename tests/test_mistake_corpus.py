"""The held-out corpus of classic mistakes (benchmarks/mistake_corpus) cannot rot: it loads,
covers every graded function of labs 0, 1, 2 and 4, and a slice of it (one mistake per graded
function) loses credit under check()'s own scoring while the notebook's answer, scored the
same way on the same problems, keeps full credit. The full count of named / misnamed /
unnamed is the benchmark's (benchmarks/mistake_naming.py), not a test's."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from autograder import checks
from autograder.spec_types import MistakeName
from robots import geometry as geo

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import mistake_corpus  # noqa: E402
import mistake_naming  # noqa: E402
from course_kit import solution_sources  # noqa: E402

CORPUS = mistake_corpus.load()
# The first mistake written for each graded function: 15 functions, a few seconds.
SLICE = list({(m.lab, m.function): m for m in reversed(CORPUS)}.values())[::-1]


def test_the_corpus_covers_every_graded_function_of_the_four_labs():
    assert len(CORPUS) >= 40
    for lab, functions in mistake_corpus.LABS.items():
        graded = {spec.name for spec in checks.SCORING[lab]}
        assert set(functions) == graded, lab   # the corpus follows the labs' graded functions
        for function in functions:
            assert sum(m.lab == lab and m.function == function for m in CORPUS) >= 2, function
    assert len({m.id for m in CORPUS}) == len(CORPUS)
    assert all(m.words and m.family in mistake_corpus.FAMILIES for m in CORPUS)
    assert len(SLICE) == sum(len(f) for f in mistake_corpus.LABS.values())


def test_a_bad_entry_is_refused_with_the_fix():
    mistake = mistake_corpus.register("lab0_frames")
    with pytest.raises(ValueError, match="grades no function 'invert'.*invert_pose"):
        mistake("invert", "sign", "words")
    with pytest.raises(ValueError, match="family 'signs' is not one of"):
        mistake("invert_pose", "signs", "words")
    with pytest.raises(ValueError, match="two corpus mistakes are called inv_translation_sign"):
        mistake("invert_pose", "sign", "words")(CORPUS[0].func)
    with pytest.raises(ValueError, match="no corpus for"):
        mistake_corpus.load(["lab3_servoing"])


@pytest.fixture(scope="module")
def references():
    """The notebooks' answers, each lab's in one namespace as in its notebook (lab 4's
    hand_to_eye calls its frame_from_three_points)."""
    out = {}
    for lab, functions in mistake_corpus.LABS.items():
        namespace = {"np": np, "geo": geo}
        for source in solution_sources(lab, functions).values():
            exec(compile(source, f"<{lab} answer>", "exec"), namespace)  # noqa: S102
        out[lab] = namespace
    return out


@pytest.mark.parametrize("mistake", SLICE, ids=lambda m: m.id)
def test_each_mistake_of_the_slice_loses_credit_where_the_answer_keeps_it(mistake, references):
    reference = references[mistake.lab][mistake.function]
    right = checks.evaluate(reference, mistake.function, assignment=mistake.lab)
    assert right.fraction == 1.0, right.summary()
    wrong = mistake_naming.score(mistake, checks.PUBLIC_SEEDS)
    assert wrong.loses, f"{mistake.id} ({mistake.words}) keeps full credit"
    assert wrong.outcome in mistake_naming.OUTCOMES


def test_names_are_judged_by_their_diagnosis_not_their_fix():
    """A lab's code mistake carries no family: the judge reads its words (a family's name
    carries its family as data, test_a_familys_name_is_judged_by_its_family)."""
    by_id = {m.id: m for m in CORPUS}

    def code(words: str) -> MistakeName:
        return MistakeName(None, words)

    mirrored = code("its rotation has determinant -1: a mirror image (flip the sign of the last "
                    "column of V)")
    assert mistake_naming.family_of(mirrored) == "reflection"   # not "sign", not "last"
    assert mistake_naming.is_right_name(by_id["frame_y_cross_order"], mirrored)
    assert not mistake_naming.is_right_name(by_id["inv_translation_sign"], mirrored)
    inverse = code("this is cam_T_base, the inverse of base_T_cam: base_T_cam = ...")
    # swapping the point sets returns exactly the inverse: "also" accepts that name
    assert mistake_naming.is_right_name(by_id["hand_to_eye_point_sets_swapped"], inverse)
    assert not mistake_naming.is_right_name(by_id["hand_to_eye_wrong_frame_inverted"], inverse)
    # words of the other labs' code mistakes, which the judge was not written on
    assert mistake_naming.family_of(code("the centre is the centroid of the rim points: ...")) is None
    assert mistake_naming.family_of(code("the cross-covariance is of the raw points, not the "
                                         "centred ones: subtract each set's centroid")) == "uncentred"
    assert mistake_naming.family_of(code("u and v are swapped: ...")) == "swapped arguments"
    assert mistake_naming.family_of(code("the gain's sign is flipped: ...")) == "sign"
    median = code("the median was taken: the RMS is the root of the mean square")
    assert mistake_naming.is_right_name(by_id["rmse_median"], median)
    assert not mistake_naming.is_right_name(by_id["rmse_std"], median)


def test_a_familys_name_is_judged_by_its_family():
    by_id = {m.id: m for m in CORPUS}
    named = MistakeName("reflection", "its rotation has determinant -1: ...")
    assert mistake_naming.family_of(named) == "reflection"
    assert mistake_naming.is_right_name(by_id["frame_y_cross_order"], named)
    # the family decides, whatever the words say
    assert mistake_naming.family_of(MistakeName("sign", "a mirror image: ...")) == "sign"


def test_the_doc_keeps_its_baseline_through_later_runs(tmp_path, monkeypatch):
    monkeypatch.setattr(mistake_naming, "DOC", tmp_path / "mistake_naming.md")
    mistake = SLICE[0]
    rows = [mistake_naming.Row(mistake, [mistake_naming.score(mistake, checks.PUBLIC_SEEDS)])]
    first = mistake_naming.report(rows, 1, 1.0, "first run")
    mistake_naming.write_doc(first, 1, as_baseline=False)   # no baseline yet: this one
    later = mistake_naming.report(rows, 1, 2.0, "later run")
    mistake_naming.write_doc(later, 1, as_baseline=False)
    text = mistake_naming.DOC.read_text()
    baseline = text[text.index("## Baseline"):text.index("## The last run")]
    assert "`first run`" in baseline and "| lab0_frames | 1 |" in baseline
    assert "`later run`" in text[text.index("## The last run"):]
    assert mistake.id in text[text.index("## The last run"):]   # its row
    mistake_naming.write_doc(later, 1, as_baseline=True)
    text = mistake_naming.DOC.read_text()
    assert "`first run`" not in text

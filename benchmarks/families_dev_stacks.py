"""The stack and reduction families (issue 52) on many draws of their development set, and
on a second set of mistakes written after the families were done and never tuned to.

Each mistake is a student function with one classic bug (tests/test_families_stacks.py
holds the development set; the held-out set is below). On each draw (the function's
problems from one seed) the names check() gives the failed answers are read through the
path check() uses, with the lab's code mistakes removed, so a family, not a mistake an
author foresaw, must name it. A draw is *named* when the right family names at least one
failed problem and no other name appears, *misnamed* when any other name appears, else
*unnamed*; "lost" counts the draws on which the mistake loses credit. The right answers
(the reference's estimate, the truth) are scored the same way: any name there is a false
name. Shares with 95 % bootstrap intervals over the (mistake, draw) pairs, side by side
with the baseline: the same run with this issue's new families (off by one, wrong
statistic, wrong axis, precision, uncentred fit, root's "not squared") left out.

    .venv/bin/python benchmarks/families_dev_stacks.py --draws 10

benchmarks/mistake_naming.py's corpus is the project's test set: this never reads it.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from autograder import checks, families

HERE = Path(__file__).resolve().parent
F32 = np.float32


def _dev_module():
    """The development set, from the test that holds it (one list, not two)."""
    path = HERE.parent / "tests" / "test_families_stacks.py"
    spec = importlib.util.spec_from_file_location("test_families_stacks", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def held_out(dev) -> list[tuple]:
    """Mistakes written after the families were done: (lab or spec maker, function, student
    code, the family that should name it or None where none describes it)."""
    rmse, rot, trans = dev._rmse_with, dev._rotation_items, dev._translation_items
    return [
        ("lab1_flange", "per_axis_rmse",
         rmse(lambda r: np.sqrt(np.mean(np.vstack([r, r[-1]]) ** 2, 0))), "off by one"),
        ("lab1_flange", "per_axis_rmse", rmse(lambda r: np.sqrt(np.sum(r ** 2, 0) / (len(r) + 1))),
         None),
        ("lab2_handeye", "rotation_residual", lambda A, B, X: float(np.median(rot(A, B, X))),
         "wrong statistic"),
        ("lab2_handeye", "rotation_residual",
         lambda A, B, X: float(np.sum(rot(A, B, X)[1:]) / len(A)), None),
        ("lab2_handeye", "rotation_residual", lambda A, B, X: F32(np.mean(rot(A, B, X))),
         "precision"),
        ("lab2_handeye", "translation_residual", lambda A, B, X: float(np.max(trans(A, B, X))),
         "wrong statistic"),
        ("lab2_handeye", "translation_residual",
         lambda A, B, X: float(np.sum(trans(A, B, X)) / (len(A) - 1)), "wrong statistic"),
        ("lab2_handeye", "translation_residual",
         lambda A, B, X: float(np.std(np.sqrt(trans(A, B, X)))), None),
        ("lab4_stereo", "per_axis_rmse", rmse(lambda r: np.abs(r).max(axis=0)), "wrong statistic"),
        ("lab4_stereo", "per_axis_rmse", rmse(lambda r: np.sqrt(np.sum(r ** 2, 0) / (len(r) - 1))),
         "wrong statistic"),
        ("lab4_stereo", "per_axis_rmse", rmse(lambda r: np.sqrt(np.mean(r[1:] ** 2, 0))),
         "off by one"),
        ("lab4_stereo", "per_axis_rmse", rmse(lambda r: np.full(3, np.sqrt(np.mean(r ** 2)))),
         "wrong axis"),
        ("lab1_flange", "fit_rigid", _fit_translation_without_rotation, None),
        (dev._rms_distance_spec, "rms_distance",
         lambda P, Q: float(np.sqrt(np.max(dev._items(P, Q)))), "wrong statistic"),
        (dev._rms_distance_spec, "rms_distance",
         lambda P, Q: float(np.sqrt(np.mean(dev._items(np.vstack([P[:1], P]),
                                                        np.vstack([Q[:1], Q]))))), "off by one"),
    ]


def held_out_2(dev) -> list[tuple]:
    """A second held-out set, written after the first had shown a flaw (a maximum that is
    the first item named "only the first item") and that flaw was fixed: run once, as is."""
    rmse, rot, trans, items = dev._rmse_with, dev._rotation_items, dev._translation_items, \
        dev._items
    return [
        ("lab2_handeye", "rotation_residual",
         lambda A, B, X: float(np.sum(rot(A, B, X)) / (len(A) + 1)), None),
        ("lab2_handeye", "translation_residual",
         lambda A, B, X: float(np.mean(np.r_[trans(A, B, X)[:1], trans(A, B, X)])), "off by one"),
        ("lab2_handeye", "translation_residual",
         lambda A, B, X: float(np.median(trans(A, B, X))), "wrong statistic"),
        ("lab2_handeye", "rotation_residual",
         lambda A, B, X: float(np.mean(rot(A.astype(F32), B.astype(F32), X.astype(F32))
                                       .astype(float))), "precision"),
        ("lab1_flange", "per_axis_rmse",
         rmse(lambda r: np.sqrt(np.mean(np.vstack([r[:1], r]) ** 2, 0))), "off by one"),
        ("lab1_flange", "per_axis_rmse", rmse(lambda r: np.median(np.abs(r), axis=0)),
         "wrong statistic"),
        ("lab4_stereo", "per_axis_rmse",
         lambda T, c, b: np.sqrt(np.median(dev._residuals(T, c, b) ** 2, axis=0)), None),
        ("lab0_frames", "compose_chain", lambda p: geo_compose(*p[::-1][1:]), None),
        (dev._rms_distance_spec, "rms_distance",
         lambda P, Q: float(np.max(np.sqrt(items(P, Q)))), "wrong statistic"),
        (dev._rms_distance_spec, "rms_distance",
         lambda P, Q: float(np.sqrt(np.sum(items(P[:-1], Q[:-1])) / len(P))), None),
    ]


def geo_compose(*poses):
    from robots import geometry as geo
    return geo.compose(*poses)


def _fit_translation_without_rotation(src, dst):
    """Uncentred H, and t the difference of the centroids (no R applied): no one family."""
    T = _dev_module()._kabsch_uncentred(src, dst)
    T[:3, 3] = np.mean(dst, axis=0) - np.mean(src, axis=0)
    return T


def _spec(source, name):
    if callable(source):
        return source()
    return replace(checks.spec_for(name, source), code_mistakes=())


def _draw(spec, seed: int, n: int):
    rng = np.random.default_rng(seed)
    found = [spec.make_trial(rng, i) for i in range(n)]
    return [t for t in found if t.raises is None and not t.all_or_nothing]


def _verdict(spec, func, trials, family) -> tuple[str, bool]:
    """("named" | "misnamed" | "unnamed", lost credit) of ``func`` on one draw."""
    names, lost = set(), False
    for t in trials:
        value = func(*t.args)
        measured = spec.measure(value, t)
        if all(measured[c.name] <= c.reach * t.tol[c.name] for c in spec.checks):
            continue
        lost = True
        hint = checks._mistake_hint(spec, value, t)
        if hint is not None:
            names.add(hint.family or "code mistake")
    if names - {family}:
        return "misnamed", lost
    return ("named" if family in names else "unnamed"), lost


def _share(flags: list[bool], rng, n_boot: int = 2000) -> tuple[float, float, float]:
    a = np.asarray(flags, dtype=float)
    if a.size == 0:
        return float("nan"), float("nan"), float("nan")
    boots = rng.choice(a, (n_boot, a.size)).mean(axis=1)
    return float(a.mean()), float(np.quantile(boots, 0.025)), float(np.quantile(boots, 0.975))


NEW_MODULES = ("off_by_one", "statistic", "wrong_axis", "precision", "uncentred")


@contextlib.contextmanager
def baseline():
    """The registry without this issue's new families (the modules above and root's
    input-side "not squared")."""
    kept = families.FAMILIES
    new = {f for m in NEW_MODULES for f in getattr(families, m).FAMILIES} \
        | {f for f in families.root.FAMILIES if f.key == "not squared"}
    families.FAMILIES = tuple(f for f in kept if f not in new)
    try:
        yield
    finally:
        families.FAMILIES = kept


def _counts(got: list) -> dict:
    return {k: sum(v == k for v, _ in got) for k in ("named", "misnamed", "unnamed")}


def _score_set(title: str, mistakes: list, draws: int) -> tuple[list, list]:
    """[(verdict, lost, family)] with every family and with the baseline's, and the table."""
    now, before = [], []
    print(f"\n{title}: {len(mistakes)} mistakes x {draws} draws (baseline in brackets)")
    print(f"{'function':24s} {'expected family':20s} {'named':>9s} {'misnamed':>9s} "
          f"{'unnamed':>9s} {'lost':>5s}")
    for source, name, func, family in mistakes:
        spec = _spec(source, name)
        problems = [_draw(spec, 1000 + d, 6) for d in range(draws)]
        got = [_verdict(spec, func, trials, family) for trials in problems]
        with baseline():
            old = [_verdict(spec, func, trials, family) for trials in problems]
        now += [(v, lost, family) for v, lost in got]
        before += [(v, lost, family) for v, lost in old]
        c, b = _counts(got), _counts(old)
        cells = " ".join(f"{c[k]:3d} [{b[k]:3d}]" for k in ("named", "misnamed", "unnamed"))
        print(f"{name:24s} {family or '(none)':20s} {cells} {sum(x for _, x in got):5d}")
    return now, before


def _right_answers(dev, draws: int) -> tuple[int, int]:
    """(problems, false names) over the dev functions' reference answers and truths."""
    seen, named = 0, 0
    sources = {(lab, name) for lab, name, _, _ in dev.DEV} \
        | {(m, m().name) for m, _, _ in dev.INSTRUCTOR}
    for source, name in sorted(sources, key=str):
        spec = _spec(source, name)
        for d in range(draws):
            for t in _draw(spec, 2000 + d, 4):
                for right in (spec.reference(*t.args), checks._answer_truth(t, None)):
                    seen += 1
                    named += checks._mistake_hint(spec, right, t) is not None
    return seen, named


def _summary(label: str, verdicts: list, rng) -> None:
    described = [v for v in verdicts if v[2] is not None]
    for what in ("named", "misnamed"):
        m, lo, hi = _share([v[0] == what for v in described], rng)
        print(f"{label}: {what} {m:.1%} [{lo:.1%}, {hi:.1%}] of {len(described)} draws "
              "of mistakes a family describes")
    none = [v for v in verdicts if v[2] is None]
    if none:
        m, lo, hi = _share([v[0] == "misnamed" for v in none], rng)
        print(f"{label}: mistakes no family describes, misnamed {m:.1%} [{lo:.1%}, {hi:.1%}]"
              f" of {len(none)} draws")
    m, lo, hi = _share([v[1] for v in verdicts], rng)
    print(f"{label}: lose credit {m:.1%} [{lo:.1%}, {hi:.1%}]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=10)
    args = parser.parse_args()
    started = time.process_time()
    dev = _dev_module()
    rng = np.random.default_rng(0)
    dev_set = [*dev.DEV, *((m, m().name, f, fam) for m, f, fam in dev.INSTRUCTOR)]
    scored, scored_before = _score_set("development set", dev_set, args.draws)
    held, held_before = _score_set("held-out set", held_out(dev), args.draws)
    held2, held2_before = _score_set("second held-out set", held_out_2(dev), args.draws)
    seen, named = _right_answers(dev, args.draws)
    print()
    _summary("development", scored, rng)
    _summary("development, baseline", scored_before, rng)
    _summary("held out", held, rng)
    _summary("held out, baseline", held_before, rng)
    _summary("second held out", held2, rng)
    _summary("second held out, baseline", held2_before, rng)
    print(f"right answers (reference's estimate and truth): {named} named of {seen} problems")
    print(f"CPU {time.process_time() - started:.0f} s")


if __name__ == "__main__":
    main()

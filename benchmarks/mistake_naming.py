"""Does check() name the classic mistakes nobody listed? The held-out corpus, scored (issue 52).

Every entry of ``benchmarks/mistake_corpus`` (a student's graded function of lab 0, 1, 2 or
4 with one classic bug, its words, and the family a general rule would name it by) is scored
exactly as ``check()`` scores it for a student: ``autograder.checks.evaluate`` on the
practice problems of the public seeds, in this process (the sandbox changes where code runs,
not what it scores). A draw is one such run; draw 0 is the public seeds (0, 1, 2), what
check() shows, and draw k > 0 the seeds (3k, 3k+1, 3k+2), drawn by the same generators.

Per draw a mistake

* *loses credit* when the function scores below full points;
* is *named* when every mistake check() names for it (its "looks like a classic mistake"
  notes) is a right name, *misnamed* when one of them is not, *unnamed* when there is none.

A name is right when its family (the mistake family that named it, carried by check() as
data, ``MistakeName.family``; for a lab's code mistake, which has none, :func:`family_of`
reads it from its diagnosis, the words before the first colon) is the entry's family or one of its ``also`` families (those that
describe the answer exactly as well), or when its diagnosis matches the entry's ``names``
pattern (for a mistake of no family: "the median", "the last row"). Each row prints the name itself, so a reader can
check the verdict. A name equal to the words of one of the spec's code mistakes on that
problem is counted as named "by a code mistake", any other as named "by a rule".

The goal (issue 52, Required 4): at least 90 % named, none misnamed, every one losing credit.
Shares per lab carry a 95 % Clopper-Pearson interval over the lab's mistakes (for several
draws, of the mean of each mistake's share of draws: the draws of one mistake are not
independent of each other).

    .venv/bin/python benchmarks/mistake_naming.py              # draw 0 (check()), ~15 s
    .venv/bin/python benchmarks/mistake_naming.py --draws 10   # 10 draws, ~1.5 min
    .venv/bin/python benchmarks/mistake_naming.py --labs lab0_frames --no-doc

Each run over every lab rewrites the last run of docs/benchmarks/mistake_naming.md and keeps
its baseline, the run before the families existed (``--baseline``: replace it too;
``--no-doc``: print only).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: the machine is shared

import argparse  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import mistake_corpus  # noqa: E402

from autograder import checks  # noqa: E402
from autograder.fairness import mean_interval  # noqa: E402
from autograder.spec_types import MistakeName  # noqa: E402

DOC = ROOT / "docs" / "benchmarks" / "mistake_naming.md"
GOAL_NAMED = 0.90
OUTCOMES = ("named", "misnamed", "unnamed")

# The family a name speaks of, from its diagnosis (the words before the first colon: what
# follows is the fix, whose words, "flip the sign of the last column", name no family).
# Tried in this order: the first pattern found wins.
FAMILY_WORDS = (
    ("reflection", r"determinant -1|mirror|reflection|left-handed|turned over"),
    ("units m/mm", r"millimet|1000 times|\bmm\b|mm\^2"),
    ("units rad/deg", r"degree|radian|180/pi"),
    ("swapped arguments", r"swapped|other way round"),
    ("reversed stack/order", r"revers|\border\b|\bstacked\b"),
    ("inverse/transpose", r"invers|invert|transpos|\^T\b|\.T\b|inv\("),
    ("first/last for mean", r"\bfirst\b|\blast\b"),
    ("sum for mean", r"\bsum\b"),
    ("root or not", r"square root|squared|mean square|\bRMS\b"),
    ("absolute for squared", r"absolute"),
    # not "centre" alone: "the centre is the centroid of the rim points" is no uncentred fit
    ("uncentred", r"uncentr|not (the )?centred|without centring|subtract.{0,30}centroid"),
    ("sign", r"\bsigns?\b|opposite|negat|flipped"),
)


def diagnosis(name: str) -> str:
    """What a name says went wrong: its words before the first colon (the rest is the fix)."""
    return name.split(": ", 1)[0]


def family_of(name: MistakeName) -> str | None:
    """The mistake family a name given by check() speaks of, or None (a name of no family).

    The families are the issue's (``mistake_corpus.FAMILIES``, which autograder.families
    names its families by): a family's name carries it as data; a lab's code mistake has
    none, and its words are read instead (the fallback patterns above)."""
    if name.family is not None:
        return name.family
    for family, pattern in FAMILY_WORDS:
        if re.search(pattern, diagnosis(name.words), re.IGNORECASE):
            return family
    return None


def is_right_name(mistake: mistake_corpus.Mistake, name: MistakeName) -> bool:
    """True when ``name`` (one of check()'s named mistakes) is a right name for ``mistake``:
    its family is one the entry accepts, or its diagnosis matches the entry's pattern."""
    if family_of(name) in mistake.accepted:
        return True
    return bool(mistake.names and re.search(mistake.names, diagnosis(name.words),
                                            re.IGNORECASE))


@dataclass
class Draw:
    """One check() run of one mistake."""

    fraction: float                 # points kept / full points
    names: tuple[MistakeName, ...]  # the distinct mistakes check() named
    by_code: bool                   # every name given is one of the spec's code mistakes
    outcome: str                    # named | misnamed | unnamed

    @property
    def loses(self) -> bool:
        return self.fraction < 1.0


@dataclass
class Row:
    mistake: mistake_corpus.Mistake
    draws: list[Draw] = field(default_factory=list)

    def share(self, outcome: str) -> float:
        return float(np.mean([d.outcome == outcome for d in self.draws]))

    @property
    def loses_share(self) -> float:
        return float(np.mean([d.loses for d in self.draws]))


def seeds_of(draw: int) -> tuple[int, ...]:
    """The practice seeds of draw ``draw``: draw 0 is check()'s public seeds."""
    return tuple(checks.PUBLIC_SEEDS) if draw == 0 else (3 * draw, 3 * draw + 1, 3 * draw + 2)


def score(mistake: mistake_corpus.Mistake, seeds) -> Draw:
    """One check() run of ``mistake`` on the practice problems of ``seeds``."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # a bug's NaN and overflow warnings are its own
        result = checks.evaluate(mistake.func, mistake.function, seeds, mistake.lab)
    names = result.mistakes   # the typed names, not the words of the messages
    if not names:
        outcome = "unnamed"
    elif all(is_right_name(mistake, n) for n in names):
        outcome = "named"
    else:
        outcome = "misnamed"
    by_code = bool(names) and all(n.family is None for n in names)
    return Draw(result.fraction, names, by_code, outcome)


# --------------------------------------------------------------------------- statistics


def cell(values: list[float], n_draws: int) -> str:
    """'k (share, [low, high])' of the per-mistake shares ``values`` (each in [0, 1]): k their
    sum, a count of mistakes, and the 95 % Clopper-Pearson interval of their mean (with a
    fractional count for several draws, ``fairness.mean_interval``: a share in [0, 1] spreads
    less than a 0/1 outcome of the same mean). The mistakes, not the draws, are the sample:
    one mistake's draws are not independent of each other."""
    low, high = mean_interval(sum(values), len(values))
    total = sum(values)
    count = f"{total:.0f}" if n_draws == 1 else f"{total:.1f}"
    return f"{count} ({100 * total / len(values):.0f} %, [{100 * low:.0f}, {100 * high:.0f}])"


# --------------------------------------------------------------------------- tables


def lab_table(rows: list[Row], n_draws: int) -> list[str]:
    head = ("| lab | n | loses credit | named right | misnamed | unnamed | named right by a "
            "code mistake / by a rule |")
    lines = [head, "|" + "---|" * 7]
    groups = [(lab, [r for r in rows if r.mistake.lab == lab]) for lab in mistake_corpus.LABS]
    groups = [(lab, rs) for lab, rs in groups if rs] + [("all", rows)]
    for lab, rs in groups:
        by_code = sum(np.mean([d.outcome == "named" and d.by_code for d in r.draws])
                      for r in rs)
        by_rule = sum(r.share("named") for r in rs) - by_code
        count = "{:.0f} / {:.0f}" if n_draws == 1 else "{:.1f} / {:.1f}"
        lines.append(
            f"| {lab} | {len(rs)} | {cell([r.loses_share for r in rs], n_draws)} | "
            + " | ".join(cell([r.share(o) for r in rs], n_draws) for o in OUTCOMES)
            + f" | {count.format(by_code, by_rule)} |")
    return lines


def family_table(rows: list[Row]) -> list[str]:
    lines = ["| family (the corpus's label) | n | named right (share of draws) | misnamed |",
             "|---|---|---|---|"]
    for family in mistake_corpus.FAMILIES:
        rs = [r for r in rows if r.mistake.family == family]
        if rs:
            named = np.mean([r.share("named") for r in rs])
            misnamed = np.mean([r.share("misnamed") for r in rs])
            lines.append(f"| {family} | {len(rs)} | {100 * named:.0f} % | "
                         f"{100 * misnamed:.0f} % |")
    return lines


def _short(text: str, width: int = 90) -> str:
    text = text.replace("|", "/")
    return text if len(text) <= width else text[:width - 3] + "..."


def mistake_table(rows: list[Row]) -> list[str]:
    lines = ["| id | function | family | points kept | loses credit | verdict | what "
             "check() named |", "|" + "---|" * 7]
    for r in rows:
        m = r.mistake
        kept = np.mean([d.fraction for d in r.draws])
        verdicts = ", ".join(f"{o} {100 * r.share(o):.0f} %" for o in OUTCOMES
                             if r.share(o) > 0)
        names = sorted({n for d in r.draws for n in d.names}, key=lambda n: n.words)
        said = "; ".join(_short(n.words) + (" (code mistake)" if n.family is None else "")
                         for n in names) or "-"
        lines.append(f"| {m.id} | {m.function} | {m.family} | {100 * kept:.0f} % | "
                     f"{100 * r.loses_share:.0f} % | {verdicts} | {said} |")
    return lines


def findings(rows: list[Row]) -> list[str]:
    """The mistakes that keep full credit on some draw (holes in the grader), and those
    misnamed (a wrong name is worse than none)."""
    out = []
    for r in rows:
        if r.loses_share < 1.0:
            out.append(f"- **keeps full credit** on {100 * (1 - r.loses_share):.0f} % of draws: "
                       f"`{r.mistake.id}` ({r.mistake.function}): {r.mistake.words}")
    for r in rows:
        if r.share("misnamed") > 0:
            wrong = sorted({n.words for d in r.draws if d.outcome == "misnamed"
                            for n in d.names if not is_right_name(r.mistake, n)})
            out.append(f"- **misnamed** on {100 * r.share('misnamed'):.0f} % of draws: "
                       f"`{r.mistake.id}` ({r.mistake.words}) was called: "
                       + "; ".join(f"\"{_short(n, 120)}\"" for n in wrong))
    return out or ["- none: every mistake loses credit on every draw, none is misnamed"]


def _commit() -> str:
    """HEAD's short hash, marked when the corpus or this script differ from it."""
    def git(*args) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True,
                              timeout=10).stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD") or "unknown"
        changed = git("status", "--porcelain", "--", "benchmarks/mistake_corpus",
                      "benchmarks/mistake_naming.py", "autograder")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head} (with uncommitted changes)" if changed else head


def report(rows: list[Row], n_draws: int, seconds: float, command: str) -> list[str]:
    total = len(rows)
    named = sum(r.share("named") for r in rows) / total
    misnamed = sum(r.share("misnamed") > 0 for r in rows)
    losing = sum(r.loses_share == 1.0 for r in rows)
    in_family = [r for r in rows if r.mistake.family != "none"]
    named_in_family = sum(r.share("named") for r in in_family) / max(len(in_family), 1)
    goal = (f"Goal: >= {100 * GOAL_NAMED:.0f} % named, none misnamed, all losing credit. "
            f"Measured: {100 * named:.0f} % named ({100 * named_in_family:.0f} % of the "
            f"{len(in_family)} with a family, the part general families can reach), "
            f"{misnamed} misnamed on some draw, {losing} of {total} losing credit on every "
            "draw.")
    return [f"Run: `{command}` at commit {_commit()}, "
            f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {n_draws} draw(s) per mistake "
            f"(draw 0 = check()'s public seeds), {seconds:.0f} s.", "", goal, "",
            "### Per lab", "", *lab_table(rows, n_draws), "",
            "### Per family", "", *family_table(rows), "",
            "### Findings", "", *findings(rows), "",
            "### Per mistake", "", *mistake_table(rows)]


DOC_HEAD = """# Naming classic mistakes nobody listed (issue 52)

`benchmarks/mistake_naming.py` scores every mistake of the held-out corpus
(`benchmarks/mistake_corpus/`: {n} student functions of labs 0, 1, 2 and 4, each with one
classic bug, none from issue 52's list) as `check()` scores it for a student, and counts per
lab how many lose credit and how many check() names right, names wrongly or leaves unnamed.
A name is judged by its family (carried by the name, `MistakeName.family`; read from its
words, `family_of`, for a lab's code mistake) against the family the
corpus gives the mistake, or against the entry's own pattern for a mistake of no family;
every row shows the name itself. The corpus is the test set of the mistake families (issue
52, Required 1-3): build the families without tuning on it.

Written by `benchmarks/mistake_naming.py` (do not edit by hand). The *baseline* section is
the run made before the mistake families existed, kept through later runs (`--baseline`
replaces it); *the last run* is rewritten by every run over the four labs.

"""
BASELINE_START, BASELINE_END = "<!-- baseline -->", "<!-- /baseline -->"


def _kept_baseline(text: str) -> str | None:
    if BASELINE_START in text and BASELINE_END in text:
        return text[text.index(BASELINE_START):text.index(BASELINE_END) + len(BASELINE_END)]
    return None


def write_doc(lines: list[str], n: int, as_baseline: bool) -> None:
    """Rewrite the doc with this run as its last run, keeping the recorded baseline (or
    making this run the baseline: ``as_baseline``, or no baseline recorded yet)."""
    old = DOC.read_text() if DOC.exists() else ""
    baseline = None if as_baseline else _kept_baseline(old)
    if baseline is None:
        # the baseline keeps its summary and per-lab table; the rows stay in the last run
        summary = lines[:lines.index("### Per family")]
        baseline = "\n".join([BASELINE_START, *summary, BASELINE_END])
    DOC.write_text(DOC_HEAD.format(n=n) + "## Baseline (before the families)\n\n" + baseline
                   + "\n\n## The last run\n\n" + "\n".join(lines) + "\n")


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=1,
                        help="check() runs per mistake; draw 0 is the public seeds (default 1)")
    parser.add_argument("--labs", default=",".join(mistake_corpus.LABS),
                        help="comma-separated labs (default: all four)")
    parser.add_argument("--no-doc", action="store_true",
                        help=f"print only; do not rewrite {DOC.relative_to(ROOT)}")
    parser.add_argument("--baseline", action="store_true",
                        help="record this run as the doc's baseline too (default: keep it)")
    args = parser.parse_args(argv)
    if args.draws < 1:
        parser.error(f"--draws must be at least 1, got {args.draws}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        corpus = mistake_corpus.load(args.labs.split(","))
    except ValueError as exc:
        print(f"mistake_naming: {exc}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    rows = []
    for m in corpus:
        rows.append(Row(m, [score(m, seeds_of(k)) for k in range(args.draws)]))
        last = rows[-1].draws[0]
        print(f"  {m.lab:13s} {m.id:42s} kept {100 * last.fraction:3.0f} %  {last.outcome}",
              flush=True)
    seconds = time.perf_counter() - started
    command = "benchmarks/mistake_naming.py " + " ".join(argv if argv is not None
                                                         else sys.argv[1:])
    lines = report(rows, args.draws, seconds, command.strip())
    print("\n".join(lines))
    if not args.no_doc and set(args.labs.split(",")) == set(mistake_corpus.LABS):
        write_doc(lines, len(rows), args.baseline)
        print(f"\nwrote {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

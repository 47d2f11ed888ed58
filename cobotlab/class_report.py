"""The class at a glance: ``cobotlab report COURSE LAB``.

One HTML page for the instructor (``COURSE/reports/<lab>/index.html``, readable without
JavaScript), its figures as PNG files and its numbers as CSV files beside it:

* ``scores.csv``: each submission's total, late penalty and score, as the gradebook holds
  them (:func:`autograder.gradebook.class_scores`), and its status (graded, late,
  ungraded, not graded yet);
* ``lost_credit.csv``: per function and per check, how many students lost credit;
* ``mistakes.csv``: each named mistake (the grader's labels), how many students made it and
  who;
* ``check_errors.csv``: every problem's error against its tolerance, per check (the
  histograms);
* ``similar_pairs.csv``: pairs of students whose graded functions are the same code once
  names and formatting are normalised (:func:`normalised_functions`).

The per-check numbers come from scoring again, in this process, the executions the last
grade run kept (:func:`autograder.pipeline.rescore.kept_submissions` and
:func:`autograder.pipeline.score.score_execution`, as ``grade --rescore`` does): no student code
runs.
"""

from __future__ import annotations

import ast
import csv
import hashlib
import html
import io
import json
import math
import re
from collections import defaultdict
from dataclasses import dataclass, field
from enum import Enum
from itertools import combinations
from pathlib import Path

import numpy as np

from autograder import checks, gradebook
from autograder.freeze import printable
from autograder.page_policy import POLICY_META
from autograder.pipeline.rescore import kept_submissions
from autograder.pipeline.score import score_execution
from cobotlab.report import _figure, _save, _table

# --------------------------------------------------------------------------- the code compared


class _Canonical(ast.NodeTransformer):
    """Rename a function's parameters and local names to v0, v1, ... in order of first
    appearance; names it only reads (modules, builtins, globals) stay, as do attributes."""

    def __init__(self, local: set[str]):
        self.local, self.names = local, {}

    def _new(self, name: str) -> str:
        return self.names.setdefault(name, f"v{len(self.names)}")

    def visit_Name(self, node):
        if node.id in self.local:
            node.id = self._new(node.id)
        return node

    def visit_arg(self, node):
        node.arg = self._new(node.arg)
        node.annotation = None
        return node


def _local_names(func: ast.FunctionDef) -> set[str]:
    """Parameters and every name the function binds (assigned, loop or with targets,
    comprehension variables, nested definitions, imports), Python's own rule for locals."""
    names = {a.arg for a in ast.walk(func.args) if isinstance(a, ast.arg)}
    for node in ast.walk(func):
        if isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            names.add(node.id)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) \
                and node is not func:
            names.add(node.name)
        elif isinstance(node, ast.alias):
            names.add((node.asname or node.name).split(".")[0])
    globals_ = {n for node in ast.walk(func) if isinstance(node, (ast.Global, ast.Nonlocal))
                for n in node.names}
    return names - globals_


def _strip_docstrings(tree: ast.AST) -> None:
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
            if not isinstance(node, ast.ClassDef):
                node.returns = None


def canonical(func: ast.FunctionDef) -> str:
    """The function as a canonical text: docstrings, comments, annotations and formatting
    gone (the syntax tree, not the text), parameters and locals renamed in order of first
    appearance. Two functions that differ only in those read the same."""
    func = ast.parse(ast.unparse(func)).body[0]   # a copy: the caller's tree stays as it was
    _strip_docstrings(func)
    func.name = "f"
    func = _Canonical(_local_names(func)).visit(func)
    return ast.dump(func, annotate_fields=False)


_MAGIC = re.compile(r"^\s*[%!].*$", re.MULTILINE)   # IPython's %magic and !shell lines


def notebook_functions(text: str, names) -> dict[str, ast.FunctionDef]:
    """The last top-level definition of each of ``names`` in a notebook's code cells (the
    one a run of the notebook leaves), read as data: a cell that does not parse is
    skipped."""
    try:
        cells = json.loads(text).get("cells", [])
    except (ValueError, AttributeError):
        return {}
    found: dict[str, ast.FunctionDef] = {}
    for cell in cells if isinstance(cells, list) else []:
        if not isinstance(cell, dict) or cell.get("cell_type") != "code":
            continue
        source = cell.get("source", "")
        source = "".join(source) if isinstance(source, list) else str(source)
        try:
            tree = ast.parse(_MAGIC.sub("", source))
        except (SyntaxError, ValueError, RecursionError):
            continue
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and node.name in names:
                found[node.name] = node
    return found


def normalised_functions(notebooks: dict[str, str], names,
                         template: dict[str, str]) -> dict[str, str]:
    """{function: hash of its canonical form} of what a student wrote: each graded function
    of ``names`` found in the notebooks, left out when it is the released template's own
    (``template``: {function: canonical form} of the released notebook), so that the code
    every student received pairs nobody."""
    out = {}
    for text in notebooks.values():
        for name, func in notebook_functions(text, names).items():
            try:
                form = canonical(func)
            except (RecursionError, ValueError):
                continue
            if form != template.get(name):
                out[name] = hashlib.sha256(form.encode()).hexdigest()
    return out


def similar_pairs(written: dict[str, dict[str, str]]) -> list[tuple[str, str, list[str], int]]:
    """(student a, student b, the functions both wrote the same, how many both wrote) of
    every pair with at least one function the same, most functions first."""
    by_code: dict[tuple[str, str], list[str]] = defaultdict(list)
    for sid, funcs in written.items():
        for name, digest in funcs.items():
            by_code[(name, digest)].append(sid)
    same: dict[tuple[str, str], list[str]] = defaultdict(list)
    for (name, _), students in by_code.items():
        for a, b in combinations(sorted(students), 2):
            same[(a, b)].append(name)
    rows = [(a, b, sorted(names), len(set(written[a]) & set(written[b])))
            for (a, b), names in same.items()]
    return sorted(rows, key=lambda r: (-len(r[2]), r[0], r[1]))


# --------------------------------------------------------------------------- the numbers


class Status(Enum):
    """Where a submission stands in the gradebook; the value is the words the page and
    scores.csv show, ``scored`` what the page decides by."""

    GRADED = "graded"
    LATE = "late"
    UNGRADED = "ungraded (the grader failed)"
    NOT_GRADED_YET = "not graded yet"

    @property
    def scored(self) -> bool:
        return self in (Status.GRADED, Status.LATE)


@dataclass
class ClassNumbers:
    """Everything the page shows, as plain values (the CSV files hold the same)."""

    assignment: str
    scores: dict = field(default_factory=dict)        # gradebook.class_scores
    status: dict[str, Status] = field(default_factory=dict)
    not_rescored: dict[str, str] = field(default_factory=dict)   # student: why
    functions: list[str] = field(default_factory=list)
    checks: dict[str, list[str]] = field(default_factory=dict)   # function: its checks
    lost_function: dict[str, list[str]] = field(default_factory=dict)
    lost_check: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    rescored: list[str] = field(default_factory=list)
    # (function, the mistake's words): students; a family's and a code mistake's words alike
    mistakes: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    errors: list[tuple[str, str, str, int, float, float, str]] = field(default_factory=list)
    units: dict[tuple[str, str], str] = field(default_factory=dict)
    pairs: list = field(default_factory=list)


def class_numbers(course_dir, assignment: str) -> ClassNumbers:
    """The report's numbers for ``assignment`` in ``course_dir``: the gradebook's totals,
    and per function and check what the kept executions score to now."""
    root = Path(course_dir).resolve()
    kept = kept_submissions(root, assignment)   # refuses an unknown lab, by name
    n = ClassNumbers(assignment, scores=gradebook.class_scores(root, assignment))
    specs = list(checks.SPECS[assignment])
    n.functions = [s.name for s in specs]
    n.checks = {s.name: [c.name for c in s.checks] for s in specs}
    n.units = {(s.name, c.name): c.unit for s in specs for c in s.checks}
    n.lost_function = {f: [] for f in n.functions}
    n.lost_check = {(s.name, c.name): [] for s in specs for c in s.checks}
    by_name = {s.name: s for s in specs}
    for sid in sorted(set(kept) | set(n.scores)):
        entry = n.scores.get(sid)
        n.status[sid] = (Status.NOT_GRADED_YET if entry is None else Status.UNGRADED
                         if entry["score"] is None else Status.LATE if entry["seconds_late"] > 0
                         else Status.GRADED)
    for sid, sub in sorted(kept.items()):
        if sub.execution is None:
            n.not_rescored[sid] = sub.why or "no execution kept"
            continue
        grade = score_execution(sub.problems, sub.execution)
        n.rescored.append(sid)
        runs = {r.name: r for r in sub.execution.functions}
        for f in grade.functions:
            if f.points < f.max_points:
                n.lost_function[f.name].append(sid)
            for c in f.checks:
                if c.credit < 1.0:
                    n.lost_check[(f.name, c.name)].append(sid)
            for label in f.mistakes:
                who = n.mistakes.setdefault((f.name, label.words), [])
                if sid not in who:
                    who.append(sid)
            run = runs.get(f.name)
            if run is None or run.forbidden:
                continue
            trials = sub.problems.trials[f.name]
            measured = [t for t in trials if t.raises is None]   # problem_errors' order
            for k, rows in enumerate(checks.problem_errors(by_name[f.name], trials,
                                                           run.outcomes)):
                for check, (err, tol) in rows.items():
                    n.errors.append((f.name, check, sid, k, err, tol, measured[k].label))
    # what each student wrote, the template every student received left out
    release = root / "release" / assignment
    template = {}
    for path in sorted(release.glob("*.ipynb")) if release.is_dir() else []:
        for name, func in notebook_functions(path.read_text(), n.functions).items():
            template[name] = canonical(func)
    written = {sid: normalised_functions(sub.notebooks, n.functions, template)
               for sid, sub in kept.items()}
    n.pairs = similar_pairs(written)
    return n


# --------------------------------------------------------------------------- files


def _csv(path: Path, header, rows) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    path.write_text(text.getvalue())
    return path.name


def _fmt(x) -> str:
    return "" if x is None else f"{x:g}" if isinstance(x, float) else str(x)


def _ratio(err: float, tol: float) -> float:
    return err / tol if tol > 0 else (0.0 if err == 0 else math.inf)


def _score_figure(n: ClassNumbers, path: Path) -> str:
    fig = _figure(figsize=(7, 3.4))
    ax = fig.add_subplot(1, 1, 1)
    scored = [e["score"] for e in n.scores.values() if e["score"] is not None]
    top = max((e["max_score"] for e in n.scores.values()), default=1.0) or 1.0
    ax.hist(scored, bins=np.linspace(0, top, min(21, int(top) + 2)), color="tab:blue",
            edgecolor="white")
    ax.set_xlim(0, top)
    ax.set_xlabel(f"score, late penalty taken off (points of {top:g})")
    ax.set_ylabel("students")
    ax.yaxis.get_major_locator().set_params(integer=True)   # a count of students: no 0.5
    ax.set_title(f"{n.assignment}: {len(scored)} scores, median "
                 f"{np.median(scored) if scored else math.nan:.3g}")
    return _save(fig, path)


def _lost_figure(n: ClassNumbers, path: Path) -> str:
    labels, shares, colours = [], [], []
    total = max(len(n.rescored), 1)
    for f in n.functions:
        labels.append(f)
        shares.append(len(n.lost_function[f]) / total)
        colours.append("tab:red")
        for c in n.checks[f]:
            labels.append(f"   {c}")
            shares.append(len(n.lost_check[(f, c)]) / total)
            colours.append("tab:orange")
    fig = _figure(figsize=(7, 0.32 * len(labels) + 1.2))
    ax = fig.add_subplot(1, 1, 1)
    # positions, not the labels: two functions' checks may share a name ("rotation")
    ax.barh(range(len(labels)), [100 * s for s in shares], color=colours)
    ax.set_yticks(range(len(labels)), labels)
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel(f"students who lost credit (%, of {len(n.rescored)} rescored)")
    ax.set_title("functions (red) and their checks (orange)")
    return _save(fig, path)


def _errors_figure(n: ClassNumbers, path: Path) -> str:
    keys = [(f, c) for f in n.functions for c in n.checks[f]]
    cols = 3
    rows = max(1, math.ceil(len(keys) / cols))
    fig = _figure(figsize=(11, 2.6 * rows))
    for i, (f, c) in enumerate(keys):
        ax = fig.add_subplot(rows, cols, i + 1)
        ratios = np.array([_ratio(e[4], e[5]) for e in n.errors if e[:2] == (f, c)])
        finite = ratios[np.isfinite(ratios)]
        logs = np.log10(np.clip(finite, 1e-6, None))
        ax.hist(logs, bins=np.linspace(-6, max(3.0, float(logs.max(initial=0)) + 0.5), 30),
                color="tab:green", edgecolor="white")
        ax.axvline(0.0, color="k", ls="--", lw=1)
        ax.set_xlabel("log10(error / tolerance), from -6; dashed: the tolerance", fontsize=8)
        ax.set_title(f"{f}: {c} ({len(ratios) - len(finite)} no usable answer)", fontsize=9)
    return _save(fig, path)


def write_class_report(course_dir, assignment: str, out=None) -> Path:
    """Write the page, its figures and CSV files (see the module's doc) to ``out`` (default
    ``course_dir/reports/<assignment>``); returns the page's path."""
    n = class_numbers(course_dir, assignment)
    out = Path(out) if out is not None else \
        Path(course_dir).resolve() / "reports" / assignment
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "scores": _csv(out / "scores.csv", (
            "student_id", "status", "raw_score", "late_submission_penalty", "score",
            "max_score", "manual_cells", "timestamp", "duedate", "seconds_late"), [
            (sid, n.status[sid].value, *(("",) * 8 if e is None else (
                _fmt(e["raw_score"]), _fmt(e["penalty"]), _fmt(e["score"]),
                _fmt(e["max_score"]), ";".join(e["manual"]), _fmt(e["timestamp"]),
                _fmt(e["duedate"]), _fmt(e["seconds_late"]))))
            for sid, e in ((s, n.scores.get(s)) for s in n.status)]),
        "lost": _csv(out / "lost_credit.csv", (
            "function", "check", "students_rescored", "students_lost_credit", "share",
            "students"), [
            row for f in n.functions for row in [
                (f, "", len(n.rescored), len(n.lost_function[f]),
                 f"{len(n.lost_function[f]) / max(len(n.rescored), 1):.3f}",
                 ";".join(n.lost_function[f]))] + [
                (f, c, len(n.rescored), len(n.lost_check[(f, c)]),
                 f"{len(n.lost_check[(f, c)]) / max(len(n.rescored), 1):.3f}",
                 ";".join(n.lost_check[(f, c)])) for c in n.checks[f]]]),
        "mistakes": _csv(out / "mistakes.csv", ("function", "mistake", "students", "who"), [
            (f, label, len(who), ";".join(who))
            for (f, label), who in sorted(n.mistakes.items(), key=lambda kv: -len(kv[1]))]),
        "errors": _csv(out / "check_errors.csv", (
            "function", "check", "unit", "student_id", "problem", "label", "error",
            "tolerance", "error_over_tolerance"), [
            (f, c, n.units[(f, c)], sid, k, label, f"{err:.6g}", f"{tol:.6g}",
             f"{_ratio(err, tol):.6g}") for f, c, sid, k, err, tol, label in n.errors]),
        "pairs": _csv(out / "similar_pairs.csv", (
            "student_a", "student_b", "functions_same", "n_same", "n_both_wrote"), [
            (a, b, ";".join(names), len(names), both) for a, b, names, both in n.pairs]),
    }
    figs = {"scores": _score_figure(n, out / "scores.png"),
            "lost": _lost_figure(n, out / "lost_credit.png"),
            "errors": _errors_figure(n, out / "check_errors.png")}
    (out / "index.html").write_text(_page(n, figs, files))
    return out / "index.html"


def _page(n: ClassNumbers, figs: dict, files: dict) -> str:
    def img(key, alt):
        return (f'<figure><img src="{figs[key]}" alt="{html.escape(alt)}">'
                f"<figcaption>{html.escape(alt)}</figcaption></figure>")

    def link(key):
        return f'<a href="{files[key]}">{files[key]}</a>'

    e = html.escape
    late = [(sid, n.status[sid].value, _fmt(n.scores[sid]["timestamp"]),
             f"{n.scores[sid]['seconds_late'] / 3600:.1f}", _fmt(n.scores[sid]["raw_score"]),
             _fmt(n.scores[sid]["penalty"])) for sid in n.status
            if sid in n.scores and n.scores[sid]["seconds_late"] > 0]
    unscored = [(sid, status.value) for sid, status in n.status.items() if not status.scored]
    mistakes = [(f, label, len(who), ", ".join(who))
                for (f, label), who in sorted(n.mistakes.items(), key=lambda kv: -len(kv[1]))]
    pairs = [(a, b, ", ".join(names), f"{len(names)} of {both}") for a, b, names, both in n.pairs]
    skipped = "".join(f"<li>{e(printable(s, 80))}: {e(why)}</li>"
                      for s, why in n.not_rescored.items())
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">{POLICY_META}
<title>{e(n.assignment)}: the class at a glance</title>
<style>
body {{ font-family: sans-serif; max-width: 1150px; margin: 1em auto; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 2px 8px; text-align: left; }}
figure {{ display: inline-block; margin: 0.5em; vertical-align: top; }}
figcaption {{ font-size: 0.85em; color: #555; }}
img {{ max-width: 100%; border: 1px solid #ddd; }}
.note {{ color: #555; font-size: 0.9em; }}
</style></head><body>
<h1>{e(n.assignment)}: the class at a glance</h1>
<p>{len(n.status)} submissions; {len(n.rescored)} scored again from the executions the last
grade run kept (no student code ran for this page). Scores are the gradebook's: a TA's
manual score counts over the automatic one, and the late penalty is taken off. The numbers
are in the CSV files beside this page: {", ".join(link(k) for k in files)}.</p>
{"<p>Not scored again here:</p><ul>" + skipped + "</ul>" if skipped else ""}

<h2>Score distribution</h2>
{img("scores", "scores of the class")}

<h2>Where credit was lost</h2>
<p>The share of students who lost credit on each function, and on each of its checks.</p>
{img("lost", "share of students who lost credit, per function and check")}

<h2>Named mistakes</h2>
<p class="note">The grader names a classic mistake when a student's answer on a problem is
clearly nearest to it (the lab's code mistakes and the mistake families of autograder.families).</p>
{_table(("function", "mistake", "students", "who"), mistakes) if mistakes else
 "<p>No named mistake.</p>"}

<h2>Errors against the tolerance</h2>
<p>Every problem of every rescored student, per check: its error over the problem's own
tolerance (left of the dashed line: within it). A problem with no usable answer (a raise, a
time-out, a value that cannot be measured) is counted in each title.</p>
{img("errors", "errors against the tolerance, per check")}

<h2>Late and ungraded submissions</h2>
{_table(("student", "status", "submitted (UTC)", "hours late", "raw score", "penalty"), late)
 if late else "<p>No late submission.</p>"}
{_table(("student", "status"), unscored) if unscored else "<p>No ungraded submission.</p>"}

<h2>Students with the same code</h2>
<p class="note">How the code is compared: each graded function a student defined in the
notebook (the last definition, as a run leaves it) is parsed to its syntax tree; its
docstring, comments, annotations and formatting go, and its parameters and local names are
renamed in order of first use (v0, v1, ...); names it only reads (numpy, the lab's helpers)
stay. Two functions with the same result are the same code. A function still as the
released notebook has it (the stub every student received) pairs nobody: only what a student
wrote is compared. A short function written the same by two students is weak evidence; read
the two notebooks before anything else.</p>
{_table(("student", "student", "same functions", "same, of those both wrote"), pairs)
 if pairs else "<p>No two students wrote any graded function the same.</p>"}
</body></html>
"""


def run_report(args) -> None:
    """``cobotlab report``: write the page and say where it is."""
    page = write_class_report(args.course_dir, args.assignment, args.out)
    print(f"wrote {page}")

"""The student's feedback page for one graded submission (``feedback_cobotlab/.../feedback.html``).

Written from the trusted side after grading (:func:`autograder.pipeline.pipeline.grade_course`), from the
numbers in a :class:`~autograder.pipeline.score.SubmissionGrade` only: per function its points and
a coloured verdict, per check how many problems were within tolerance and the worst error
against that tolerance in its unit, and each distinct error once with the number of problems
it happened on. Cells are numbered as the student sees them (``In [n]`` after Restart and
Run All), not as the grader counted them: an error's or a note's place is typed
(:class:`~autograder.outcomes.Place`), never in its words, and written in here.

What the page never holds: the secret, hidden-test code, problem inputs or true answers
(only error magnitudes), or anything from the submission that is not escaped and capped:
error messages and notes come from student code and are treated as hostile text.
"""

from __future__ import annotations

import html
import math
from collections import Counter

from autograder.checks import CheckResult, FunctionResult, voided_sentence
from autograder.errors import ErrorGroup
from autograder.freeze import printable
from autograder.outcomes import Failed, Place, note_place, placed, student_words
from autograder.page_policy import POLICY_META
from autograder.pipeline.cells import CellOrigin
from autograder.pipeline.score import SubmissionGrade

__all__ = ["feedback_html", "feedback_section", "function_verdict", "error_lines"]

MAX_TEXT = 300            # characters of one error or note shown
MAX_LINES = 8             # distinct errors shown per function, and notes per page

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 62em; margin: 2em auto; color: #222; }
h1 { margin-bottom: 0.2em; }
.score { font-size: 1.3em; font-weight: bold; }
table { border-collapse: collapse; margin: 0.6em 0; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.badge { display: inline-block; padding: 0.05em 0.5em; border-radius: 0.6em; color: #fff;
         font-weight: bold; font-size: 0.9em; }
.passed { background: #2e7d32; } .partial { background: #e08a00; }
.failed { background: #c62828; } .missing { background: #6d6d6d; }
.forbidden { background: #6a1b9a; } .timed-out { background: #ad1457; }
tr.row-passed td:first-child { border-left: 6px solid #2e7d32; }
tr.row-partial td:first-child { border-left: 6px solid #e08a00; }
tr.row-failed td:first-child { border-left: 6px solid #c62828; }
section.function { border-top: 2px solid #ddd; margin-top: 1.5em; }
code { background: #f6f6f6; padding: 0 0.2em; word-break: break-word; }
"""

# verdict -> (css class, label)
_VERDICTS = {
    "passed": ("passed", "passed"),
    "partial": ("partial", "partly passed"),
    "failed": ("failed", "failed"),
    "not_implemented": ("missing", "not implemented"),
    "not_found": ("missing", "not found"),
    "forbidden": ("forbidden", "forbidden routine"),
    "timed_out": ("timed-out", "timed out"),
    "not_graded": ("missing", "not graded"),
}

def _esc(text, limit: int = MAX_TEXT) -> str:
    return html.escape(printable(text, limit))


def _cell_name(index: int, origins: list[CellOrigin]) -> str:
    """The grader's cell index as the student's ``In [n]`` (plus the notebook when several)."""
    if not 0 <= index < len(origins):
        return f"cell {index}"
    origin = origins[index]
    several = len({o.notebook for o in origins}) > 1
    return (f"{origin.notebook} " if several else "") + f"cell In [{origin.prompt}]"


def line_name(place: Place, origins: list[CellOrigin]) -> str:
    """``place`` as the student names it: "cell In [n], line m", or "cell In [n]" for a
    whole cell (the notebook first when several)."""
    cell = _cell_name(place.cell, origins)
    return cell if place.line is None else f"{cell}, line {place.line}"


def student_placed(words: str, place: Place | None, origins: list[CellOrigin]) -> str:
    """``words`` with ``place`` written in as the student names its cell (see
    :func:`autograder.outcomes.placed`)."""
    return placed(words, place, lambda index: _cell_name(index, origins))


def _in_one_notebook(place: Place | None, origins: list[CellOrigin]) -> bool:
    """``place`` is one of ``origins``' cells, all of one notebook: the not-implemented
    sentence names the line only then (it says "the released notebook", one notebook)."""
    return place is not None and 0 <= place.cell < len(origins) \
        and len({o.notebook for o in origins}) == 1


def function_verdict(f: FunctionResult) -> str:
    """One word for a function's result: a key of the verdict table (passed, partial, failed,
    not_implemented, not_found, forbidden, timed_out, not_graded)."""
    if f.forbidden:
        return "forbidden"
    groups = f.error_groups
    if f.n_problems and groups:
        if sum(g.count for g in groups if g.failure is not None
               and g.failure.kind is Failed.RAISED
               and g.failure.exception == "NotImplementedError") >= f.n_problems:
            return "not_implemented"
        if sum(g.count for g in groups if g.failure is not None
               and g.failure.kind is Failed.NOT_FOUND) >= f.n_problems:
            return "not_found"
    if f.max_points and f.points >= f.max_points:
        return "passed"
    if any(g.failure is not None and g.failure.is_time_out for g in groups):
        return "timed_out"
    if not f.n_problems and not any(c.n_trials for c in f.checks):
        return "not_graded"
    return "partial" if f.points > 0 else "failed"


def _time_out_line(f: FunctionResult, groups: list[ErrorGroup], origins: list[CellOrigin],
                   of: str) -> str | None:
    """The time-out said in words (what stopped, and what was therefore not run), or None."""
    timed = sum(g.count for g in groups if g.failure.kind is Failed.TIMED_OUT)
    skipped = sum(g.count for g in groups if g.failure.skipped_after_earlier)
    if not (timed or skipped):
        return None
    limits = [g.failure.limit_s for g in groups if g.failure.limit_s is not None]
    limit = f" of {min(limits):g} s of CPU time" if limits else ""
    stopped = next((g.failure.place for g in groups if g.failure.kind is Failed.TIMED_OUT
                    and g.failure.place is not None), None)
    line = (f"Timed out: {f.name} did not return within its time limit{limit} on "
            f"{timed or 1}{of} problem(s)"
            + (f" (stopped at {line_name(stopped, origins)})" if stopped else ""))
    if skipped:
        line += (f"; the other {skipped} problem(s) were then not run, and count as "
                 "failed. Look for a loop that never ends or work that grows too fast")
    return line + "."


def error_lines(f: FunctionResult, origins: list[CellOrigin]) -> list[str]:
    """Plain-text lines, one per distinct error of ``f`` with the number of problems it
    happened on; a time-out is said in words (what stopped, and what was therefore not run).
    Text from student code is capped but not yet HTML-escaped."""
    groups = f.error_groups
    of = f" of {f.n_problems}" if f.n_problems else ""
    timed = _time_out_line(f, [g for g in groups if g.failure is not None], origins, of)
    lines = [timed] if timed else []
    merged: Counter = Counter()
    kinds: dict[str, list[str]] = {}
    for g in groups:
        if g.failure is not None and g.failure.is_time_out:
            continue
        # messages that read the same once their places are named are one line
        shown = student_placed(printable(g.message, MAX_TEXT), g.place, origins)
        merged[shown] += g.count
        labels = kinds.setdefault(shown, [])
        labels.extend(label for label in g.labels if label not in labels)
    for message, n in sorted(merged.items(), key=lambda item: -item[1])[:MAX_LINES]:
        which = f": {', '.join(kinds[message][:3])}" if kinds.get(message) else ""
        lines.append(f"{message} (on {n}{of} problems{which})" if n else message)
    if len(merged) > MAX_LINES:
        lines.append(f"... and {len(merged) - MAX_LINES} other distinct errors")
    return lines


def _number(value: float, unit: str) -> str:
    if not math.isfinite(value):
        return "no usable answer"
    return f"{value:.3g}" + (f" {unit}" if unit else "")


def _check_status(c: CheckResult) -> tuple[str, str]:
    if c.credit >= 1.0:
        return "passed", "passed"
    return ("partial", "partly passed") if c.credit > 0 else ("failed", "FAILED")


def _check_table(f: FunctionResult) -> str:
    rows = ["<table><tr><th>check</th><th>result</th><th>problems within tolerance</th>"
            "<th>worst error</th><th>tolerance</th></tr>"]
    for c in f.checks:
        css, label = _check_status(c)
        rows.append(f"<tr class='row-{css}'><td>{_esc(c.name)}</td>"
                    f"<td><span class='badge {css}'>{label}</span></td>"
                    f"<td class='num'>{c.n_full} / {c.n_trials}</td>"
                    f"<td class='num'>{_esc(_number(c.worst_error, c.unit))}</td>"
                    f"<td class='num'>{_esc(_number(c.tolerance, c.unit))}</td></tr>")
    rows.append("</table>")
    return "".join(rows)


def _check_sentence(c: CheckResult) -> str:
    _, label = _check_status(c)
    unit = f" {c.unit}" if c.unit else ""
    worst = (f"worst error {c.worst_error:.3g}{unit} against a tolerance of "
             f"{c.tolerance:.3g}{unit}" if math.isfinite(c.worst_error)
             else "no usable answer on some problems")
    outside = c.n_trials - c.n_full - c.n_voided
    if outside > 0:
        text = (f"{c.name}: {label}, outside the tolerance on {outside} of {c.n_trials} "
                f"problems; {worst}" + (f"; {voided_sentence(c)}" if c.n_voided else "")
                + (f"; this check measures {c.describe}" if c.describe else ""))
    else:
        # Within its tolerance everywhere: what failed is another check, so neither "outside
        # the tolerance" nor what this check measures is the story.
        text = (f"{c.name}: {label}, within the tolerance on every problem (worst error "
                f"{_number(c.worst_error, c.unit)}, tolerance {_number(c.tolerance, c.unit)}), "
                f"but {voided_sentence(c, more=False)}")
    return _esc(text, 600)


def _function_section(f: FunctionResult, origins: list[CellOrigin]) -> str:
    verdict = function_verdict(f)
    css, label = _VERDICTS[verdict]
    parts = [f"<section class='function'><h2>{_esc(f.name)}: {f.points:g} / "
             f"{f.max_points:g} <span class='badge {css}'>{label}</span></h2>"]
    if verdict == "not_implemented":
        where = next((_esc(line_name(g.failure.place, origins), 120)
                      for g in f.error_groups if g.failure is not None
                      and _in_one_notebook(g.failure.place, origins)), "")
        parts.append(f"<p>Not implemented yet: <code>{_esc(f.name)}</code> still raises "
                     "<code>NotImplementedError</code> (the placeholder of the released "
                     f"notebook{', ' + where if where else ''}) on every problem. Replace "
                     "that line with your code and run "
                     f"<code>check({_esc(f.name)})</code> in your notebook.</p></section>")
        return "".join(parts)
    if verdict == "not_found":
        parts.append(f"<p>Not found: your notebook defines no function named "
                     f"<code>{_esc(f.name)}</code>, or its cell raised before defining it. "
                     "Keep the name and signature of the released notebook.</p></section>")
        return "".join(parts)
    if verdict == "forbidden":
        routines = ", ".join(f"<code>{_esc(r, 80)}</code>" for r in f.forbidden[:8])
        reference = any(r == "solutions" or r.startswith("solutions.") for r in f.forbidden)
        what = ("the course's reference solutions, which are not yours to call" if reference
                else "a routine that does the computation this exercise asks you to write "
                     "yourself")
        parts.append(f"<p>Score 0: <code>{_esc(f.name)}</code> calls {routines}: {what}. "
                     "Write it yourself from basic numpy operations and it is graded as "
                     "usual; <code>check(...)</code> in your notebook applies the same rule."
                     "</p></section>")
        return "".join(parts)
    if verdict == "not_graded":
        parts.append("<p>Not graded: there was no notebook code to run.</p></section>")
        return "".join(parts)
    if f.n_problems:
        parts.append(f"<p>Failed on {f.n_failed} of {f.n_problems} problems.</p>" if f.n_failed
                     else f"<p>All {f.n_problems} problems right.</p>")
    if f.checks:
        parts.append(_check_table(f))
    # When every problem raised, the errors are the story; what a check measures is not.
    crashed = f.n_problems and sum(g.count for g in f.error_groups) >= f.n_problems
    failing = [] if crashed else [c for c in f.checks if c.credit < 1.0]
    errors = error_lines(f, origins)
    if failing or errors:
        parts.append("<p>What went wrong:</p><ul>"
                     + "".join(f"<li>{_check_sentence(c)}</li>" for c in failing)
                     + "".join(f"<li><code>{_esc(e, 2 * MAX_TEXT)}</code></li>"
                               for e in errors)
                     + "</ul>")
    parts.append("</section>")
    return "".join(parts)


def _notebook_notes(grade: SubmissionGrade) -> list[str]:
    """The notes about running the student's notebook (those with words for the student;
    every other note, the grader's retries, its sandbox, nbgrader's cross-check, is the
    instructor's, whatever it says), each distinct one once with a count."""
    merged: Counter = Counter()
    for note in grade.notes:
        words = student_words(note)
        if words is None:
            continue
        merged[student_placed(printable(words.strip(), MAX_TEXT), note_place(note),
                              grade.cell_origins)] += 1
    lines = [f"{note} (in {n} cells)" if n > 1 else note
             for note, n in sorted(merged.items(), key=lambda item: -item[1])[:MAX_LINES]]
    if len(merged) > MAX_LINES:
        lines.append(f"... and {len(merged) - MAX_LINES} other distinct notes")
    return lines


def _body(grade: SubmissionGrade, heading: str, anchor: str) -> list[str]:
    """The page's content: ``heading``, the score, a summary table of the functions, then per
    function the checks and errors, and the notes; ``anchor`` prefixes the link targets."""
    failing = [f for f in grade.functions if f.points < f.max_points]
    parts = [f"<h1>{heading}</h1>",
             f"<p class='score'>Score: {grade.score:g} / {grade.max_score:g}</p>",
             "<p>Each function was run on hidden problems from the same generator as "
             "<code>check(...)</code> in your notebook; errors are measured against the true "
             "answer. Cells are named by the <code>In [n]</code> number they get after "
             "<i>Kernel &rarr; Restart Kernel and Run All Cells</i>.</p>",
             "<table><tr><th>function</th><th>points</th><th>result</th><th>problems</th></tr>"]
    for f in grade.functions:
        css, label = _VERDICTS[function_verdict(f)]
        problems = (f"failed on {f.n_failed} of {f.n_problems}" if f.n_failed
                    else f"all {f.n_problems} right") if f.n_problems else ""
        row = css if css in ("passed", "partial") else "failed"
        target = anchor + _esc(f.name, 80)
        parts.append(f"<tr class='row-{row}'>"
                     f"<td><a href='#{target}'>{_esc(f.name, 80)}</a></td>"
                     f"<td class='num'>{f.points:g} / {f.max_points:g}</td>"
                     f"<td><span class='badge {css}'>{label}</span></td><td>{problems}</td></tr>")
    parts.append("</table>")
    if failing:
        parts.append(f"<p>{len(failing)} of {len(grade.functions)} functions lost points.</p>")
    for f in grade.functions:
        parts.append(f"<a id='{anchor}{_esc(f.name, 80)}'></a>"
                     + _function_section(f, grade.cell_origins))
    notes = _notebook_notes(grade)
    if notes:
        parts.append("<section class='function'><h2>While running your notebook</h2><ul>"
                     + "".join(f"<li><code>{_esc(n, 2 * MAX_TEXT)}</code></li>" for n in notes)
                     + "</ul></section>")
    return parts


def feedback_html(grade: SubmissionGrade) -> str:
    """The feedback page of one submission: a summary table of its functions, then per
    function the checks (error against tolerance, with units) and each distinct error once.
    Every text from the submission is escaped and capped; no test code or true answers."""
    title = f"{_esc(grade.assignment, 80)} feedback"
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'>{POLICY_META}<title>{title}</title>"
             f"<style>{_STYLE}</style></head><body>",
             *_body(grade, f"{_esc(grade.assignment, 80)}: {_esc(grade.student_id, 80)}", ""),
             "</body></html>"]
    return "\n".join(parts)


SECTION_CLASS = "cobotlab-feedback"


def _scoped_style(scope: str) -> str:
    """:data:`_STYLE` restricted to the elements under ``scope`` (its ``body`` rule styles
    ``scope`` itself), so the section does not restyle the page it is put in."""
    rules = []
    for rule in _STYLE.split("}"):
        if "{" not in rule:
            continue
        selectors, declarations = rule.split("{", 1)
        scoped = ", ".join(scope if s.strip() == "body" else f"{scope} {s.strip()}"
                           for s in selectors.split(","))
        rules.append(f"{scoped} {{{declarations}}}")
    # framed, and headings the size of the page's own (its Bootstrap's are larger)
    rules.append(f"{scope} {{ border: 1px solid #ccc; border-radius: 4px; padding: 0 1em 1em; "
                 f"margin: 0 0 1.5em 0; }}\n{scope} h1 {{ font-size: 1.7em; }}\n"
                 f"{scope} h2 {{ font-size: 1.3em; }}")
    return "\n".join(rules)


def feedback_section(grade: SubmissionGrade) -> str:
    """The same feedback as :func:`feedback_html`, as one ``<div>`` to put at the top of
    another page (nbgrader's feedback page: :mod:`autograder.nbgrader_hooks`), its style
    scoped to it and its link targets prefixed so they do not clash with the page's."""
    heading = f"cobotlab: {_esc(grade.assignment, 80)}, {_esc(grade.student_id, 80)}"
    return "".join([f"<div class='{SECTION_CLASS}'>",
                    f"<style>{_scoped_style('div.' + SECTION_CLASS)}</style>",
                    *_body(grade, heading, "cobotlab-"), "</div>"])

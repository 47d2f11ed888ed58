"""``cobotlab labs verify``: the author's gate, before a lab reaches a student.

Two kinds of evidence, one table:

* **static**: every graded function has a solution region, a spec and a ``test_<fn>`` cell
  holding ``check(fn)``; the notebook's ``def`` takes the parameters the spec says
  (``FunctionSpec.parameters``, compared with :mod:`ast`); each test cell is worth the
  spec's points; outputs are cleared; the release (nbgrader's preprocessors) holds no
  solution or hidden test; forbidden routines name real objects; each generator follows its
  rng (the same stream gives the same problems, another stream others) and gives finite,
  positive tolerances; no practice problem is one of the hidden ones.
* **statistical** (:mod:`autograder.fairness`, the engine the fairness benchmark uses): the
  notebook's solution regions pasted into its release are loaded once in the grader's real
  bubblewrap worker and answer N hidden draws there, scored exactly as the grader scores
  them; each code mistake of the spec answers the first draws (1,000 at most) in this
  process (it is the author's own code). The reference must never lose credit; each mistake
  must lose it on at least 99 % of draws (the Clopper-Pearson 95 % lower bound); the table
  also gives the share of *problems* each mistake loses, which a draw-level count hides.
* **trivial answers** (:mod:`autograder.trivial`): on the first ``TRIVIAL_DRAWS`` draws the
  answers that compute nothing (zeros, the identity, a constant unit vector, the inputs
  echoed back, the mean of the input points, another problem's truth, raising on every
  problem) are scored the same way; one that earns more than 5 % of a function's points on
  average fails the lab, naming the answer and the check that credits it.
* **mistake families** (:mod:`cobotlab.verify_families`): on the first ``FAMILY_DRAWS``
  draws, each family of :mod:`autograder.families` that applies to the function (by the
  kinds of its answer and inputs) answers as that mistake would, and the table gives the
  share of draws on which that answer loses credit; a family that applies but loses on
  fewer than 99 % of its draws is a warning (a hole in the tolerances), one that applies
  nowhere is listed as such.
* **tolerances**: per check, the range of its tolerance over the draws in the check's unit,
  with a warning (not a failure) where the largest is as large as a trivial answer's typical
  error, e.g. a 3.5 m tolerance on a translation.

``--worst`` prints, per function, the reference's worst problem (the one closest to its
tolerance) as a notebook cell: the inputs as numpy literals, the call, the measured errors.

The default N is the smallest number of draws whose 0 losses bound the loss rate below 1e-3
(95 % Clopper-Pearson); ``--draws 10000`` is for a release. The JSON report (default
``.cobotlab/verified/<lab>.json``, beside the private specs) holds the hash of the lab's
scoring and spec and the digest of all its files, which ``cobotlab grade`` and ``course init``
compare: a lab edited after verify is unverified, one whose last verify failed is not
released (:func:`autograder.registry.release_problem`).
"""

from __future__ import annotations

import ast
import hashlib
import json
import math
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from autograder import checks, fairness, registry
from autograder.inside import wire
from autograder.nbgrader_cells import cell_role, nbgrader_metadata
from autograder.pipeline import worker
from autograder.pipeline.cells import cell_source, extract_code
from autograder.pipeline.notebook_runner import NotebookRunner
from autograder.pipeline.problems import problem_rng
from autograder.pipeline.worker import GraderError, Limits, WorkerSetup
from autograder.spec_types import FunctionSpec, Trial
from cobotlab.verify_families import APPLIES, NO_REFERENCE, NOT_APPLICABLE, FamilyGate

__all__ = ["Finding", "run_verify", "verify_lab", "worst_cell", "DEFAULT_RATE", "FAMILY_DRAWS",
           "MISTAKE_DRAWS", "TRIVIAL_DRAWS"]

DEFAULT_RATE = 1e-3          # the reference's loss rate the default draws can bound
MISTAKE_TARGET = 0.99        # a mistake's Clopper-Pearson lower bound must reach this
MISTAKE_DRAWS = 1000         # 1,000 losses in 1,000 draws bound the rate above 99.6 %
# Trivial answers are scored on the first 200 draws: with none credited, the 95 % bound on
# their mean share is 1.8 %, well under the 5 % they may earn; 200 draws of lab 5's 48-problem
# fit_flange_circle take about 30 s on one core.
TRIVIAL_DRAWS = 200
# Mistake families are scored on the first 100 draws: a family's answer that loses on all of
# them is shown as such (95 % lower bound 0.964), one that passes on a few percent shows as
# a hole. Lab 2's axes_ls takes about 1.3 s a draw for its family mistakes (the input side
# calls the reference solver on swapped and inverted motions), 6 minutes for the lab.
FAMILY_DRAWS = 100
SECRET = "cobotlab-labs-verify"   # not the course's: verify needs no course secret
SOLUTION_BEGIN, SOLUTION_END = "### BEGIN SOLUTION", "### END SOLUTION"


@dataclass
class Finding:
    """One failed check: ``function`` (None: the lab as a whole), ``check`` (what was
    checked), ``message`` (what is wrong, where, and the fix)."""

    check: str
    message: str
    function: str | None = None


@dataclass
class Report:
    lab: str
    spec_hash: str
    draws: int
    findings: list[Finding] = field(default_factory=list)
    functions: list[dict] = field(default_factory=list)
    seconds: float = 0.0
    warnings: list[Finding] = field(default_factory=list)   # shown, never a failure
    lab_digest: str = ""   # registry.lab_digest: an edit of any of the lab's files after
    #                        verify makes it unverified (course init and grade compare it)

    @property
    def passed(self) -> bool:
        return not self.findings

    def to_json(self) -> dict:
        return {"lab": self.lab, "spec_hash": self.spec_hash, "lab_digest": self.lab_digest,
                "draws": self.draws,
                "passed": self.passed, "findings": [asdict(f) for f in self.findings],
                "warnings": [asdict(f) for f in self.warnings],
                "functions": self.functions, "seconds": round(self.seconds, 1)}


# --------------------------------------------------------------------------- the notebook


def _cells(path: Path) -> list[dict]:
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def _solution_defs(cells: list[dict]) -> dict[str, list[ast.FunctionDef]]:
    """{function name: its defs} in the notebook's solution cells."""
    found: dict[str, list] = {}
    for cell in cells:
        if cell.get("cell_type") != "code" or not cell_role(cell).solution:
            continue
        try:
            tree = ast.parse(cell_source(cell))
        except SyntaxError:
            continue
        for node in tree.body:
            if isinstance(node, ast.FunctionDef):
                found.setdefault(node.name, []).append(node)
    return found


def _parameters(text: str) -> str:
    """A parameter list in one canonical spelling (ast's), for comparison."""
    return ast.unparse(ast.parse(f"def f({text}):\n    pass").body[0].args)


def _static(lab: registry.Lab, specs: tuple[FunctionSpec, ...]) -> list[Finding]:
    """The notebook's checks (solution regions, test cells, points, outputs, release)."""
    findings: list[Finding] = []
    notebook = lab.notebook
    cells = _cells(notebook)
    if not any(SOLUTION_BEGIN in cell_source(c) for c in cells):
        findings.append(Finding("solution region", f"{notebook}: no cell holds a "
                                f"{SOLUTION_BEGIN} ... {SOLUTION_END} region; put the "
                                "reference code of each graded function between them, in a "
                                "cell whose nbgrader metadata says solution"))
    defs = _solution_defs(cells)
    tests = {cell_role(c).grade_id: c for c in cells
             if c.get("cell_type") == "code" and cell_role(c).grade}
    for spec in specs:
        name = spec.name
        if name not in defs:
            findings.append(Finding("solution region", f"{notebook}: no solution cell defines "
                                    f"{name}; add `def {name}(...)` with its reference code "
                                    f"inside {SOLUTION_BEGIN} ... {SOLUTION_END}", name))
        elif len(defs[name]) > 1:
            findings.append(Finding("solution region", f"{notebook}: {name} is defined in "
                                    f"{len(defs[name])} solution cells; keep one", name))
        elif spec.parameters is None:
            findings.append(Finding("parameters", f"the spec of {name} has no parameters "
                                    "field; set parameters= to the def's parameter list, e.g. "
                                    f"parameters=\"{ast.unparse(defs[name][0].args)}\"", name))
        else:
            have = ast.unparse(defs[name][0].args)
            try:
                want = _parameters(spec.parameters)
            except SyntaxError:
                want = None
            if want is None:
                findings.append(Finding("parameters", f"the spec of {name}: parameters="
                                        f"{spec.parameters!r} is not a Python parameter list",
                                        name))
            elif have != want:
                findings.append(Finding("parameters", f"{notebook}: def {name}({have}) but the "
                                        f"spec says ({want}); students write to the notebook's "
                                        "def, the grader calls the spec's: make them the same",
                                        name))
        test = tests.get(f"test_{name}")
        if test is None:
            findings.append(Finding("test cell", f"{notebook}: no graded cell with grade_id "
                                    f"test_{name}; add one holding check({name}), the sanity "
                                    "asserts and the hidden-test region", name))
            continue
        if f"check({name}" not in cell_source(test):
            findings.append(Finding("test cell", f"{notebook}: cell test_{name} does not call "
                                    f"check({name}); students see their score there", name))
        points = nbgrader_metadata(test).get("points")
        if not isinstance(points, (int, float)) or not math.isclose(points, spec.points):
            findings.append(Finding("points", f"{notebook}: cell test_{name} is worth {points} "
                                    f"points, the spec {spec.points:g}; nbgrader's total and "
                                    "the grader's must agree: set one to the other", name))
    graded = {s.name for s in specs}
    for grade_id in tests:
        if grade_id and grade_id.startswith("test_") and grade_id[5:] not in graded:
            findings.append(Finding("test cell", f"{notebook}: cell {grade_id} grades "
                                    f"{grade_id[5:]}, which no spec entry grades; add it to "
                                    "the spec or remove the cell"))
    dirty = [i for i, c in enumerate(cells) if c.get("cell_type") == "code"
             and (c.get("outputs") or c.get("execution_count"))]
    if dirty:
        findings.append(Finding("outputs", f"{notebook}: cells {dirty[:8]} hold outputs; "
                                "clear them (Kernel > Restart and Clear Outputs) so no answer "
                                "ships in a printed result"))
    from cobotlab.labs import release_notebook

    try:
        release_notebook(notebook)
    except Exception as exc:  # noqa: BLE001 - nbgrader's own complaints, reported as found
        findings.append(Finding("release", f"{notebook}: the release is not clean: "
                                f"{type(exc).__name__}: {exc}"))
    return findings


def _forbidden(specs) -> list[Finding]:
    from autograder.forbidden import resolve

    return [Finding("forbidden", f"{spec.name}: forbidden routine {dotted!r} names nothing "
                    "importable here; spell it as module.attribute (e.g. "
                    "'cv2.calibrateHandEye') or the ban catches nothing", spec.name)
            for spec in specs for dotted in spec.forbidden if resolve(dotted) is None]


# --------------------------------------------------------------------------- the generators


def _fingerprint(spec: FunctionSpec, trial: Trial) -> str:
    """A hash of a problem's inputs: what a student's function is given, which for a closed
    loop (``drive``) is the loop's set-up, kept in the truth."""
    given = (tuple(trial.args), trial.truth) if spec.drive is not None else tuple(trial.args)
    body = json.dumps(wire.encode(given), sort_keys=True, default=str)
    return hashlib.sha256(body.encode()).hexdigest()


def _numbers(value):
    if isinstance(value, dict):
        for v in value.values():
            yield from _numbers(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _numbers(v)
    else:
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            return
        yield array


def _trial_problem(trial) -> str | None:
    """What is wrong with a drawn problem's tolerances and truth, or None."""
    if not isinstance(trial, Trial):
        return f"returned {type(trial).__name__}, not a Trial"
    bad = {k: v for k, v in trial.tol.items() if not (isinstance(v, (int, float))
                                                       and math.isfinite(v) and v > 0)}
    if bad:
        return f"tolerance(s) {bad} are not finite positive numbers"
    arrays = list(_numbers(trial.truth))
    if trial.raises is None and any(np.isinf(a).any() for a in arrays):
        return "the truth holds inf"
    if trial.raises is None and arrays and all(np.isnan(a).all() for a in arrays):
        return "the truth is NaN"
    return None


def _draw(lab: str, spec: FunctionSpec, rng, where: str
          ) -> tuple[list[Trial] | None, Finding | None]:
    fix = f"fix make_trial of {spec.name} in {registry.spec_path(lab)}"
    try:
        trials = checks.make_trials(spec, rng)
    except Exception as exc:  # noqa: BLE001 - the author's generator: say where it failed
        return None, Finding("generator", f"{spec.name}: the generator raised on {where}: "
                             f"{type(exc).__name__}: {exc} ({registry.raised_at(exc)}); "
                             f"{fix}",
                             spec.name)
    for i, trial in enumerate(trials):
        problem = _trial_problem(trial)
        if problem:
            return None, Finding("generator", f"{spec.name}: problem {i} of {where} "
                                 f"({getattr(trial, 'label', '')!r}): {problem}; {fix}",
                                 spec.name)
    return trials, None


def _generator(lab: str, spec: FunctionSpec) -> list[Finding]:
    """The generator follows its rng: same stream, same problems; another, others."""
    streams = [problem_rng(SECRET, None, lab, sid, spec.name)
               for sid in ("verify-a", "verify-a", "verify-b")]
    drawn = []
    for rng, where in zip(streams, ("a first draw", "the same draw again", "a second draw")):
        trials, finding = _draw(lab, spec, rng, where)
        if finding:
            return [finding]
        drawn.append([_fingerprint(spec, t) for t in trials])
    if drawn[0] != drawn[1]:
        return [Finding("generator", f"{spec.name}: the same rng gave other problems: the "
                        "generator draws from a random source of its own (np.random.*, "
                        "random, time); draw everything from the rng it is given, or no "
                        f"regrade reproduces a grade ({registry.spec_path(lab)})", spec.name)]
    if drawn[0] == drawn[2]:
        return [Finding("generator", f"{spec.name}: two different rngs gave the same "
                        "problems: the generator ignores its rng, so every student gets the "
                        "same hidden problems; draw them from the rng it is given "
                        f"({registry.spec_path(lab)})", spec.name)]
    return []


def _practice_fingerprints(lab: str, spec: FunctionSpec) -> set[str]:
    seeds = tuple(checks.PUBLIC_SEEDS) + tuple(checks.KERNEL_SEEDS)
    return {_fingerprint(spec, t) for seed in seeds for t in checks.public_trials(spec, seed)}


# --------------------------------------------------------------------------- the reference


def reference_notebook(source: Path) -> dict:
    """The release of ``source`` (nbgrader's preprocessors) with each solution cell's code
    put back, minus the region markers: what a student who wrote the reference submits."""
    import nbformat

    from cobotlab.labs import release_notebook

    released = release_notebook(source)
    solutions = {cell_role(c).grade_id: cell_source(c) for c in _cells(source)
                 if cell_role(c).solution}
    for cell in released.cells:
        grade_id = cell_role(cell).grade_id
        if grade_id and grade_id in solutions:
            cell.source = "\n".join(line for line in solutions[grade_id].splitlines()
                                    if line.strip() not in (SOLUTION_BEGIN, SOLUTION_END))
    return nbformat.from_dict(released)


class SandboxedReference:
    """The reference notebook loaded once in the grader's bubblewrap worker, called through
    the grader's own :class:`autograder.pipeline.notebook_runner.NotebookRunner`; a worker that dies
    (a limit, a crash) is started again for the next problem."""

    def __init__(self, source: Path, limits: Limits):
        import nbformat

        self.limits = limits
        self._folder = tempfile.TemporaryDirectory(prefix="cobotlab-verify-")
        path = Path(self._folder.name) / source.name
        nbformat.write(reference_notebook(source), path)
        self.cells, _ = extract_code(path)
        self.tripped: set[str] = set()
        # A day of CPU: the worker answers thousands of problems, and this is the author's
        # code. Each call's tripwire still sees the spec's forbidden routines.
        self.runner = NotebookRunner(self.cells, limits, setup=WorkerSetup(cpu_s=86400),
                                     batch_calls=True)
        self.runner.loaded()
        self.load_errors = [f"cell {r.get('index')}: {r.get('error')}"
                            for r in self.runner.load_report if not r.get("ok")]

    @property
    def worker(self):
        return self.runner.worker

    def __call__(self, spec: FunctionSpec, trial: Trial) -> checks.TrialOutcome:
        (outcome,) = self.many(spec, [trial])
        return outcome

    def many(self, spec: FunctionSpec, trials: list[Trial], retries: int = 1
             ) -> list[checks.TrialOutcome]:
        """The reference's outcomes on ``trials`` (one round trip where it can be)."""
        try:
            outcomes, tripped = self.runner.run(spec, trials)
        except GraderError:   # a busy machine starved it: not the reference's loss
            self.runner.close()
            if retries:
                return self.many(spec, trials, retries - 1)
            raise
        self.tripped |= tripped
        return outcomes

    def close(self) -> None:
        self.runner.close()
        self._folder.cleanup()


# --------------------------------------------------------------------------- verify


def _lab_from_path(path: str) -> str:
    """The lab a PATH names: a lab folder (its course found from cobotlab.toml above it), a
    notebook in one, or a lab's name."""
    candidate = Path(path).expanduser()
    if candidate.suffix == ".ipynb":
        candidate = candidate.parent
    if candidate.is_dir():
        folder = candidate.resolve()
        course = next((p for p in (folder, *folder.parents)
                       if (p / registry.CONFIG_NAME).is_file()), None)
        if course is not None:
            registry.use_course(course)
        lab = registry.all_labs().get(folder.name)
        if lab is None:
            raise registry.LabError(
                f"{folder}: not a lab of this course; a lab folder holds <name>.ipynb and "
                f"scoring.py and sits in a folder the course's {registry.CONFIG_NAME} lists "
                "(cobotlab labs new NAME writes one)")
        if lab.folder is not None and lab.folder.resolve() != folder:
            raise registry.LabError(f"{folder}: the course's lab {lab.name} is {lab.folder}, "
                                    "not this folder")
        return lab.name
    return registry.find_lab(str(path)).name


def verify_lab(name: str, draws: int | None = None, progress: bool = True,
               limits: Limits | None = None) -> Report:
    """Verify lab ``name`` (static checks, then ``draws`` hidden draws per function: default
    the smallest number that bounds a 0-loss rate below 1e-3). Never raises for a broken lab:
    every problem is a :class:`Finding` of the report."""
    started = time.monotonic()
    draws = draws or fairness.draws_for_rate(DEFAULT_RATE)
    lab = registry.find_lab(name)
    report = Report(name, "", draws)
    try:
        report.spec_hash = registry.spec_hash(name)
        report.lab_digest = registry.lab_digest(name)
        registry.scoring(name)
        specs = registry.specs(name)
    except registry.LabError as exc:
        report.findings.append(Finding("spec", str(exc)))
        return report
    if lab.notebook is None or not lab.notebook.is_file():
        report.findings.append(Finding("notebook", f"{lab.folder}: no {name}.ipynb; the lab's "
                                       "notebook carries the lab's name"))
        return report
    report.findings += _static(lab, specs) + _forbidden(specs)
    broken = set()
    for spec in specs:
        found = _generator(name, spec)
        report.findings += found
        if found:
            broken.add(spec.name)
    if not worker.sandbox_available():   # a module attribute: tests stand one in
        report.findings.append(Finding("sandbox", "bubblewrap is not available here, and "
                                       "verify runs the reference where the grader runs "
                                       "student code: install it (sudo apt-get install "
                                       "bubblewrap) and allow unprivileged user namespaces"))
        report.seconds = time.monotonic() - started
        return report
    if any(f.check in ("solution region", "release") for f in report.findings):
        report.seconds = time.monotonic() - started
        return report   # no reference to run
    reference = SandboxedReference(lab.notebook, limits or Limits())
    try:
        if reference.load_errors:
            report.findings.append(Finding("reference", f"{lab.notebook}: the reference "
                                           "notebook raised while loading in the sandbox ("
                                           + "; ".join(reference.load_errors[:3]) + "); a "
                                           "lab may import cobotlab's requirements and the "
                                           "packages its course's cobotlab.toml lists in "
                                           "notebook_packages (see docs/authoring.md)"))
        for spec in specs:
            if spec.name not in broken:
                report.functions.append(_statistics(name, spec, draws, reference, report,
                                                    progress))
        if reference.tripped:
            report.findings.append(Finding("forbidden", "the reference calls forbidden "
                                           f"routines {sorted(reference.tripped)}: the "
                                           "students could not use its method"))
    finally:
        reference.close()
    report.seconds = time.monotonic() - started
    return report


def _statistics(lab: str, spec: FunctionSpec, draws: int, reference, report: Report,
                progress: bool) -> dict:
    """Score the sandboxed reference on ``draws`` hidden draws and each code mistake on the
    first of them (the fairness engine, one draw at a time so the worst draw is known and a
    progress bar moves); add a finding for every unfair result."""
    practice = _practice_fingerprints(lab, spec)
    seen_practice: list[str] = []

    def rng_of(student: str):
        return problem_rng(SECRET, None, lab, student, spec.name)

    class Watched:
        """The reference, watched for a hidden problem that is a practice problem."""

        def __call__(self, spec_, trial):
            (outcome,) = self.many(spec_, [trial])
            return outcome

        def many(self, spec_, trials):
            for trial in trials:
                if not seen_practice and _fingerprint(spec_, trial) in practice:
                    seen_practice.append(trial.label)
            return reference.many(spec_, trials)

    callers = {"reference": Watched()}
    callers.update((m.label, fairness.in_process(m.func)) for m in spec.code_mistakes)
    totals: dict[str, fairness.DrawStats] = {}
    worst_draw, worst_margin = None, -math.inf
    gate = fairness.TrivialGate(spec)
    family_gate = FamilyGate(spec)
    tolerances = _Tolerances(spec)

    def on_draw(k: int, trials: list[Trial]) -> None:
        tolerances.add(trials)
        if k < TRIVIAL_DRAWS:
            gate.add(trials)
        if k < FAMILY_DRAWS:
            family_gate.add(trials)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=draws, unit="draw", desc=f"{lab}.{spec.name}", file=sys.stderr,
                   leave=False)
    try:
        for k in range(draws):
            one = fairness.score_draws(spec, lab, range(k, k + 1), callers, rng_of,
                                       correct=("reference",),
                                       mistakes_stop=min(draws, MISTAKE_DRAWS),
                                       on_draw=on_draw)
            if one["reference"].margin > worst_margin:
                worst_draw, worst_margin = fairness.student_id(k), one["reference"].margin
            totals = {name: totals[name].merged(s) if name in totals else s
                      for name, s in one.items()}
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    worst = totals["reference"].worst if "reference" in totals else None
    row = {"function": spec.name, "points": spec.points, "variants": [],
           "worst_draw": worst_draw, "worst_margin": worst_margin,
           "worst_problem": None if worst is None else {
               "draw": worst.student, "problem": worst.problem, "label": worst.trial,
               "check": worst.check, "error": worst.error, "tolerance": worst.tolerance,
               "unit": worst.unit, "reason": worst.reason}}
    for label, stats in totals.items():
        low, high = fairness.clopper_pearson(stats.lost, stats.seen)
        loss = stats.first_loss
        row["variants"].append({
            "variant": label, "correct": stats.correct, "draws": stats.seen,
            "lost": stats.lost, "low": low, "high": high,
            "problems": stats.problems, "problems_lost": stats.problems_lost,
            "margin": stats.margin if stats.correct else None,
            "first_loss": loss.describe() if loss else None})
        if stats.correct and stats.lost:
            report.findings.append(Finding("reference", (
                f"{spec.name}: the reference lost credit on {stats.lost} of {stats.seen} "
                f"draws; first: {loss.describe()}. Fix: derive that problem's tolerance from "
                "its own noise (a larger multiple if the error's tail is heavier than the "
                "derivation assumed), or redraw such ill-conditioned problems in the "
                "generator"), spec.name))
        if not stats.correct and low < MISTAKE_TARGET and stats.lost == stats.seen:
            report.findings.append(Finding("draws", (
                f"{spec.name}: the code mistake {label!r} lost credit on all {stats.seen} "
                f"draws, but {stats.seen} draws cannot show a rate of at least "
                f"{MISTAKE_TARGET} (95 % lower bound {low:.3f}). Fix: run at least "
                f"{_draws_to_show(MISTAKE_TARGET)} draws (--draws)"), spec.name))
        elif not stats.correct and low < MISTAKE_TARGET:
            report.findings.append(Finding("mistake", (
                f"{spec.name}: the code mistake {label!r} lost credit on only {stats.lost} of "
                f"{stats.seen} draws (95 % lower bound {low:.3f} < {MISTAKE_TARGET}). Fix: a "
                "mistake must lose credit on at least 99 % of draws: tighten the tolerance if "
                "it is far above the reference's worst error (margin), or draw problems where "
                "the mistake shows; a mistake that gives the reference's answers is not a "
                "mistake (remove it)"), spec.name))
    if seen_practice:
        report.findings.append(Finding("practice", f"{spec.name}: a hidden problem equals a "
                                       f"practice problem ({seen_practice[0]!r}): students "
                                       "would see its answer in check(); draw from a wider "
                                       "range so the two never coincide", spec.name))
    row["trivial"] = _trivial(spec, gate, report)
    row["trivial_seconds"] = round(gate.seconds, 2)
    row["tolerances"] = tolerances.rows(gate, report)
    row["families"] = _families(spec, family_gate, report)
    row["families_seconds"] = round(family_gate.seconds, 2)
    return row


def _families(spec: FunctionSpec, gate: FamilyGate, report: Report) -> list[dict]:
    """The family rows (:meth:`FamilyGate.rows`); a warning, never a failure, for each
    family that applies but keeps full credit on more than 1 % of its draws: the lab's own
    code mistakes are what it must catch, a family is what it may also meet."""
    rows = gate.rows()
    for r in rows:
        if r["status"] == APPLIES and r["share"] < MISTAKE_TARGET:
            report.warnings.append(Finding("family", (
                f"{spec.name}: the mistake family {r['family']!r} ({r['mistake']}) applies "
                f"on {r['draws']} draws but its answer loses credit on only {r['lost']} "
                f"({r['share']:.1%}): on the others a student making it keeps full credit "
                "and check() cannot tell it from a right answer. Fix: if the mistake "
                "changes nothing this function computes (millimetres in an input it does "
                "not read), nothing to do; if its answer is near the truth on those "
                "problems, draw problems where it is far (or add an all-or-nothing check "
                "that sees it); if the tolerance is wider than the noise needs, derive it "
                "from the noise"), spec.name))
    return rows


def _trivial(spec: FunctionSpec, gate: fairness.TrivialGate, report: Report) -> list[dict]:
    """The trivial answers' rows, best first; a finding for each above the limit."""
    rows = []
    for score in gate.ranked():
        low, high = score.interval()
        rows.append({"answer": score.answer, "mean": score.mean, "low": low, "high": high,
                     "draws": score.draws, "check": score.check, "raises": score.raises})
    # One finding per check that credits trivial answers (the best of them named, the count
    # of the others): a plane's offset check credits the mean and the median of the points
    # with any normal, which is one fault, not eight.
    groups: dict[str | None, list[fairness.TrivialScore]] = {}
    for score in gate.failing():
        groups.setdefault("raises" if score.raises else score.check, []).append(score)
    for scores in groups.values():
        score = scores[0]
        low, high = score.interval()
        also = "" if len(scores) == 1 else (
            f"; {len(scores) - 1} more above it the same way, e.g. {scores[1].answer!r} "
            f"({scores[1].mean:.1%})")
        what = (f"{spec.name}: the trivial answer {score.answer!r} earns {score.mean:.1%} of "
                f"its points on average (95 % interval [{low:.1%}, {high:.1%}] over "
                f"{score.draws} draws; at most {fairness.TRIVIAL_LIMIT:.0%} allowed{also}), ")
        if score.raises:
            fix = ("from the problems that expect that exception alone. Fix: a degenerate "
                   "problem shows that the function refuses bad input, not that it solves "
                   "anything: fewer of them per student, or worth less than the others")
        else:
            fix = (f"credited by the check {score.check!r}. Fix: the check must measure what "
                   "only a computed answer gets right: derive its tolerance from the "
                   "problem's noise (is it wider than the method needs?), score the part of "
                   "the answer the check ignores, mark problems where a constant is right "
                   "all_or_nothing, or draw problems on which the trivial answer is far off")
        report.findings.append(Finding("trivial", what + fix, spec.name))
    return rows


class _Tolerances:
    """Per check, the range of its full-credit tolerance over the problems of all draws
    (problems that expect an exception have no tolerance that counts and are left out)."""

    def __init__(self, spec: FunctionSpec):
        self.spec = spec
        self.low = {c.name: math.inf for c in spec.checks}
        self.high = {c.name: -math.inf for c in spec.checks}

    def add(self, trials: list[Trial]) -> None:
        for trial in trials:
            if trial.raises is not None:
                continue
            for c in self.spec.checks:
                tol = float(trial.tol[c.name])
                self.low[c.name] = min(self.low[c.name], tol)
                self.high[c.name] = max(self.high[c.name], tol)

    def rows(self, gate: fairness.TrivialGate, report: Report) -> list[dict]:
        """One row per check; a warning where the largest tolerance reaches the typical
        error of the best trivial answer on that check (the truth's own size, in effect)."""
        rows = []
        for c in self.spec.checks:
            typical, by = math.inf, None
            for score in gate.scores.values():
                error = score.typical_error(c.name)
                if not score.raises and error < typical:
                    typical, by = error, score.answer
            low, high = self.low[c.name], self.high[c.name]
            rows.append({"check": c.name, "unit": c.unit, "low": low, "high": high,
                         "trivial_error": typical, "trivial_answer": by})
            if math.isfinite(high) and high >= typical:
                unit = f" {c.unit}" if c.unit else ""
                report.warnings.append(Finding("tolerance", (
                    f"{self.spec.name}: the tolerance of check {c.name!r} reaches "
                    f"{_quantity(high, c.unit)} while the trivial answer {by!r} is typically "
                    f"off by only {typical:.3g}{unit} on it: a tolerance as large as the "
                    "quantity it checks gives credit for nothing on some problems; derive "
                    "it from the problem's noise, or redraw such ill-conditioned problems"),
                    self.spec.name))
        return rows


def _quantity(value: float, unit: str) -> str:
    """``value`` in ``unit``, with metres beside millimetres once it is past a metre (so a
    3.5 m tolerance reads as one)."""
    text = f"{value:.3g} {unit}".strip()
    if unit == "mm" and abs(value) >= 1000:
        text += f" (= {value / 1000:.3g} m)"
    return text


def _draws_to_show(rate: float) -> int:
    """The fewest draws whose all-lost count bounds a rate above ``rate`` (95 %: 367 for
    0.99), the mirror image of :func:`fairness.draws_for_rate`."""
    return fairness.draws_for_rate(1 - rate)


# --------------------------------------------------------------------------- the table


def _clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[:width - 3] + "..."


def _print(report: Report, out=None) -> None:
    out = out or sys.stdout   # looked up now: a caller may have redirected it
    print(f"cobotlab labs verify {report.lab}: {report.draws} hidden draws per function, "
          f"spec {report.spec_hash}", file=out)
    print(f"{'function':<24} {'variant':<46} {'lost / draws':>14}  {'95% interval':<20} "
          f"{'problems lost':>18} {'margin':>7}", file=out)
    for row in report.functions:
        for v in row["variants"]:
            label = _clip(("+ " if v["correct"] else "- ") + v["variant"], 46)
            margin = v.get("margin")
            margin = f"{margin:.3g}" if isinstance(margin, (int, float)) and \
                math.isfinite(margin) else ""
            problems = v.get("problems") or 0
            share = f"{v.get('problems_lost', 0) / problems:6.1%}" if problems else ""
            print(f"{row['function']:<24} {label:<46} {v['lost']:>6} / {v['draws']:<6} "
                  f"[{v['low']:.4f}, {v['high']:.4f}]   {share:>18} {margin:>7}", file=out)
    trivial = [row for row in report.functions if row.get("trivial")]
    if trivial:
        print(f"\ntrivial answers: mean share of the function's points (at most "
              f"{fairness.TRIVIAL_LIMIT:.0%}), 95 % interval, the check that credits it",
              file=out)
        print(f"{'function':<24} {'trivial answer':<46} {'draws':>6} {'mean':>7}  "
              f"{'95% interval':<18} check", file=out)
        for row in trivial:
            best = row["trivial"][0]
            shown = [best] + [t for t in row["trivial"][1:]
                              if t["mean"] > fairness.TRIVIAL_LIMIT]
            for t in shown:
                flag = "FAIL " if t["mean"] > fairness.TRIVIAL_LIMIT else ""
                print(f"{row['function']:<24} {_clip(t['answer'], 46):<46} {t['draws']:>6} "
                      f"{t['mean']:>7.2%}  [{t['low']:.3f}, {t['high']:.3f}]   "
                      f"{flag}{t['check'] or '-'}", file=out)
    tolerances = [row for row in report.functions if row.get("tolerances")]
    if tolerances:
        print("\ntolerances over the draws (full credit within), in each check's unit; the "
              "typical error of the best trivial answer beside them", file=out)
        print(f"{'function':<24} {'check':<14} {'unit':<9} {'smallest':>10} {'largest':>22} "
              f"{'trivial error':>14}", file=out)
        for row in tolerances:
            for t in row["tolerances"]:
                if not math.isfinite(t["high"]):
                    continue
                typical = t["trivial_error"]
                typical = f"{typical:.3g}" if math.isfinite(typical) else "-"
                print(f"{row['function']:<24} {t['check']:<14} {t['unit'] or '(ratio)':<9} "
                      f"{t['low']:>10.3g} {_quantity(t['high'], t['unit']):>22} "
                      f"{typical:>14}", file=out)
    _print_families(report, out)
    print("", file=out)
    for row in report.functions:
        if row.get("worst_draw") is not None:
            print(f"{row['function']}: reference's worst draw {row['worst_draw']}, largest "
                  f"error / tolerance {row['worst_margin']:.3g}", file=out)
    for f in report.warnings:
        print(f"WARN {f.check}: {f.message}", file=out)
    for f in report.findings:
        print(f"FAIL {f.check}: {f.message}", file=out)
    verdict = "passed" if report.passed else f"FAILED ({len(report.findings)} problem" + \
        ("s)" if len(report.findings) > 1 else ")")
    print(f"{report.lab}: {verdict} in {report.seconds:.0f} s", file=out)


def _print_families(report: Report, out) -> None:
    """The family table: per function, each family that applies with its loss share, then
    in one line the families that do not apply."""
    rows = [row for row in report.functions if row.get("families")]
    if not rows:
        return
    print("\nmistake families: share of the draws on which the family's answer loses credit "
          "(where it applies), 95 % interval; below 99 %: a hole", file=out)
    print(f"{'function':<24} {'family':<22} {'mistake':<26} {'lost / draws':>14}  "
          f"{'share':>7}  95% interval", file=out)
    for row in rows:
        for f in row["families"]:
            if f["status"] != APPLIES:
                continue
            flag = "  HOLE" if f["share"] < MISTAKE_TARGET else ""
            print(f"{row['function']:<24} {_clip(f['family'], 22):<22} "
                  f"{_clip(f['mistake'], 26):<26} {f['lost']:>6} / {f['draws']:<6} "
                  f"{f['share']:>7.1%}  [{f['low']:.3f}, {f['high']:.3f}]{flag}", file=out)
        for status in (NOT_APPLICABLE, NO_REFERENCE):
            names = [f"{f['family']} ({f['mistake']})" for f in row["families"]
                     if f["status"] == status]
            if names:
                print(f"{row['function']:<24} {status}: " + ", ".join(names), file=out)


# --------------------------------------------------------------------------- --worst


def _py(value) -> str:
    """``value`` as Python source that rebuilds it exactly (numpy arrays with their dtype,
    floats by their shortest round-tripping repr, NaN and inf spelled out)."""
    if isinstance(value, np.ndarray):
        return f"np.array({_py(value.tolist())}, dtype={value.dtype.name!r})"
    if isinstance(value, (bool, np.bool_)):
        return repr(bool(value))
    if isinstance(value, (int, np.integer)):
        return repr(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isnan(value):
            return "float('nan')"
        if math.isinf(value):
            return "float('inf')" if value > 0 else "-float('inf')"
        return repr(value)
    if isinstance(value, tuple):
        inner = ", ".join(_py(v) for v in value)
        return f"({inner},)" if len(value) == 1 else f"({inner})"
    if isinstance(value, list):
        return "[" + ", ".join(_py(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_py(k)}: {_py(v)}" for k, v in value.items()) + "}"
    if value is None or isinstance(value, str):
        return repr(value)
    raise TypeError(f"cannot write a {type(value).__name__} as a Python literal")


def worst_cell(lab: str, spec: FunctionSpec, student: str, problem: int,
               note: str = "") -> str:
    """A notebook cell (Python source) that rebuilds problem ``problem`` of ``student``'s
    hidden problems of ``spec`` (as verify drew them), calls the notebook's function on it and
    prints the measured errors, the tolerances and the score. It holds the hidden truth:
    for the author's notebook, never a released one."""
    trials = checks.make_trials(spec, problem_rng(SECRET, None, lab, student,
                                                          spec.name))
    trial = trials[problem]
    call = f"spec.drive({spec.name}, trial)" if spec.drive is not None else \
        f"{spec.name}(*trial.args)"
    lines = [f"# {lab}.{spec.name}: problem {problem} of {student}'s hidden problems "
             f"({trial.label!r}), from `cobotlab labs verify --worst`."]
    lines += [f"# {part}" for part in note.splitlines() if part]
    lines += [
        "# It holds the hidden truth: keep it in the author's notebook, never in a release.",
        "import numpy as np",
        "",
        "from autograder import checks"
        "",
        f"spec = checks.spec_for({spec.name!r}, assignment={lab!r})",
        "trial = checks.Trial(",
        f"    args={_py(tuple(trial.args))},",
        f"    truth={_py(trial.truth)},",
        f"    tol={_py(dict(trial.tol))},",
        f"    label={trial.label!r}, all_or_nothing={trial.all_or_nothing!r}, "
        f"raises={trial.raises!r})",
        "try:",
        f"    answer = {call}",
        "    outcome = checks.TrialOutcome(value=answer)",
        "    print('errors:', spec.measure(answer, trial), 'tolerances:', trial.tol)",
        "except Exception as exc:",
        "    outcome = checks.TrialOutcome(error=f'{type(exc).__name__}: {exc}',",
        "                                  failure=checks.raised(type(exc).__name__))",
        "print(checks.score_function(spec, [trial], [outcome]).summary())",
    ]
    return "\n".join(lines) + "\n"


def _worst_cells(report: Report) -> list[str]:
    specs = {s.name: s for s in registry.specs(report.lab)}
    cells = []
    for row in report.functions:
        worst = row.get("worst_problem")
        if not worst or worst.get("problem") is None or row["function"] not in specs:
            continue
        unit = f" {worst['unit']}" if worst.get("unit") else ""
        note = (f"The reference's largest error / tolerance over {report.draws} draws: "
                f"{row['worst_margin']:.3g}" + (
                    f" (check {worst['check']}: {worst['error']:.3g}{unit} of "
                    f"{worst['tolerance']:.3g}{unit})." if worst.get("check") else "."))
        cells.append(worst_cell(report.lab, specs[row["function"]], worst["draw"],
                                worst["problem"], note))
    return cells


def run_verify(path: str, draws: int | None = None, json_out: str | None = None,
               worst: bool = False) -> int:
    """The command: verify the lab PATH names, print the table, write the JSON; with
    ``worst``, then print each function's worst problem as a notebook cell. 0 when the lab
    passed, 1 when it did not."""
    if draws is not None and draws < 1:
        raise ValueError(f"--draws must be at least 1, got {draws}")
    name = _lab_from_path(path)
    report = verify_lab(name, draws)
    _print(report)
    target = Path(json_out) if json_out else registry.verification_path(name)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(report.to_json(), indent=1, default=float) + "\n")
    print(f"wrote {target}")
    if worst:
        for cell in _worst_cells(report):
            print(f"\n# ---- cell ----\n{cell}", end="")
    return 0 if report.passed else 1

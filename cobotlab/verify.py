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
  must lose it on at least 99 % of draws (the Clopper-Pearson 95 % lower bound).

The default N is the smallest number of draws whose 0 losses bound the loss rate below 1e-3
(95 % Clopper-Pearson); ``--draws 10000`` is for a release. The JSON report (default
``.cobotlab/verified/<lab>.json``, beside the private specs) holds the hash of the lab's
scoring and spec, which ``cobotlab grade`` compares before it grades.
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

from autograder import checks, fairness, grading, registry, wire
from autograder.spec_types import FunctionSpec, Trial

__all__ = ["Finding", "run_verify", "verify_lab", "DEFAULT_RATE", "MISTAKE_DRAWS"]

DEFAULT_RATE = 1e-3          # the reference's loss rate the default draws can bound
MISTAKE_TARGET = 0.99        # a mistake's Clopper-Pearson lower bound must reach this
MISTAKE_DRAWS = 1000         # 1,000 losses in 1,000 draws bound the rate above 99.6 %
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

    @property
    def passed(self) -> bool:
        return not self.findings

    def to_json(self) -> dict:
        return {"lab": self.lab, "spec_hash": self.spec_hash, "draws": self.draws,
                "passed": self.passed, "findings": [asdict(f) for f in self.findings],
                "functions": self.functions, "seconds": round(self.seconds, 1)}


# --------------------------------------------------------------------------- the notebook


def _cells(path: Path) -> list[dict]:
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def _meta(cell: dict) -> dict:
    meta = cell.get("metadata", {}).get("nbgrader", {})
    return meta if isinstance(meta, dict) else {}


def _solution_defs(cells: list[dict]) -> dict[str, list[ast.FunctionDef]]:
    """{function name: its defs} in the notebook's solution cells."""
    found: dict[str, list] = {}
    for cell in cells:
        if cell.get("cell_type") != "code" or not _meta(cell).get("solution"):
            continue
        try:
            tree = ast.parse(grading.cell_source(cell))
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
    if not any(SOLUTION_BEGIN in grading.cell_source(c) for c in cells):
        findings.append(Finding("solution region", f"{notebook}: no cell holds a "
                                f"{SOLUTION_BEGIN} ... {SOLUTION_END} region; put the "
                                "reference code of each graded function between them, in a "
                                "cell whose nbgrader metadata says solution"))
    defs = _solution_defs(cells)
    tests = {_meta(c).get("grade_id"): c for c in cells
             if c.get("cell_type") == "code" and _meta(c).get("grade")}
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
        if f"check({name}" not in grading.cell_source(test):
            findings.append(Finding("test cell", f"{notebook}: cell test_{name} does not call "
                                    f"check({name}); students see their score there", name))
        points = _meta(test).get("points")
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
    from autograder.forbidden import _resolve

    return [Finding("forbidden", f"{spec.name}: forbidden routine {dotted!r} names nothing "
                    "importable here; spell it as module.attribute (e.g. "
                    "'cv2.calibrateHandEye') or the ban catches nothing", spec.name)
            for spec in specs for dotted in spec.forbidden if _resolve(dotted) is None]


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
    streams = [grading.problem_rng(SECRET, None, lab, sid, spec.name)
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
    solutions = {_meta(c).get("grade_id"): grading.cell_source(c) for c in _cells(source)
                 if _meta(c).get("solution")}
    for cell in released.cells:
        grade_id = _meta(cell).get("grade_id")
        if grade_id in solutions:
            cell.source = "\n".join(line for line in solutions[grade_id].splitlines()
                                    if line.strip() not in (SOLUTION_BEGIN, SOLUTION_END))
    return nbformat.from_dict(released)


class SandboxedReference:
    """The reference notebook loaded once in the grader's bubblewrap worker; calls go there.
    A worker that dies (a limit, a crash) is started again for the next problem."""

    def __init__(self, source: Path, limits: grading.Limits):
        import nbformat

        self.limits = limits
        self._folder = tempfile.TemporaryDirectory(prefix="cobotlab-verify-")
        path = Path(self._folder.name) / source.name
        nbformat.write(reference_notebook(source), path)
        self.cells, _ = grading.extract_code(path)
        self.worker = None
        self.load_errors: list[str] = []
        self.tripped: set[str] = set()
        self._start()

    def _start(self) -> None:
        # A day of CPU: the worker answers thousands of problems, and this is the author's code.
        self.worker = grading.Worker(self.cells, self.limits, cpu_s=86400)
        self.load_errors = [f"cell {r.get('index')}: {r.get('error')}"
                            for r in self.worker.load_report if not r.get("ok")]

    def __call__(self, spec: FunctionSpec, trial: Trial, retries: int = 1) -> checks.TrialOutcome:
        if self.worker is None or not self.worker.alive:
            self._start()
        worker = self.worker

        def once(args, timeout_s):
            return worker.call(spec.name, args, timeout_s, spec.forbidden,
                               spec.substitutes(args) if spec.substitutes else None)

        try:
            outcome = checks.run_trial(spec, trial, once, self.limits.call_limit_s(spec),
                                       self.limits.wall_factor)
        except grading.WorkerFailure as exc:
            worker.close()
            self.worker = None
            return checks.TrialOutcome(error=f"the worker stopped: {exc}")
        except grading.GraderError:   # a busy machine starved it: not the reference's loss
            self.worker = None
            if retries:
                return self(spec, trial, retries - 1)
            raise
        self.tripped |= worker.tripped
        worker.tripped.clear()
        return outcome

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
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
               limits: grading.Limits | None = None) -> Report:
    """Verify lab ``name`` (static checks, then ``draws`` hidden draws per function: default
    the smallest number that bounds a 0-loss rate below 1e-3). Never raises for a broken lab:
    every problem is a :class:`Finding` of the report."""
    started = time.monotonic()
    draws = draws or fairness.draws_for_rate(DEFAULT_RATE)
    lab = registry.find_lab(name)
    report = Report(name, "", draws)
    try:
        report.spec_hash = registry.spec_hash(name)
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
    if not grading.sandbox_available():
        report.findings.append(Finding("sandbox", "bubblewrap is not available here, and "
                                       "verify runs the reference where the grader runs "
                                       "student code: install it (sudo apt-get install "
                                       "bubblewrap) and allow unprivileged user namespaces"))
        report.seconds = time.monotonic() - started
        return report
    if any(f.check in ("solution region", "release") for f in report.findings):
        report.seconds = time.monotonic() - started
        return report   # no reference to run
    reference = SandboxedReference(lab.notebook, limits or grading.Limits())
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
        return grading.problem_rng(SECRET, None, lab, student, spec.name)

    def watched(spec_, trial):
        if not seen_practice and _fingerprint(spec_, trial) in practice:
            seen_practice.append(trial.label)
        return reference(spec_, trial)

    callers = {"reference": watched}
    callers.update((m.label, fairness.in_process(m.func)) for m in spec.code_mistakes)
    totals: dict[str, fairness.DrawStats] = {}
    worst_draw, worst_margin = None, -math.inf
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=draws, unit="draw", desc=f"{lab}.{spec.name}", file=sys.stderr,
                   leave=False)
    try:
        for k in range(draws):
            one = fairness.score_draws(spec, lab, range(k, k + 1), callers, rng_of,
                                       correct=("reference",),
                                       mistakes_stop=min(draws, MISTAKE_DRAWS))
            if one["reference"].margin > worst_margin:
                worst_draw, worst_margin = fairness.student_id(k), one["reference"].margin
            totals = {name: totals[name].merged(s) if name in totals else s
                      for name, s in one.items()}
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    row = {"function": spec.name, "points": spec.points, "variants": [],
           "worst_draw": worst_draw, "worst_margin": worst_margin}
    for label, stats in totals.items():
        low, high = fairness.clopper_pearson(stats.lost, stats.seen)
        loss = stats.first_loss
        row["variants"].append({
            "variant": label, "correct": stats.correct, "draws": stats.seen,
            "lost": stats.lost, "low": low, "high": high,
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
    return row


def _draws_to_show(rate: float) -> int:
    """The fewest draws whose all-lost count bounds a rate above ``rate`` (95 %: 367 for
    0.99), the mirror image of :func:`fairness.draws_for_rate`."""
    return fairness.draws_for_rate(1 - rate)


# --------------------------------------------------------------------------- the table


def _print(report: Report, out=None) -> None:
    out = out or sys.stdout   # looked up now: a caller may have redirected it
    print(f"cobotlab labs verify {report.lab}: {report.draws} hidden draws per function, "
          f"spec {report.spec_hash}", file=out)
    print(f"{'function':<24} {'variant':<46} {'lost / draws':>14}  {'95% interval':<20} "
          f"{'margin':>7}", file=out)
    for row in report.functions:
        for v in row["variants"]:
            label = ("+ " if v["correct"] else "- ") + v["variant"]
            label = label if len(label) <= 46 else label[:43] + "..."
            margin = v.get("margin")
            margin = f"{margin:.3g}" if isinstance(margin, (int, float)) and \
                math.isfinite(margin) else ""
            print(f"{row['function']:<24} {label:<46} {v['lost']:>6} / {v['draws']:<6} "
                  f"[{v['low']:.4f}, {v['high']:.4f}]   {margin:>7}", file=out)
    for row in report.functions:
        if row.get("worst_draw") is not None:
            print(f"{row['function']}: reference's worst draw {row['worst_draw']}, largest "
                  f"error / tolerance {row['worst_margin']:.3g}", file=out)
    for f in report.findings:
        print(f"FAIL {f.check}: {f.message}", file=out)
    verdict = "passed" if report.passed else f"FAILED ({len(report.findings)} problem" + \
        ("s)" if len(report.findings) > 1 else ")")
    print(f"{report.lab}: {verdict} in {report.seconds:.0f} s", file=out)


def run_verify(path: str, draws: int | None = None, json_out: str | None = None) -> int:
    """The command: verify the lab PATH names, print the table, write the JSON; 0 when the
    lab passed, 1 when it did not."""
    if draws is not None and draws < 1:
        raise ValueError(f"--draws must be at least 1, got {draws}")
    name = _lab_from_path(path)
    report = verify_lab(name, draws)
    _print(report)
    target = Path(json_out) if json_out else registry.verification_path(name)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(report.to_json(), indent=1, default=float) + "\n")
    print(f"wrote {target}")
    return 0 if report.passed else 1

"""Practice problems as data: what ``check()`` and ``hidden_test()`` score on, in every install.

The generators that draw a lab's problems compute their truths, so they are the instructor's
(``autograder/specs``, not in the student package). For the public seeds
(``checks.PUBLIC_SEEDS``, what ``check()`` shows) and the kernel seeds
(``checks.KERNEL_SEEDS``, what nbgrader's in-kernel ``hidden_test()`` uses) the private side
draws the very problems ``checks.public_trials`` draws (same random stream, same counts) and
writes them, with what scoring needs beside them, to one file per lab,
``practice_<assignment>.json.gz`` next to the lab's notebook: per problem its inputs, truth,
tolerances, label, edge-case flags, the answers its classic mistakes give, and the stand-in
tables of the graded functions it relies on (see :class:`autograder.spec_types.Trial`).

The file is data only: JSON in :mod:`autograder.inside.wire`'s encoding (arrays as raw little-endian
bytes of a whitelisted dtype, sizes capped), gzipped; never pickle, so a file from anywhere
cannot run code. :func:`load_practice` looks for it in ``$COBOTLAB_PRACTICE_DIR`` (nbgrader's
kernel sandbox points it at the assignment's folder), then in the current folder (a
notebook's kernel starts in its lab folder); only when neither has it and the private
generators are importable (an instructor's install) does it build the same data in memory.

Drawing the public and kernel seeds' problems costs seconds of CPU a lab, so the private side
keeps them in the instructor's cache (:mod:`autograder.practice_cache`), checked on every read
as a student's file is; :func:`drawn` is the draw itself.
"""

from __future__ import annotations

import gzip
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from autograder import families, registry
from autograder.inside import wire
from autograder.spec_types import FunctionSpec, Trial, mistake_answers

__all__ = ["ENV_DIR", "PracticeDataError", "PracticeSet", "build_practice", "drawn",
           "load_practice",
           "practice_file_name", "practice_rng", "practice_trials", "precomputed_mistakes",
           "releasable",
           "save_practice", "write_practice"]

# The seeds check() shows a student (autograder.checks re-exports both).
PUBLIC_SEEDS = (0, 1, 2)
# The seeds nbgrader's in-kernel hidden tests use; not secret (the kernel is not trusted), just
# different from the practice seeds. The authoritative grade uses secret per-student seeds.
KERNEL_SEEDS = (1001, 1002)
ENV_DIR = "COBOTLAB_PRACTICE_DIR"
FORMAT = 1
# Far above the largest lab's file (lab 3's depth images, ~9 MB of JSON): a cap, so a damaged
# or hostile file cannot make the kernel allocate without bound.
MAX_JSON_BYTES = 128 * 1024 * 1024
_TRIAL_KEYS = ("args", "truth", "tol", "label", "all_or_nothing", "raises", "mistakes",
               "substitutes")


class PracticeDataError(Exception):
    """The practice data is missing, damaged, or lacks the problems asked for."""


def practice_rng(seed: int) -> np.random.Generator:
    """The random stream of practice seed ``seed`` (``checks.public_trials`` draws from it)."""
    return np.random.default_rng([20240917, int(seed)])


def practice_file_name(assignment: str) -> str:
    """The name of ``assignment``'s practice data file, which sits next to its notebook."""
    return f"practice_{assignment}.json.gz"


# --------------------------------------------------------------------------- the private side


def _full_spec(assignment: str, name: str) -> FunctionSpec:
    for spec in registry.specs(assignment):
        if spec.name == name:
            return spec
    raise PracticeDataError(f"{assignment} grades no function named {name!r}")


def _encode_trial(spec: FunctionSpec, trial: Trial) -> dict:
    """``trial`` in the file's form, with its mistakes and stand-in tables computed now."""
    mistakes = precomputed_mistakes(spec, trial)
    # With a drive the stand-ins are needed at states only the closed loop reaches: the
    # public scoring entry derives those tables itself.
    tables = spec.substitutes(trial.args) if spec.substitutes and spec.drive is None else None
    return wire.encode({
        "args": tuple(trial.args), "truth": trial.truth, "tol": dict(trial.tol),
        "label": trial.label, "all_or_nothing": bool(trial.all_or_nothing),
        "raises": trial.raises, "mistakes": mistakes, "substitutes": tables})


def precomputed_mistakes(spec: FunctionSpec, trial: Trial) -> list[tuple]:
    """What practice data carries of ``trial``'s mistakes: ``(words, answer, family)`` of
    each code mistake (family None) and each input-side mistake family (the private
    reference called on transformed inputs; the output side is computed from the truth
    where check() runs), so a student's install names them without any answer code."""
    code = [(str(words), value, None) for words, value in mistake_answers(spec, trial)]
    inputs = families.predictions(spec, trial, sides=(families.INPUT,))
    return code + [(name.words, p.answer, name.family) for name, p in inputs]


def _built(assignment: str, name: str, seed: int) -> tuple:
    """The encoded practice problems of one function and seed, drawn by its generator (kept
    in memory and on disk per version of the lab's spec and of the code that draws it:
    another course's lab of that name, or an edited spec, is drawn again)."""
    return _built_for(assignment, name, seed, registry.spec_hash(assignment))


@lru_cache(maxsize=256)
def _built_for(assignment: str, name: str, seed: int, spec_hash: str) -> tuple:
    # Drawn once per machine (autograder.practice_cache), not once per process: the six
    # built-in labs cost ~12 s of CPU in every process that laid out a course. Imported
    # here: only the private side draws, and nbgrader's kernel view lists no cache module.
    from autograder import practice_cache

    if int(seed) not in _default_seeds():   # the cache holds released data only
        return drawn(assignment, name, seed)
    return tuple(practice_cache.cached(
        assignment, practice_cache.key(assignment, spec_hash, FORMAT), f"{name}-{int(seed)}",
        lambda: list(drawn(assignment, name, seed)), _check_cached))


def _check_cached(encoded: list, where: str) -> None:
    """Refuse a cache file holding anything a student's file could not (the same checks)."""
    for data in encoded:
        _trial_from(data, where)


def drawn(assignment: str, name: str, seed: int) -> tuple:
    """The encoded practice problems of one function and seed, drawn by its generator now
    (no cache: what the cache stores, and what tests of the drawing itself compare)."""
    spec = _full_spec(assignment, name)
    rng = practice_rng(seed)
    n = spec.practice_trials or spec.n_trials
    try:
        return tuple(_encode_trial(spec, spec.make_trial(rng, i)) for i in range(n))
    except Exception as exc:  # noqa: BLE001 - the author's generator: say which and where
        raise registry.LabError(
            f"{registry.spec_path(assignment)}: the generator of {name} raised while drawing "
            f"practice problems (seed {seed}): {type(exc).__name__}: {exc} "
            f"({registry.raised_at(exc)}); fix make_trial, then run `cobotlab labs verify` "
            "on the lab") from None


def _default_seeds() -> tuple[int, ...]:
    return tuple(PUBLIC_SEEDS) + tuple(KERNEL_SEEDS)


def build_practice(assignment: str, seeds=None) -> dict:
    """The practice data of ``assignment`` (a JSON-ready dict) for ``seeds`` (default: the
    public and the kernel seeds). Needs the private generators."""
    if not registry.private_available(assignment):
        raise PracticeDataError(f"building practice data of {assignment} needs its private "
                                "spec (the instructor's install of cobotlab, or the course "
                                "repository of an instructor's lab)")
    seeds = tuple(int(s) for s in (_default_seeds() if seeds is None else seeds))
    specs = registry.specs(assignment)
    return {"cobotlab_practice": FORMAT, "assignment": assignment, "seeds": list(seeds),
            "functions": {spec.name: {str(seed): list(_built(assignment, spec.name, seed))
                                      for seed in seeds} for spec in specs}}


def releasable(names, force: bool = False) -> tuple[dict[str, dict], dict[str, str]]:
    """({lab: practice data}, {lab: why it is skipped}) of the labs ``names`` that are to be
    released (``course init``, ``labs student``): a lab that does not load, whose generators
    raise, or whose last ``labs verify`` failed (unless ``force``) is skipped, with the
    reason and the fix (:func:`autograder.registry.release_problem`), never stopping the
    others."""
    documents: dict[str, dict] = {}
    skipped: dict[str, str] = {}
    for name in names:
        why = registry.release_problem(name, force=force)
        if why is None:
            try:
                documents[name] = build_practice(name)
            except registry.LabError as exc:
                why = f"it does not load: {exc}"
        if why is not None:
            skipped[name] = why
    return documents, skipped


def write_practice(assignment: str, folder, seeds=None) -> Path:
    """Write ``assignment``'s practice data into ``folder`` (next to its notebook, where
    ``check()`` finds it); return the file's path. Needs the private generators."""
    return save_practice(build_practice(assignment, seeds), folder)


def save_practice(document: dict, folder) -> Path:
    """Write practice data made by :func:`build_practice` into ``folder``; return its path."""
    body = json.dumps(document, separators=(",", ":"), allow_nan=True).encode("utf-8")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / practice_file_name(document["assignment"])
    partial = path.with_name(path.name + ".partial")
    # mtime=0: the same problems give the same bytes, so a re-release changes no file.
    # Level 6: level 9 took twice the CPU (1.6 s of `course init`'s 9.5 s for the six built-in
    # labs) for files 0.2 % smaller.
    partial.write_bytes(_compressed(body))
    partial.replace(path)
    return path


def _compressed(body: bytes) -> bytes:
    """``body`` gzipped, through the instructor's cache (only the private side releases
    practice data; its drawing is cached there too)."""
    from autograder import practice_cache

    return practice_cache.compressed(
        body, lambda data: gzip.compress(data, compresslevel=6, mtime=0))


# --------------------------------------------------------------------------- loading


def _damaged(where: str, why: str) -> PracticeDataError:
    return PracticeDataError(f"{where} is damaged ({why}); download the whole lab folder again "
                             "(the notebook and the files beside it)")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _trial_from(data, where: str) -> Trial:
    """A :class:`Trial` from its encoded form, checked to hold only what a trial may."""
    try:
        fields = wire.decode(data)
    except (wire.WireError, ValueError, TypeError, RecursionError) as exc:
        raise _damaged(where, f"{type(exc).__name__}: {exc}") from None
    if not isinstance(fields, dict) or set(fields) != set(_TRIAL_KEYS):
        raise _damaged(where, "a problem without the expected fields")
    args, tol, mistakes, tables = (fields["args"], fields["tol"], fields["mistakes"],
                                   fields["substitutes"])
    if not isinstance(args, tuple):
        raise _damaged(where, "a problem's inputs are not a tuple")
    if not isinstance(tol, dict) or not all(_is_number(v) for v in tol.values()):
        raise _damaged(where, "a problem's tolerances are not numbers")
    if not isinstance(fields["label"], str) or not isinstance(fields["all_or_nothing"], bool) \
            or not (fields["raises"] is None or isinstance(fields["raises"], str)):
        raise _damaged(where, "a problem's label or flags")
    if not isinstance(mistakes, list) or not all(
            isinstance(m, tuple) and len(m) in (2, 3) and isinstance(m[0], str)
            and (len(m) == 2 or m[2] is None or isinstance(m[2], str)) for m in mistakes):
        raise _damaged(where, "a problem's mistakes are not (words, answer[, family]) tuples")
    if tables is not None and not (isinstance(tables, dict) and all(
            isinstance(entries, list) and all(
                isinstance(e, tuple) and len(e) == 2 and isinstance(e[0], tuple)
                for e in entries) for entries in tables.values())):
        raise _damaged(where, "a problem's stand-in tables are not (inputs, value) pairs")
    return Trial(args=args, truth=fields["truth"], tol=tol, label=fields["label"],
                 all_or_nothing=fields["all_or_nothing"], raises=fields["raises"],
                 mistakes=mistakes, substitutes=tables)


class PracticeSet:
    """One lab's practice problems: from its file, or drawn in memory by the private side."""

    def __init__(self, assignment: str, source: str, functions: dict | None = None):
        self.assignment = assignment
        self.source = source               # the file's path, or how the data was made
        self._functions = functions or {}  # {name: {str(seed): [encoded trial, ...]}}

    @property
    def seeds(self) -> list[int]:
        """The seeds the file holds (every function has the same)."""
        found = {int(s) for seeds in self._functions.values() for s in seeds}
        return sorted(found)

    def trials(self, name: str, seed: int) -> list[Trial]:
        """The practice problems of graded function ``name`` for ``seed`` (fresh objects)."""
        encoded = self._functions.get(name, {}).get(str(int(seed)))
        if encoded is None:
            if not registry.private_available(self.assignment):
                have = ", ".join(str(s) for s in self.seeds) or "none"
                raise PracticeDataError(
                    f"{self.source} holds no practice problems of {name} for seed {seed} (its "
                    f"seeds: {have}); call check() without seeds= to use them")
            encoded = _built(self.assignment, name, int(seed))
        return [_trial_from(e, self.source) for e in encoded]


def _read(path: Path, assignment: str) -> PracticeSet:
    where = str(path)
    try:
        with gzip.open(path, "rb") as f:
            body = f.read(MAX_JSON_BYTES + 1)
    except (OSError, EOFError) as exc:
        raise _damaged(where, f"{type(exc).__name__}: {exc}") from None
    if len(body) > MAX_JSON_BYTES:
        raise _damaged(where, f"larger than {MAX_JSON_BYTES} bytes")
    try:
        document = json.loads(body.decode("utf-8"))
    except (ValueError, RecursionError) as exc:
        raise _damaged(where, f"not JSON: {type(exc).__name__}") from None
    if not isinstance(document, dict) or document.get("cobotlab_practice") != FORMAT:
        raise _damaged(where, f"not cobotlab practice data of format {FORMAT}")
    if document.get("assignment") != assignment:
        raise _damaged(where, f"it holds {document.get('assignment')!r}, not {assignment!r}")
    functions = document.get("functions")
    if not isinstance(functions, dict) or not all(
            isinstance(by_seed, dict) and all(isinstance(v, list) for v in by_seed.values())
            for by_seed in functions.values()):
        raise _damaged(where, "no problems per function and seed")
    return PracticeSet(assignment, where, functions)


def _candidates(assignment: str) -> list[Path]:
    name = practice_file_name(assignment)
    folders = [os.environ.get(ENV_DIR), os.getcwd()]
    return [Path(folder) / name for folder in folders if folder]


_loaded: dict[tuple, PracticeSet] = {}


def load_practice(assignment: str) -> PracticeSet:
    """``assignment``'s practice problems: its file from ``$COBOTLAB_PRACTICE_DIR`` or the
    current folder, else (an instructor's install) drawn in memory by the private side.

    Raises :class:`PracticeDataError` in a student's install without the file, saying where
    it was looked for and how to get it.
    """
    candidates = _candidates(assignment)
    for path in candidates:
        try:
            stat = path.stat()
        except OSError:
            continue
        key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
        if key not in _loaded:
            _loaded[key] = _read(path, assignment)
        return _loaded[key]
    if registry.private_available(assignment):
        return PracticeSet(assignment, "the private generators (drawn in memory)")
    looked = " and ".join(str(p.parent) for p in candidates)
    raise PracticeDataError(
        f"the practice problems of {assignment} are in {practice_file_name(assignment)}, "
        f"which sits next to the lab's notebook, and it is not there (looked in {looked}); "
        "download the whole lab folder (the notebook and the files beside it) and open the "
        "notebook from that folder")


def practice_trials(assignment: str, name: str, seeds) -> list[Trial]:
    """The practice problems of ``assignment``'s graded function ``name`` for ``seeds``."""
    practice = load_practice(assignment)
    return [t for seed in seeds for t in practice.trials(name, seed)]

"""Does every install resolve to wheels only, on every system students and lab staff use?

Run:  .venv/bin/python benchmarks/wheels_everywhere.py [--workers 16]
                                                       [--systems win-amd64,mac-arm64]

Asks the package registry, with pip's own resolver (``pip install --dry-run --report
--only-binary :all: --platform ... --python-version ...``, installed packages ignored), for
each of the 20 targets: Windows amd64, macOS arm64 and x86_64, Linux x86_64 and aarch64, each
with CPython 3.10 to 3.13. Per target it checks

* the **student** install: the requirements of ``student/pyproject.toml`` (the wheel
  ``cobotlab_student-*.whl`` that docs/students.md installs);
* the **course** install: the main package with its ``course`` extra (docs/instructors.md);
* the **real** extra: each robot SDK where the table "Robot SDK wheels" of
  docs/instructors.md says it has a wheel must resolve beside the course install, and each one
  it says has none must fail to resolve, so the table stays true.

One pip call per target asks for all three at once (a set that resolves has subsets that do);
only when it fails are the installs asked one by one, to name the one that breaks. Each "no
wheel" cell of the table costs one more small call (``--no-deps``). All calls run at once:
each mostly waits on the registry (pip's HTTP cache keeps the files' metadata, but pip
revalidates every index page it reads, one round trip each).

pip evaluates environment markers (``pywinpty; os_name == "nt"``, ``tomli; python_version <
'3.11'``) against the Python running it, not the target, even with ``--platform``: each call
therefore runs pip with its marker environment set to the target's, so the dependencies a
Windows or a Python 3.10 install really pulls in are the ones checked.

pip's configuration files and its ``PIP_FIND_LINKS`` / ``PIP_EXTRA_INDEX_URL`` /
``PIP_CONSTRAINT`` are left out (a folder of local wheels would hide a wheel missing from the
registry); ``PIP_INDEX_URL``, ``PIP_CERT`` and the proxy variables are kept.

tests/test_wheels_everywhere.py runs a slice (one target per system, the Pythons spread
over them); this script runs all 20 and prints the matrix with its wall time and CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import tomllib
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
SDK_TABLE_DOC = ROOT / "docs" / "instructors.md"
SDK_TABLE_TITLE = "Robot SDK wheels"
PYTHONS = ("3.10", "3.11", "3.12", "3.13")

# The oldest system release each target stands for (what docs/students.md promises); a newer
# one accepts every wheel an older one does, so resolving for the oldest checks them all.
# macOS 12 on both processors: on 11, OpenCV >= 4.10 has no Intel wheel and SciPy no Apple
# silicon one for CPython 3.13 (checked with this script). glibc 2.31 on Linux (Ubuntu 20.04,
# Debian 11).
MACOS_INTEL = "12_0"
MACOS_ARM = "12_0"
GLIBC_MINOR = 31


@dataclass(frozen=True)
class System:
    """One operating system and processor: its pip platform tags and marker values."""

    key: str            # short name used in the docs' table and on the command line
    label: str
    platforms: tuple[str, ...]
    os_name: str
    sys_platform: str
    platform_system: str
    platform_machine: str


def _manylinux(arch: str, newest_minor: int) -> tuple[str, ...]:
    """Every manylinux tag a glibc 2.``newest_minor`` system accepts, newest first.

    pip expands a macOS ``--platform`` to the older releases but takes a Linux one literally,
    so the list is spelt out, with the legacy aliases (manylinux2014 = 2.17, 2010 = 2.12,
    1 = 2.5).
    """
    oldest = 5 if arch == "x86_64" else 17
    tags = [f"manylinux_2_{minor}_{arch}" for minor in range(newest_minor, oldest - 1, -1)]
    tags.append(f"manylinux2014_{arch}")
    if arch == "x86_64":
        tags += ["manylinux2010_x86_64", "manylinux1_x86_64"]
    return tuple(tags)


SYSTEMS = (
    System("linux-x86_64", "Linux x86_64", _manylinux("x86_64", GLIBC_MINOR),
           "posix", "linux", "Linux", "x86_64"),
    System("linux-aarch64", "Linux aarch64", _manylinux("aarch64", GLIBC_MINOR),
           "posix", "linux", "Linux", "aarch64"),
    System("win-amd64", "Windows amd64", ("win_amd64",), "nt", "win32", "Windows", "AMD64"),
    System("mac-arm64", "macOS arm64", (f"macosx_{MACOS_ARM}_arm64",),
           "posix", "darwin", "Darwin", "arm64"),
    System("mac-x86_64", "macOS x86_64", (f"macosx_{MACOS_INTEL}_x86_64",),
           "posix", "darwin", "Darwin", "x86_64"),
)


@dataclass(frozen=True)
class Target:
    system: System
    python: str         # "3.12"

    @property
    def name(self) -> str:
        return f"{self.system.label}, CPython {self.python}"

    def marker_environment(self) -> dict[str, str]:
        """PEP 508 marker values of this target (what its own pip would evaluate)."""
        full = f"{self.python}.0"
        return {
            "implementation_name": "cpython", "implementation_version": full,
            "platform_python_implementation": "CPython",
            "python_version": self.python, "python_full_version": full,
            "os_name": self.system.os_name, "sys_platform": self.system.sys_platform,
            "platform_system": self.system.platform_system,
            "platform_machine": self.system.platform_machine,
            "platform_release": "", "platform_version": "",
        }

    def pip_options(self) -> list[str]:
        abi = "cp" + self.python.replace(".", "")
        options = ["--only-binary", ":all:", "--python-version", self.python,
                   "--implementation", "cp", "--abi", abi, "--abi", "abi3", "--abi", "none"]
        for platform in self.system.platforms:
            options += ["--platform", platform]
        return options


TARGETS = tuple(Target(s, v) for s in SYSTEMS for v in PYTHONS)


@dataclass
class Resolution:
    """pip's answer for one set of requirements on one target."""

    ok: bool
    versions: dict[str, str] = field(default_factory=dict)   # name -> version, when ok
    missing: str = ""            # the requirement pip named as having no distribution
    errors: str = ""             # pip's ERROR lines, for the human reading a failure
    cpu_s: float = 0.0


# Run in the pip subprocess: pip's resolver, with markers evaluated as on the target.
_RUNNER = """
import json, sys
import pip._vendor.packaging.markers as markers
target_environment = json.loads(sys.argv[1])
markers.default_environment = lambda: dict(target_environment)
from pip._internal.cli.main import main
sys.exit(main(sys.argv[2:]))
"""

_KEPT_PIP_VARIABLES = {"PIP_INDEX_URL", "PIP_CERT", "PIP_CLIENT_CERT", "PIP_CACHE_DIR",
                       "PIP_DEFAULT_TIMEOUT", "PIP_PROXY", "PIP_RETRIES", "PIP_TRUSTED_HOST"}


def _pip_environment() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("PIP_") or k in _KEPT_PIP_VARIABLES}
    env["PIP_CONFIG_FILE"] = os.devnull
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def resolve(target: Target, requirements: list[str], *, no_deps: bool = False,
            python: str = sys.executable) -> Resolution:
    """Ask the registry whether ``requirements`` install from wheels alone on ``target``."""
    with tempfile.TemporaryDirectory(prefix="wheels-") as tmp:
        report = Path(tmp) / "report.json"
        # --target: pip before 23.1 takes --platform only with it (nothing is installed).
        argv = [python, "-c", _RUNNER, json.dumps(target.marker_environment()),
                "install", "--dry-run", "--ignore-installed", "--quiet", "--report",
                str(report), "--target", str(Path(tmp) / "target"), *target.pip_options(),
                *(["--no-deps"] if no_deps else []), *requirements]
        returncode, stderr, cpu = _run_measured(argv, Path(tmp))
        if returncode != 0:
            return _failure(stderr, cpu)
        installed = json.loads(report.read_text())["install"]
    versions = {item["metadata"]["name"].lower(): item["metadata"]["version"]
                for item in installed}
    return Resolution(True, versions, cpu_s=cpu)


def _run_measured(argv: list[str], tmp: Path) -> tuple[int, str, float]:
    """(exit code, stderr, CPU seconds of that process alone): calls run in parallel threads,
    so the CPU is read from the process's own rusage, not from the parent's totals."""
    with open(tmp / "stderr", "w+") as err:
        child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err,
                                 env=_pip_environment())
        try:
            _, status, usage = os.wait4(child.pid, 0)
        finally:
            child.returncode = -1   # reaped above; keeps Popen from waiting again
        err.seek(0)
        return (os.waitstatus_to_exitcode(status), err.read(),
                usage.ru_utime + usage.ru_stime)


def _failure(stderr: str, cpu: float) -> Resolution:
    errors = "\n".join(line for line in stderr.splitlines() if line.startswith("ERROR"))
    # pip names the requirement it found nothing for; the raw lines go along regardless.
    found = re.search(r"No matching distribution found for (\S+)", stderr)
    return Resolution(False, missing=found.group(1) if found else "(see pip's errors)",
                      errors=errors or stderr[-2000:], cpu_s=cpu)


# --- what each install asks for -----------------------------------------------------------

def _project(path: Path) -> dict:
    return tomllib.loads(path.read_text())["project"]


def student_requirements() -> list[str]:
    """What ``pip install cobotlab_student-*.whl`` resolves (student/pyproject.toml)."""
    return list(_project(ROOT / "student" / "pyproject.toml")["dependencies"])


def course_requirements() -> list[str]:
    """The main package's dependencies and its ``course`` extra (docs/instructors.md)."""
    project = _project(ROOT / "pyproject.toml")
    return [*project["dependencies"], *project["optional-dependencies"]["course"]]


def real_requirements() -> dict[str, str]:
    """The ``real`` extra's requirements by distribution name (markers kept)."""
    extra = _project(ROOT / "pyproject.toml")["optional-dependencies"]["real"]
    return {re.match(r"[A-Za-z0-9._-]+", req).group(0).lower(): req for req in extra}


def _marker_applies(requirement: str, target: Target) -> bool:
    marker = Requirement(requirement).marker
    return marker is None or marker.evaluate(target.marker_environment())


# --- the docs' table of robot SDK wheels ----------------------------------------------------

def _python_set(cell: str) -> frozenset[str]:
    """'3.10-3.12' / '3.10, 3.12' / 'none' (with any note in parentheses) -> the Pythons."""
    text = re.sub(r"\(.*?\)", "", cell).strip()
    if text.lower() in ("none", "no", "-", "—"):
        return frozenset()
    found: set[str] = set()
    for part in text.split(","):
        ends = [p.strip() for p in part.split("-")]
        unknown = set(ends) - set(PYTHONS)
        if unknown or len(ends) > 2:
            raise ValueError(f"the SDK wheel table's cell '{cell}' names Pythons "
                             f"{sorted(unknown)}: use {', '.join(PYTHONS)}, ranges like "
                             "3.10-3.12, or none")
        low, high = PYTHONS.index(ends[0]), PYTHONS.index(ends[-1])
        found.update(PYTHONS[low:high + 1])
    return frozenset(found)


def sdk_wheel_table(doc: Path = SDK_TABLE_DOC) -> dict[tuple[str, str], frozenset[str]]:
    """The table of docs/instructors.md: (SDK, system key) -> Pythons with a wheel."""
    text = doc.read_text()
    start = text.find(f"## {SDK_TABLE_TITLE}")
    if start < 0:
        raise ValueError(f"{doc} has no section '## {SDK_TABLE_TITLE}'")
    rows = [line for line in text[start:].splitlines() if line.startswith("|")]
    header = [c.strip(" `") for c in rows[0].strip("|").split("|")]
    labels = {s.label: s.key for s in SYSTEMS}
    table = {}
    for row in rows[2:]:
        cells = [c.strip() for c in row.strip("|").split("|")]
        system = labels.get(cells[0])
        if system is None:
            raise ValueError(f"the SDK wheel table's row '{cells[0]}' is none of "
                             f"{sorted(labels)}")
        for sdk, cell in zip(header[1:], cells[1:]):
            table[sdk.lower(), system] = _python_set(cell)
    return table


def expected_sdks(table, target: Target) -> tuple[list[str], list[str]]:
    """The ``real`` requirements the table says resolve on ``target``, and those it says
    have no wheel there (an SDK whose marker leaves the target out is in neither)."""
    have, lack = [], []
    for name, requirement in real_requirements().items():
        if (name, target.system.key) not in table:
            raise ValueError(f"the SDK wheel table of {SDK_TABLE_DOC.name} has no column "
                             f"'{name}' (row {target.system.label})")
        if not _marker_applies(requirement, target):
            continue
        wheel = target.python in table[name, target.system.key]
        (have if wheel else lack).append(requirement)
    return have, lack


# --- one target, every install ---------------------------------------------------------------

@dataclass
class TargetReport:
    target: Target
    failures: list[str]          # one sentence per problem, naming the package and target
    versions: dict[str, str]
    cpu_s: float
    calls: int


def _groups(have: list[str]) -> dict[str, list[str]]:
    return {"student install": student_requirements(),
            "course install": course_requirements(),
            "real extra (SDKs with a wheel per the table)": course_requirements() + have}


def _together(have: list[str]) -> list[str]:
    return sorted(set().union(*_groups(have).values()))


def _report(target: Target, have: list[str], together: Resolution,
            absent: dict[str, Resolution]) -> TargetReport:
    """Judge one target from its calls; when the joint call failed, ask each install alone
    (rare, so sequential) to name the one that breaks."""
    results = [together, *absent.values()]
    failures = []
    if not together.ok:
        for group, requirements in _groups(have).items():
            alone = resolve(target, requirements)
            results.append(alone)
            if not alone.ok:
                failures.append(f"{group}: no wheel for {alone.missing} on {target.name}\n"
                                f"{alone.errors}")
        if not failures:
            failures.append(f"all installs together: no wheel for {together.missing} on "
                            f"{target.name}\n{together.errors}")
    for requirement, alone in absent.items():
        if alone.ok:
            failures.append(f"{SDK_TABLE_DOC.name}'s '{SDK_TABLE_TITLE}' says {requirement} "
                            f"has no wheel on {target.name}, but the registry has "
                            f"{alone.versions}: update the table")
    return TargetReport(target, failures, together.versions,
                        sum(r.cpu_s for r in results), len(results))


def check_targets(targets, workers: int = 16, table=None) -> list[TargetReport]:
    """Every install on each target: one call for all that should resolve there, and one
    small call (``--no-deps``) per SDK the table says has no wheel there, all at once.

    Each call spends most of its time waiting on the registry (pip revalidates every index
    page it reads), so many run in parallel; their CPU is what they cost.
    """
    table = sdk_wheel_table() if table is None else table
    plans = [(target, *expected_sdks(table, target)) for target in targets]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        together = {t: pool.submit(resolve, t, _together(have)) for t, have, _ in plans}
        absent = {(t, req): pool.submit(resolve, t, [req], no_deps=True)
                  for t, _, lack in plans for req in lack}
        return [_report(t, have, together[t].result(),
                        {req: absent[t, req].result() for req in lack})
                for t, have, lack in plans]


# --- the command line ------------------------------------------------------------------------

SHOWN = ("numpy", "scipy", "opencv-python-headless", "mujoco", "matplotlib", "nbgrader")


def _print_matrix(reports: list[TargetReport]) -> None:
    print("| target | result | " + " | ".join(SHOWN) + " | pip calls | CPU s |")
    print("|" + " --- |" * (len(SHOWN) + 4))
    for r in reports:
        result = "ok" if not r.failures else "FAIL"
        shown = " | ".join(r.versions.get(name, "-") for name in SHOWN)
        print(f"| {r.target.name} | {result} | {shown} | {r.calls} | {r.cpu_s:.1f} |")
    for r in reports:
        for failure in r.failures:
            print(f"\n{failure}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=8,
                        help="pip calls at once (they mostly wait on the network)")
    parser.add_argument("--systems", default=",".join(s.key for s in SYSTEMS),
                        help="comma-separated: " + ", ".join(s.key for s in SYSTEMS))
    args = parser.parse_args(argv)
    keys = args.systems.split(",")
    unknown = set(keys) - {s.key for s in SYSTEMS}
    if unknown:
        parser.error(f"--systems: unknown {sorted(unknown)}; "
                     f"choose from {', '.join(s.key for s in SYSTEMS)}")
    targets = [t for t in TARGETS if t.system.key in keys]
    started, before = time.perf_counter(), os.times()
    reports = check_targets(targets, workers=args.workers)
    after = os.times()
    _print_matrix(reports)
    cpu = (after.children_user - before.children_user
           + after.children_system - before.children_system)
    calls = sum(r.calls for r in reports)
    print(f"\n{len(targets)} targets, {calls} pip calls: wall {time.perf_counter() - started:.0f} s,"
          f" CPU {cpu:.0f} s (pip processes)")
    return 1 if any(r.failures for r in reports) else 0


if __name__ == "__main__":
    sys.exit(main())

"""Every install resolves to wheels alone on the systems students use (issue 49, item 2).

Asks the package registry with pip's own resolver (benchmarks/wheels_everywhere.py), with no
compiler in sight: ``--only-binary :all:`` for a target platform and Python. One target per
Python here, on four of the five systems: 4 joint pip calls (student, course and the SDKs with
a wheel; about 7 CPU seconds each, most of it pip parsing the big index pages of NumPy, SciPy,
OpenCV and MuJoCo) and a small one per SDK the table says has no wheel there, all at once.
The file cost 50 s of CPU with a target per system (5); the suite is CPU-bound (issue 51), so
Linux aarch64, the rarest system a student brings, is left to
``benchmarks/wheels_everywhere.py``, which runs all 20 targets. The rest are checks of the
pieces that need no network.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import tomllib

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import wheels_everywhere as wheels  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# Ubuntu 24.04's Python on a PC, the Intel Mac on the newest Python (its MuJoCo and OpenCV are
# capped), Windows on the oldest (its own markers: tomli, pywinpty): each Python once.
SLICE = {("linux-x86_64", "3.12"), ("win-amd64", "3.10"), ("mac-arm64", "3.11"),
         ("mac-x86_64", "3.13")}
BENCHMARK_ONLY = {"linux-aarch64"}


def _target(system: str, python: str) -> wheels.Target:
    (found,) = [t for t in wheels.TARGETS if (t.system.key, t.python) == (system, python)]
    return found


@pytest.mark.slow   # started early: a minute of waiting on the registry is no run's tail
@pytest.mark.timeout(900)
def test_student_course_and_real_installs_resolve_to_wheels_on_each_python():
    targets = [_target(*key) for key in sorted(SLICE)]
    reports = wheels.check_targets(targets)
    failures = [f for r in reports for f in r.failures]
    assert not failures, "\n\n".join(failures)
    for report in reports:   # the engine itself, not only "something resolved"
        assert "mujoco" in report.versions, (report.target.name, report.versions)
        assert "pybullet" not in report.versions, report.target.name


def test_a_package_without_a_wheel_is_named_with_its_target():
    # PyBullet publishes Linux x86_64 wheels for CPython 3.11 and older only (bullet3 #4742).
    target = _target("win-amd64", "3.12")
    found = wheels.resolve(target, ["pybullet>=3.2.6,<3.3"], no_deps=True)
    assert not found.ok
    assert found.missing.startswith("pybullet"), found
    assert "pybullet" in found.errors, found


def test_the_slice_covers_every_python_and_every_system_but_one():
    assert {s for s, _ in SLICE} | BENCHMARK_ONLY == {s.key for s in wheels.SYSTEMS}
    assert not {s for s, _ in SLICE} & BENCHMARK_ONLY
    assert sorted(p for _, p in SLICE) == sorted(wheels.PYTHONS)
    assert len(wheels.TARGETS) == 20


def test_pybullet_is_an_extra_and_mujoco_the_base():
    main = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    student = tomllib.loads((ROOT / "student" / "pyproject.toml").read_text())["project"]
    for project in (main, student):
        base = " ".join(project["dependencies"])
        assert "mujoco" in base and "pybullet" not in base, project["name"]
        assert any(r.startswith("pybullet")
                   for r in project["optional-dependencies"]["pybullet"])
    # the suite keeps its PyBullet slice
    assert any(r.startswith("pybullet") for r in main["optional-dependencies"]["dev"])


def test_markers_are_evaluated_as_on_the_target():
    windows_310 = _target("win-amd64", "3.10")
    mac_313 = _target("mac-arm64", "3.13")
    assert wheels._marker_applies('pywinpty>=2; os_name == "nt"', windows_310)
    assert not wheels._marker_applies('pywinpty>=2; os_name == "nt"', mac_313)
    assert wheels._marker_applies("tomli>=2; python_version < '3.11'", windows_310)
    assert not wheels._marker_applies("tomli>=2; python_version < '3.11'", mac_313)
    assert wheels._marker_applies("appnope; platform_system == 'Darwin'", mac_313)


def test_linux_targets_list_every_older_manylinux_tag():
    tags = _target("linux-x86_64", "3.12").system.platforms
    assert tags[0] == f"manylinux_2_{wheels.GLIBC_MINOR}_x86_64"
    assert {"manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
            "manylinux1_x86_64"} <= set(tags)
    arm = _target("linux-aarch64", "3.12").system.platforms
    assert "manylinux2014_aarch64" in arm and not any("x86_64" in t for t in arm)
    assert "--platform" in _target("mac-x86_64", "3.10").pip_options()


def test_the_sdk_table_has_a_cell_for_every_sdk_and_system():
    table = wheels.sdk_wheel_table()
    sdks = set(wheels.real_requirements())
    assert {sdk for sdk, _ in table} == sdks
    assert {system for _, system in table} == {s.key for s in wheels.SYSTEMS}


@pytest.mark.parametrize("cell, pythons", [
    ("3.10-3.12", {"3.10", "3.11", "3.12"}),
    ("3.10, 3.12", {"3.10", "3.12"}),
    ("3.10-3.11 (ur-rtde 1.5.9)", {"3.10", "3.11"}),
    ("none", set()),
])
def test_table_cells_read_as_sets_of_pythons(cell, pythons):
    assert wheels._python_set(cell) == pythons


def test_a_table_cell_naming_an_unknown_python_is_refused():
    with pytest.raises(ValueError, match=r"Pythons \['3.9'\]"):
        wheels._python_set("3.9-3.11")

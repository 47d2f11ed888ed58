"""Graded-function specs, one module per assignment (``autograder/specs/<assignment>.py``).

Each module defines ``SPECS``: the tuple of ``autograder.checks.FunctionSpec`` its notebook is
graded on. Modules are found by name, so adding a lab adds a file here and touches nothing else.
"""

from __future__ import annotations

import importlib
import pkgutil


def collect_specs() -> dict:
    """{assignment name: tuple of FunctionSpec} for every module in this package."""
    specs = {}
    for module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        specs[module.name] = importlib.import_module(f"{__name__}.{module.name}").SPECS
    return specs

"""Find a backend by name and connect to it: ``connect(kind="sim", **options) -> Workcell``.

``robots`` never imports a backend at import time (the arrows in DESIGN.md point from the
backends to ``robots``). Instead a backend is either registered at run time with
:func:`register_backend`, or named in the table below as ``"module:function"`` and imported
the first time someone connects to it.

Where the settings come from (highest wins)
-------------------------------------------
1. keyword arguments to ``connect`` (``kind`` and every option);
2. environment variables: ``COBOTLAB_KIND`` (the backend), ``COBOTLAB_HOST`` (the robot's
   address; passed as ``host=`` to real drivers only, never to "sim") and
   ``COBOTLAB_SIM_ENGINE`` (the simulator's engine, "mujoco" or "pybullet"; "sim" only);
3. ``lab.toml`` in the current working directory::

       [connect]
       kind = "ur"                  # the default backend for this directory
       [connect.ur]
       host = "192.168.1.10"       # options used whenever kind is "ur"
       [connect.sim]
       arm = "ur5e"                # options used whenever kind is "sim"
       engine = "mujoco"           # the simulator's engine (see below)

   (read with ``tomllib`` on Python 3.11+, or ``tomli`` on 3.10 if installed; otherwise the
   file is skipped with a warning);
4. the default: ``kind = "sim"``.

The simulator's engine
----------------------
"sim" is one workcell built by one of two engines (``SIM_ENGINES``): MuJoCo
(``sim_backends.mujoco_world``, wheels for every system) or PyBullet (``sim_backends.world``,
wheels for Linux x86_64 and CPython <= 3.11 only). ``engine=`` picks one; without it
(``default_sim_engine``) MuJoCo is used, since it is the one every student can install and it
builds every scene the labs use, and PyBullet where only PyBullet is installed. An engine that
is asked for but not installed, or a scene the MuJoCo engine cannot build, raises
``BackendNotAvailableError`` naming what to ``pip install``: a lab never silently runs on a
different engine than the one asked for.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

from robots.interfaces import Workcell

__all__ = [
    "BUILTIN_BACKENDS",
    "BackendNotAvailableError",
    "register_backend",
    "available_backends",
    "resolve_connect_options",
    "connect",
    "SIM_ENGINES",
    "default_sim_engine",
]

DEFAULT_KIND = "sim"

# name -> "module:factory". The module is imported only when this backend is first used.
BUILTIN_BACKENDS: dict[str, str] = {
    "sim": "sim_backends.world:create_workcell",
    "ur": "robots.drivers.ur:create_workcell",
    "franka": "robots.drivers.franka:create_workcell",
    "aubo": "robots.drivers.aubo:create_workcell",
    "cobotta": "robots.drivers.cobotta:create_workcell",
}

# engine -> ("module:factory", the package it needs, how to install it). "sim" above is the
# default engine's entry; the engine modules are imported only when first used.
SIM_ENGINES: dict[str, tuple[str, str, str]] = {
    "mujoco": ("sim_backends.mujoco_world:create_workcell", "mujoco",
               "pip install 'mujoco>=3.5,<4'"),
    "pybullet": ("sim_backends.world:create_workcell", "pybullet", "pip install pybullet"),
}
# Tried in this order when no engine is named (see the module docstring for why).
DEFAULT_ENGINE_ORDER = ("mujoco", "pybullet")

_registry: dict[str, Callable[..., Workcell]] = {}


class BackendNotAvailableError(ImportError):
    """The backend's module (or a library it needs) is not installed."""


def register_backend(name: str, factory: Callable[..., Workcell]) -> None:
    """Make ``connect(name, **options)`` call ``factory(**options)``, which returns a Workcell.

    Registering a name again replaces the factory (convenient when a notebook reloads a module).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"backend name must be a non-empty string, got {name!r}")
    if not callable(factory):
        raise ValueError(f"factory for backend {name!r} must be callable, got {factory!r}")
    _registry[name] = factory


def available_backends() -> list[str]:
    """Names ``connect`` accepts (registered or built in), whether or not they are installed."""
    return sorted(set(_registry) | set(BUILTIN_BACKENDS))


def _load_factory(kind: str) -> Callable[..., Workcell]:
    if kind in _registry:
        return _registry[kind]
    if kind not in BUILTIN_BACKENDS:
        raise ValueError(
            f"unknown robot kind {kind!r}; known kinds: {', '.join(available_backends())}. "
            "Check the spelling, or register your own with robots.register_backend(name, factory)"
        )
    module_name, func_name = BUILTIN_BACKENDS[kind].split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as error:  # "cannot import name X" is a bug: let it through
        missing = getattr(error, "name", None) or str(error)
        if kind != "sim":
            fix = "install the real-robot extras with `pip install cobotlab[real]`"
        elif module_name.startswith(str(missing)):
            fix = "the simulator is not installed; reinstall cobotlab (`pip install cobotlab`)"
        else:
            fix = f"the simulator needs {missing!r}; reinstall cobotlab (`pip install cobotlab`)"
        raise BackendNotAvailableError(
            f"backend {kind!r} is not available: cannot import {missing!r} "
            f"(needed by {module_name}); {fix}"
        ) from error
    # The module may have registered itself on import; otherwise use the named function.
    factory = _registry.get(kind) or getattr(module, func_name, None)
    if factory is None:
        raise BackendNotAvailableError(
            f"backend {kind!r}: module {module_name} has no function {func_name}(); "
            "the installation looks incomplete"
        )
    _registry[kind] = factory
    return factory


def _installed(package: str) -> bool:
    return importlib.util.find_spec(package) is not None


def default_sim_engine(installed: Callable[[str], bool] = _installed) -> str:
    """The engine ``connect("sim")`` uses when none is named: the first of
    ``DEFAULT_ENGINE_ORDER`` whose package is installed (``installed(package) -> bool``).

    Raises BackendNotAvailableError naming both installs when neither engine is there.
    """
    for engine in DEFAULT_ENGINE_ORDER:
        if installed(SIM_ENGINES[engine][1]):
            return engine
    fixes = " or ".join(f"`{SIM_ENGINES[e][2]}`" for e in DEFAULT_ENGINE_ORDER)
    raise BackendNotAvailableError(
        f"the simulator needs an engine and none is installed; install one: {fixes}")


def _sim_engine_factory(engine) -> Callable[..., Workcell]:
    """The workcell factory of a simulator engine, imported on first use."""
    if engine not in SIM_ENGINES:
        raise ValueError(
            f"engine must be one of {', '.join(map(repr, SIM_ENGINES))}, got {engine!r} "
            "(from connect(engine=...), COBOTLAB_SIM_ENGINE or lab.toml's [connect.sim])")
    target, package, install = SIM_ENGINES[engine]
    if not _installed(package):
        raise BackendNotAvailableError(
            f"the {engine!r} simulator engine is not installed: `{install}`, or choose the "
            f"other engine with connect('sim', engine=...) or COBOTLAB_SIM_ENGINE")
    module_name, func_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        missing = getattr(error, "name", None) or str(error)
        raise BackendNotAvailableError(
            f"the {engine!r} simulator engine cannot import {missing!r} (needed by "
            f"{module_name}); reinstall cobotlab, or `pip install {missing}`") from error
    return getattr(module, func_name)


def _read_lab_toml(path: Path) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        try:
            import tomli as tomllib
        except ModuleNotFoundError:
            warnings.warn(
                f"{path} ignored: reading it needs Python 3.11+ or `pip install tomli`",
                RuntimeWarning,
                stacklevel=3,
            )
            return {}
    with open(path, "rb") as f:
        try:
            data = tomllib.load(f)
        except tomllib.TOMLDecodeError as error:
            raise ValueError(f"{path} is not valid TOML: {error}") from error
    section = data.get("connect", {})
    if not isinstance(section, dict):
        raise ValueError(f"{path}: [connect] must be a table")
    return section


def resolve_connect_options(
    kind: str | None = None,
    options: Mapping | None = None,
    cwd: str | Path | None = None,
    environ: Mapping[str, str] | None = None,
) -> tuple[str, dict]:
    """Merge the settings for ``connect`` (see the module docstring for the precedence).

    ``cwd`` (default: the working directory) is where ``lab.toml`` is looked for and
    ``environ`` (default: ``os.environ``) supplies the variables. Returns ``(kind, options)``.
    """
    environ = os.environ if environ is None else environ
    path = Path.cwd() if cwd is None else Path(cwd)
    toml = _read_lab_toml(path / "lab.toml") if (path / "lab.toml").is_file() else {}

    resolved_kind = kind or environ.get("COBOTLAB_KIND") or toml.get("kind") or DEFAULT_KIND
    merged: dict = {}
    per_kind = toml.get(resolved_kind, {})
    if not isinstance(per_kind, dict):
        raise ValueError(f"lab.toml: [connect.{resolved_kind}] must be a table")
    merged.update(per_kind)
    if resolved_kind != "sim" and environ.get("COBOTLAB_HOST"):
        merged["host"] = environ["COBOTLAB_HOST"]
    if resolved_kind == "sim" and environ.get("COBOTLAB_SIM_ENGINE"):
        merged["engine"] = environ["COBOTLAB_SIM_ENGINE"]
    merged.update(options or {})
    return resolved_kind, merged


def connect(kind: str | None = None, **options) -> Workcell:
    """Connect to a robot cell and return its :class:`~robots.interfaces.Workcell`.

    ``kind`` is "sim" (the default: the simulated workcell, built by the engine named by
    ``engine="mujoco"`` or ``"pybullet"``, see this module's docstring) or a driver name
    ("ur", "franka", "aubo", "cobotta"); ``options`` go to the backend, e.g.
    ``connect("sim", arm="panda", mount="eye_in_hand", seed=0)`` or
    ``connect("ur", host="192.168.1.10")``. Settings may also come from the environment and
    ``lab.toml``; explicit arguments win (see this module's docstring).

    Use the result as a context manager so the robot always stops and disconnects::

        with connect("sim", arm="panda", seed=0) as cell:
            cell.robot.move_to(T)
            frame = cell.camera.capture()

    Raises ValueError for an unknown kind (listing the known ones) and
    BackendNotAvailableError (an ImportError) when the backend is not installed.
    """
    kind, options = resolve_connect_options(kind, options)
    if kind == "sim" and "sim" not in _registry:  # a registered "sim" replaces the engines
        engine = options.pop("engine", None) or default_sim_engine()
        factory = _sim_engine_factory(engine)
    else:
        factory = _load_factory(kind)
    cell = factory(**options)
    if not isinstance(cell, Workcell):
        raise TypeError(f"backend {kind!r} returned {type(cell).__name__}, not a robots.Workcell")
    return cell

"""PyBullet simulation backend for cobotlab (the default ``robots.connect("sim", ...)``).

Importing this package loads PyBullet (a few tens of milliseconds, with its build-time banner
swallowed: ``_pybullet``); the world and its models are loaded only when a workcell is
created. ``robots.backends`` finds the factory by name ("sim" ->
``sim_backends.world:create_workcell``), so nothing needs registering by hand; the
``create_workcell`` attribute below is the same function, imported on first use.

Modules: ``world`` (the workcell factory and ground truth), ``arms``/``ik``/``tools`` (the
simulated robots), ``flanges`` (their ISO 9409-1 flange faces), ``camera`` (pinhole RGB-D
rendering), ``depth_noise`` (a RealSense D4xx's depth artefacts, off by default), ``scene``
and ``textures`` (table, calibration targets, chess set).
"""

from sim_backends import _pybullet  # noqa: F401  (loads PyBullet without its banner)

__all__ = ["create_workcell"]


def __getattr__(name):
    if name == "create_workcell":
        from sim_backends.world import create_workcell

        return create_workcell
    raise AttributeError(f"module 'sim_backends' has no attribute {name!r}")

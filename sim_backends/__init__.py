"""The simulated workcell behind ``robots.connect("sim", ...)``, built by one of two engines.

``robots.backends`` picks the engine (``engine="mujoco"`` or ``"pybullet"``, see its docstring)
and imports its module on first use: ``sim_backends.world`` (PyBullet) or
``sim_backends.mujoco_world`` (MuJoCo). ``docs/simulation.md`` says where a third would plug in.

Engine-neutral modules (no simulator imported): ``layout`` (the workcell's description: its
validation, seeded random streams and where the table, targets, chess set and cameras go),
``arm_specs`` (the five arms' models and limits), ``arm_motion`` (encoder offsets, IK and
planned paths of any engine's arm), ``ik_core`` (verified damped-least-squares IK on any
forward kinematics), ``rendered_camera`` (a pinhole RGB-D camera's lens, noise and RealSense
depth model around any engine's render), ``chess``, ``tool_specs``, ``truth``, ``sim_robot``,
``scene_shapes``, ``textures``, ``flanges``, ``depth_noise``.

PyBullet modules: ``world`` (its workcell factory), ``arms``/``ik``/``tools`` (the simulated
robots), ``camera`` (TinyRenderer), ``scene`` (table, targets, chess set), ``viewer_scene``.
Importing this package loads PyBullet when it is installed (a few tens of milliseconds, with
its build-time banner swallowed: ``_pybullet``), so those modules' own ``import pybullet``
gets the silent module; without PyBullet the MuJoCo engine works alone.

MuJoCo modules: ``mujoco_world`` (its workcell factory), ``mujoco_model`` (the description's
parts as one MuJoCo model), ``mujoco_arm``, ``mujoco_camera``, ``mujoco_tools``,
``mujoco_viewer_scene`` and ``mujoco_gl`` (off-screen OpenGL without a display).
"""

try:
    from sim_backends import _pybullet  # noqa: F401  (loads PyBullet without its banner)
except ModuleNotFoundError as error:  # the MuJoCo-only install
    if error.name != "pybullet":
        raise

__all__ = ["create_workcell"]


def __getattr__(name):
    if name == "create_workcell":
        from sim_backends.world import create_workcell

        return create_workcell
    raise AttributeError(f"module 'sim_backends' has no attribute {name!r}")

"""MuJoCo, imported with an off-screen OpenGL that works without a display.

MuJoCo picks its OpenGL platform from ``MUJOCO_GL`` when it is imported. On Linux a lab runs
on laptops, on a JupyterHub and on CI machines, most with no display, so when the variable is
unset this module chooses EGL (Mesa's CPU renderer when there is no GPU) and, failing that,
OSMesa, checking first that the system library is there. macOS and Windows keep MuJoCo's own
default (CGL, WGL), which render off-screen as they are. Every MuJoCo module of
``sim_backends`` imports ``mujoco`` through :func:`import_mujoco`.
"""

from __future__ import annotations

import ctypes.util
import os
import sys

__all__ = ["GL_PACKAGES", "OpenGLUnavailableError", "import_mujoco", "gl_hint"]

# The Debian/Ubuntu packages each platform needs (docs/hub.md and the Makefile name the same).
GL_PACKAGES = {"egl": "libegl1 libgl1-mesa-dri", "osmesa": "libosmesa6"}
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}


class OpenGLUnavailableError(RuntimeError):
    """MuJoCo cannot open an off-screen OpenGL context on this machine."""


def gl_hint(platform: str | None = None) -> str:
    """What to install for off-screen rendering (for error messages)."""
    if platform in GL_PACKAGES:
        return f"`sudo apt-get install {GL_PACKAGES[platform]}`"
    return (f"`sudo apt-get install {GL_PACKAGES['egl']}` (EGL through Mesa; or "
            f"{GL_PACKAGES['osmesa']} with MUJOCO_GL=osmesa)")


def _choose_linux_platform(find_library=ctypes.util.find_library) -> str:
    for platform in ("egl", "osmesa"):
        if find_library(_LIBRARIES[platform]):
            return platform
    raise OpenGLUnavailableError(
        "the MuJoCo simulator renders off-screen through EGL or OSMesa and this machine has "
        f"neither library; install them: {gl_hint()}, then restart the kernel")


def import_mujoco():
    """The ``mujoco`` module, with ``MUJOCO_GL`` chosen first on Linux when it is unset.

    Raises OpenGLUnavailableError naming the Debian packages when neither EGL nor OSMesa is
    installed, and ImportError (from ``robots.connect``, naming ``pip install mujoco``) when
    MuJoCo itself is missing.
    """
    # Even when mujoco was imported first, the choice is recorded: the renderer then asks for
    # that platform's context by name (mujoco_camera._gl_context_class).
    if sys.platform.startswith("linux") and not os.environ.get("MUJOCO_GL"):
        os.environ["MUJOCO_GL"] = _choose_linux_platform()
        # PyOpenGL must agree with MuJoCo on the platform.
        os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    import mujoco

    return mujoco

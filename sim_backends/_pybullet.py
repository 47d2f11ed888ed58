"""PyBullet, imported once with its build-time banner swallowed.

PyBullet's C module writes ``pybullet build time: ...`` to the process's standard error when
it loads. Jupyter shows a kernel's C-level output as a red stderr stream, so every lab's first
simulator cell opened with it. The package's ``__init__`` imports this module first, so every
later ``import pybullet`` in ``sim_backends`` gets the already loaded, silent module.
"""

from __future__ import annotations

import ctypes
import os
import sys


def _flush_c_stdio() -> None:
    """Flush the C library's buffered streams, so nothing written during the import reaches
    the real descriptors after they are restored."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to reach this way (Windows)
        pass


def import_pybullet():
    """The ``pybullet`` module, loaded with file descriptors 1 and 2 on the null device."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no standard streams to redirect
        import pybullet

        return pybullet
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            try:
                import pybullet
            finally:
                _flush_c_stdio()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        for fd in saved:
            os.close(fd)
    return pybullet


import_pybullet()

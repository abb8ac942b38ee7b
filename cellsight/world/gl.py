"""Choice of MuJoCo's OpenGL back-end for offscreen rendering.

MuJoCo reads ``MUJOCO_GL`` once, when it is first imported, so :mod:`cellsight.world` calls
:func:`choose_gl_backend` before it imports MuJoCo.
"""

from __future__ import annotations

import ctypes.util
import os


def choose_gl_backend() -> str:
    """Set ``MUJOCO_GL`` (unless the user set it) to ``egl``, falling back to ``osmesa`` when
    libEGL is missing and libOSMesa is present; returns the value in effect."""
    if "MUJOCO_GL" not in os.environ:
        osmesa = ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa")
        os.environ["MUJOCO_GL"] = "osmesa" if osmesa else "egl"
    return os.environ["MUJOCO_GL"]

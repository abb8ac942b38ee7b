"""Choice of MuJoCo's OpenGL back-end for offscreen rendering.

MuJoCo reads ``MUJOCO_GL`` once, when it is first imported, so :mod:`cellsight.world` calls
:func:`choose_gl_backend` before it imports MuJoCo.

Without a GPU, Mesa's software rasteriser (llvmpipe) renders, by default in as many threads as
there are cores, handing each render to them and waiting. Most renders here are the tracker's
windows (:meth:`~cellsight.world.render.GrayRenderer.render_region`, about 11,000 pixels),
for which the hand-over costs more than the threads gain: rendered in the calling thread
(``LP_NUM_THREADS=0``), the windows of a frame of the bench line (the cell of
``bench/bench_many_parts.py``, 4 parts, 6 cameras) render in 4.3-4.7 ms instead of
5.2-5.8 ms (two runs each, in turn, on a 2-core machine), with the same pixels
(``tests/test_shots.py``). It is set unless the user set it; a GPU's driver ignores it.
"""

from __future__ import annotations

import ctypes.util
import os


def choose_gl_backend() -> str:
    """Set ``MUJOCO_GL`` (unless the user set it) to ``egl``, falling back to ``osmesa`` when
    libEGL is missing and libOSMesa is present, and the software rasteriser's threads to none
    (``LP_NUM_THREADS``; module docstring); returns ``MUJOCO_GL``'s value in effect."""
    os.environ.setdefault("LP_NUM_THREADS", "0")
    if "MUJOCO_GL" not in os.environ:
        osmesa = ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa")
        os.environ["MUJOCO_GL"] = "osmesa" if osmesa else "egl"
    return os.environ["MUJOCO_GL"]

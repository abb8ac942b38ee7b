"""Where the unmodelled bodies of a realism profile go (:mod:`cellsight.world.intruders`).

- ``unknown.box``: a box standing at the part's height 15-30 cm from its start towards one
  camera (up to 10 cm to either side), turned to face it, so that it may hide the part's lower
  features from that camera;
- ``unknown.forearm``: a 40 x 8 x 8 cm bar, horizontal and across one camera's line of sight to
  the part (5 cm above the part's start), 25-60 % of the way to the camera; it comes in along
  its own length from 80 cm to the side and leaves the same way.

``place`` values in [0, 1) pick the spot within those ranges. Units: m, s.
"""

from __future__ import annotations

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.polyhedron import box
from cellsight.geometry.transforms import make_pose, transform_points
from cellsight.model.cell import Workpiece
from cellsight.world.intruders import Intruder

FOREARM_SIZE = (0.40, 0.08, 0.08)  # m: length, width, height
FOREARM_REACH = 0.8  # m travelled sideways to come in


def _frame(x_axis: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """A pose with horizontal x along ``x_axis`` (projected), z up, at ``origin``."""
    x = np.array([x_axis[0], x_axis[1], 0.0])
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, 1.0])
    return make_pose(np.column_stack([x, np.cross(z, x), z]), origin)


def table_box(part: Workpiece, camera: Camera, size: np.ndarray, place: np.ndarray) -> Intruder:
    """The box of the module docstring, ``size`` (3,) m."""
    start = part.T_base_part[:3, 3]
    bottom = transform_points(part.T_base_part, part.solid.vertices)[:, 2].min()
    towards = camera.center - start
    frame = _frame(towards, np.zeros(3))
    ahead, side = frame[:3, 0], frame[:3, 1]
    centre = start + (0.15 + 0.15 * place[0]) * ahead + (place[1] - 0.5) * 0.2 * side
    centre[2] = bottom + 0.5 * size[2]
    frame[:3, 3] = centre
    return Intruder("unknown.box", box("unknown.box", size), frame)


def forearm(part: Workpiece, camera: Camera, t_in: float, t_out: float, place: float
            ) -> Intruder:
    """The forearm of the module docstring, in view from ``t_in`` to ``t_out`` (s)."""
    target = part.T_base_part[:3, 3] + [0.0, 0.0, 0.05]
    sight = camera.center - target
    across = np.cross(sight, [0.0, 0.0, 1.0])
    T_in = _frame(across, target + (0.25 + 0.35 * place) * sight)
    T_out = T_in.copy()
    T_out[:3, 3] += FOREARM_REACH * T_in[:3, 0]
    return Intruder("unknown.forearm", box("unknown.forearm", FOREARM_SIZE), T_in, T_out,
                    t_in, t_out)

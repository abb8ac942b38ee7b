"""Candidate cameras: a shell of viewpoints around the work area, each looking at its centre.

The work area is the box of the workpiece's positions over the task; its centre is the
target. Viewpoints lie at ``radii`` (m) from the target, at ``elevations`` (deg above the
target's horizontal plane) and every ``azimuth_step`` (deg) around it; each is a copy of a
template camera (its intrinsics, size and distortion), posed by
:func:`~cellsight.geometry.transforms.look_at` (optical axis at the target, image x
horizontal). A viewpoint is dropped when it is below ``z_min`` or above ``z_max`` (m), or
within ``clearance`` (m) of the box of any solid of the cell at any frame of the task (a
camera there would be hit or would stand inside the table).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import look_at
from cellsight.model.cell import Cell
from cellsight.placement.task import TaskFrames


def work_area(task: TaskFrames) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest corner (m, base frame) of the part's positions over the task."""
    xyz = task.part_poses[:, :3, 3]
    return xyz.min(axis=0), xyz.max(axis=0)


def object_boxes(cell: Cell, task: TaskFrames, frames: Sequence[int]) -> np.ndarray:
    """(K, 6) base-frame boxes (min xyz, max xyz; m) that hold every solid of the cell at
    every frame in ``frames``."""
    lo = np.full((len(cell.objects), 3), np.inf)
    hi = np.full((len(cell.objects), 3), -np.inf)
    for k in frames:
        poses = cell.snapshot(*task.state(k)).poses
        for i, obj in enumerate(cell.objects):
            v = obj.solid.vertices @ poses[i][:3, :3].T + poses[i][:3, 3]
            lo[i] = np.minimum(lo[i], v.min(axis=0))
            hi[i] = np.maximum(hi[i], v.max(axis=0))
    return np.hstack([lo, hi])


@dataclass(frozen=True)
class Shell:
    """Where candidates stand: at the ``radii`` (m) from the work area's centre, at the
    ``elevations`` (degrees over the horizontal), every ``azimuth_step`` (degrees) around it,
    between the heights ``z_min`` and ``z_max`` (m), ``clearance`` (m) off every object's box
    over the task."""

    radii: Sequence[float] = (1.4, 1.7, 2.0)
    elevations: Sequence[float] = (20, 35, 50, 65, 80)
    azimuth_step: float = 15.0
    z_min: float = 0.3
    z_max: float = 3.0
    clearance: float = 0.15


def shell_candidates(cell: Cell, task: TaskFrames, template: Camera, shell: Shell | None = None,
                     box_frames: int = 60) -> list[Camera]:
    """The candidate cameras (module docstring) on the ``shell``; the task's boxes are taken
    over ``box_frames`` frames spread over it."""
    shell = shell or Shell()
    radii, elevations, azimuth_step = shell.radii, shell.elevations, shell.azimuth_step
    z_min, z_max, clearance = shell.z_min, shell.z_max, shell.clearance
    lo, hi = work_area(task)
    target = 0.5 * (lo + hi)
    frames = np.unique(np.linspace(0, task.n - 1, min(box_frames, task.n)).astype(int))
    boxes = object_boxes(cell, task, frames)
    out = []
    for r in radii:
        for e in elevations:
            for a in np.arange(0.0, 360.0, azimuth_step):
                el, az = math.radians(e), math.radians(a)
                eye = target + r * np.array([math.cos(el) * math.cos(az),
                                             math.cos(el) * math.sin(az), math.sin(el)])
                near = np.all((eye >= boxes[:, :3] - clearance)
                              & (eye <= boxes[:, 3:] + clearance), axis=1)
                if not (z_min <= eye[2] <= z_max) or near.any():
                    continue
                out.append(Camera(template.K, template.width, template.height,
                                  look_at(eye, target), template.dist,
                                  f"r{r:.2f}_e{e:g}_a{a:g}"))
    return out

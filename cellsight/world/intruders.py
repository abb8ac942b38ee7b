"""Bodies in the world that the cell file does not know: a box left on the table, an operator's
forearm reaching across a camera's view. They are rendered, occlude in the ray-cast truth
(labelled by their names, ``unknown.<what>``) and take part in the collision check; the
predictor, the tracker and the planner never hear of them.

Each is a MuJoCo mocap body (:func:`cellsight.world.mjcf.cell_mjcf`). One that stays has no
``T_out``; one that reaches in waits at ``T_out``, slides to ``T_in`` during the ``travel_s``
before ``t_in``, stays until ``t_out`` and slides back (positions interpolated linearly, the
orientation of ``T_in`` throughout). Units: m, s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellsight.geometry.polyhedron import Polyhedron
from cellsight.world.scene import Scene


@dataclass(frozen=True)
class Intruder:
    """One unknown body (module docstring); ``solid`` in its own frame, poses in the base
    frame."""

    name: str
    solid: Polyhedron
    T_in: np.ndarray
    T_out: np.ndarray | None = None
    t_in: float = 0.0
    t_out: float = math.inf
    travel_s: float = 0.5

    def pose(self, t: float) -> np.ndarray:
        """``T_base_body`` at time ``t`` (s)."""
        if self.T_out is None:
            return self.T_in
        coming = (t - (self.t_in - self.travel_s)) / self.travel_s
        going = (self.t_out + self.travel_s - t) / self.travel_s
        f = float(np.clip(min(coming, going), 0.0, 1.0))
        T = self.T_in.copy()
        T[:3, 3] = (1.0 - f) * self.T_out[:3, 3] + f * self.T_in[:3, 3]
        return T


class Intruders:
    """Moves the intruders' mocap bodies in a :class:`Scene`."""

    def __init__(self, scene: Scene, intruders: Sequence[Intruder]) -> None:
        self.scene, self.intruders = scene, tuple(intruders)
        model = scene.model
        self.bodies = [model.body(i.name).id for i in self.intruders]
        self._moving = [(i, int(model.body_mocapid[b]))
                        for i, b in zip(self.intruders, self.bodies, strict=True)
                        if i.T_out is not None]

    def step(self, t: float) -> None:
        """Put every moving intruder where it is at time ``t`` (s); the others stay where the
        model put them (:func:`cellsight.world.mjcf.cell_mjcf`, at their pose at t = 0)."""
        for intruder, mocap in self._moving:
            self.scene.set_mocap(mocap, intruder.pose(t))

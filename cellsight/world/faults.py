"""Faults the world plays out at a set time: the part kidnapped while every camera is blind,
a camera knocked.

:class:`Knock`: at ``t`` (s) camera ``camera`` (index) is knocked: its pose becomes
``T_base_cam @ T_delta`` (a move in its own frame) for the rest of the run, in the rendering
and in the truth; the tracker keeps the cell file's calibration.

:class:`Kidnap`: from ``t_start`` (s) for ``blind_s`` (s) no camera delivers a frame; at the
middle of that spell the workpiece ``part``, unless a gripper holds it, is moved by ``shift``
(2,) m in the base frame's horizontal plane and turned by ``turn`` (rad) about the vertical
through its origin (:meth:`~cellsight.world.paths.PartMotion.displace`). A test of whether the
tracker notices a confident pose gone wrong and finds the part again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from cellsight.geometry.transforms import rotation_angle


@dataclass(frozen=True)
class Kidnap:
    """The part moved while the cameras are blind (module docstring). Units: s, m, rad."""

    part: str
    t_start: float
    blind_s: float
    shift: np.ndarray
    turn: float

    @property
    def t_move(self) -> float:
        """When the part is moved (s): the middle of the blind spell."""
        return self.t_start + 0.5 * self.blind_s

    @property
    def t_back(self) -> float:
        """When the cameras see again (s)."""
        return self.t_start + self.blind_s

    def blind(self, t: float) -> bool:
        """No camera delivers the frame of time ``t`` (s)."""
        return self.t_start - 1e-9 <= t < self.t_back - 1e-9

    def record(self) -> dict:
        """The fault as plain data (mm, deg, s) for ``metrics.json``."""
        return {"part": self.part, "t_start_s": round(self.t_start, 4),
                "blind_s": round(self.blind_s, 4), "t_move_s": round(self.t_move, 4),
                "shift_mm": np.round(1e3 * np.asarray(self.shift), 2).tolist(),
                "distance_mm": round(1e3 * float(np.hypot(*self.shift)), 2),
                "turn_deg": round(float(np.degrees(self.turn)), 2)}


@dataclass(frozen=True)
class Knock:
    """A camera knocked (module docstring). Units: s, m."""

    camera: int
    t: float
    T_delta: np.ndarray

    def record(self, name: str) -> dict:
        """The fault as plain data (mm, deg, s) for ``metrics.json``; ``name``: the camera's."""
        angle = np.degrees(rotation_angle(self.T_delta[:3, :3]))
        return {"camera": name, "t_s": round(self.t, 4),
                "shift_mm": round(1e3 * float(np.linalg.norm(self.T_delta[:3, 3])), 2),
                "rotation_deg": round(float(angle), 3)}


class Movable(Protocol):
    """What a fault moves: the world's workpieces (:class:`~cellsight.world.paths.PartMotion`)."""

    def displace(self, name: str, shift: np.ndarray, turn: float) -> bool: ...


class Faults:
    """Plays the world's faults as time goes (module docstring); None: no such fault.
    ``moved``: whether the kidnapping moved the part (None until it was due); ``knocked``:
    the knock has happened; ``knock_camera(index, T_delta)`` moves a camera (the world's)."""

    def __init__(self, kidnap: Kidnap | None, knock: Knock | None = None,
                 knock_camera: Callable[[int, np.ndarray], None] | None = None) -> None:
        self.kidnap, self.knock, self.knock_camera = kidnap, knock, knock_camera
        self.moved: bool | None = None
        self.knocked = False

    def step(self, t: float, parts: Movable) -> None:
        """Play what is due by time ``t`` (s), once."""
        k = self.kidnap
        if k is not None and self.moved is None and t >= k.t_move - 1e-9:
            self.moved = parts.displace(k.part, k.shift, k.turn)
        b = self.knock
        if b is not None and not self.knocked and t >= b.t - 1e-9 and self.knock_camera:
            self.knock_camera(b.camera, b.T_delta)
            self.knocked = True

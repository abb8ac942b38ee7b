"""Timed motions the world plays back: the conveyor's path and a robot's own joint-space task."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ConveyorPath:
    """The conveyor's motion of a workpiece in the horizontal plane.

    The part frame's origin runs along the polyline ``points`` ((k, 2) x, y in the base frame,
    m) at ``speed`` (m/s), starting at ``t_start`` and stopping at ``t_stop`` (s) or at the end
    of the polyline, whichever comes first. Before ``t_start`` it waits at ``points[0]``. Height
    and orientation keep the workpiece's nominal values (the part translates, it does not turn).
    ``workpiece`` names the part it carries (default: the cell's first workpiece). A path with
    no points (:meth:`still`) leaves the part at its nominal pose.
    """

    points: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    speed: float = 0.0
    t_start: float = 0.0
    t_stop: float = math.inf
    workpiece: str | None = None
    _arc: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(pts)):
            raise ValueError(f"ConveyorPath: points must be finite, got {pts.tolist()}")
        if not (np.isfinite(self.speed) and self.speed >= 0):
            raise ValueError(f"ConveyorPath: speed must be a finite number >= 0, got {self.speed}")
        if not (np.isfinite(self.t_start) and self.t_stop >= self.t_start):
            raise ValueError(
                f"ConveyorPath: need a finite t_start <= t_stop, got {self.t_start}, {self.t_stop}"
            )
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "_arc", np.concatenate([[0.0], np.cumsum(seg)]))

    @classmethod
    def still(cls, workpiece: str | None = None) -> ConveyorPath:
        """A conveyor that does not move the part."""
        return cls(workpiece=workpiece)

    @property
    def is_still(self) -> bool:
        return len(self.points) == 0

    @property
    def length(self) -> float:
        """Length of the polyline (m)."""
        return float(self._arc[-1]) if len(self.points) else 0.0

    def position(self, t: float) -> np.ndarray:
        """(x, y) of the part frame's origin at time ``t`` (s); only for a path with points."""
        if self.is_still:
            raise ValueError("ConveyorPath.still() has no position of its own")
        run = min(max(t, self.t_start), self.t_stop) - self.t_start
        s = min(self.speed * run, self.length)
        k = int(np.clip(np.searchsorted(self._arc, s, side="right") - 1, 0, len(self.points) - 1))
        if k == len(self.points) - 1:
            return self.points[-1].copy()
        frac = (s - self._arc[k]) / max(self._arc[k + 1] - self._arc[k], 1e-15)
        return self.points[k] + frac * (self.points[k + 1] - self.points[k])


@dataclass(frozen=True)
class Waypoint:
    """A joint-space waypoint: reach the joint vector ``q`` at time ``t`` (s).

    The segment arriving at this waypoint is interpolated with a quintic smooth step (zero
    velocity and acceleration at both ends) when ``smooth``, linearly otherwise.
    """

    t: float
    q: np.ndarray
    smooth: bool = True

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=float).ravel()
        if not (np.isfinite(self.t) and np.all(np.isfinite(q))):
            raise ValueError(f"Waypoint: t and q must be finite, got t={self.t}, q={q.tolist()}")
        object.__setattr__(self, "q", q)


class JointTask:
    """A robot's own timed task: from ``q0`` at t = 0 through the waypoints, then holding the
    last one. Waypoint times must increase strictly and be > 0."""

    def __init__(self, q0: np.ndarray, waypoints: Sequence[Waypoint]) -> None:
        q0 = np.asarray(q0, dtype=float).ravel()
        self._t = np.array([0.0] + [w.t for w in waypoints])
        if np.any(np.diff(self._t) <= 0):
            raise ValueError(f"JointTask: waypoint times must increase from > 0, got {self._t[1:]}")
        for w in waypoints:
            if w.q.shape != q0.shape:
                raise ValueError(f"JointTask: waypoint q needs {q0.size} values, got {w.q.size}")
        self._q = np.vstack([q0] + [w.q for w in waypoints])
        self._smooth = [True] + [w.smooth for w in waypoints]

    def at(self, t: float) -> np.ndarray:
        """Joint set-point at time ``t`` (s)."""
        if t >= self._t[-1]:
            return self._q[-1].copy()
        k = int(np.searchsorted(self._t, max(t, 0.0), side="right"))  # segment k-1 -> k
        tau = (t - self._t[k - 1]) / (self._t[k] - self._t[k - 1])
        if self._smooth[k]:
            tau = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        return self._q[k - 1] + tau * (self._q[k] - self._q[k - 1])

"""Pose estimates on their way from the tracker to the planner (a realism profile's latency).

An :class:`Estimate` is what the planner receives of a vision frame: the estimated pose and
linear velocity of the part at the frame's exposure time ``t``. :class:`Deliveries` holds them
until their delivery time (exposure plus latency) has come.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.tracking.records import PartFrame
from cellsight.tracking.status import TrackStatus


@dataclass(frozen=True)
class Estimate:
    """The tracker's estimate of frame time ``t`` (s): ``T_base_part`` and linear velocity
    (m/s), both None when the tracker has no estimate; ``lost``: the tracker lost the part."""

    t: float
    pose: np.ndarray | None
    velocity: np.ndarray | None
    lost: bool = False

    @classmethod
    def of(cls, t: float, rec: PartFrame) -> Estimate:
        if not rec.status.has_estimate:
            return cls(t, None, None, rec.status is TrackStatus.LOST)
        return cls(t, np.array(rec.T_base_part), rec.velocity)


class Deliveries:
    """Estimates in flight, each with its delivery time (s)."""

    def __init__(self) -> None:
        self._pending: list[tuple[float, Estimate]] = []

    def add(self, at: float, estimate: Estimate) -> None:
        self._pending.append((float(at), estimate))

    def due(self, now: float) -> list[Estimate]:
        """The estimates whose delivery time has come by ``now`` (s), oldest exposure first;
        they leave the queue."""
        ready = [e for at, e in self._pending if at <= now + 1e-9]
        self._pending = [(at, e) for at, e in self._pending if at > now + 1e-9]
        return sorted(ready, key=lambda e: e.t)

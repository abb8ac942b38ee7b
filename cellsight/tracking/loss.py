"""When a track coasts and when it is lost.

A part is *lost* after ``lost_after_s`` seconds without an accepted measurement (the tracker
then re-acquires it); until then frames without measurements only predict. The prediction
coasts at most ``coast_s`` seconds after the last accepted measurement, then stops: the last
velocity would carry the pose away for ever, and a part that left the views is looked for
where it was last predicted.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LossRule:
    """Coasting and loss times (s) after the last accepted measurement."""

    lost_after_s: float = 2.0
    coast_s: float = 4.0

    def coasts(self, t: float, last_update: float) -> bool:
        """The motion model still propagates the estimate at time ``t`` (s)."""
        return t - last_update <= self.coast_s

    def lost(self, t: float, last_update: float) -> bool:
        """The track is lost at time ``t`` (s)."""
        return t - last_update > self.lost_after_s

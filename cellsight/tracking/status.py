"""The state of a workpiece's track at one frame."""

from __future__ import annotations

from enum import StrEnum


class TrackStatus(StrEnum):
    """What the tracker did with a workpiece this frame (values are the ``frames.csv`` text).

    ``WAITING``: not acquired yet; ``ACQUIRED``: its filter started this frame from a PnP fix
    (or, with the kinematic prior, where the gripper holding it puts it);
    ``TRACKING``: updated by accepted measurements; ``DEGRADED``: updated by accepted
    measurements, but the health monitor finds the track inconsistent (:mod:`.health`; the
    record's ``health`` says why); ``COASTING``: no accepted measurement, prediction only;
    ``LOST``: no accepted measurement for ``lost_after_s``, being re-acquired.
    """

    WAITING = "waiting"
    ACQUIRED = "acquired"
    TRACKING = "tracking"
    DEGRADED = "degraded"
    COASTING = "coasting"
    LOST = "lost"

    @property
    def has_estimate(self) -> bool:
        """The track has a pose estimate worth using (acquired, tracking, degraded or
        coasting)."""
        return self in (TrackStatus.ACQUIRED, TrackStatus.TRACKING, TrackStatus.DEGRADED,
                        TrackStatus.COASTING)

"""When a track coasts and when it is lost.

A part is *lost* after ``lost_after_s`` seconds without an accepted measurement, or sooner,
after ``unseen_s`` seconds in which every frame that looked for at least ``min_looked`` of its
features (in the images that came) accepted fewer than ``min_found`` of them, or, accepting
nothing, predicted the part outside every camera's view: the part is not where it is
predicted (moved while the cameras were blind, or the estimate has gone bad; a lone wrong
corner that fits a wide prediction does not hold such a track, nor does a velocity that wrong
corners threw out of the views). For the same reason a coasting track resumes only on a frame
that accepts, together, at least ``resume_found`` of the features it looked for (after a blind
second, four wrong corners of eleven fitted the wide prediction of a kidnapped part;
:meth:`LossRule.resume_support`), and so does a filter's first update after an acquisition
(its covariance is as wide: in ``harsh`` runs re-acquired under the approaching gripper, two
to five of eleven features, the gripper's corners among them, moved the estimate 15-25 mm
in that update and gave it a velocity that carried it 100 mm off while it coasted). The
tracker then
re-acquires it, from the whole image when it can (:mod:`.search`); until then frames without
measurements only predict. The prediction
coasts at most ``coast_s`` seconds after the last accepted measurement, then stops: the last
velocity would carry the pose away for ever, and a part that left the views is looked for
where it was last predicted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class LossRule:
    """Coasting and loss times (s) after the last accepted measurement (module docstring)."""

    lost_after_s: float = 2.0
    coast_s: float = 4.0
    unseen_s: float = 0.3
    min_looked: int = 4
    min_found: float = 0.34
    resume_found: float = 0.5

    def coasts(self, t: float, last_update: float) -> bool:
        """The motion model still propagates the estimate at time ``t`` (s)."""
        return t - last_update <= self.coast_s

    def in_vain(self, looked: int, accepted: int, in_view: bool = True) -> bool | None:
        """A frame looked in vain, saw the part, or says nothing (module docstring);
        ``in_view``: some camera's image holds a predicted feature point."""
        if looked >= self.min_looked and accepted < self.min_found * looked:
            return True
        if not in_view and not accepted:
            return True
        return False if accepted else None

    def resume_support(self, looked: int) -> int:
        """How many of ``looked`` features a coasting track must accept together to resume:
        the share ``resume_found`` of them, so that a few wrong corners that fit a wide
        prediction do not resume it; 0 below ``min_looked``."""
        return math.ceil(self.resume_found * looked) if looked >= self.min_looked else 0

    def lost(self, t: float, last_update: float, unseen_since: float = float("inf")) -> bool:
        """The track is lost at time ``t`` (s): nothing accepted since ``last_update`` (s) for
        too long, or looked for in vain since ``unseen_since`` (s)."""
        return t - last_update > self.lost_after_s or t - unseen_since >= self.unseen_s - 1e-9

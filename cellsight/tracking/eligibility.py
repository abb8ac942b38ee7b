"""Which predicted-visible features may be measured: not those next to another object's
silhouette.

The predictor flags ``near_occluder`` a visible feature whose image lies within a few pixels of
another object's silhouette: its image corner is a junction with that silhouette, a few pixels
off, which the extractor would take for the feature. Such a feature is neither selected nor
used for acquisition, and stays out for ``hold_s`` seconds after it was last flagged (a
feature on the edge of the predictor's ring flickers).
"""

from __future__ import annotations

import numpy as np


class NearOccluderHold:
    """Per track: the last time (s) each (camera, feature) was flagged, and the usable mask."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = float(hold_s)
        self._flagged_at: np.ndarray | None = None

    def usable(self, visible: np.ndarray, near_occluder: np.ndarray, t: float) -> np.ndarray:
        """(C, F) bool: visible and not flagged within the last ``hold_s`` at time ``t`` (s)."""
        if self._flagged_at is None:
            self._flagged_at = np.full(visible.shape, -np.inf)
        self._flagged_at[near_occluder] = t
        return visible & (t - self._flagged_at > self.hold_s)

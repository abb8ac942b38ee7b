"""Per-frame timing of the vision loop as a real cell has it (a profile's ``timing`` knobs).

Each vision frame is exposed at its time ``t`` (its images and joint readings are of that
instant); with probability ``drop_percent`` / 100 its images never arrive; otherwise its pose
estimate reaches the planner ``latency_ms`` plus a Gaussian jitter of ``latency_jitter_ms``
later (never before the exposure). Seeded, its own stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.realism.profile import TimingKnobs


@dataclass(frozen=True)
class FrameTiming:
    """One frame's fate: ``dropped`` (no images), ``latency_s`` (exposure to planner, s)."""

    dropped: bool
    latency_s: float


class FrameClock:
    """Draws :class:`FrameTiming` frame after frame (module docstring)."""

    def __init__(self, knobs: TimingKnobs, seed: int) -> None:
        self.knobs = knobs
        self._rng = np.random.default_rng([int(seed), 3])

    @property
    def ideal(self) -> bool:
        """No latency, no jitter, no drops: frames act at once, as in the ideal world."""
        k = self.knobs
        return k.latency_ms == 0 and k.latency_jitter_ms == 0 and k.drop_percent == 0

    def next(self) -> FrameTiming:
        if self.ideal:
            return FrameTiming(False, 0.0)
        k = self.knobs
        dropped = bool(self._rng.random() < k.drop_percent / 100.0)
        jitter = self._rng.standard_normal() * k.latency_jitter_ms
        return FrameTiming(dropped, max(k.latency_ms + jitter, 0.0) / 1e3)

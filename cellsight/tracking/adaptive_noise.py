"""Adaptive pixel noise (optional, beyond the paper; for :mod:`.ekf`): a scalar pixel variance per
camera re-estimated by robust covariance matching over a sliding window of the last
innovations."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np


@dataclass
class AdaptiveNoise:
    """Robust covariance-matching estimate of a scalar pixel noise per camera.

    For a feature's innovation ``nu`` (2,) with ``C P- C^T`` of trace ``tr``, in the isotropic
    approximation ``|nu|^2 ~ (sigma^2 + tr / 2) chi2_2``, whose median is
    ``(sigma^2 + tr / 2) 2 ln 2``. Each feature gives ``y = |nu|^2 / (2 ln 2) - tr / 2`` and
    ``sigma^2 = median(y)`` over the last ``window`` features of the camera: the median keeps
    outliers out, so every innovation, gated or not, is used (gating with a too small sigma
    would otherwise keep only the small innovations and drive the estimate down).
    ``min_samples`` are needed before the estimate replaces the model's default sigma; the
    result is clamped to ``[sigma_min, sigma_max]`` (px).
    """

    window: int = 200
    min_samples: int = 20
    sigma_min: float = 0.1
    sigma_max: float = 5.0
    _samples: dict[int, deque] = field(default_factory=dict, init=False, repr=False)

    def sigma(self, camera_index: int, default: float) -> float:
        """Current pixel sigma (px) for a camera, ``default`` until enough samples."""
        samples = self._samples.get(camera_index)
        if samples is None or len(samples) < self.min_samples:
            return default
        var = float(np.median(samples))
        return float(np.clip(np.sqrt(max(var, 0.0)), self.sigma_min, self.sigma_max))

    def add(self, camera_index: int, innovation: np.ndarray, predicted_trace: np.ndarray) -> None:
        """Add innovations (m, 2) and the traces of their ``C_j P- C_j^T`` (m,)."""
        samples = self._samples.setdefault(camera_index, deque(maxlen=self.window))
        samples.extend(np.sum(innovation**2, axis=1) / (2 * np.log(2)) - 0.5 * predicted_trace)

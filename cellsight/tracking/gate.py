"""Validation gate of the EKF update (beyond the paper): rejects a measured feature whose
innovation is too unlikely under the filter's prediction — a wrong corner, an occlusion the
predictor missed.

For feature ``j``: innovation ``nu_j`` (2,) px with covariance ``S_j`` (2x2) px^2,
``d_j^2 = nu_j^T S_j^-1 nu_j``; the feature is accepted when ``d_j^2`` is at most the
chi-square quantile with 2 degrees of freedom at ``probability``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy.stats import chi2

if TYPE_CHECKING:
    from cellsight.tracking.interfaces import Gate


@dataclass(frozen=True)
class ChiSquareGate:
    """Per-feature chi-square gate; ``probability`` in (0, 1): the fraction of correct
    measurements that pass."""

    probability: float = 0.999
    threshold: float = field(init=False)

    def __post_init__(self) -> None:
        if not 0 < self.probability < 1:
            raise ValueError(
                f"ChiSquareGate: probability must be in (0, 1), got {self.probability}")
        object.__setattr__(self, "threshold", float(chi2.ppf(self.probability, 2)))

    def accepts(self, mahalanobis2: np.ndarray) -> np.ndarray:
        """Boolean mask (m,): which squared Mahalanobis distances pass."""
        return np.asarray(mahalanobis2) <= self.threshold


@dataclass(frozen=True)
class SupportedGate:
    """What ``gate`` accepts (everything when None), provided at least ``min_support``
    features pass together; otherwise none."""

    gate: Gate | None
    min_support: int

    def accepts(self, mahalanobis2: np.ndarray) -> np.ndarray:
        """Boolean mask (m,): which squared Mahalanobis distances pass."""
        d2 = np.asarray(mahalanobis2)
        passed = np.ones(d2.shape, dtype=bool) if self.gate is None else self.gate.accepts(d2)
        return passed if passed.sum() >= self.min_support else np.zeros_like(passed)


@numba.njit(cache=True)
def mahalanobis2(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``d_j^2 = nu_j^T S_j^-1 nu_j`` (m,) for innovations (m, 2) and covariances (m, 2, 2)."""
    d2 = np.empty(len(innovation))
    for j in range(len(innovation)):
        a, b, c = S[j, 0, 0], S[j, 0, 1], S[j, 1, 1]
        nu0, nu1 = innovation[j, 0], innovation[j, 1]
        d2[j] = (c * nu0**2 - 2 * b * nu0 * nu1 + a * nu1**2) / (a * c - b * b)
    return d2

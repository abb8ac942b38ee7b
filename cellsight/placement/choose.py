"""Choosing K cameras among the candidates.

The objective is the tracker's single-frame position error, predicted: at frame k, a set S of
cameras gives the pose information ``A_k = P0 + sum_{c in S} I_kc`` (:mod:`.scoring`; ``P0``
a weak prior, ``PRIOR_M`` m and ``PRIOR_RAD`` rad of standard deviation, which keeps a frame
that sees too little finite), and the predicted position error is
``sigma_k = sqrt(trace(A_k^-1)_xyz)`` (m). The loss of S over the task is::

    loss(S) = mean_k sigma_k (mm) + FEW_POINTS_MM * (fraction of frames where S sees < 4 points)

(a frame with fewer than 4 points counted over all chosen cameras cannot give the tracker a
pose fix of its own). :func:`choose_cameras` adds, greedily, the candidate that lowers the
loss most, then exchanges each chosen camera for the best other one while the loss drops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.placement.scoring import CandidateScores

PRIOR_M, PRIOR_RAD = 0.1, 1.0
FEW_POINTS_MM = 100.0
MIN_POINTS = 4
_BATCH = 48  # candidates evaluated at once (memory: N x _BATCH 6x6 matrices)


def _prior() -> np.ndarray:
    return np.diag([PRIOR_M**-2] * 3 + [PRIOR_RAD**-2] * 3)


def position_sigma_mm(info: np.ndarray) -> np.ndarray:
    """Predicted position error (mm) of information matrices (..., 6, 6) plus the prior."""
    cov = np.linalg.inv(info.astype(np.float64) + _prior())
    return 1e3 * np.sqrt(np.trace(cov[..., :3, :3], axis1=-2, axis2=-1))


@dataclass(frozen=True)
class Placement:
    """A set of candidates (indices into :attr:`CandidateScores.cameras`) and its figures:
    ``loss`` (module docstring), ``sigma_mm`` (N,) predicted position error per frame,
    ``points`` (N,) features seen per frame, counted over the cameras, ``few`` (N,) bool:
    fewer than 4."""

    chosen: tuple[int, ...]
    loss: float
    sigma_mm: np.ndarray
    points: np.ndarray

    @property
    def few(self) -> np.ndarray:
        return self.points < MIN_POINTS


def placement_loss(scores: CandidateScores, chosen) -> Placement:
    """The figures of the candidates ``chosen`` (module docstring)."""
    chosen = tuple(int(c) for c in chosen)
    info = scores.info[:, list(chosen)].sum(axis=1)
    sigma = position_sigma_mm(info)
    points = scores.visible[:, list(chosen)].sum(axis=(1, 2))
    return Placement(chosen, float(sigma.mean() + FEW_POINTS_MM * np.mean(points < MIN_POINTS)),
                     sigma, points)


def _losses(scores: CandidateScores, base_info: np.ndarray, base_points: np.ndarray) -> np.ndarray:
    """(C,) loss of the set whose information is ``base_info`` (N, 6, 6) and point count
    ``base_points`` (N,) with each candidate added."""
    C = len(scores.cameras)
    out = np.empty(C)
    counts = scores.visible.sum(axis=2)  # (N, C)
    for a in range(0, C, _BATCH):
        b = min(a + _BATCH, C)
        sigma = position_sigma_mm(base_info[:, None] + scores.info[:, a:b])
        few = (base_points[:, None] + counts[:, a:b]) < MIN_POINTS
        out[a:b] = sigma.mean(axis=0) + FEW_POINTS_MM * few.mean(axis=0)
    return out


def _best_addition(scores: CandidateScores, fixed: list[int]) -> tuple[int, float]:
    info = scores.info[:, fixed].sum(axis=1) if fixed else np.zeros(scores.info.shape[::3][:1]
                                                                      + (6, 6))
    points = scores.visible[:, fixed].sum(axis=(1, 2)) if fixed else np.zeros(len(info), int)
    losses = _losses(scores, info.astype(np.float64), points)
    losses[fixed] = np.inf
    best = int(np.argmin(losses))
    return best, float(losses[best])


def choose_cameras(scores: CandidateScores, k: int, max_rounds: int = 5) -> Placement:
    """The best ``k`` candidates found by greedy additions and then exchanges (module
    docstring)."""
    if not 1 <= k <= len(scores.cameras):
        raise ValueError(f"choose_cameras: k must be 1..{len(scores.cameras)}, got {k}")
    chosen: list[int] = []
    for _ in range(k):
        chosen.append(_best_addition(scores, chosen)[0])
    loss = placement_loss(scores, chosen).loss
    for _ in range(max_rounds):
        improved = False
        for i in range(k):
            others = chosen[:i] + chosen[i + 1:]
            best, best_loss = _best_addition(scores, others)
            if best_loss < loss - 1e-9:
                chosen[i], loss, improved = best, best_loss, True
        if not improved:
            break
    return placement_loss(scores, chosen)

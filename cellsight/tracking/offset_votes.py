"""Votes for a camera's image offset (:mod:`.registration`): the Shi-Tomasi corners of a
region, with the extractor's settings, and the peaks of a grid of votes."""

from __future__ import annotations

import cv2
import numpy as np

from cellsight.tracking.extraction import ExtractionConfig


def corners_in(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(N, 2) px: the Shi-Tomasi corners (whole pixels, image coordinates) of the region
    ``box`` (u0, v0, u1, v1) of ``image``, with the extractor's window settings."""
    cfg = ExtractionConfig()
    h, w = image.shape[:2]
    u0, v0 = max(int(box[0]), 0), max(int(box[1]), 0)
    u1, v1 = min(int(box[2]), w), min(int(box[3]), h)
    if u1 - u0 < 5 or v1 - v0 < 5:
        return np.zeros((0, 2))
    crop = np.ascontiguousarray(image[v0:v1, u0:u1], dtype=np.float32)
    found = cv2.goodFeaturesToTrack(crop, maxCorners=200, qualityLevel=cfg.quality_level,
                                    minDistance=cfg.min_distance_px, blockSize=cfg.block_size)
    return np.zeros((0, 2)) if found is None else found.reshape(-1, 2) + [u0, v0]


def vote_peaks(votes: np.ndarray, count: int, fraction: float = 1.0) -> list[np.ndarray]:
    """Up to ``count`` offsets (2,) (u, v), px, of the peaks of ``votes`` ((2R+1, 2R+1), rows
    v, columns u, offset -R at index 0): first the bin with the most votes in its 3x3
    neighbourhood (the coarse offset), then the next such peaks, each more than 2 px from the
    ones before (in u or v) and with at least ``fraction`` of the first's votes; the first
    always."""
    reach = votes.shape[0] // 2
    padded = np.pad(votes, 1)
    summed = sum(padded[1 + dv:1 + dv + votes.shape[0], 1 + du:1 + du + votes.shape[1]]
                 for dv in (-1, 0, 1) for du in (-1, 0, 1))
    v, u = np.unravel_index(int(np.argmax(summed)), summed.shape)
    best = summed[v, u]
    peaks: list[np.ndarray] = []
    while not peaks or (len(peaks) < count and summed[v, u] > 0.0
                        and summed[v, u] >= fraction * best):
        peaks.append(np.array([u - reach, v - reach], dtype=float))
        summed[max(v - 2, 0):v + 3, max(u - 2, 0):u + 3] = -np.inf
        v, u = np.unravel_index(int(np.argmax(summed)), summed.shape)
    return peaks

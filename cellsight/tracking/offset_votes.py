"""A camera's image offset gathered at one place (:mod:`.registration`): the Shi-Tomasi corners
of a region, with the extractor's settings, vote for it; the peaks of the votes give a coarse
offset; the sub-pixel corners near it give the residuals (:class:`OffsetGathering`)."""

from __future__ import annotations

from typing import Any, Protocol

import cv2
import numpy as np

from cellsight.tracking.extraction import ExtractionConfig, extract_corner
from cellsight.tracking.grabbing import grabbed


class GatheringRule(Protocol):
    """The numbers a gathering follows (:class:`~.registration.RegistrationRule`'s): px."""

    reach_px: int
    vote_frames: int
    rivals: int
    rival_fraction: float
    window_px: int
    agree_px: float
    min_corners: int


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


class OffsetGathering:
    """One camera's votes (stage 1) and residuals (stage 2) at one place, by ``rule``
    (:class:`GatheringRule`), the votes within ``reach_px`` (px); the stages
    are those of :mod:`.registration`'s docstring."""

    def __init__(self, rule: GatheringRule, reach_px: int) -> None:
        self.rule = rule
        self.coarse: np.ndarray | None = None
        self.measured = 0  # frames measured at the coarse offset
        self.points: list[np.ndarray] = []  # the corners found, base frame (m)
        self.found: list[np.ndarray] = []  # where they were found (px)
        self.gaps: list[np.ndarray] = []  # found less predicted (px)
        # the votes' other peaks, measured beside the coarse offset until one is chosen:
        # (offset (2,) px, and its points, found and gaps)
        self.rivals: list[tuple[np.ndarray, list, list, list]] = []
        self._start_votes(reach_px)

    def _start_votes(self, reach_px: int) -> None:
        """No votes yet, within ``reach_px`` (px)."""
        self.reach = reach_px
        side = 2 * reach_px + 1
        self.votes = np.zeros((side, side))
        self.voted = 0

    @property
    def ready(self) -> bool:
        """Whether it has the residuals an offset is made of."""
        return not self.rivals and len(self.points) >= self.rule.min_corners

    def add(self, observed: Any, points: np.ndarray, pixels: np.ndarray) -> None:
        """This frame's image (or what grabs from it) and the gripper's corners (N, 3) m, base
        frame, predicted at (N, 2) px in it: votes until the coarse offset is known, residuals
        after."""
        if self.coarse is None:
            self._vote(observed, pixels)
        else:
            self._measure(observed, points, pixels)

    def _vote(self, observed: Any, pixels: np.ndarray) -> None:
        reach = self.reach
        box = np.concatenate([np.floor(pixels.min(axis=0)) - reach - 8,
                              np.ceil(pixels.max(axis=0)) + reach + 9]).astype(int)
        corners = corners_in(grabbed(observed, [box.tolist()]), box)
        if len(corners):
            gap = np.rint(corners[None, :, :] - pixels[:, None, :]).reshape(-1, 2).astype(int)
            gap = gap[(np.abs(gap) <= reach).all(axis=1)]
            np.add.at(self.votes, (gap[:, 1] + reach, gap[:, 0] + reach), 1.0)
        self.voted += 1
        if self.voted >= self.rule.vote_frames:
            near = self.reach < self.rule.reach_px  # around a camera registered already
            peaks = vote_peaks(self.votes, self.rule.rivals + 1 if near else 1,
                               self.rule.rival_fraction)
            self.coarse = peaks[0]
            self.rivals = [(peak, [], [], []) for peak in peaks[1:]]
            self.measured = 0

    def _measure(self, observed: Any, points: np.ndarray, pixels: np.ndarray) -> None:
        tallies = [(self.coarse, self.points, self.found, self.gaps), *self.rivals]
        half = self.rule.window_px // 2
        starts = [np.floor(pixels + offset).astype(int) for offset, *_ in tallies]
        every = np.concatenate(starts)
        image = grabbed(observed, np.column_stack([every - half, every + half + 1]).tolist())
        for (offset, kept, found, gaps), start in zip(tallies, starts, strict=True):
            for pixel, corner, point in zip(pixels, start, points, strict=True):
                at = extract_corner(image, np.concatenate([corner - half, corner + half + 1]),
                                    pixel + offset)
                if at is not None and np.linalg.norm(at - pixel - offset) <= self.rule.agree_px:
                    kept.append(point)
                    found.append(at)
                    gaps.append(at - pixel)
        self.measured += 1
        if self.measured == self.rule.vote_frames:
            self._choose()
            if len(self.points) < self.rule.vote_frames:
                self._strike_out()

    def _choose(self) -> None:
        """The coarse offset becomes whichever of it and its rivals found the most residuals
        over the first ``vote_frames`` frames (votes nearly tied between two peaks, as the
        pairs of neighbouring corners can make them, are settled by the corners found), moved
        to the nearest whole pixel of its residuals' median (the votes' 1 px bins and 3x3 sums
        leave it up to 2 px off, where fewer corners come within ``agree_px``)."""
        best = max(self.rivals, key=lambda rival: len(rival[1]), default=None)
        if best is not None and len(best[1]) > len(self.points):
            self.coarse, self.points, self.found, self.gaps = best
        self.rivals = []
        if self.gaps:
            self.coarse = np.rint(np.median(self.gaps, axis=0))

    def _strike_out(self) -> None:
        """The coarse offset found too few residuals. Votes of a reach short of the rule's
        ``reach_px`` start again with that reach (the camera as registered so far is further
        off here than the reach allowed for); otherwise the offset's votes (3x3 bins) are
        struck out, and the next frame's votes with the rest give another."""
        u, v = (self.coarse + self.reach).astype(int)
        self.coarse, self.points, self.found, self.gaps = None, [], [], []
        if self.reach < self.rule.reach_px:
            self._start_votes(self.rule.reach_px)
            return
        self.votes[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2] = 0.0
        self.voted = self.rule.vote_frames - 1

"""Each camera registered to the robot by its gripper (beyond the paper; with the kinematic
prior).

A camera's calibration error moves its whole image of the work area by nearly one offset (in
the realistic world's ``harsh`` cells, 2-9 px per camera); the part of it the cameras share
moves the estimate by millimetres that no corner of the part shows (3-10 mm, steady, in every
``harsh`` run), and the gripper then grasps where the estimate says. The robot knows where its
gripper is: the joint measurements and the arm's model put the corners of the gripper's palm
and jaws (the cell file's boxes) in the base frame. While the gripper stands still in view
(moved less than ``still_mm`` since the last frame: the exposure's time then does not matter),
each camera looks at the corners with a face turned towards it, ``margin_px`` inside its
image, in two stages:

1. votes: the Shi-Tomasi corners of the region around them (the tracker's extractor's
   settings) vote for every offset within ``reach_px`` that brings a predicted corner onto one
   (1 px bins); after ``vote_frames`` frames, the bin with the most votes in its 3x3
   neighbourhood is the coarse offset (the gripper's corners all vote for the camera's
   offset, the pairs of a corner with its neighbours' scatter);
2. residuals: the sub-pixel corner (:func:`~cellsight.tracking.extraction.extract_corner`) in
   a window of ``window_px`` centred on each predicted corner moved by the coarse offset;
   one within ``agree_px`` of the coarse offset is a residual (found minus predicted, px).

Once every camera has ``min_corners`` residuals its offset is their median, and the tracker
takes each camera with its principal point moved by it
(:meth:`~cellsight.tracking.Tracker.recalibrate`): every pixel it predicts moves by the offset
exactly, the lens distortion included.

What it registers is the camera against the arm: the arm's own error (its base, its links, the
gripper's size) goes into the offset, which is what a task driven by the arm wants. One offset,
made where the gripper stood: a lens distortion error makes a camera's offset vary across its
image (in one ``harsh`` camera by 6 px between the gripper at HOME and the part), which it does
not follow. Every camera is registered on the same frame, once each has ``min_corners``
residuals: a camera that never sees the gripper standing still leaves them all as they are.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell
from cellsight.tracking.extraction import ExtractionConfig, extract_corner
from cellsight.tracking.grabbing import grabbed

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RegistrationRule:
    """The numbers of the module docstring. Units: px, mm. ``enabled`` False: never
    registers."""

    margin_px: float = 15.0
    still_mm: float = 0.5
    reach_px: int = 15
    vote_frames: int = 10
    window_px: int = 15
    agree_px: float = 2.0
    min_corners: int = 100
    enabled: bool = True

    def registration(self, cell: Cell, robot: str) -> GripperRegistration:
        """The registration of ``cell``'s cameras to ``robot``'s gripper."""
        return GripperRegistration(self, cell, robot)


@dataclass(frozen=True)
class Registered:
    """One camera's registration: its ``offset_px`` (2,) (u, v), the ``coarse_px`` (2,) offset
    of the votes, how many residuals it had (``corners``) and the time it was made (``t``,
    s)."""

    offset_px: np.ndarray
    coarse_px: np.ndarray
    corners: int
    t: float


class GripperRegistration:
    """The votes and residuals gathered per camera, and the registrations once made (module
    docstring). ``registered``: camera index -> :class:`Registered`; ``done``: True once the
    offsets are made."""

    def __init__(self, rule: RegistrationRule, cell: Cell, robot: str) -> None:
        self.rule = rule
        self.cell = cell
        self.robot = robot
        self.objects = [i for i, f in enumerate(cell.frames)
                        if f.kind in ("palm", "jaw") and f.owner == robot]
        side = 2 * rule.reach_px + 1
        self._votes = np.zeros((len(cell.cameras), side, side))
        self._voted = np.zeros(len(cell.cameras), dtype=int)
        self._coarse: list[np.ndarray | None] = [None] * len(cell.cameras)
        self._residuals: list[list[np.ndarray]] = [[] for _ in cell.cameras]
        self._last: np.ndarray | None = None
        self.registered: dict[int, Registered] = {}
        self.done = not rule.enabled or not self.objects

    def add(self, t: float, observed: Sequence[Any], joints: Mapping[str, np.ndarray],
            openings: Mapping[str, float]) -> dict[int, Camera]:
        """One frame at ``t`` (s): ``observed`` what each camera took (images, or
        :class:`~cellsight.tracking.grabbing.OnDemandImage`; None: nothing), ``joints`` and
        ``openings`` the measured joints and jaw openings. Returns the registered cameras
        (index -> camera with its principal point moved) on the frame the offsets are made,
        else an empty dict."""
        if self.done:
            return {}
        poses = self.cell.snapshot(joints, None, openings).poses
        tcp = poses[self.objects[0]][:3, 3]
        still = self._last is not None and \
            1e3 * np.linalg.norm(tcp - self._last) <= self.rule.still_mm
        self._last = tcp.copy()
        if not still:
            return {}
        for c, cam in enumerate(self.cell.cameras):
            pixels = self._predicted(poses, cam)
            if observed[c] is None or not len(pixels):
                continue
            if self._coarse[c] is None:
                self._vote(c, observed[c], pixels)
            else:
                self._measure(c, observed[c], pixels)
        if min(len(r) for r in self._residuals) < self.rule.min_corners:
            return {}
        return self._register(float(t))

    def _predicted(self, poses: np.ndarray, cam: Camera) -> np.ndarray:
        """(N, 2) px: the gripper's corners with a face turned towards ``cam``, projected,
        ``margin_px`` inside its image."""
        points = []
        for i in self.objects:
            solid, T = self.cell.objects[i].solid, poses[i]
            V = transform_points(T, solid.vertices)
            normals = solid.normals @ T[:3, :3].T
            seen = np.zeros(len(V), dtype=bool)
            for k, face in enumerate(solid.faces):
                if normals[k] @ (cam.center - V[face[0]]) > 0:
                    seen[list(face)] = True
            points.append(V[seen])
        pixels = cam.project(np.concatenate(points))
        pixels = pixels[np.isfinite(pixels).all(axis=1)]
        return pixels[cam.in_image(pixels, self.rule.margin_px)]

    def _vote(self, c: int, observed: Any, pixels: np.ndarray) -> None:
        """Camera ``c``'s votes of this frame (stage 1); the coarse offset after
        ``vote_frames`` frames."""
        reach = self.rule.reach_px
        box = np.concatenate([np.floor(pixels.min(axis=0)) - reach - 8,
                              np.ceil(pixels.max(axis=0)) + reach + 9]).astype(int)
        corners = _corners_in(grabbed(observed, [box.tolist()]), box)
        if len(corners):
            gap = np.rint(corners[None, :, :] - pixels[:, None, :]).reshape(-1, 2).astype(int)
            gap = gap[(np.abs(gap) <= reach).all(axis=1)]
            np.add.at(self._votes[c], (gap[:, 1] + reach, gap[:, 0] + reach), 1.0)
        self._voted[c] += 1
        if self._voted[c] >= self.rule.vote_frames:
            self._coarse[c] = coarse_offset(self._votes[c])

    def _measure(self, c: int, observed: Any, pixels: np.ndarray) -> None:
        """Camera ``c``'s residuals of this frame (stage 2)."""
        coarse, half = self._coarse[c], self.rule.window_px // 2
        centres = pixels + coarse
        corner = np.floor(centres).astype(int)
        boxes = np.column_stack([corner - half, corner + half + 1]).tolist()
        image = grabbed(observed, boxes)
        for box, centre, predicted in zip(boxes, centres, pixels, strict=True):
            found = extract_corner(image, np.array(box), centre)
            if found is not None and np.linalg.norm(found - centre) <= self.rule.agree_px:
                self._residuals[c].append(found - predicted)

    def _register(self, t: float) -> dict[int, Camera]:
        """Every camera's offset (once): the registered cameras."""
        self.done = True
        out = {}
        for c, cam in enumerate(self.cell.cameras):
            residuals = np.array(self._residuals[c])
            offset = np.median(residuals, axis=0)
            log.info("camera %s registered to %s's gripper at %.2f s: offset (%.2f, %.2f) px "
                     "from %d corners (votes: (%.0f, %.0f) px)", cam.name, self.robot, t,
                     offset[0], offset[1], len(residuals), *self._coarse[c])
            self.registered[c] = Registered(offset, self._coarse[c], len(residuals), t)
            out[c] = shifted(cam, offset)
        return out


def _corners_in(image: np.ndarray, box: np.ndarray) -> np.ndarray:
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


def coarse_offset(votes: np.ndarray) -> np.ndarray:
    """The offset (2,) (u, v), px, of the bin of ``votes`` ((2R+1, 2R+1), rows v, columns u,
    offset -R at index 0) with the most votes in its 3x3 neighbourhood."""
    reach = votes.shape[0] // 2
    padded = np.pad(votes, 1)
    summed = sum(padded[1 + dv:1 + dv + votes.shape[0], 1 + du:1 + du + votes.shape[1]]
                 for dv in (-1, 0, 1) for du in (-1, 0, 1))
    v, u = np.unravel_index(int(np.argmax(summed)), summed.shape)
    return np.array([u - reach, v - reach], dtype=float)


def shifted(camera: Camera, offset_px: np.ndarray) -> Camera:
    """``camera`` with its principal point moved by ``offset_px`` (u, v): every pixel it
    projects moves by the offset."""
    K = camera.K.copy()
    K[:2, 2] += offset_px
    return replace(camera, K=K)

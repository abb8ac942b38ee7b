"""Each camera registered to the robot by its gripper (beyond the paper; with the kinematic
prior).

A camera's calibration error moves its image of the work area by a few pixels, nearly one
offset over a small region (in the realistic world's ``harsh`` cells, 2-9 px per camera; its
lens distortion's error makes it vary across the image, by up to 6 px between the arm's HOME
and the part in one ``harsh`` camera); the part of it the cameras share moves the estimate by
millimetres that no corner of the part shows (3-10 mm, steady, in every ``harsh`` run), and
the gripper then grasps where the estimate says. The robot knows where its gripper is: the
joint measurements and the arm's model put the corners of the gripper's palm and jaws (the
cell file's boxes) in the base frame. Each camera looks at the corners with a face turned
towards it, ``margin_px`` inside its image, in two stages:

1. votes: the Shi-Tomasi corners of the region around them (the tracker's extractor's
   settings) vote for every offset within ``reach_px`` that brings a predicted corner onto one
   (1 px bins; the earlier frames' votes weigh ``vote_decay`` less each frame); from
   ``vote_frames`` frames on, the bin with the most votes in its 3x3 neighbourhood is the
   coarse offset (the gripper's corners all vote for the camera's offset, the pairs of a
   corner with its neighbours' scatter), and it follows the offset as the gripper moves;
2. residuals: the sub-pixel corner (:func:`~cellsight.tracking.extraction.extract_corner`) in
   a window of ``window_px`` centred on each predicted corner moved by the coarse offset; one
   within ``agree_px`` of it is a residual (found minus predicted, px).

The corners are predicted at the camera's exposure time: the joints interpolated between the
last frame's and this one's (a moving gripper, cameras not triggered together).

The camera's offset is the median of its latest ``corners`` residuals, made again every
``every_s`` while the gripper is within ``near_m`` of the part's estimate (anywhere, for the
first): so the offset is the one where the gripper works, by the part, and stays so when the
gripper leaves it. The tracker then takes each camera with its principal point moved by the
offset (:meth:`~cellsight.tracking.Tracker.recalibrate`): every pixel it predicts moves by the
offset exactly, the lens distortion included.

What it registers is the camera against the arm: the arm's own error (its base, its links, the
gripper's size) goes into the offset, which is what a task driven by the arm wants.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from cellsight.camera import Camera
from cellsight.model.cell import Cell
from cellsight.tracking.extraction import ExtractionConfig, extract_corner
from cellsight.tracking.grabbing import grabbed

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RegistrationRule:
    """The numbers of the module docstring. Units: px, mm, s, m. ``enabled`` False: never
    registers."""

    margin_px: float = 15.0
    reach_px: int = 15
    vote_frames: int = 10
    vote_decay: float = 0.9
    window_px: int = 15
    agree_px: float = 3.0
    corners: int = 100
    every_s: float = 0.5
    near_m: float = 0.3
    enabled: bool = True

    def registration(self, cell: Cell, robot: str) -> GripperRegistration:
        """The registration of ``cell``'s cameras to ``robot``'s gripper."""
        return GripperRegistration(self, cell, robot)


@dataclass(frozen=True)
class Registered:
    """One camera's registration: its ``offset_px`` (2,) (u, v), the ``coarse_px`` (2,) offset
    of the votes, when it was first made and last made again (``first_t``, ``t``, s) and how
    many times it was made (``updates``)."""

    offset_px: np.ndarray
    coarse_px: np.ndarray
    first_t: float
    t: float
    updates: int


class GripperRegistration:
    """The votes and residuals gathered per camera, and each camera's registration (module
    docstring). ``registered``: camera index -> :class:`Registered`, its latest."""

    def __init__(self, rule: RegistrationRule, cell: Cell, robot: str) -> None:
        self.rule = rule
        self.cell = cell
        self.robot = robot
        self.objects = [i for i, f in enumerate(cell.frames)
                        if f.kind in ("palm", "jaw") and f.owner == robot]
        side, n = 2 * rule.reach_px + 1, len(cell.cameras)
        self._votes = np.zeros((n, side, side))
        self._voted = np.zeros(n, dtype=int)
        self._coarse: list[np.ndarray | None] = [None] * n
        self._residuals = [deque(maxlen=rule.corners) for _ in range(n)]
        self._last: tuple[float, dict, dict] | None = None
        self.registered: dict[int, Registered] = {}
        self.enabled = rule.enabled and bool(self.objects)

    def add(self, t: float, observed: Sequence[Any], joints: Mapping[str, np.ndarray],
            openings: Mapping[str, float], stamps: Sequence[float | None] | None = None,
            part_at: np.ndarray | None = None) -> dict[int, Camera]:
        """One frame at ``t`` (s): ``observed`` what each camera took (images, or
        :class:`~cellsight.tracking.grabbing.OnDemandImage`; None: nothing), ``joints`` and
        ``openings`` the measured joints and jaw openings, ``stamps`` each camera's exposure
        time (None: ``t``), ``part_at`` (3,) the part's estimated position (m; None: none).
        Returns the cameras registered on this frame (index -> the cell file's camera with its
        principal point moved by its offset)."""
        if not self.enabled:
            return {}
        poses = self.cell.snapshot(joints, None, openings).poses
        tcp = poses[self.objects[0]][:3, 3]
        last, self._last = self._last, (float(t), dict(joints), dict(openings))
        near = part_at is not None and np.linalg.norm(tcp - part_at) <= self.rule.near_m
        out = {}
        for c, cam in enumerate(self.cell.cameras):
            if observed[c] is None or (c in self.registered and not near):
                continue
            stamp = None if stamps is None else stamps[c]
            exposed = poses if stamp is None or last is None else self._at(stamp, last, t,
                                                                           joints, openings)
            pixels = self._predicted(exposed, cam)
            if not len(pixels):
                continue
            self._vote(c, observed[c], pixels)
            if self._coarse[c] is not None:
                self._measure(c, observed[c], pixels)
            if self._due(c, t):
                out[c] = self._register(c, float(t))
        return out

    def _at(self, stamp: float, last: tuple, t: float, joints: Mapping[str, np.ndarray],
            openings: Mapping[str, float]) -> np.ndarray:
        """The cell's poses at time ``stamp`` (s): the joints and openings interpolated between
        the ``last`` frame's and this one's (at ``t``)."""
        t0, joints0, openings0 = last
        f = float(np.clip((stamp - t0) / (t - t0), 0.0, 1.0)) if t > t0 else 1.0
        q = {n: np.asarray(joints0[n]) + f * (np.asarray(v) - np.asarray(joints0[n]))
             if n in joints0 else v for n, v in joints.items()}
        o = {n: openings0[n] + f * (v - openings0[n]) if n in openings0 else v
             for n, v in openings.items()}
        return self.cell.snapshot(q, None, o).poses

    def _predicted(self, poses: np.ndarray, cam: Camera) -> np.ndarray:
        """(N, 2) px: the gripper's corners with a face turned towards ``cam``, projected,
        ``margin_px`` inside its image."""
        points = []
        for i in self.objects:
            solid, T = self.cell.objects[i].solid, poses[i]
            V = solid.vertices @ T[:3, :3].T + T[:3, 3]
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
        """Camera ``c``'s votes of this frame (stage 1), and its coarse offset from
        ``vote_frames`` frames on."""
        reach = self.rule.reach_px
        self._votes[c] *= self.rule.vote_decay
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
        half = self.rule.window_px // 2
        centres = pixels + self._coarse[c]
        corner = np.floor(centres).astype(int)
        boxes = np.column_stack([corner - half, corner + half + 1]).tolist()
        image = grabbed(observed, boxes)
        for box, centre, predicted in zip(boxes, centres, pixels, strict=True):
            found = extract_corner(image, np.array(box), centre)
            if found is not None and np.linalg.norm(found - centre) <= self.rule.agree_px:
                self._residuals[c].append(found - predicted)

    def _due(self, c: int, t: float) -> bool:
        """Whether camera ``c``'s offset is to be made (again) at ``t``."""
        done = self.registered.get(c)
        return len(self._residuals[c]) >= self.rule.corners and (
            done is None or t - done.t >= self.rule.every_s - 1e-9)

    def _register(self, c: int, t: float) -> Camera:
        """Camera ``c``'s offset from its latest residuals: the registered camera."""
        cam, done = self.cell.cameras[c], self.registered.get(c)
        offset = np.median(np.array(self._residuals[c]), axis=0)
        if done is None:
            log.info("camera %s registered to %s's gripper at %.2f s: offset (%.2f, %.2f) px "
                     "(votes: (%.0f, %.0f) px)", cam.name, self.robot, t, offset[0],
                     offset[1], *self._coarse[c])
        self.registered[c] = Registered(offset, self._coarse[c], t if done is None
                                        else done.first_t, t,
                                        1 if done is None else done.updates + 1)
        return shifted(cam, offset)


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

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
gripper's size) goes into the offset, which is what a task driven by the arm wants. A lens
distortion error makes a camera's offset vary across its image (in one ``harsh`` camera by
6 px between the gripper at HOME and the part), so each camera is registered once more, by
the part: once the gripper's TCP comes within ``near_m`` of the part's estimate, the two
stages start again from nothing, on every frame it is that near with its jaws open (within
``open_mm`` of their widest: closed on the part, the part's corners among the jaws' would
lead the votes astray, by 4-6 px in the ``harsh`` runs that registered so), moving or not
(its corners are predicted at the camera's exposure time, the joints interpolated between the
last frame's and this one's), and the camera takes the new offset once it has
``min_corners`` residuals.
Each camera is registered at HOME on the same frame, once each has its residuals (a camera
that never sees the gripper standing still leaves them all as they are); by the part, each on
its own. ``near_m`` 0: at HOME only.
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
    """The numbers of the module docstring. Units: px, mm, m. ``enabled`` False: never
    registers."""

    margin_px: float = 15.0
    still_mm: float = 0.5
    reach_px: int = 15
    vote_frames: int = 10
    window_px: int = 15
    agree_px: float = 2.0
    min_corners: int = 100
    near_m: float = 0.10
    open_mm: float = 5.0
    enabled: bool = True

    def registration(self, cell: Cell, robot: str) -> GripperRegistration:
        """The registration of ``cell``'s cameras to ``robot``'s gripper."""
        return GripperRegistration(self, cell, robot)


@dataclass(frozen=True)
class Registered:
    """One camera's registration: its ``offset_px`` (2,) (u, v), the ``coarse_px`` (2,) offset
    of the votes, how many residuals it had (``corners``), the time it was made (``t``, s) and
    where (``where``: ``home`` or ``part``)."""

    offset_px: np.ndarray
    coarse_px: np.ndarray
    corners: int
    t: float
    where: str = "home"


class _Gathering:
    """One camera's votes (stage 1) and residuals (stage 2) of the module docstring."""

    def __init__(self, rule: RegistrationRule) -> None:
        self.rule = rule
        side = 2 * rule.reach_px + 1
        self.votes = np.zeros((side, side))
        self.voted = 0
        self.coarse: np.ndarray | None = None
        self.residuals: list[np.ndarray] = []

    @property
    def ready(self) -> bool:
        """Whether it has the residuals an offset is made of."""
        return len(self.residuals) >= self.rule.min_corners

    def add(self, observed: Any, pixels: np.ndarray) -> None:
        """This frame's image (or what grabs from it) and the gripper's predicted corners
        (N, 2) px in it: votes until the coarse offset is known, residuals after."""
        if self.coarse is None:
            self._vote(observed, pixels)
        else:
            self._measure(observed, pixels)

    def _vote(self, observed: Any, pixels: np.ndarray) -> None:
        reach = self.rule.reach_px
        box = np.concatenate([np.floor(pixels.min(axis=0)) - reach - 8,
                              np.ceil(pixels.max(axis=0)) + reach + 9]).astype(int)
        corners = _corners_in(grabbed(observed, [box.tolist()]), box)
        if len(corners):
            gap = np.rint(corners[None, :, :] - pixels[:, None, :]).reshape(-1, 2).astype(int)
            gap = gap[(np.abs(gap) <= reach).all(axis=1)]
            np.add.at(self.votes, (gap[:, 1] + reach, gap[:, 0] + reach), 1.0)
        self.voted += 1
        if self.voted >= self.rule.vote_frames:
            self.coarse = coarse_offset(self.votes)

    def _measure(self, observed: Any, pixels: np.ndarray) -> None:
        half = self.rule.window_px // 2
        centres = pixels + self.coarse
        corner = np.floor(centres).astype(int)
        boxes = np.column_stack([corner - half, corner + half + 1]).tolist()
        image = grabbed(observed, boxes)
        for box, centre, predicted in zip(boxes, centres, pixels, strict=True):
            found = extract_corner(image, np.array(box), centre)
            if found is not None and np.linalg.norm(found - centre) <= self.rule.agree_px:
                self.residuals.append(found - predicted)


class GripperRegistration:
    """The votes and residuals gathered per camera, and the registrations once made (module
    docstring). ``registered``: camera index -> its latest :class:`Registered`; ``at_home``:
    camera index -> its registration at HOME; ``done``: True once nothing is left to
    register."""

    def __init__(self, rule: RegistrationRule, cell: Cell, robot: str) -> None:
        self.rule = rule
        self.cell = cell
        self.robot = robot
        self.objects = [i for i, f in enumerate(cell.frames)
                        if f.kind in ("palm", "jaw") and f.owner == robot]
        self._gathering = [_Gathering(rule) for _ in cell.cameras]
        self._last_palm: np.ndarray | None = None
        self._last_frame: tuple[float, Mapping, Mapping] | None = None
        self.registered: dict[int, Registered] = {}
        self.at_home: dict[int, Registered] = {}
        self.done = not rule.enabled or not self.objects

    def add(self, t: float, observed: Sequence[Any], joints: Mapping[str, np.ndarray],
            openings: Mapping[str, float], stamps: Sequence[float | None] | None = None,
            part_at: np.ndarray | None = None) -> dict[int, Camera]:
        """One frame at ``t`` (s): ``observed`` what each camera took (images, or
        :class:`~cellsight.tracking.grabbing.OnDemandImage`; None: nothing), ``joints`` and
        ``openings`` the measured joints and jaw openings, ``stamps`` each camera's exposure
        time (s; None: ``t``), ``part_at`` (3,) the part's estimated position (m; None: not
        known). Returns the cameras registered on this frame (index -> the cell file's camera
        with its principal point moved by its offset), else an empty dict."""
        if self.done:
            return {}
        last, self._last_frame = self._last_frame, (float(t), joints, openings)
        if not self.at_home:
            poses = self.cell.snapshot(joints, None, openings).poses
            return self._at_home(float(t), observed, poses)
        robot = self.cell.robot(self.robot)
        tcp = robot.tcp_pose(joints[self.robot])[:3, 3]
        if part_at is None or np.linalg.norm(tcp - part_at) > self.rule.near_m:
            return {}
        if 1e3 * (robot.tool.max_opening - openings[self.robot]) > self.rule.open_mm:
            return {}  # the jaws on the part: its corners among the jaws' would vote
        out = {}
        for c, cam in enumerate(self.cell.cameras):
            if observed[c] is None or self.registered[c].where == "part":
                continue
            stamp = None if stamps is None else stamps[c]
            pixels = self._predicted(self._poses_at(stamp, last, float(t), joints, openings),
                                     cam)
            if len(pixels):
                self._gathering[c].add(observed[c], pixels)
            if self._gathering[c].ready:
                out[c] = self._register(c, float(t), "part")
        self.done = all(r.where == "part" for r in self.registered.values())
        return out

    def record(self) -> dict[str, dict]:
        """Each camera's registration as plain data (``metrics.json``), by camera name: its
        latest offset (px), its corners, when (s) and where (``home``, ``part``) it was made,
        and its offset at HOME; None where there is none."""
        out = {}
        for c, cam in enumerate(self.cell.cameras):
            done, home = self.registered.get(c), self.at_home.get(c)
            out[cam.name] = {
                "offset_px": None if done is None else np.round(done.offset_px, 3).tolist(),
                "corners": None if done is None else done.corners,
                "t": None if done is None else round(done.t, 4),
                "where": None if done is None else done.where,
                "home_offset_px": None if home is None else np.round(home.offset_px, 3).tolist()}
        return out

    def _at_home(self, t: float, observed: Sequence[Any], poses: np.ndarray
                 ) -> dict[int, Camera]:
        """The first registration, from the frames where the gripper stands still: every
        camera on the frame where all have their residuals."""
        palm = poses[self.objects[0]][:3, 3]
        still = self._last_palm is not None and \
            1e3 * np.linalg.norm(palm - self._last_palm) <= self.rule.still_mm
        self._last_palm = palm.copy()
        if not still:
            return {}
        for c, cam in enumerate(self.cell.cameras):
            pixels = self._predicted(poses, cam)
            if observed[c] is not None and len(pixels):
                self._gathering[c].add(observed[c], pixels)
        if not all(g.ready for g in self._gathering):
            return {}
        out = {c: self._register(c, t, "home") for c in range(len(self.cell.cameras))}
        self.at_home = dict(self.registered)
        self._gathering = [_Gathering(self.rule) for _ in self.cell.cameras]
        self.done = self.rule.near_m <= 0.0
        return out

    def _poses_at(self, stamp: float | None, last: tuple | None, t: float,
                  joints: Mapping[str, np.ndarray], openings: Mapping[str, float]) -> np.ndarray:
        """The cell's poses at time ``stamp`` (s): the joints and openings interpolated between
        the ``last`` frame's and this one's (at ``t``); this frame's without a ``stamp`` or a
        ``last`` frame."""
        if stamp is None or last is None:
            return self.cell.snapshot(joints, None, openings).poses
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

    def _register(self, c: int, t: float, where: str) -> Camera:
        """Camera ``c``'s offset from its residuals: the registered camera."""
        cam, gathering = self.cell.cameras[c], self._gathering[c]
        residuals = np.array(gathering.residuals)
        offset = np.median(residuals, axis=0)
        log.info("camera %s registered to %s's gripper %s at %.2f s: offset (%.2f, %.2f) px "
                 "from %d corners (votes: (%.0f, %.0f) px)", cam.name, self.robot,
                 "at HOME" if where == "home" else "by the part", t, offset[0], offset[1],
                 len(residuals), *gathering.coarse)
        self.registered[c] = Registered(offset, gathering.coarse, len(residuals), t, where)
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

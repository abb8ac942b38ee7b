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
   Around a camera registered already (votes reaching less than ``reach_px``), up to
   ``rivals`` other peaks of the votes (more than 2 px away, with at least ``rival_fraction``
   of the first's votes) are measured beside it for the first ``vote_frames`` frames, and the
   one that found the most residuals is kept: where few corners vote (a camera that sees the
   gripper small or dark by the part), a pattern of neighbouring corners can outvote the true
   offset by a vote or two (in one ``harsh`` camera, 14 votes against 13, and 1.8 corners a
   frame found there against 2.4). Not over the full reach: there a camera that sees the
   gripper dark at its image's edge (``ur-cell``'s camera 3 at HOME) had a rival 15 px off
   the true offset find more corners than the first, a repeated pattern of the gripper's, and
   was registered there. The coarse offset kept is moved to its residuals' median's nearest
   whole pixel (the 1 px bins and 3x3 sums leave it up to 2 px off, where fewer corners come
   within ``agree_px``).

Once every camera has ``min_corners`` residuals, the tracker takes each camera with its pose
refitted to every corner gathered so far (:func:`~cellsight.tracking.camera_fit.refit_pose`:
the corners' model points in the base frame against the pixels they were found at; its
intrinsics kept) through :meth:`~cellsight.tracking.Tracker.recalibrate`; the residuals'
median against the cell file's camera is the camera's ``offset_px`` at that place (logged,
and in ``metrics.json``). At one place the camera is only *pointed* (turned about its x and
y axes, its position and roll held): that moves its image by about one offset, all one place
can show; fitted there with all six numbers, the corners' sub-pixel biases turned an exact
world's cameras by up to 0.27 deg and moved them 6 mm, and doubled its error. From two places
on, it is moved and turned (a prior of ``position_sd_mm`` and ``rotation_sd_deg`` holding the
correction small).

What it registers is the camera against the arm: the arm's own error (its base, its links, the
gripper's size) goes into the fit, which is what a task driven by the arm wants. One offset
fits one place only: a lens or pose error moves the image by different amounts across the
work area (in one ``harsh`` camera by 6 px between the gripper at HOME and the part; a part
set down 40 cm from where an offset was found was 5-11 mm off), so each camera gathers again
at more places and is refitted to all of them: **by the part**, once the gripper's TCP comes
within ``near_m`` of the part's estimate, on every frame it is that near with its jaws open
(within ``open_mm`` of their widest: closed on the part, the part's corners among the jaws'
would lead the votes astray, by 4-6 px in the ``harsh`` runs that registered so), moving or
not (its corners are predicted at the camera's exposure time, the joints interpolated between
the last frame's and this one's); and
**where the jaws open again** near the part after they closed (the release, or a grasp tried
again), the same way. Each place starts both stages from nothing, and after HOME the corners
are predicted by the camera as registered so far, the votes within ``reach_part_px`` by the
part (HOME alone may leave a lens error's 4-5 px there) and ``reach_release_px`` where the jaws
open again (the fit to two places brought the genuine ones of the ``harsh`` runs within 2 px;
the part's corners among the opening jaws voted 14 px away in one, and 4 px away in another,
where that place moved the camera's fit by 20 mm and 0.7 deg and the part's estimate by 6 mm). A
place whose corners do not fit one pose with the earlier places' (fewer than ``agree_fraction``
of its corners, or of an earlier place's, within 3 pixel sd of the fit to all) is not taken,
and gathered again.
HOME's registration is made on one frame: the one where every camera has its residuals, or
else the first frame the gripper is ``leave_mm`` from where it first stood still (it has left
HOME), with the cameras that have them. A camera that sees the gripper too dark, too small or
cut by its image's edge to find them there, as ``ur-cell``'s camera 3 does in ``harsh``, is
registered first by the part, its votes reaching ``reach_px`` around the cell file's camera.
At the later places each camera is registered on its own. A coarse offset that gives fewer
than one residual a frame over ``vote_frames`` frames is taken back: votes of a reach short
of ``reach_px`` start again with that reach (the camera as registered so far is further off
there than the reach allowed for), others have the offset's votes struck out, and the camera's
next frame votes with the rest for another. ``near_m`` 0: at HOME only.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell
from cellsight.tracking.camera_fit import PoseFit, refit_pose
from cellsight.tracking.offset_votes import OffsetGathering

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RegistrationRule:
    """The numbers of the module docstring. Units: px, mm, m. ``enabled`` False: never
    registers."""

    margin_px: float = 15.0
    still_mm: float = 0.5
    leave_mm: float = 20.0
    reach_px: int = 15
    reach_part_px: int = 5
    reach_release_px: int = 3
    vote_frames: int = 10
    rivals: int = 2
    rival_fraction: float = 0.7
    window_px: int = 15
    agree_px: float = 2.0
    min_corners: int = 100
    near_m: float = 0.10
    open_mm: float = 5.0
    agree_fraction: float = 0.7
    position_sd_mm: float = 10.0
    rotation_sd_deg: float = 0.5
    enabled: bool = True

    def registration(self, cell: Cell, robot: str) -> GripperRegistration:
        """The registration of ``cell``'s cameras to ``robot``'s gripper."""
        return GripperRegistration(self, cell, robot)


SITES = ("home", "part", "release")
"""The places a camera is registered at, in order (module docstring)."""


@dataclass(frozen=True)
class Registered:
    """One camera's registration: its ``offset_px`` (2,) (u, v) and the ``coarse_px`` (2,)
    offset of the votes at this place, how many residuals it had (``corners``), the time it was
    made (``t``, s), where (``where``: one of :data:`SITES`), and the pose correction fitted to
    every place's corners so far (``position_mm`` (3,), ``rotation_deg`` (3,), in the cell
    file's camera axes; ``rms_px`` the fit's reprojection error)."""

    offset_px: np.ndarray
    coarse_px: np.ndarray
    corners: int
    t: float
    where: str
    position_mm: np.ndarray
    rotation_deg: np.ndarray
    rms_px: float


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
        self._gathering = [OffsetGathering(rule, rule.reach_px) for _ in cell.cameras]
        self.cameras = list(cell.cameras)  # as registered so far
        self._gathered: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in cell.cameras]
        self._site = SITES[0]
        self._waiting: set[int] = set()  # the cameras not registered at this place yet
        self._last_palm: np.ndarray | None = None
        self._stood_at: np.ndarray | None = None  # where the gripper first stood still (m)
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
        with its pose refitted), else an empty dict."""
        if self.done:
            return {}
        last, self._last_frame = self._last_frame, (float(t), joints, openings)
        if self._site == SITES[0]:
            poses = self.cell.snapshot(joints, None, openings).poses
            return self._at_home(float(t), observed, poses)
        robot = self.cell.robot(self.robot)
        if 1e3 * (robot.tool.max_opening - openings[self.robot]) > self.rule.open_mm:
            self._jaws_closed()
            return {}  # the jaws on the part: its corners among the jaws' would vote
        tcp = robot.tcp_pose(joints[self.robot])[:3, 3]
        if part_at is None or np.linalg.norm(tcp - part_at) > self.rule.near_m:
            return {}
        out = {}
        for c, cam in enumerate(self.cameras):
            if observed[c] is None or c not in self._waiting:
                continue
            stamp = None if stamps is None else stamps[c]
            poses = self._poses_at(stamp, last, float(t), joints, openings)
            points, pixels = self._predicted(poses, cam)
            if len(pixels):
                self._gathering[c].add(observed[c], points, pixels)
            if self._gathering[c].ready:
                camera = self._register(c, float(t), self._site)
                if camera is not None:
                    out[c] = camera
                    self._waiting.discard(c)
        return out

    def record(self) -> dict[str, dict]:
        """Each camera's registration as plain data (``metrics.json``), by camera name: its
        latest offset (px), its corners, when (s) and where (:data:`SITES`) it was made, its
        pose correction (mm, deg) and the fit's error (px), and its offset at HOME; None where
        there is none."""
        out = {}
        for c, cam in enumerate(self.cell.cameras):
            done, home = self.registered.get(c), self.at_home.get(c)
            out[cam.name] = {
                "offset_px": None if done is None else np.round(done.offset_px, 3).tolist(),
                "corners": None if done is None else done.corners,
                "t": None if done is None else round(done.t, 4),
                "where": None if done is None else done.where,
                "position_mm": None if done is None else np.round(done.position_mm, 3).tolist(),
                "rotation_deg": None if done is None else
                np.round(done.rotation_deg, 4).tolist(),
                "rms_px": None if done is None else round(done.rms_px, 3),
                "home_offset_px": None if home is None else np.round(home.offset_px, 3).tolist()}
        return out

    def _jaws_closed(self) -> None:
        """The jaws are closed: once a camera has been registered near the part since they last
        were, the next place is where they open again (a release, or a grasp tried again)."""
        if len(self._waiting) < len(self.cell.cameras):
            self._site = SITES[2]
            self._again(self.rule.reach_release_px)

    def _at_home(self, t: float, observed: Sequence[Any], poses: np.ndarray
                 ) -> dict[int, Camera]:
        """The first registration, from the frames where the gripper stands still: on the
        frame where every camera has its residuals, or where the gripper has left HOME, the
        cameras that have them (module docstring)."""
        palm = poses[self.objects[0]][:3, 3]
        still = self._last_palm is not None and \
            1e3 * np.linalg.norm(palm - self._last_palm) <= self.rule.still_mm
        self._last_palm = palm.copy()
        if still:
            if self._stood_at is None:
                self._stood_at = palm.copy()
            for c, cam in enumerate(self.cameras):
                points, pixels = self._predicted(poses, cam)
                if observed[c] is not None and len(pixels):
                    self._gathering[c].add(observed[c], points, pixels)
        ready = [c for c, g in enumerate(self._gathering) if g.ready]
        left = self._stood_at is not None and \
            1e3 * np.linalg.norm(palm - self._stood_at) > self.rule.leave_mm
        if len(ready) < len(self.cameras) and not left:
            return {}
        out = {c: self._register(c, t, SITES[0]) for c in ready}
        self.at_home = dict(self.registered)
        self._site = SITES[1]
        self._again(self.rule.reach_part_px)
        self.done = self.rule.near_m <= 0.0
        return out

    def _again(self, reach_px: int) -> None:
        """Every camera to be registered at the next place, looked for with its registered
        camera within ``reach_px`` (``reach_px`` of the rule where it has no place yet)."""
        self._waiting = set(range(len(self.cell.cameras)))
        self._gathering = [OffsetGathering(self.rule, reach_px if self._gathered[c]
                                      else self.rule.reach_px)
                           for c in range(len(self.cell.cameras))]

    def feed(self, tracker: Any, t: float, observed: Sequence[Any],
             joints: Mapping[str, np.ndarray], openings: Mapping[str, float],
             stamps: Sequence[float | None] | None = None,
             part_at: np.ndarray | None = None) -> None:
        """One frame (:meth:`add`) for ``tracker`` (a :class:`~cellsight.tracking.Tracker`):
        each camera registered goes to it (``recalibrate``)."""
        for c, camera in self.add(t, observed, joints, openings, stamps, part_at).items():
            tracker.recalibrate(c, camera)

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

    def _predicted(self, poses: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The gripper's corners with a face turned towards ``cam`` that project
        ``margin_px`` inside its image: (N, 3) m, base frame, and (N, 2) px."""
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
        points = np.concatenate(points)
        pixels = cam.project(points)
        keep = np.isfinite(pixels).all(axis=1)
        keep[keep] = cam.in_image(pixels[keep], self.rule.margin_px)
        return points[keep], pixels[keep]

    def _register(self, c: int, t: float, where: str) -> Camera | None:
        """Camera ``c``'s offset from its residuals here, and its pose refitted to every
        place's corners so far: the registered camera; None (the place's corners dropped, to
        be gathered again) where fewer than ``agree_fraction`` of some place's corners come
        within 3 ``pixel_sd`` of the pose that fits every place (a place led astray)."""
        cam, gathering = self.cell.cameras[c], self._gathering[c]
        points, found = np.array(gathering.points), np.array(gathering.found)
        places = [*self._gathered[c], (points, found)]
        fit = self._fit(cam, places)
        self._gathering[c] = OffsetGathering(self.rule, gathering.reach)
        offset = np.median(found - cam.project(points), axis=0)
        ends = np.cumsum([len(p) for p, _ in places])
        agree = min(float(part.mean()) for part in np.split(fit.inlier, ends[:-1]))
        if len(places) > 1 and agree < self.rule.agree_fraction:
            log.info("camera %s: the corners of %s's gripper %s at %.2f s (offset (%.2f, %.2f) "
                     "px) disagree with the earlier places' (%.0f %% of a place's fit one "
                     "pose): not taken", cam.name, self.robot, _PLACES[where], t, *offset,
                     100 * agree)
            return None
        self._gathered[c] = places
        log.info("camera %s registered to %s's gripper %s at %.2f s: offset (%.2f, %.2f) px "
                 "from %d corners (coarse: (%.0f, %.0f) px); its pose fitted to %d corners at "
                 "%d places: moved (%.1f, %.1f, %.1f) mm, turned (%.3f, %.3f, %.3f) deg, "
                 "%.2f px rms, %.0f %% of each place's within 3 sd", cam.name, self.robot,
                 _PLACES[where], t, *offset, len(points), *gathering.coarse, fit.inliers,
                 len(places), *1e3 * fit.position, *np.degrees(fit.rotation), fit.rms_px,
                 100 * agree)
        self.registered[c] = Registered(offset, gathering.coarse, len(points), t, where,
                                        1e3 * fit.position, np.degrees(fit.rotation),
                                        fit.rms_px)
        self.cameras[c] = fit.camera
        return fit.camera

    def _fit(self, cam: Camera, places: list[tuple[np.ndarray, np.ndarray]]) -> PoseFit:
        """``cam`` refitted to every place's corners: at one place only pointed (turned about
        its x and y axes, its position and roll held), at more moved and turned (module
        docstring)."""
        points = np.concatenate([p for p, _ in places])
        pixels = np.concatenate([uv for _, uv in places])
        turn = np.radians(self.rule.rotation_sd_deg)
        if len(places) == 1:
            return refit_pose(cam, points, pixels, position_sd=_HELD_M,
                              rotation_sd=[turn, turn, _HELD_RAD])
        return refit_pose(cam, points, pixels, position_sd=1e-3 * self.rule.position_sd_mm,
                          rotation_sd=turn)


_HELD_M, _HELD_RAD = 1e-6, 1e-7  # a prior's sd that holds a position (m) or an angle (rad)
_PLACES = {"home": "at HOME", "part": "by the part", "release": "where the jaws opened again"}



"""A camera that disagrees (knocked, or an extrinsic error beyond its calibration's): found by
a consistent bias of its innovations while another camera holds the pose, then dropped from
the filter and its pose re-estimated online.

Per camera, over the last ``window_s`` seconds, the innovations (measured minus predicted
ideal pixel, px) of its measured features, accepted by the gate or not. A camera is *biased*
when at least ``min_points`` innovations in the window have a mean longer than ``bias_px`` and
than ``sigmas`` standard errors of that mean; it *disagrees* when it is biased while another
camera, with at least ``min_points`` innovations in the window, is not. A camera knocked
further than its windows reach finds its features no more: when, over ``window_s``, it found
fewer than half of the features it looked for while another camera found at least two thirds
of its own, the corners of its whole image (the sensor's ``detect``; at most every
``window_s``) are matched to its predicted pixels: the image offset (within ``max_offset_px``)
that brings the most predicted pixels within ``match_px`` of a corner (counted, too, after the
image similarity fitted to the corners near that offset, turned at most ``max_turn_deg`` and
scaled at most ``max_scale``: a knock turns the camera, and the image of the part moves by more
than ``match_px`` apart across it), if it brings at least ``min_matched`` of them and
``matched_share`` of the predicted-visible ones, and a second look ``confirm_s`` or more later
finds it again (within twice ``match_px``), is a displacement of the camera, not an occluder
(an occluder hides some features, it does not move them all alike: the knocked camera of the
tests matched 12-14 of 14, while clutter beside a gripper hiding part of the features of a
camera that was not moved matched 6 of 10, and in the `harsh` world, with the estimate off
along the other camera's line of sight, 6 of 8). The second look is for clutter: in a cell of
500 whole-image corners around a part on a conveyor, one look found 10 of 13 predicted pixels
at an offset of (-18, -10) px where nothing had moved, after looks that had found (-20, 0) and
(-64, -19); a knock's offset stays. Between the two looks the camera does not update the
filter (a knocked camera's features pulled the estimate enough to move its offset from (33, 1)
to (17, 10) px in 0.25 s). A near miss (``min_matched`` or more at an offset, short of the
share) is looked at again ``confirm_s`` later, not ``window_s``, the camera still in the filter:
a carried part's knocked camera found 8 of 12 at its first look (the gripper hides some, the
rest are off by the knock's turn), and the knock was found 3 s after it; looked at again
soon, 1 s after it. Held out of the filter on such a near miss instead, a camera was held
out in 9 of 60 `harsh` runs with no knock (in one, for 8 of 14 at an 8 px offset, 0.27 s,
and the estimate went 10.5 mm off while `tracking`). A frame with fewer than
``min_matched`` of the camera's features predicted visible (the gripper hides them), or
without its image, is not a look: the next frame's may be.
A camera that disagrees either way is *dropped*: its features are still measured, but no
longer update the filter. Only a camera that has agreed once (a window, ``window_s`` or more
after the check's first frame, of at least ``min_points`` innovations without a bias, in which
it found two thirds of the features it looked for) can be dropped: a knock is a change, and with two
cameras a disagreement from the start does not say which is wrong (an estimate off along one
camera's line of sight shows as an offset in the other camera only; in the `harsh` world that
dropped the good camera 0.5 s and 1.0 s into a run).

While dropped, from ``window_s`` after the drop (the estimate has settled on the other cameras)
in every frame where they updated it, its pixels of the estimated feature points (base frame)
are gathered: the measured ones, or, for a displaced camera, the whole-image corners found
within ``match_px`` of each predicted pixel moved by the offset; once ``recalibrate_points``
are in hand its pose is refitted to them
(:func:`~cellsight.tracking.camera_fit.refit_pose`: robust, its own intrinsics and distortion,
from its pose before the drop with a prior of ``knock_mm`` and ``knock_deg``): the recovered
``T_base_cam`` (:attr:`CameraCheck.recovered`). The camera stays dropped (the visibility
source keeps its camera): one small part at one place fixes the pose there, not elsewhere. A
knocked camera taken back with such a pose (or registered again to the gripper at one place)
pulled the estimate 12 mm off once the part was set down 40 cm away, and the camera that was
right got dropped for it.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose, rotation_angle
from cellsight.tracking.camera_fit import refit_pose

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraCheckRule:
    """The numbers of the module docstring. Units: s, px. ``enabled`` False: never drops."""

    window_s: float = 1.0
    bias_px: float = 8.0
    sigmas: float = 5.0
    min_points: int = 15
    max_offset_px: float = 150.0
    match_px: float = 2.5
    max_turn_deg: float = 3.0
    max_scale: float = 0.03
    min_matched: int = 8
    matched_share: float = 0.75
    confirm_s: float = 0.25
    recalibrate_points: int = 60
    knock_mm: float = 30.0
    knock_deg: float = 2.0
    enabled: bool = True

    def check(self, cameras: Sequence[Camera]) -> CameraCheck:
        """The check of these cameras (one for all the tracked parts)."""
        return CameraCheck(self, cameras)


class CameraCheck:
    """Innovations per camera, the dropped cameras and their recovered poses (module
    docstring). ``dropped``: camera index -> time (s) it was dropped; ``recovered``: camera
    index -> re-estimated ``T_base_cam``."""

    def __init__(self, rule: CameraCheckRule, cameras: Sequence[Camera]) -> None:
        self.rule = rule
        self.cameras = list(cameras)
        self._innovations = [_WindowMoments() for _ in self.cameras]
        self._found: list[deque] = [deque() for _ in self.cameras]
        self._searched = np.full(len(self.cameras), -np.inf)
        self._offsets: dict[int, np.ndarray] = {}
        self._pending: dict[int, np.ndarray] = {}  # an offset found once, to be found again
        self._gathered: dict[int, tuple[list, list]] = {}
        self._agreed = np.zeros(len(self.cameras), bool)
        self._first: float | None = None
        self.dropped: dict[int, float] = {}
        self.recovered: dict[int, np.ndarray] = {}

    def usable(self, camera_index: int) -> bool:
        """The camera's measurements update the filter: it is not dropped, nor waiting for the
        second look at an offset (its features, if it was knocked, would pull the estimate
        towards them in between, and the offset would seem to move)."""
        return camera_index not in self.dropped and camera_index not in self._pending

    def in_filter(self) -> np.ndarray:
        """(C,) bool: each camera :meth:`usable`. Only their features count as looked for in
        the health figures, the first update's support, the unknown-occluder map and the loss
        rule (a dropped camera's features, not found where the estimate predicts them, would
        keep a track coasting that the other camera holds)."""
        return np.array([self.usable(c) for c in range(len(self.cameras))], dtype=bool)

    def update(self, t: float, frame: CheckFrame) -> None:
        """One tracked frame at ``t`` (s) (:class:`CheckFrame`)."""
        if not self.rule.enabled:
            return
        for c in range(len(self.cameras)):
            rows = frame.innovation[c][np.isfinite(frame.innovation[c, :, 0])]
            self._innovations[c].slide(t, rows, self.rule.window_s)
            looked = int(frame.looked[c].sum())
            if looked:
                found = int((frame.looked[c] & np.isfinite(frame.measured[c, :, 0])).sum())
                _slide(self._found[c], t, [(t, looked, found)], self.rule.window_s)
        biased = [self._biased(c) for c in range(len(self.cameras))]
        shares = [self._share(c) for c in range(len(self.cameras))]
        self._first = t if self._first is None else self._first
        if t - self._first >= self.rule.window_s - 1e-9:
            self._agreed |= np.array([b == 0.0 and (shares[c] or 0.0) >= 2 / 3
                                      for c, b in enumerate(biased)])
        for c, bias in enumerate(biased):
            others = [b for o, b in enumerate(biased) if o != c and o not in self.dropped]
            if self._judged(c) and bias is not None and bias > 0 and 0.0 in others:
                self._drop(t, c, f"its innovations are {bias:.1f} px off on average")
        for c in range(len(self.cameras)):
            if self._judged(c) and self._lost_features(c, shares):
                self._look_for_offset(t, c, frame)
            else:
                self._pending.pop(c, None)
        if frame.updated:
            for c, since in self.dropped.items():
                if c not in self.recovered and t >= since + self.rule.window_s - 1e-9:
                    self._gather(t, c, self._pixels(c, frame), frame.points_base)

    def _judged(self, c: int) -> bool:
        """Camera ``c`` may be dropped: it is not, and it has agreed once."""
        return c not in self.dropped and bool(self._agreed[c])

    def _drop(self, t: float, c: int, why: str) -> None:
        self.dropped[c] = t
        self._innovations[c].clear()
        log.warning("t=%6.2f s camera %s disagrees with the others: %s over %.1f s; dropped "
                    "from the filter", t, self.cameras[c].name, why, self.rule.window_s)

    def _share(self, c: int) -> float | None:
        """The share of the features camera ``c`` looked for over the window that it found;
        None below ``min_points`` looked for."""
        rows = self._found[c]
        looked = sum(r[1] for r in rows)
        return None if looked < self.rule.min_points else sum(r[2] for r in rows) / looked

    def _lost_features(self, c: int, shares: list[float | None]) -> bool:
        """Camera ``c`` found fewer than half of what it looked for over the window while
        another camera found two thirds of its own (``shares``: each camera's,
        :meth:`_share`)."""
        mine = shares[c]
        others = [shares[o] for o in range(len(self.cameras))
                  if o != c and o not in self.dropped]
        return mine is not None and mine < 0.5 and any(x is not None and x >= 2 / 3
                                                       for x in others)

    def _look_for_offset(self, t: float, c: int, frame: CheckFrame) -> None:
        """Match camera ``c``'s whole-image corners to its predicted pixels (module
        docstring); drop it when one offset moves them all, twice in a row."""
        pending = self._pending.get(c)
        wait = self.rule.window_s if pending is None else self.rule.confirm_s
        if t - self._searched[c] < wait - 1e-9:
            return
        visible = frame.pixels[c][frame.visible[c]]
        corners = None if len(visible) < self.rule.min_matched else frame.corners(c)
        if corners is None:
            # too few predicted visible to judge by, or no image: not a look (a pending
            # offset waits for the next frame's)
            return
        self._searched[c] = t
        self._pending.pop(c, None)
        if len(corners) == 0:
            return
        offset, matched = _best_offset(visible, corners, self.rule.max_offset_px,
                                       self.rule.match_px)
        matched = max(matched, _matched_turned(visible, corners, offset, self.rule))
        if matched < self.rule.min_matched or np.linalg.norm(offset) <= self.rule.bias_px:
            return
        if matched < self.rule.matched_share * len(visible):
            # a near miss: a first look again after confirm_s, the camera still in the filter
            self._searched[c] = t - self.rule.window_s + self.rule.confirm_s
            return
        if pending is None:
            self._pending[c] = offset  # once: to be found again
            return
        if np.linalg.norm(offset - pending) > 2 * self.rule.match_px:
            return  # not where it was: clutter; the next first look after ``window_s``
        self._offsets[c] = offset
        self._drop(t, c, f"its {matched} of {len(visible)} features are found "
                         f"({offset[0]:+.0f}, {offset[1]:+.0f}) px from where predicted")

    def _pixels(self, c: int, frame: CheckFrame) -> np.ndarray:
        """(F, 2) camera ``c``'s pixels of the features this frame (NaN where none): measured,
        or for a displaced camera the corners found at the offset."""
        if c not in self._offsets:
            return frame.measured[c]
        out = np.full((len(frame.pixels[c]), 2), np.nan)
        corners = frame.corners(c)
        if corners is None or len(corners) == 0:
            return out
        ok = self._at_offset(c, frame.pixels[c], frame.visible[c], corners, out)
        if ok < self.rule.min_matched:  # the estimate or the camera moved: find it again
            self._offsets[c] = _best_offset(frame.pixels[c][frame.visible[c]], corners,
                                            self.rule.max_offset_px, self.rule.match_px)[0]
            ok = self._at_offset(c, frame.pixels[c], frame.visible[c], corners, out)
        return out if ok >= self.rule.min_matched else np.full_like(out, np.nan)

    def _at_offset(self, c: int, pixels: np.ndarray, visible: np.ndarray, corners: np.ndarray,
                   out: np.ndarray) -> int:
        """Write into ``out`` (F, 2) the corners within ``match_px`` of the visible ``pixels``
        moved by camera ``c``'s offset; how many there are."""
        nearest, distance = _nearest_corner(pixels + self._offsets[c], corners)
        ok = visible & (distance <= self.rule.match_px)
        out[:] = np.nan
        out[ok] = corners[nearest[ok]]
        return int(ok.sum())

    def _biased(self, c: int) -> float | None:
        """The mean innovation's length (px) when camera ``c`` is biased, 0.0 when it has
        enough innovations and is not, None when it has too few."""
        window = self._innovations[c]
        if window.n < self.rule.min_points:
            return None
        mean, spread = window.mean(), window.std() / np.sqrt(window.n)
        length = float(np.linalg.norm(mean))
        return length if (length > self.rule.bias_px
                          and length > self.rule.sigmas * float(np.linalg.norm(spread))) else 0.0

    def _gather(self, t: float, c: int, measured: np.ndarray, points_base: np.ndarray) -> None:
        """Gather camera ``c``'s correspondences of this frame; refit its pose once there are
        enough."""
        found = np.isfinite(measured[:, 0])
        pixels, points = self._gathered.setdefault(c, ([], []))
        pixels.extend(measured[found])
        points.extend(points_base[found])
        if len(pixels) < self.rule.recalibrate_points:
            return
        camera = self.cameras[c]
        fit = refit_pose(camera, np.array(points), np.array(pixels),
                         position_sd=1e-3 * self.rule.knock_mm,
                         rotation_sd=np.radians(self.rule.knock_deg))
        self.recovered[c] = fit.camera.T_base_cam
        moved = invert_pose(camera.T_base_cam) @ fit.camera.T_base_cam
        log.warning("t=%6.2f s camera %s re-estimated from %d points: %.1f mm and %.2f deg from "
                    "its pose before, %.2f px rms over the %d it fits", t, camera.name,
                    len(pixels), 1e3 * np.linalg.norm(moved[:3, 3]),
                    np.degrees(rotation_angle(moved[:3, :3])), fit.rms_px, fit.inliers)


@dataclass(frozen=True)
class CheckFrame:
    """What the check reads of one tracked frame: per camera (C, F, 2) the innovations (px,
    NaN where none), the measured pixels (as in the image, NaN where none) and the predicted
    ones, the (C, F) features predicted ``visible`` and ``looked`` for; whether the usable
    cameras ``updated`` the estimate; the estimated feature points (F, 3), base frame; and
    ``corners(c)``, the whole-image corners of camera ``c`` (None: none to be had)."""

    innovation: np.ndarray
    measured: np.ndarray
    pixels: np.ndarray
    visible: np.ndarray
    looked: np.ndarray
    updated: bool
    points_base: np.ndarray
    corners: Callable[[int], np.ndarray | None]


class _WindowMoments:
    """The count, sum and sum of squares (per coordinate) of the 2-D rows of a sliding
    window of frames, kept as frames come and go: the window's mean and standard deviation
    without gathering its rows again at every frame (the line's four parts each feed every
    camera's window every frame: gathered for each, the rows took about a fifth of the time
    of the parts' updates in a profile of the line)."""

    def __init__(self) -> None:
        self._frames: deque[tuple[float, int, np.ndarray]] = deque()  # (t, rows, their sums)
        self.n = 0
        self._sums = np.zeros((2, 2))  # rows: sum, sum of squares; columns: coordinates

    def slide(self, t: float, rows: np.ndarray, span: float) -> None:
        """Add a frame's ``rows`` (k, 2) at ``t`` (s); drop the frames older than ``span``."""
        if len(rows):
            sums = np.array([rows.sum(axis=0), np.square(rows).sum(axis=0)])
            self._frames.append((t, len(rows), sums))
            self.n += len(rows)
            self._sums += sums
        while self._frames and self._frames[0][0] < t - span - 1e-9:
            _, k, sums = self._frames.popleft()
            self.n -= k
            self._sums -= sums
        if not self._frames:  # start again from exact zeros
            self.clear()

    def clear(self) -> None:
        self._frames.clear()
        self.n, self._sums = 0, np.zeros((2, 2))

    def mean(self) -> np.ndarray:
        """(2,) the rows' mean (n >= 1)."""
        return self._sums[0] / self.n

    def std(self) -> np.ndarray:
        """(2,) the rows' sample standard deviation (n >= 2)."""
        centred = self._sums[1] - np.square(self._sums[0]) / self.n
        return np.sqrt(np.maximum(centred, 0.0) / (self.n - 1))


def _slide(window: deque, t: float, rows: list, span: float) -> None:
    """Append ``rows`` (each starting with its time) and drop those older than ``span``."""
    window.extend(rows)
    while window and window[0][0] < t - span - 1e-9:
        window.popleft()


def _matched_turned(pixels: np.ndarray, corners: np.ndarray, offset: np.ndarray,
                    rule: CameraCheckRule) -> int:
    """How many ``pixels`` (n, 2) come within ``match_px`` of a corner (m, 2) once moved by the
    image similarity fitted to the corners within twice ``match_px`` of the pixels moved by
    ``offset`` (2,), if it turns them at most ``max_turn_deg`` and scales them at most
    ``max_scale``; else, or where fewer than three corners are that near, 0. A knock turns the
    camera too: across the part its image moves by more than ``match_px`` apart from the
    offset (1 deg: 10 of 14 within 2.5 px of one offset, 12 with the turn)."""
    nearest, distance = _nearest_corner(pixels + offset, corners)
    near = distance <= 2 * rule.match_px
    if near.sum() < 3:
        return 0
    fit, _ = cv2.estimateAffinePartial2D(pixels[near], corners[nearest[near]],
                                         method=cv2.RANSAC, ransacReprojThreshold=rule.match_px)
    if fit is None:
        return 0
    scale = float(np.hypot(fit[0, 0], fit[1, 0]))
    turn = float(np.degrees(np.arctan2(fit[1, 0], fit[0, 0])))
    if abs(turn) > rule.max_turn_deg or abs(scale - 1.0) > rule.max_scale:
        return 0
    return int(np.sum(_nearest_corner(pixels @ fit[:, :2].T + fit[:, 2], corners)[1]
                      <= rule.match_px))


def _nearest_corner(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``points`` (n, 2): the index of its nearest corner (m, 2), and how far it
    is (px)."""
    d = np.linalg.norm(points[:, None] - corners[None], axis=2)
    nearest = np.argmin(d, axis=1)
    return nearest, d[np.arange(len(points)), nearest]


def _best_offset(pixels: np.ndarray, corners: np.ndarray, max_px: float,
                 match_px: float) -> tuple[np.ndarray, int]:
    """The image offset (2,) px, within ``max_px``, that brings the most ``pixels`` (n, 2)
    within ``match_px`` of a corner (m, 2), and how many it brings (every pixel-to-corner
    offset is a candidate)."""
    diff = (corners[None] - pixels[:, None]).reshape(-1, 2)
    candidates = diff[np.linalg.norm(diff, axis=1) <= max_px]
    best, count = np.zeros(2), 0
    for d in candidates:
        moved = pixels + d
        near = np.min(np.linalg.norm(moved[:, None] - corners[None], axis=2), axis=1)
        n = int(np.sum(near <= match_px))
        if n > count:
            best, count = d, n
    return best, count

"""Whole-image search for a workpiece resting on its support plane (re-acquisition anywhere in
the views, not only near the last prediction).

A part that rests (on the conveyor, on the table) keeps the height, roll and pitch of its
support pose ``T_support`` (the cell's nominal pose of the part): only ``x, y`` (m, base
frame) and the turn ``psi`` (rad, about the base z axis, 0 = the support pose's heading) are
free, ``T = Trans(x, y, z_s) Rz(psi) R_s``. The search:

1. corners: every corner the sensor finds in each camera's whole image
   (:class:`~cellsight.tracking.interfaces.CornerDetector`), as a distance image
   (``cv2.distanceTransform``: the distance of every pixel to the nearest corner, px);
2. coarse: every pose of a grid over the squares of half-width ``extent_m`` around the
   ``centres`` (the last estimate and the support pose; steps ``step_m`` and
   ``turn_step_deg``, the whole turn) whose centroid some camera sees is projected into every
   camera; its score sums over its feature points ``1 - d / tol`` for the nearest corner at
   ``d <= tol`` px, the tolerance ``tol`` being the pixels that half a grid step moves a point
   by at the part's depth (at least ``min_tolerance_px``);
3. fine: the ``keep`` best coarse poses over all cameras, and the ``keep`` best in each camera
   alone (a part one camera alone sees scores less than clutter two cameras see), are refined
   ``rounds`` times by a local grid of a quarter of the previous steps, with the tolerance
   shrunk alike;
4. the refined poses, best first (by that score), at least a grid step apart, that have at
   least ``min_matches`` points within ``match_px`` of a corner.

Nothing checks visibility here: a hidden point simply matches no corner, and a wrong pose
matches the clutter's corners by chance. The tracker verifies each candidate with the
acquisition's windows and PnP (:mod:`.acquisition`) before it trusts it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

import cellsight.tracking._search_kernel as kernel
from cellsight.camera import Camera, seen_by_any
from cellsight.geometry.transforms import rotation_z


@dataclass(frozen=True)
class Candidate:
    """A pose the search proposes: ``T_base_part`` and its number of matched points."""

    T_base_part: np.ndarray
    matches: int


@dataclass(frozen=True)
class PlaneSearch:
    """Search of a resting part over its support plane (module docstring). Units: m, deg, px,
    s. For the tracker: ``every_s``, how often a part being acquired is searched for, and
    ``out_of_view_every_s`` one never acquired whose guess lies outside every camera's view
    (it may enter them: a part carried in from upstream; one lost out of every view left them,
    and is not searched for); the ``verify`` best
    candidates are tried, and a candidate's PnP fix counts with at least ``min_points``
    points."""

    extent_m: float = 0.5
    step_m: float = 0.02
    turn_step_deg: float = 10.0
    keep: int = 10
    rounds: int = 2
    min_tolerance_px: float = 2.0
    match_px: float = 3.0
    min_matches: int = 4
    every_s: float = 0.2
    out_of_view_every_s: float = 1.0
    verify: int = 5
    min_points: int = 6

    def candidates(self, cameras: Sequence[Camera], points: np.ndarray,
                   T_support: np.ndarray, centres: np.ndarray,
                   corners: Sequence[np.ndarray | None]) -> list[Candidate]:
        """The candidate poses, best first (module docstring). ``points`` (F, 3) in the part
        frame (m); ``centres`` (K, 2) x, y (m) of the searched squares (the grid is shared:
        its points are multiples of the step); ``corners``: per camera, the (N, 2) px of the
        corners found in its whole image (None: the camera gave nothing)."""
        maps = [None if c is None else _distance_image(cam, c)
                for cam, c in zip(cameras, corners, strict=True)]
        if all(m is None for m in maps):
            return []
        board = _Board(cameras, maps, np.asarray(points, dtype=float).reshape(-1, 3),
                       np.asarray(T_support, dtype=float))
        xy = _squares(np.asarray(centres, dtype=float).reshape(-1, 2), self.extent_m,
                      self.step_m)
        xy = xy[board.seen(xy)]
        if len(xy) == 0:
            return []
        turns = np.radians(np.arange(0.0, 360.0, self.turn_step_deg))
        step, turn = self.step_m, math.radians(self.turn_step_deg)
        grid = _grid(xy, turns)
        per_camera = board.scores(grid, board.reach(step, turn), self.min_tolerance_px)
        best = _top(grid, per_camera.sum(axis=1), self.keep)
        for c in range(per_camera.shape[1]):  # a part that one camera alone sees
            best += _top(grid, per_camera[:, c], self.keep)
        for _ in range(self.rounds):
            step, turn = step / 4, turn / 4
            reach = board.reach(step, turn)
            local = [_around(p, step, turn) for p, _ in best]
            best = [_top(g, board.score(g, reach, self.min_tolerance_px), 1)[0] for g in local]
        best.sort(key=lambda ps: -ps[1])
        found = []
        for p, _ in best:
            matches = int(board.score(p[None], 0.0, self.match_px, hard=True)[0])
            far = all(math.hypot(*(p[:2] - q.T_base_part[:2, 3])) >= self.step_m for q in found)
            if matches >= self.min_matches and far:
                found.append(Candidate(board.pose(p), matches))
        return found


class _Board:
    """The scoring of poses ``(x, y, psi)`` against the cameras' distance images."""

    def __init__(self, cameras: Sequence[Camera], maps: list[np.ndarray | None],
                 points: np.ndarray, T_support: np.ndarray) -> None:
        self.cameras, self.maps = cameras, maps
        self.R_s = T_support[:3, :3]
        self.points = points @ self.R_s.T  # turned to the support pose, about the part's origin
        self.z = float(T_support[2, 3])
        self.radius = float(np.max(np.linalg.norm(self.points[:, :2], axis=1)))
        self.centroid = self.points.mean(axis=0)

    def pose(self, p: np.ndarray) -> np.ndarray:
        """``T_base_part`` of the pose ``(x, y, psi)``."""
        T = np.eye(4)
        T[:3, :3] = rotation_z(p[2]) @ self.R_s
        T[:3, 3] = [p[0], p[1], self.z]
        return T

    def reach(self, step: float, turn: float) -> float:
        """How far (m) a point may be from where it is when the pose is off by half a grid
        step ``step`` (m) in x and y and half a turn step ``turn`` (rad)."""
        return 0.5 * math.hypot(step, step) + 0.5 * turn * self.radius

    def seen(self, xy: np.ndarray) -> np.ndarray:
        """(G,) bool: the part's centroid at each ``xy`` (G, 2) is inside some camera's view."""
        c = np.column_stack([xy, np.full(len(xy), self.z)]) + self.centroid
        return seen_by_any([cam for cam, m in zip(self.cameras, self.maps, strict=True)
                            if m is not None], c)

    def score(self, poses: np.ndarray, reach: float, min_px: float,
              hard: bool = False) -> np.ndarray:
        """(G,) :meth:`scores` summed over the cameras."""
        return self.scores(poses, reach, min_px, hard).sum(axis=1)

    def scores(self, poses: np.ndarray, reach: float, min_px: float,
               hard: bool = False) -> np.ndarray:
        """(G, C) score of each pose ``(x, y, psi)`` (G, 3) in each camera: per point, ``1 - d
        / tol`` for the nearest corner at ``d <= tol`` px, ``tol`` being ``reach`` (m) seen at
        the points' depth, at least ``min_px``; ``hard``: count the points within ``tol``."""
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        total = np.zeros((len(poses), len(self.cameras)))
        for c, (cam, dist) in enumerate(zip(self.cameras, self.maps, strict=True)):
            if dist is None:
                continue
            R, t = cam.T_cam_base[:3, :3], cam.T_cam_base[:3, 3]
            z = kernel.depths(poses, self.points, self.z, R, t)
            front = z[z > 0]
            depth = float(np.median(front)) if len(front) else 1.0
            tol = max(min_px, cam.K[0, 0] * reach / depth)
            total[:, c] = kernel.scores(poses, self.points, self.z, R, t, cam.K, cam.dist5, dist,
                                        tol, hard)
        return total


def _distance_image(camera: Camera, corners: np.ndarray) -> np.ndarray:
    """(H, W) float32: each pixel's distance (px) to the nearest of ``corners`` (N, 2) px."""
    mask = np.full((camera.height, camera.width), 255, dtype=np.uint8)
    uv = np.rint(np.asarray(corners, dtype=float).reshape(-1, 2)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (
        uv[:, 1] < camera.height)
    mask[uv[inside, 1], uv[inside, 0]] = 0
    if not inside.any():
        return np.full(mask.shape, np.inf, dtype=np.float32)
    return cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _squares(centres: np.ndarray, extent: float, step: float) -> np.ndarray:
    """(G, 2) the points of the grid of pitch ``step`` (m) within ``extent`` (m, per axis) of
    any of ``centres`` (K, 2), each once."""
    n = int(round(extent / step))
    axis = np.arange(-n, n + 1)
    offsets = np.stack(np.meshgrid(axis, axis), -1).reshape(-1, 2)
    cells = np.unique(np.concatenate([offsets + np.rint(c / step).astype(int) for c in centres]),
                      axis=0)
    return cells * step


def _grid(xy: np.ndarray, turns: np.ndarray) -> np.ndarray:
    """(G * T, 3) every ``(x, y)`` with every turn."""
    return np.column_stack([np.repeat(xy, len(turns), axis=0), np.tile(turns, len(xy))])


def _around(p: np.ndarray, step: float, turn: float) -> np.ndarray:
    """(125, 3) the 5 x 5 x 5 grid of poses around ``p`` with steps ``step`` (m), ``turn``
    (rad)."""
    k = np.arange(-2, 3)
    dx, dy, dt = np.meshgrid(k * step, k * step, k * turn, indexing="ij")
    return p + np.column_stack([dx.ravel(), dy.ravel(), dt.ravel()])


def _top(poses: np.ndarray, scores: np.ndarray, k: int) -> list[tuple[np.ndarray, float]]:
    """The ``k`` best-scoring poses (G, 3) with their scores, best first (ties: the first)."""
    order = np.argsort(-scores, kind="stable")[:k]
    return [(poses[i], float(scores[i])) for i in order]

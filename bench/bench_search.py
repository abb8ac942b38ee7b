"""The whole-image search (``PlaneSearch.candidates``), per call, on the built-in cell.

The part lies 20 cm from its nominal place, turned 30 deg; MuJoCo renders both cameras'
images and OpenCV finds their corners (the tracker's detector), once. Timed, each over the same
corners, the search's default grid (1 m square around the nominal place, 2 cm, 10 deg, two
finer rounds):

- cellsight: the grid's scores in the compiled kernel (``tracking/_search_kernel.py``);
- the same sums in NumPy: every pose's points placed, projected by the camera
  (``Camera.project_camera``) and looked up in the distance image, as (poses x points) arrays.

Median of ``REPEATS`` calls (ms), the ratio, and whether the two gave the same best
candidate (within 1 mm and 0.1 deg).
"""

from __future__ import annotations

import math
from unittest import mock

import numpy as np
from timing import warm_median_s

from cellsight import load_cell
from cellsight.geometry.transforms import rotation_z
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.search import PlaneSearch, _Board
from cellsight.world import World

REPEATS = 5


def numpy_scores(board: _Board, poses: np.ndarray, reach: float, min_px: float,
                 hard: bool = False) -> np.ndarray:
    """(G, C) :meth:`_Board.scores` with (G * F)-row NumPy arrays, camera by camera."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    px, py, pz = board.points.T
    X = c[:, None] * px - s[:, None] * py + poses[:, :1]
    Y = s[:, None] * px + c[:, None] * py + poses[:, 1:2]
    world = np.stack([X, Y, np.broadcast_to(pz + board.z, X.shape)], -1).reshape(-1, 3)
    total = np.zeros((len(poses), len(board.cameras)))
    for k, (cam, dist) in enumerate(zip(board.cameras, board.maps, strict=True)):
        if dist is None:
            continue
        cam_pts = cam.to_camera(world)
        front = cam_pts[:, 2] > 0
        depth = float(np.median(cam_pts[front, 2])) if front.any() else 1.0
        tol = max(min_px, cam.K[0, 0] * reach / depth)
        uv = cam.project_camera(cam_pts)
        h, w = dist.shape
        ok = np.isfinite(uv[:, 0]) & np.isfinite(uv[:, 1])
        u, v = np.full(len(uv), -1), np.full(len(uv), -1)
        u[ok], v[ok] = np.rint(uv[ok, 0]).astype(int), np.rint(uv[ok, 1]).astype(int)
        ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
        match = np.zeros(len(uv))
        match[ok] = np.maximum(0.0, 1.0 - dist[v[ok], u[ok]] / tol)
        total[:, k] = (match > 0 if hard else match).reshape(len(poses), -1).sum(axis=1)
    return total


def main() -> None:
    cell = load_cell()
    part = cell.workpieces[0]
    T = part.T_base_part.copy()
    T[:3, :3] = rotation_z(math.radians(30.0)) @ T[:3, :3]
    T[:2, 3] += [0.2, 0.0]
    world = World(cell, seed=0)
    try:
        world.place_part(part.name, T)
        world.step({}, {})
        corners = [CornerExtractor().detect(image) for image in world.render()]
    finally:
        world.close()
    search = PlaneSearch()

    def run():
        return search.candidates(cell.cameras, part.feature_points, part.T_base_part,
                                 part.T_base_part[None, :2, 3], corners)

    kernel_s = warm_median_s(run, REPEATS)
    best = run()[0].T_base_part
    with mock.patch.object(_Board, "scores", numpy_scores):
        numpy_s = warm_median_s(run, REPEATS)
        other = run()[0].T_base_part
    turn = math.degrees(math.acos(np.clip((np.trace(best[:3, :3].T @ other[:3, :3]) - 1) / 2,
                                          -1, 1)))
    same = np.linalg.norm(best[:3, 3] - other[:3, 3]) < 1e-3 and turn < 0.1
    print(f"whole-image search, built-in cell, {sum(len(c) for c in corners)} corners in "
          f"{len(corners)} images; median of {REPEATS} calls")
    print("| scoring | ms a search | ratio |")
    print("|---|---|---|")
    print(f"| compiled kernel (cellsight) | {1e3 * kernel_s:.1f} | "
          f"{kernel_s / numpy_s:.2f}x |")
    print(f"| NumPy arrays (the same sums) | {1e3 * numpy_s:.1f} | 1.00x |")
    print(f"same best candidate: {'yes' if same else 'no'}; the best "
          f"{1e3 * np.linalg.norm(best[:3, 3] - T[:3, 3]):.1f} mm from the part")


if __name__ == "__main__":
    main()

"""Scaling of the BSP build and visit with the number of polygons (``make bench``).

Scenes: randomly rotated boxes (6 quads each) of random size, one per cell of a jittered grid so
that they barely overlap; 64 random query points inside the scene; the viewpoint outside, above
a corner. Times are warm medians (``time.perf_counter``) in milliseconds: ``build`` is
``BSPTree.build`` on a ready soup, ``visit`` one ``visibility`` call for the 64 points. The
fitted exponents are least-squares slopes of log(time) against log(polygons).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.occlusion import BSPTree, PolygonSoup

SIZES = (100, 300, 1000, 3000, 10000, 30000)
N_POINTS = 64
_CORNERS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4],
                   [1, 5, 7, 3]])


def box_scene(n_polygons: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
    """Flat (vertices, offsets) of ``n_polygons // 6`` boxes, query points and a viewpoint."""
    rng = np.random.default_rng(seed)
    n_boxes = max(1, n_polygons // 6)
    side = int(np.ceil(n_boxes ** (1 / 3)))
    cells = np.stack(np.unravel_index(np.arange(n_boxes), (side, side, side)), axis=1)
    rotations = Rotation.random(n_boxes, random_state=seed).as_matrix()
    half = rng.uniform(0.1, 0.3, (n_boxes, 1, 3))
    local = np.einsum("bij,bkj->bki", rotations, _CORNERS[None] * half)
    corners = local + (cells + rng.uniform(-0.1, 0.1, (n_boxes, 3)))[:, None, :]
    vertices = corners[:, _FACES].reshape(-1, 3)
    offsets = np.arange(0, 24 * n_boxes + 1, 4)
    points = rng.uniform(0, side - 1, (N_POINTS, 3))
    viewpoint = np.array([-1.0, -2.0, 2.0 * side])
    return vertices, offsets, points, viewpoint


def _median_ms(call, budget_s: float, max_repeats: int) -> float:
    """Warm median wall time of ``call`` in ms, repeated within about ``budget_s`` seconds."""
    call()
    times: list[float] = []
    deadline = time.perf_counter() + budget_s
    while len(times) < max_repeats and (len(times) < 3 or time.perf_counter() < deadline):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def run(sizes: tuple[int, ...] = SIZES) -> list[dict]:
    """One row per scene size: polygons, nodes, splits, depth, build_ms, visit_ms."""
    rows = []
    for n in sizes:
        vertices, offsets, points, viewpoint = box_scene(n)
        soup = PolygonSoup.from_arrays(vertices, offsets)
        tree = BSPTree.build(soup)
        rows.append({
            "polygons": len(soup),
            "nodes": tree.stats["nodes"],
            "splits": tree.stats["splits"],
            "depth": tree.stats["depth"],
            "build_ms": _median_ms(lambda: BSPTree.build(soup), 3.0, 200),  # noqa: B023
            "visit_ms": _median_ms(lambda: tree.visibility(points, viewpoint), 1.0, 500),  # noqa: B023
        })
    return rows


def exponent(rows: list[dict], key: str) -> float:
    """Least-squares slope of log(rows[key]) against log(polygons)."""
    x = np.log([r["polygons"] for r in rows])
    y = np.log([r[key] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def main() -> None:
    """Print the scaling table and the fitted exponents."""
    from rich.console import Console
    from rich.table import Table

    rows = run()
    table = Table(title=f"BSP scaling: random boxes, {N_POINTS} points, warm medians")
    for name in ("polygons", "nodes", "splits", "depth", "build ms", "visit ms"):
        table.add_column(name, justify="right")
    for r in rows:
        table.add_row(str(r["polygons"]), str(r["nodes"]), str(r["splits"]), str(r["depth"]),
                      f"{r['build_ms']:.3f}", f"{r['visit_ms']:.4f}")
    console = Console()
    console.print(table)
    console.print(f"fitted exponents: build {exponent(rows, 'build_ms'):.2f}, "
                  f"visit {exponent(rows, 'visit_ms'):.2f}")


if __name__ == "__main__":
    main()

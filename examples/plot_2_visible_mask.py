"""
# Point visibility among polygons: `visible_mask` and `PolygonSoup`

Underneath the cell-level predictor is a plain geometric query: given polygons (any planar,
simple polygons, in any orientation), points and a viewpoint, which points does the viewpoint
see? A point is visible when the open segment from the viewpoint to it crosses no polygon; a
point lying on a polygon is not hidden by that polygon. `cellsight.occlusion.visible_mask`
answers it in one call, with no cell, robot or camera involved: it works on any polygon soup
(a scanned fixture, a CAD export's faces, a mesh's triangles).

This tutorial builds a small scene of boxes, asks which points of the floor a viewpoint sees,
checks every answer against a brute-force segment test written here from scratch, and shows
how `PolygonSoup` serves repeated queries against the same polygons.
"""

# %%
# ## A scene: three boxes
#
# `cellsight.geometry.polyhedron.box(name, size, center)` gives an axis-aligned box (metres)
# whose `polygons()` are its six faces as (4, 3) vertex arrays; `transformed(T)` moves it.
# Any list of (k, 3) arrays would do.

import time

import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from cellsight.geometry.polyhedron import box
from cellsight.geometry.transforms import make_pose, rotation_z
from cellsight.occlusion import BSPTree, PolygonSoup, visible_mask

boxes = [
    box("crate", (0.4, 0.3, 0.5), (0.0, 0.0, 0.25)),
    box("beam", (1.2, 0.1, 0.1), (0.1, 0.3, 0.3)),
    box("block", (0.3, 0.3, 0.3), (0.0, 0.0, 0.0)).transformed(
        make_pose(rotation_z(0.6), (-0.6, -0.3, 0.15))),
]
polygons = [face for b in boxes for face in b.polygons()]
owner = np.repeat(np.arange(len(boxes)), [len(b.polygons()) for b in boxes])
print(f"{len(boxes)} boxes, {len(polygons)} polygons")

# A grid of points on the floor (z = 0) and a viewpoint above and to one side. (The grid's
# spacing keeps its points off the boxes' edges, where "on the face" and "just behind it" are
# a matter of tolerance.)
xs, ys = np.meshgrid(np.linspace(-1.2, 1.2, 50), np.linspace(-1.0, 1.4, 50))
points = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
viewpoint = np.array([1.45, -1.15, 1.3])
print(f"{len(points)} points; viewpoint {viewpoint} m")

# %%
# ## One call
#
# `visible_mask(polygons, points, viewpoint)` validates the polygons (planar, simple, not
# degenerate: a `GeometryError` names the first bad one), then answers one flag per point.

visible = visible_mask(polygons, points, viewpoint)
print(f"visible: {visible.sum()} of {len(points)} points")

# %%
# ## A brute-force check
#
# The definition, tested directly: for each point and each polygon, where does the segment
# from the viewpoint to the point cross the polygon's plane, and is that crossing inside the
# polygon (every face here is convex, so "inside" is on the inner side of every edge)? A
# crossing at the point itself (the last micrometre of the segment) does not hide it, so
# that a point lying on a face stays visible.


def brute_force_visible(polygons, points, viewpoint, end_tol=1e-9):
    hidden = np.zeros(len(points), dtype=bool)
    d = points - viewpoint  # the segments, viewpoint + s d for s in (0, 1)
    for poly in polygons:
        normal = np.cross(poly[1] - poly[0], poly[2] - poly[0])
        normal /= np.linalg.norm(normal)
        denom = d @ normal
        parallel = np.abs(denom) < 1e-12  # the segment runs along the plane: no crossing
        s = (poly[0] - viewpoint) @ normal / np.where(parallel, 1.0, denom)
        length = np.linalg.norm(d, axis=1)
        crosses = ~parallel & (s > 0) & (s * length < length - end_tol)
        hit = viewpoint + s[:, None] * d
        inside = np.ones(len(points), dtype=bool)
        for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
            inside &= np.cross(b - a, hit - a) @ normal >= 0
        hidden |= crosses & inside
    return ~hidden


reference = brute_force_visible(polygons, points, viewpoint)
disagree = int(np.sum(visible != reference))
print(f"brute force: {reference.sum()} visible; disagreements with visible_mask: {disagree}")

# %%
# The box faces are listed counter-clockwise seen from outside, which the inside test above
# relies on (`visible_mask` itself does not care about orientation).
#
# ## Which box hides a point
#
# `BSPTree.build(soup).visibility(points, viewpoint)` is the tree behind the answer (the
# paper's back-to-front visit); it also returns, per point, the index of the first polygon
# crossed from the viewpoint, the nearest occluder (-1 when visible).

soup = PolygonSoup.from_polygons(polygons)
tree = BSPTree.build(soup)
visible_tree, occluder = tree.visibility(points, viewpoint)
hider = np.where(occluder >= 0, owner[np.maximum(occluder, 0)], -1)
print(f"tree: {tree.stats}; same flags as visible_mask: "
      f"{bool(np.array_equal(visible_tree, visible))}")
for k, b in enumerate(boxes):
    print(f"  hidden by {b.name}: {np.sum(hider == k)} points")

# %%
# ## Repeated queries: `PolygonSoup`
#
# A list of arrays is joined into flat arrays, and checked, at every call. When the same
# polygons are queried again and again (a camera moving around a fixed fixture; every
# frame's points), join them once with `PolygonSoup.from_polygons` and pass the soup: its
# planes, bounds and checks are computed once. Here the viewpoint circles the scene, and
# every answer is checked against the brute force again (`soup` was built above, for the
# tree).

angles = np.linspace(0.0, 2 * np.pi, 60, endpoint=False)
orbit = np.column_stack([1.8 * np.cos(angles), 1.8 * np.sin(angles), np.full_like(angles, 1.3)])
from_soup = [visible_mask(soup, points, v) for v in orbit]
orbit_disagree = sum(int(np.sum(a != brute_force_visible(polygons, points, v)))
                     for a, v in zip(from_soup, orbit, strict=True))
fraction = np.array([m.mean() for m in from_soup])
print(f"orbit of {len(orbit)} viewpoints: disagreements with the brute force: {orbit_disagree}")
print(f"visible fraction along the orbit: min {fraction.min():.2f}, max {fraction.max():.2f}")

# %%
# What the soup saves grows with the polygons, not the points: the list's joining and checks
# are per polygon. A cell's case is many polygons and few points (a part's corners), so time
# both inputs on a clutter of 400 small cubes (2400 polygons) and 16 points, from 30
# viewpoints (the first call of each, outside the timing, warms the compiled code).

rng = np.random.default_rng(0)
clutter = [face for i in range(400)
           for face in box(f"cube{i}", (0.05, 0.05, 0.05),
                           rng.uniform([-1, -1, 0.2], [1, 1, 1])).polygons()]
clutter_soup = PolygonSoup.from_polygons(clutter)
few = rng.uniform([-1, -1, 0], [1, 1, 0], (16, 3))
views_from = orbit[::2] + [0.0, 0.0, 0.7]
visible_mask(clutter, few, views_from[0])
visible_mask(clutter_soup, few, views_from[0])
start = time.perf_counter()
from_list = [visible_mask(clutter, few, v) for v in views_from]
t_list = (time.perf_counter() - start) / len(views_from)
start = time.perf_counter()
from_clutter_soup = [visible_mask(clutter_soup, few, v) for v in views_from]
t_soup = (time.perf_counter() - start) / len(views_from)
same = all(np.array_equal(a, b) for a, b in zip(from_list, from_clutter_soup, strict=True))
print(f"{len(clutter)} polygons, {len(few)} points: list {1e3 * t_list:.2f} ms per call, "
      f"soup {1e3 * t_soup:.2f} ms per call ({t_list / t_soup:.1f} x); same answers: {same}")

# %%
# ## The picture
#
# Left, the scene and the viewpoint; right, the floor seen from above, each point coloured by
# the box that hides it (green: visible). The hidden regions are the boxes' shadows for a
# light at the viewpoint. Bottom, the visible fraction of the floor grid as the viewpoint
# circles the scene.

colours = ["#d62728", "#9467bd", "#ff7f0e"]
fig = plt.figure(figsize=(11, 8))
ax3 = fig.add_subplot(2, 2, 1, projection="3d")
for b, c in zip(boxes, colours, strict=True):
    ax3.add_collection3d(Poly3DCollection(b.polygons(), facecolor=c, edgecolor="k",
                                          linewidths=0.4, alpha=0.5))
ax3.scatter(*points[visible].T, s=1, c="#2ca02c")
ax3.scatter(*points[~visible].T, s=1, c="grey")
ax3.scatter(*viewpoint, c="k", marker="^", s=50)
ax3.set(xlabel="x [m]", ylabel="y [m]", zlabel="z [m]", title="scene and viewpoint")
ax3.set_box_aspect((2.8, 2.6, 1.4))
ax3.view_init(elev=28, azim=-120)

ax = fig.add_subplot(2, 2, 2)
ax.scatter(*points[visible, :2].T, s=6, c="#2ca02c", label="visible")
for k, (b, c) in enumerate(zip(boxes, colours, strict=True)):
    ax.scatter(*points[hider == k, :2].T, s=6, c=c, label=f"hidden by {b.name}")
ax.plot(*viewpoint[:2], "k^", label="viewpoint (x, y)")
ax.set(xlabel="x [m]", ylabel="y [m]", title="floor points, seen from above", aspect="equal")
ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7)

ax = fig.add_subplot(2, 1, 2)
ax.plot(np.degrees(angles), 100 * fraction, "o-", ms=3)
ax.set(xlabel="viewpoint's azimuth on the orbit [deg]", ylabel="floor points visible [%]",
       title="the same soup, queried from 60 viewpoints")
ax.grid(alpha=0.3)
fig.tight_layout()

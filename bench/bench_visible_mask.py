"""``visible_mask`` (cull, then direct pair test or BSP) against the BSP of everything and
Open3D's ``RaycastingScene`` rebuilt per call, on the same segments.

Scenes: 40 random boxes (240 quads, :func:`bench_bsp_scaling.box_scene`) with 32 points, and
the two UR5 collision meshes of ``ur-cell`` at HOME (every object's faces triangulated, about
10,900 triangles) with 16 random points in the robots' box seen from camera 0. Times are warm
medians in milliseconds per call, for three inputs: the list of (k, 3) polygons (joined per
call), the same polygons as one (P, k, 3) array (quads, triangles), and the list joined once
into a ``PolygonSoup`` (its planes and checks done once), the last two prepared outside the
timing like Open3D's flat vertex and triangle arrays. Open3D tests occlusion
of the rays viewpoint->point up to ``1 - 1e-4`` of their length (its peer tolerance). On the UR5
scene, MuJoCo's ``mj_multiRay`` casts the same rays in the world's model of ``ur-cell`` (the
same meshes; its bodies placed by ``mj_kinematics`` in each call, as a moving cell needs, its
meshes' trees built once when the model compiled), to the same tolerance. Two more rows there
compare like with like: cellsight's per-object hierarchies (the occlusion predictor's
structure: each body's tree built once in its own frame, the bodies' poses given per call,
as MuJoCo's) against ``mj_multiRay`` alone, and with the cell's kinematics (``Cell.snapshot``,
checked) against ``mj_kinematics`` plus ``mj_multiRay``; and the floor of any method handed
the triangles anew each call: one compiled pass culling every triangle against the segments
(:func:`~cellsight.occlusion._segment_kernel.cull_segments`, from planes already made).
"""

from __future__ import annotations

import numpy as np
from timing import warm_median_s

from cellsight.occlusion import PolygonSoup, visible_mask

PEER_TOLERANCE = 1e-4


def box_scene_polygons() -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """40 random boxes as quads, 32 points, a viewpoint."""
    from bench_bsp_scaling import box_scene

    vertices, offsets, points, viewpoint = box_scene(240)
    polygons = [vertices[offsets[i]:offsets[i + 1]] for i in range(len(offsets) - 1)]
    return polygons, points[:32], viewpoint


def mujoco_masks():
    """MuJoCo in the world's model of ``ur-cell`` (at HOME, as :func:`ur_scene_polygons` poses
    it): ``(points, viewpoint) -> visible`` by ``mj_kinematics`` then ``mj_multiRay``, and by
    ``mj_multiRay`` alone, its bodies placed once (the query without the kinematics)."""
    import mujoco

    import cellsight
    from cellsight.world.world import World

    world = World(cellsight.load_cell("ur-cell"))
    model, data = world.scene.model, world.scene.data
    mujoco.mj_kinematics(model, data)

    def rays(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
        vec = points - viewpoint
        length = np.linalg.norm(vec, axis=1)
        n = len(points)
        geomid, dist = np.empty(n, np.int32), np.empty(n)
        mujoco.mj_multiRay(model, data, viewpoint, (vec / length[:, None]).ravel(), None, 1, -1,
                           geomid, dist, None, n, float(length.max()) + 1.0)
        return ~((dist >= 0) & (dist < length * (1.0 - PEER_TOLERANCE)))

    def with_kinematics(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
        mujoco.mj_kinematics(model, data)
        return rays(points, viewpoint)
    return with_kinematics, rays


def forest_masks():
    """cellsight's per-object hierarchies of ``ur-cell`` (the occlusion predictor's):
    ``(points, viewpoint) -> visible`` with the bodies' poses at HOME given, and the same
    with the cell's kinematics (``Cell.snapshot``) in each call."""
    import cellsight
    from cellsight.occlusion.backends import visibility_predictor

    cell = cellsight.load_cell("ur-cell")
    predictor = visibility_predictor(cell)
    poses = cell.snapshot().poses

    def given(points: np.ndarray, viewpoint: np.ndarray, poses=poses) -> np.ndarray:
        return predictor.forest.occluders(poses, viewpoint[None, :],
                                          np.array([0, len(points)]), points,
                                          predictor.surface_tolerance) < 0

    def with_kinematics(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
        return given(points, viewpoint, cell.snapshot().poses)
    return given, with_kinematics


def cull_floor_ms(stacked: np.ndarray, points: np.ndarray, viewpoint: np.ndarray) -> float:
    """The floor of a query handed its triangles anew (ms): one culling pass over every
    triangle, its planes already made."""
    from cellsight.occlusion._segment_kernel import cull_segments

    soup = PolygonSoup.from_arrays(stacked.reshape(-1, 3),
                                   np.arange(0, 3 * len(stacked) + 1, 3))
    arrays, spheres = soup.arrays(), soup.spheres
    return _median_ms(lambda: cull_segments(arrays, spheres, points, viewpoint))


def ur_scene_polygons() -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """The ur-cell's triangles at HOME, 16 random points in the robots' box, camera 0."""
    import cellsight
    from cellsight.occlusion.backends import visibility_predictor

    cell = cellsight.load_cell("ur-cell")
    surfaces = visibility_predictor(cell).surfaces
    vertices = surfaces.world_vertices(cell.snapshot())
    triangles = np.concatenate([
        surfaces.offsets[k] + cell.objects[obj].solid.face_triangles(face)
        for k, (obj, face) in enumerate(surfaces.poly_source)
    ])
    polygons = [vertices[t] for t in triangles]
    robots = [k for k, o in enumerate(cell.objects) if o.name.startswith("UR5")]
    used = np.concatenate([np.arange(surfaces.offsets[k], surfaces.offsets[k + 1])
                           for k, (obj, _) in enumerate(surfaces.poly_source) if obj in robots])
    lo, hi = vertices[used].min(axis=0), vertices[used].max(axis=0)
    points = np.random.default_rng(3).uniform(lo, hi, (16, 3))
    return polygons, points, np.asarray(cell.cameras[0].center, dtype=np.float64)


def fan_triangles(polygons) -> tuple[np.ndarray, np.ndarray]:
    """Flat float32 vertices and fan triangles (T, 3) uint32 of the polygons (prepared once,
    outside Open3D's timing, as a caller holding a triangle mesh would)."""
    counts = np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = [np.stack([np.full(c - 2, s), s + np.arange(1, c - 1), s + np.arange(2, c)], 1)
            for s, c in zip(starts, counts, strict=True)]
    return np.concatenate(polygons).astype(np.float32), np.concatenate(tris).astype(np.uint32)


def open3d_mask(mesh, points, viewpoint) -> np.ndarray:
    """Open3D: scene rebuilt from the triangles ``mesh``, then one occlusion test."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh[0]), o3d.core.Tensor(mesh[1]))
    rays = np.hstack([np.broadcast_to(viewpoint, points.shape), points - viewpoint])
    hit = scene.test_occlusions(o3d.core.Tensor(rays.astype(np.float32)), tnear=0.0,
                                tfar=1.0 - PEER_TOLERANCE)
    return ~hit.numpy().astype(bool)


def _median_ms(call, repeats: int = 30) -> float:
    """Warm median wall time of ``call`` in ms."""
    return 1e3 * warm_median_s(call, repeats)


def run() -> list[dict]:
    """One row per scene: polygons, points, before/after/bsp-after-cull/Open3D ms, agreement."""
    rows = []
    for name, scene in (("40 boxes", box_scene_polygons), ("two UR5", ur_scene_polygons)):
        polygons, points, viewpoint = scene()
        answer = visible_mask(polygons, points, viewpoint, _method="full")
        row = {"scene": name, "polygons": len(polygons), "points": len(points)}
        for key, method in (("before", "full"), ("after", "auto"), ("direct", "direct"),
                            ("culled_bsp", "bsp")):
            def call(m=method, polys=polygons, pts=points, view=viewpoint):
                return visible_mask(polys, pts, view, _method=m)

            row[key] = _median_ms(call)
            row[key + "_same"] = bool((visible_mask(polygons, points, viewpoint, _method=method)
                                       == answer).all())
        stacked = np.stack(polygons)  # (P, k, 3): prepared once, like Open3D's mesh below
        row["array"] = _median_ms(lambda: visible_mask(stacked, points, viewpoint))  # noqa: B023
        row["array_same"] = bool((visible_mask(stacked, points, viewpoint) == answer).all())
        soup = PolygonSoup.from_polygons(polygons)  # the list joined once
        row["soup"] = _median_ms(lambda: visible_mask(soup, points, viewpoint))  # noqa: B023
        row["soup_same"] = bool((visible_mask(soup, points, viewpoint) == answer).all())
        mesh = fan_triangles(polygons)
        row["open3d"] = _median_ms(lambda: open3d_mask(mesh, points, viewpoint))  # noqa: B023
        row["open3d_same"] = int((open3d_mask(mesh, points, viewpoint) == answer).sum())
        if name == "two UR5":
            mj, rays = mujoco_masks()
            row["mujoco"] = _median_ms(lambda: mj(points, viewpoint))  # noqa: B023
            row["mujoco_same"] = int((mj(points, viewpoint) == answer).sum())
            row["mujoco_rays"] = _median_ms(lambda: rays(points, viewpoint))  # noqa: B023
            given, with_kinematics = forest_masks()
            row["forest"] = _median_ms(lambda: given(points, viewpoint))  # noqa: B023
            row["forest_kinematics"] = _median_ms(
                lambda: with_kinematics(points, viewpoint))  # noqa: B023
            row["forest_same"] = int((given(points, viewpoint) == answer).sum())
            row["cull_floor"] = cull_floor_ms(stacked, points, viewpoint)
        rows.append(row)
    return rows


def main() -> None:
    """Print one line per scene."""
    for r in run():
        print(f"{r['scene']}: {r['polygons']} polygons, {r['points']} points | BSP of all "
              f"{r['before']:.3f} ms | visible_mask: list {r['after']:.3f} ms (direct "
              f"{r['direct']:.3f}, culled BSP {r['culled_bsp']:.3f}), (P, k, 3) array "
              f"{r['array']:.3f} ms, list joined once {r['soup']:.3f} ms | Open3D "
              f"{r['open3d']:.3f} ms | list/Open3D {r['after'] / r['open3d']:.2f}, array/Open3D "
              f"{r['array'] / r['open3d']:.2f}, joined once/Open3D {r['soup'] / r['open3d']:.2f}"
              f" | same as the BSP of all: {r['after_same'] and r['array_same'] and r['soup_same']}"
              f", Open3D agrees on "
              f"{r['open3d_same']}/{r['points']}")
        if "mujoco" in r:
            print(f"  MuJoCo mj_kinematics + mj_multiRay {r['mujoco']:.3f} ms | array/MuJoCo "
                  f"{r['array'] / r['mujoco']:.2f}, joined once/MuJoCo "
                  f"{r['soup'] / r['mujoco']:.2f} | MuJoCo agrees on "
                  f"{r['mujoco_same']}/{r['points']}")
            print(f"  per-object hierarchies (bodies' trees built once, poses given) "
                  f"{r['forest']:.4f} ms against mj_multiRay alone {r['mujoco_rays']:.4f} ms: "
                  f"{r['forest'] / r['mujoco_rays']:.2f}x, agrees on "
                  f"{r['forest_same']}/{r['points']} | with the cell's kinematics "
                  f"{r['forest_kinematics']:.4f} ms against mj_kinematics + mj_multiRay: "
                  f"{r['forest_kinematics'] / r['mujoco']:.2f}x")
            print(f"  floor of the triangles handed anew: one culling pass "
                  f"{r['cull_floor']:.4f} ms, {r['cull_floor'] / r['mujoco']:.2f}x MuJoCo")


if __name__ == "__main__":
    main()

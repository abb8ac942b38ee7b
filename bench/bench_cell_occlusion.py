"""Per-frame occlusion prediction on the built-in cell: cellsight (per-object hierarchies, and
the paper's per-frame BSP) against ray casters.

The question, each frame: for every camera and every workpiece feature, does the open segment
from the optical centre to the feature cross a surface? Every method starts from the same
snapshot (object poses) and pays for moving the surfaces to the base frame.

- cellsight: ``VisibilityPredictor.predict_snapshot`` (transform, cull, BSP build, visit per
  camera, labels), with and without culling; per camera and for all cameras; the feature
  points only (``near_px=0``), as for the peers, and, in a row of its own, with the tracker's
  near-occluder ring (16 more points around each feature in view: 8 in front, 8 behind); a
  0.1 mm surface tolerance like the peers' (the tracker's default 2 mm keeps points resting on
  a surface visible, where the ray casters call them hidden).
- Open3D ``RaycastingScene``: rebuilt each frame from the triangulated surfaces, then
  ``test_occlusions`` on the rays centre -> feature with tfar just short of the feature.
- trimesh + embreex: ``RayMeshIntersector`` rebuilt each frame, then ``intersects_any`` on
  rays cast from just off each feature towards the camera (which answers the same segment
  question as long as nothing lies behind the camera on that line).

Median of warm frames; ratios are peer time / cellsight time. Answers are compared with
cellsight's; disagreements are counted and printed.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from cellsight import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.visibility import FRAME_BSP

FRAMES = 300
PEER_TOLERANCE = 1e-4  # m: about where the peers' rays end short of a feature 1.7 m away


def _triangles(predictor: VisibilityPredictor) -> np.ndarray:
    """Triangles over the predictor's flat vertex array (each face's vertices in order)."""
    tris = []
    for k, (obj_index, face_index) in enumerate(predictor.surfaces.poly_source):
        solid = predictor.cell.objects[obj_index].solid
        tris.append(predictor.surfaces.offsets[k] + solid.face_triangles(face_index))
    return np.concatenate(tris)


def _features(predictor: VisibilityPredictor, snapshot) -> np.ndarray:
    cell = predictor.cell
    return np.concatenate([
        (snapshot.poses[k][:3, :3] @ p.feature_points.T).T + snapshot.poses[k][:3, 3]
        for k, p in zip(predictor.part_objects, cell.workpieces, strict=True)
    ])


def _median_ms(fn, snapshots) -> tuple[float, list]:
    out = [fn(s) for s in snapshots[:20]]  # warm-up (JIT, caches)
    times, out = [], []
    for s in snapshots:
        t0 = time.perf_counter()
        out.append(fn(s))
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times), out


def run(frames: int = FRAMES) -> list[dict]:
    """Rows: method, cameras, median ms per frame, ratio to cellsight, disagreements."""
    import open3d as o3d
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    cell = load_cell()
    snapshots = random_snapshots(cell, frames, seed=7)
    n_cam = len(cell.cameras)
    rows = []
    ours_all = visibility_predictor(cell)
    tris = _triangles(ours_all)

    def ours(predictor):
        def fn(s):
            return np.concatenate([np.concatenate([v.visible for v in views])
                                   for views in predictor.predict_snapshot(s).values()])
        return fn

    def in_view(s, cams):
        pts = _features(ours_all, s)
        return pts, np.concatenate([cell.cameras[c].sees(pts) for c in cams])

    def open3d_fn(cams):
        def fn(s):
            verts = ours_all.surfaces.world_vertices(s).astype(np.float32)
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris.astype(np.uint32)))
            pts = _features(ours_all, s)
            rays = np.concatenate([
                np.hstack([np.repeat(cell.cameras[c].center[None], len(pts), 0),
                           pts - cell.cameras[c].center]) for c in cams]).astype(np.float32)
            hit = scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=1.0 - 1e-4)
            return ~hit.numpy()
        return fn

    def embree_fn(cams):
        def fn(s):
            verts = ours_all.surfaces.world_vertices(s)
            mesh = trimesh.Trimesh(verts, tris, process=False)
            caster = RayMeshIntersector(mesh)
            pts = _features(ours_all, s)
            dirs = np.concatenate([cell.cameras[c].center - pts for c in cams])
            origins = np.concatenate([pts] * len(cams)) + 1e-4 * dirs
            return ~caster.intersects_any(origins, dirs)
        return fn

    for label, cams in [(f"all {n_cam} cameras", list(range(n_cam)))] + [
        (cell.cameras[c].name, [c]) for c in range(n_cam)
    ]:
        masks = [in_view(s, cams)[1] for s in snapshots]
        # the same question as the peers: the features only (near_px=0), a surface tolerance
        # like their ray's end short of the feature (the tracker's 2 mm would differ on points
        # resting on a surface)
        same = {"cameras": cams, "surface_tolerance": PEER_TOLERANCE}
        base_ms, base = _median_ms(ours(visibility_predictor(cell, near_px=0.0, **same)),
                                   snapshots)
        rows.append({"method": "cellsight object-bvh (default)", "cameras": label,
                     "ms": base_ms, "ratio": 1.0, "disagree": 0,
                     "checked": int(sum(m.sum() for m in masks))})
        bsp = {"near_px": 0.0, "structure": FRAME_BSP, **same}
        for name, fn in [
            ("cellsight frame-bsp (paper's, culled)", ours(visibility_predictor(cell, **bsp))),
            ("cellsight frame-bsp, no culling", ours(visibility_predictor(cell, cull=False,
                                                                         **bsp))),
            ("cellsight object-bvh + near-occluder ring (tracker's)",
             ours(visibility_predictor(cell, **same))),
            ("Open3D RaycastingScene", open3d_fn(cams)),
            ("trimesh + embreex", embree_fn(cams)),
        ]:
            ms, answers = _median_ms(fn, snapshots)
            disagree = sum(int(((a != b) & m).sum()) for a, b, m in zip(answers, base, masks,
                                                                        strict=True))
            rows.append({"method": name, "cameras": label, "ms": ms, "ratio": ms / base_ms,
                         "disagree": disagree, "checked": rows[-1]["checked"]})
    return rows


def main() -> None:
    from rich.console import Console
    from rich.table import Table

    rows = run()
    table = Table(title=f"Occlusion prediction per frame, built-in cell ({FRAMES} random frames,"
                        " median, warm)")
    for col in ("cameras", "method", "ms / frame", "x cellsight", "disagreements"):
        table.add_column(col, justify="left" if col in ("cameras", "method") else "right",
                         no_wrap=True)
    for r in rows:
        table.add_row(r["cameras"], r["method"], f"{r['ms']:.3f}", f"{r['ratio']:.1f}",
                      f"{r['disagree']} / {r['checked']}")
    Console(width=140).print(table)


if __name__ == "__main__":
    main()

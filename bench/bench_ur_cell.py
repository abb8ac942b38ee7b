"""Per-frame occlusion prediction on a cell with two UR5 (real collision meshes) and three
cameras (issues 11, 12): cellsight (static per-object hierarchies, and the paper's culled
per-frame BSP) against Open3D and MuJoCo on the same rays.

The cell: the built-in UR cell (``cellsight/data/ur_cell.yaml``) when it exists, else
``bench/ur2_cell.yaml`` (the UR5 test cell with a second UR5 and a third camera). 300 random
configurations: both arms uniformly random within their joint limits, the part near its
nominal pose (random position and yaw, sometimes lifted and tipped; ``random_snapshots`` with
no part in a gripper). Every method starts from the same snapshot (object poses) and pays for
moving the surfaces:

- cellsight: ``VisibilityPredictor.predict_snapshot``, ``object-bvh`` (the default) and
  ``frame-bsp`` (exact cull, one BSP tree, a visit per camera), labels included, the features
  only (``near_px=0``) and a 0.1 mm surface tolerance like the peers'; in a row of its own,
  with the tracker's near-occluder ring (16 more points each: 8 in front, 8 behind);
- Open3D ``RaycastingScene`` rebuilt each frame from the same triangles (moved to the base
  frame), ``test_occlusions`` on the rays centre -> feature ending 1e-4 short of the feature;
- MuJoCo ``mj_multiRay`` on the world's model (the same meshes, ``cellsight.world.World``):
  joints, jaw openings and the part's pose written, ``mj_kinematics``, one call per camera,
  a hit counting when more than 0.1 mm before the feature.

Times are milliseconds per frame (all three cameras), median and 99th percentile over the
configurations; each configuration is timed ``REPEATS`` times (one method at a time) and its
best time kept, so that other processes on this shared 2-core machine do not make the tail.
Answers (features in the image only) are compared with cellsight's; disagreements are counted.
A second table splits the frame-bsp mode's time into stages (transform and cull, build, visit)
with the surfaces kept, median and 99th percentile.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import cellsight
from cellsight import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.visibility import FRAME_BSP

FRAMES = 300
REPEATS = 3
PEER_TOLERANCE = 1e-4  # m: where the peers' rays end short of a feature, and cellsight's
BUILTIN = Path(cellsight.__file__).parent / "data" / "ur_cell.yaml"
FALLBACK = Path(__file__).parent / "ur2_cell.yaml"


def ur_cell(path: Path | None = None):
    """The cell at ``path``, by default the two-UR5, three-camera cell (built-in when present,
    else the bench's), and its file."""
    path = path or (BUILTIN if BUILTIN.exists() else FALLBACK)
    return load_cell(path), path


def _triangles(predictor: VisibilityPredictor) -> np.ndarray:
    """Triangles over the predictor's flat vertex array (each face's vertices in order)."""
    tris = []
    for k, (obj_index, face_index) in enumerate(predictor.surfaces.poly_source):
        solid = predictor.cell.objects[obj_index].solid
        tris.append(predictor.surfaces.offsets[k] + solid.face_triangles(face_index))
    return np.concatenate(tris).astype(np.uint32)


def _features(predictor: VisibilityPredictor, snapshot) -> np.ndarray:
    """Every workpiece feature in the base frame (m), (F, 3)."""
    return np.concatenate([
        local @ snapshot.poses[k][:3, :3].T + snapshot.poses[k][:3, 3]
        for k, local in zip(predictor.part_objects, predictor.part_features, strict=True)
    ])


def cellsight_fn(predictor: VisibilityPredictor):
    """Visible flags from cellsight's predictor, cameras after cameras, each camera's in the
    order of :func:`_features` (the parts' features, parts in cell order), as the peers'."""
    def fn(s):
        views = list(predictor.predict_snapshot(s).values())  # per part, per camera
        return np.concatenate([v[c].visible for c in range(len(predictor.cameras))
                               for v in views])
    return fn


def open3d_fn(predictor: VisibilityPredictor):
    """Visible flags from an Open3D scene rebuilt per frame."""
    import open3d as o3d

    tris = o3d.core.Tensor(_triangles(predictor))
    centres = [cam.center for cam in predictor.cell.cameras]

    def fn(s):
        scene = o3d.t.geometry.RaycastingScene()
        vertices = predictor.surfaces.world_vertices(s).astype(np.float32)
        scene.add_triangles(o3d.core.Tensor(vertices), tris)
        pts = _features(predictor, s)
        rays = np.concatenate([np.hstack([np.repeat(c[None], len(pts), 0), pts - c])
                               for c in centres]).astype(np.float32)
        hit = scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0,
                                    tfar=1.0 - PEER_TOLERANCE)
        return ~hit.numpy()
    return fn


def mujoco_fn(predictor: VisibilityPredictor):
    """Visible flags from MuJoCo ``mj_multiRay`` on the world's model of the cell."""
    import mujoco

    from cellsight.world.mjcf import body_name, joint_name
    from cellsight.world.world import World

    cell = predictor.cell
    world = World(cell)
    model, data = world.scene.model, world.scene.data
    qadr = {r.name: [model.jnt_qposadr[model.joint(joint_name(r.name, i)).id]
                     for i in range(1, r.n_joints + 1)] for r in cell.robots}
    jaws = {r.name: [model.jnt_qposadr[model.joint(body_name(r.name, j)).id]
                     for j in ("jaw1", "jaw2")] for r in cell.robots if r.tool is not None}
    mocap = {p.name: model.body_mocapid[model.body(p.name).id] for p in cell.workpieces}
    geomid = np.empty(0, np.int32)

    def fn(s):
        nonlocal geomid
        for name, adr in qadr.items():
            data.qpos[adr] = s.joints[name]
        for name, adr in jaws.items():
            data.qpos[adr] = 0.5 * s.openings[name]
        for name, m in mocap.items():
            T = s.part_poses[name]
            data.mocap_pos[m] = T[:3, 3]
            mujoco.mju_mat2Quat(data.mocap_quat[m], np.ascontiguousarray(T[:3, :3]).ravel())
        mujoco.mj_kinematics(model, data)
        pts = _features(predictor, s)
        n = len(pts)
        if geomid.size != n:
            geomid = np.empty(n, np.int32)
        out = []
        for cam in cell.cameras:
            vec = pts - cam.center
            length = np.linalg.norm(vec, axis=1)
            dist = np.empty(n)
            mujoco.mj_multiRay(model, data, cam.center, (vec / length[:, None]).ravel(), None,
                               1, -1, geomid, dist, None, n, float(length.max()) + 1.0)
            out.append(~((dist >= 0) & (dist < length - PEER_TOLERANCE)))
        return np.concatenate(out)
    return fn


def in_view(predictor: VisibilityPredictor, snapshots) -> list[np.ndarray]:
    """Per snapshot, which rays (cameras, then features, as the methods answer) end in an
    image: the rays compared."""
    return [np.concatenate([cam.sees(_features(predictor, s)) for cam in predictor.cameras])
            for s in snapshots]


def compared(results: dict, reference: str, masks) -> dict[str, dict]:
    """Method name -> median and p99 ms and ``disagree``: the rays in view (``masks``) where
    its answers differ from the ``reference`` method's (``results`` from :func:`timed`)."""
    ours = results[reference][1]
    return {name: {"median": 1e3 * float(np.median(times)),
                   "p99": 1e3 * float(np.percentile(times, 99)),
                   "disagree": sum(int(((a != b) & m).sum())
                                   for a, b, m in zip(answers, ours, masks, strict=True))}
            for name, (times, answers) in results.items()}


def timed(methods: dict, snapshots) -> dict:
    """Method name -> (best time per configuration (s), answers); each method warmed up, then
    ``REPEATS`` passes over the configurations (one method at a time)."""
    out = {}
    for name, fn in methods.items():
        for s in snapshots[:20]:
            fn(s)
        best = np.full(len(snapshots), np.inf)
        answers = [None] * len(snapshots)
        for _ in range(REPEATS):
            for i, s in enumerate(snapshots):
                t0 = time.perf_counter()
                answers[i] = fn(s)
                best[i] = min(best[i], time.perf_counter() - t0)
        out[name] = (best, answers)
    return out


def run(frames: int = FRAMES, path: Path | None = None) -> tuple[list[dict], dict]:
    """Rows (method, median and p99 ms, disagreements / checked) and the cell's facts (the
    cell at ``path``, default :func:`ur_cell`'s)."""
    cell, path = ur_cell(path)
    snapshots = random_snapshots(cell, frames, seed=7, in_gripper=0.0)
    same = {"surface_tolerance": PEER_TOLERANCE}
    base = visibility_predictor(cell, near_px=0.0, **same)
    methods = {
        "cellsight object-bvh (default)": cellsight_fn(base),
        "cellsight frame-bsp (paper's, culled)": cellsight_fn(
            visibility_predictor(cell, near_px=0.0, structure=FRAME_BSP, **same)),
        "cellsight object-bvh + near-occluder ring (tracker's)": cellsight_fn(
            visibility_predictor(cell, **same)),
        "Open3D RaycastingScene (rebuilt)": open3d_fn(base),
        "MuJoCo mj_multiRay (mj_kinematics)": mujoco_fn(base),
    }
    results = timed(methods, snapshots)
    masks = in_view(base, snapshots)
    rows = [{"method": name, **figures, "checked": int(sum(m.sum() for m in masks))}
            for name, figures in compared(results, "cellsight object-bvh (default)",
                                          masks).items()]
    paper = visibility_predictor(cell, near_px=0.0, structure=FRAME_BSP, **same)
    facts = {"cell": path.name, "surfaces": len(base.surfaces.poly_owner),
             "cameras": len(cell.cameras), "features": len(_features(base, snapshots[0])),
             "stages": stages(paper, snapshots)}
    return rows, facts


def stages(predictor: VisibilityPredictor, snapshots) -> list[tuple[str, float, float]]:
    """(stage, median, p99) of cellsight's stages (ms; surfaces: counts), best of
    ``REPEATS`` per configuration."""
    per = np.full((len(snapshots), 4), np.inf)
    kept = np.zeros(len(snapshots))
    for _ in range(REPEATS):
        for i, s in enumerate(snapshots):
            t = predictor.stage_times(s)
            per[i] = np.minimum(per[i], [t["cull"], t["build"], t["visit"], t["total"]])
            kept[i] = t["kept"]
    out = [(name, 1e3 * np.median(per[:, j]), 1e3 * np.percentile(per[:, j], 99))
           for j, name in enumerate(["transform + cull", "build", "visit", "total"])]
    return out + [("surfaces kept", float(np.median(kept)), float(np.percentile(kept, 99)))]


def main(path: Path | None = None) -> None:
    """Print the tables (``python bench/bench_ur_cell.py [cell.yaml]``)."""
    from rich.console import Console
    from rich.table import Table

    rows, facts = run(path=path)
    table = Table(title=f"Occlusion prediction per frame, {facts['cell']} ({facts['surfaces']} "
                        f"surfaces, {facts['cameras']} cameras, {facts['features']} features, "
                        f"{FRAMES} random frames, best of {REPEATS})")
    for col in ("method", "median ms", "p99 ms", "disagreements"):
        table.add_column(col, justify="left" if col == "method" else "right", no_wrap=True)
    for r in rows:
        table.add_row(r["method"], f"{r['median']:.3f}", f"{r['p99']:.3f}",
                      f"{r['disagree']} / {r['checked']}")
    console = Console(width=120)
    console.print(table)
    split = Table(title="cellsight frame-bsp (culled): stages")
    for col in ("stage", "median", "p99"):
        split.add_column(col, justify="left" if col == "stage" else "right", no_wrap=True)
    for name, med, p99 in facts["stages"]:
        split.add_row(name, f"{med:.3f}", f"{p99:.3f}")
    console.print(split)


if __name__ == "__main__":
    import sys

    main(Path(sys.argv[1]) if len(sys.argv) > 1 else None)

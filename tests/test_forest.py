"""Static per-object hierarchies (issue 12, ``structure="object-bvh"``): against the segment
oracle on random objects in random poses, against the paper's per-frame BSP on real cells
(same labels, pixels and near-occluder flags), and on cells with several workpieces hiding
each other."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from oracle import (
    cell_scene,
    random_convex_solid,
    random_prism,
    random_rotation,
    random_soup,
    segment_oracle,
)

from cellsight import load_cell
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.forest import LEAF_SIZE, ObjectForest
from cellsight.occlusion.scale_cells import scale_cell
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.visibility import FRAME_BSP, STRUCTURES

ROOT = Path(__file__).resolve().parents[1]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_forest_matches_the_oracle_on_random_objects_in_random_poses(seed) -> None:
    """Three objects (a random open soup, a closed convex solid, a closed non-convex prism),
    each in its own frame, moved by a random rigid pose; 40 points seen from a random
    viewpoint, inside and outside the solids."""
    rng = np.random.default_rng(seed)
    objects = [(random_soup(rng, int(rng.integers(3, 16))), False),
               (random_convex_solid(rng, rng.uniform(-0.5, 0.5, 3), 0.6)[0], True),
               (random_prism(rng, rng.uniform(-0.5, 0.5, 3), 0.6)[0], True)]
    poses, local, offsets, object_polys, base = [], [], [0], [0], []
    for polygons, _ in objects:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = random_rotation(rng), rng.uniform(-1, 1, 3)
        poses.append(T)
        for poly in polygons:
            local.append(poly)
            offsets.append(offsets[-1] + len(poly))
            base.append(poly @ T[:3, :3].T + T[:3, 3])
        object_polys.append(object_polys[-1] + len(polygons))
    forest = ObjectForest(np.concatenate(local), np.asarray(offsets), np.asarray(object_polys),
                          np.array([closed for _, closed in objects]), 1e-3)
    view = rng.uniform(-3, 3, 3)
    points = rng.uniform(-2, 2, (40, 3))
    occ = forest.occluders(np.array(poses), view[None], np.array([0, len(points)]), points, 0.0)
    oracle = segment_oracle(base, points, view)
    for j in np.flatnonzero(~oracle.ambiguous):
        assert (occ[j] < 0) == oracle.visible[j], (j, occ[j], oracle.occluder[j])
        if not oracle.visible[j]:  # the nearest crossing names the occluder
            assert oracle.t[j, occ[j]] == pytest.approx(oracle.t[j, oracle.occluder[j]],
                                                        abs=1e-9)


def test_every_node_box_holds_its_polygons_and_leaves_partition_each_object() -> None:
    cell = load_cell(ROOT / "bench" / "ur2_cell.yaml")
    predictor = visibility_predictor(cell)
    forest, surfaces = predictor.forest, predictor.surfaces
    verts, offsets = surfaces.local_vertices, surfaces.offsets
    for k, root in enumerate(forest.object_root):
        seen, todo = [], [root]
        while todo:
            node = todo.pop()
            first, second, start, count = forest.node_links[node]
            box = forest.node_box[node]
            if count:
                assert count <= LEAF_SIZE
                for q in forest.node_polys[start:start + count]:
                    v = verts[offsets[q]:offsets[q + 1]]
                    assert np.all(v >= box[:3]) and np.all(v <= box[3:])
                    seen.append(q)
                continue
            for child in (first, second):
                assert np.all(forest.node_box[child, :3] >= box[:3])
                assert np.all(forest.node_box[child, 3:] <= box[3:])
                todo.append(child)
        a, b = surfaces.object_polys[k], surfaces.object_polys[k + 1]
        assert sorted(seen) == list(range(a, b))


CELLS = {"dual-arm": lambda: load_cell(),
         "two UR5": lambda: load_cell(ROOT / "bench" / "ur2_cell.yaml"),
         "3 cameras, 2 UR5, 3 parts": lambda: scale_cell(3, 2, 3)}


@pytest.mark.parametrize("name", list(CELLS))
def test_object_bvh_answers_equal_the_per_frame_bsp(name) -> None:
    """Labels, pixels and near-occluder flags of every feature of every part in every camera."""
    cell = CELLS[name]()
    bsp = visibility_predictor(cell, structure=FRAME_BSP)
    bvh = visibility_predictor(cell)
    hidden = near = 0
    for snapshot in random_snapshots(cell, 60, seed=21):
        a, b = bsp.predict_snapshot(snapshot), bvh.predict_snapshot(snapshot)
        assert a.keys() == b.keys()
        for part in a:
            for x, y in zip(a[part], b[part], strict=True):
                assert x.reason == y.reason
                np.testing.assert_array_equal(x.near_occluder, y.near_occluder)
                np.testing.assert_array_equal(x.pixels, y.pixels)
                hidden += int((x.status == 0).sum() - x.visible.sum())
                near += int(x.near_occluder.sum())
    assert hidden > 20 and near > 0


@pytest.fixture(scope="module")
def three_parts(tmp_path_factory):
    """The built-in dual-arm cell with two more copies of its part on the table."""
    spec = yaml.safe_load((ROOT / "cellsight" / "data" / "dual_arm_cell.yaml").read_text())
    part = spec["workpieces"][0]
    for name, xyz, yaw in (("part2", [0.8, 0.05, 0.62], 1.2), ("part3", [0.35, -0.1, 0.62], -0.5)):
        spec["workpieces"].append({**part, "name": name, "pose": {"xyz": xyz,
                                                                   "rpy": [0.0, 0.0, yaw]}})
    path = tmp_path_factory.mktemp("cells") / "three_parts.yaml"
    path.write_text(yaml.safe_dump(spec))
    return load_cell(path)


@pytest.mark.parametrize("structure", STRUCTURES)
def test_several_workpieces_against_the_oracle(three_parts, structure) -> None:
    """Every part's features in every camera, one call per frame; parts hide each other."""
    cell = three_parts
    predictor = visibility_predictor(cell, structure=structure)
    checked = by_parts = 0
    mismatches = []
    parts = {p.name for p in cell.workpieces}
    for snapshot in random_snapshots(cell, 34, seed=4) + [_stacked(cell)]:
        result = predictor.predict_snapshot(snapshot)
        for part in cell.workpieces:
            polygons, labels, features = cell_scene(cell, snapshot, part.name)
            for cam, pred in zip(cell.cameras, result[part.name], strict=True):
                seen = np.flatnonzero(pred.status == 0)
                if not seen.size:
                    continue
                oracle = segment_oracle(polygons, features[seen], cam.center,
                                        predictor.surface_tolerance, prune=True)
                for j, i in enumerate(seen):
                    if oracle.ambiguous[j]:
                        continue
                    checked += 1
                    want = "" if oracle.visible[j] else labels[oracle.occluder[j]]
                    by_parts += want in parts
                    if pred.reason[i] != want:
                        mismatches.append((cam.name, part.name, i, pred.reason[i], want))
    assert not mismatches, mismatches[:10]
    assert checked > 2000 and by_parts > 10


def _stacked(cell):
    """part2 held up on cam1's line of sight to the first part, a third of the way: it must
    hide some of that part's features from cam1."""
    snapshot = cell.snapshot()
    part1 = snapshot.pose("part")[:3, 3]
    eye = cell.cameras[0].center
    on_line = part1 + (eye - part1) / 3.0
    return cell.snapshot(part_poses={"part2": pose_from_xyz_rpy(on_line, [0.3, 0.2, 0.0])})


def test_unknown_structure_is_refused() -> None:
    with pytest.raises(CellsightError,
                       match=r"structure must be one of object-bvh, frame-bsp, got .octree."):
        visibility_predictor(load_cell(), structure="octree")

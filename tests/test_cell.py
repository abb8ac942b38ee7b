"""Cell loading, validation errors and snapshots."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

from cellsight import load_cell
from cellsight.errors import CellFileError, KinematicsError
from cellsight.geometry.transforms import invert_pose, pose_from_xyz_rpy, transform_points
from cellsight.model.loader import builtin_cell_path

BUILTIN = yaml.safe_load(builtin_cell_path().read_text())


def _write(tmp_path, data, name="cell.yaml") -> str:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return str(path)


def test_builtin_cell_matches_the_paper_setup() -> None:
    cell = load_cell()
    assert [r.name for r in cell.robots] == ["R7AX", "R6AX"]
    r7, r6 = cell.robot("R7AX"), cell.robot("R6AX")
    assert r7.n_joints == 7 and r7.chain.links[0].kind == "prismatic" and r6.n_joints == 6
    part = cell.workpieces[0]
    assert len(part.feature_points) == 16 and len(part.solid.faces) == 10
    assert 0.08 <= np.ptp(part.feature_points[:, :2], axis=0).max() <= 0.12
    assert max(len(f) for f in part.solid.faces) == 8
    assert len(cell.cameras) == 2
    for cam in cell.cameras:
        assert (cam.width, cam.height) == (768, 576)
        distance = np.linalg.norm(cam.center - part.T_base_part[:3, 3])
        assert 1.5 <= distance <= 2.5
        assert cam.sees(transform_points(part.T_base_part, part.feature_points)).all()


def test_snapshot_poses_follow_the_kinematic_chain() -> None:
    cell = load_cell()
    rng = np.random.default_rng(0)
    r7 = cell.robot("R7AX")
    q = r7.chain.random_q(rng)
    T_part = pose_from_xyz_rpy([0.7, 0.1, 0.62], [0, 0, 1.0])
    snap = cell.snapshot({"R7AX": q}, {"part": T_part}, {"R7AX": 0.05})
    frames = r7.T_base_robot @ r7.chain.fkine(q)
    np.testing.assert_allclose(snap.pose("R7AX.link3"), frames[3], atol=1e-12)
    tool = frames[-1] @ r7.tool.T_flange_tool
    np.testing.assert_allclose(snap.pose("R7AX.gripper"), tool, atol=1e-12)
    jaw1, jaw2 = snap.pose("R7AX.gripper.jaw1"), snap.pose("R7AX.gripper.jaw2")
    np.testing.assert_allclose(np.linalg.norm(jaw1[:3, 3] - jaw2[:3, 3]), 0.05, atol=1e-12)
    np.testing.assert_allclose(snap.pose("part"), T_part)
    np.testing.assert_allclose(snap.pose("R6AX.link2"),
                               cell.robot("R6AX").link_poses(cell.robot("R6AX").home)[2])
    for k, cam in enumerate(cell.cameras):  # paper: W^k = (C^b_k)^-1 W^b
        np.testing.assert_allclose(snap.in_camera(k), invert_pose(cam.T_base_cam) @ snap.poses,
                                   atol=1e-12)


def test_snapshot_rejects_bad_joints() -> None:
    cell = load_cell()
    with pytest.raises(KinematicsError, match="R7AX: joint 4 is not finite"):
        cell.snapshot({"R7AX": [0.3, 0, 0, math.nan, 0, 0, 0]})
    with pytest.raises(KinematicsError, match="R7AX: joint 1 = 5 outside its limits"):
        cell.snapshot({"R7AX": [5.0, 0, 0, 0, 0, 0, 0]})
    with pytest.raises(KeyError, match="no robot 'R9'"):
        cell.snapshot({"R9": [0.0]})


def _edit(path_fn, value):
    data = copy.deepcopy(BUILTIN)
    path_fn(data, value)
    return data


MALFORMED = [
    ("reversed joint limits", lambda d, v: d["robots"][0]["links"][2].update(qlim=v), [1.0, -1.0],
     r"robots\[0\]\.links\[2\].*qlim must be \[lo, hi\]"),
    ("negative image width", lambda d, v: d["cameras"][1].update(width=v), -5,
     r"cameras\[1\]\.width.*-5"),
    ("text prism height", lambda d, v: d["workpieces"][0]["solid"]["prism"].update(height=v),
     "tall", r"workpieces\[0\]\.solid\.prism\.height.*'tall'"),
    ("home of wrong length", lambda d, v: d["robots"][1].update(home=v), [0.0, 0.1],
     r"robots\[1\]\.home.*expected 6 values"),
    ("NaN base position", lambda d, v: d["robots"][0]["base"].update(xyz=v),
     [float("nan"), 0, 0], r"robots\[0\]\.base\.xyz\[0\].*nan"),
    ("unknown camera field", lambda d, v: d["cameras"][0].update(lens=v), 12,
     r"cameras\[0\]\.lens.*Extra inputs"),
    ("two solid kinds", lambda d, v: d["static"][0]["solids"][0].update(prism=v),
     {"polygon": [[0, 0], [1, 0], [0, 1]], "height": 1}, r"static\[0\]\.solids\[0\].*exactly one"),
    ("joint kind", lambda d, v: d["robots"][0]["links"][0].update(kind=v), "spherical",
     r"robots\[0\]\.links\[0\]\.kind.*'spherical'"),
    ("camera looking along up", lambda d, v: d["cameras"][0].update(look_at=v),
     {"eye": [0, 0, 2], "target": [0, 0, 0]}, r"cameras\[0\].*parallel to up"),
    ("home out of limits", lambda d, v: d["robots"][0].update(home=v),
     [9.0, 0, 0, 0, 0, 0, 0], r"robots\[0\]\.home.*joint 1 = 9 outside"),
    ("non-planar inline solid", lambda d, v: d["workpieces"][0].update(solid=v),
     {"vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0], [0.5, 0.5, -1]],
      "faces": [[0, 1, 2, 3], [0, 4, 1], [1, 4, 2], [2, 4, 3], [3, 4, 0]]},
     r"workpieces\[0\]\.solid.*solid 'part' face 0: non-planar"),
    ("missing mesh file", lambda d, v: d["static"][1].update(solids=v),
     [{"mesh": {"file": "nowhere.stl"}}], r"static\[1\]\.solids\[0\].*does not exist"),
    ("no cameras", lambda d, v: d.update(cameras=v), [], r"field 'cameras'"),
    ("duplicate names", lambda d, v: d["static"][0].update(name=v), "R6AX",
     r"field 'name'.*R6AX"),
]


@pytest.mark.parametrize(("case", "edit", "value", "message"), MALFORMED,
                         ids=[m[0] for m in MALFORMED])
def test_malformed_cell_files_name_file_field_and_value(tmp_path, case, edit, value, message):
    path = _write(tmp_path, _edit(edit, value))
    with pytest.raises(CellFileError, match=message) as info:
        load_cell(path)
    assert str(info.value).startswith(path)


def test_yaml_syntax_error_names_the_line(tmp_path) -> None:
    path = _write(tmp_path, "name: x\ncameras: [\n  {name: a\n")
    with pytest.raises(CellFileError, match=r"cell.yaml: field 'line \d+'"):
        load_cell(path)


def test_a_repeated_key_is_an_error_not_the_last_one_wins(tmp_path) -> None:
    text = builtin_cell_path().read_text().replace(
        "    width: 768\n", "    width: 768\n    width: 640\n", 1)
    path = _write(tmp_path, text)
    with pytest.raises(CellFileError, match=r"cell.yaml: field 'line \d+': got \"duplicate key "
                                            r"'width'\"; expected valid YAML"):
        load_cell(path)


def test_camera_names_must_be_unique(tmp_path) -> None:
    raw = yaml.safe_load(builtin_cell_path().read_text())
    raw["cameras"][1]["name"] = raw["cameras"][0]["name"]
    path = _write(tmp_path, yaml.safe_dump(raw))
    with pytest.raises(CellFileError, match=r"field 'cameras\[\]\.name': got \['cam1'\]; "
                                            r"expected unique camera names"):
        load_cell(path)


def test_missing_file_is_named(tmp_path) -> None:
    with pytest.raises(CellFileError, match="nope.yaml"):
        load_cell(tmp_path / "nope.yaml")


def test_mesh_solids_load_relative_to_the_cell_file(tmp_path) -> None:
    import trimesh

    trimesh.creation.box((0.3, 0.3, 0.3)).export(tmp_path / "crate.stl")
    data = copy.deepcopy(BUILTIN)
    data["static"].append({"name": "crate", "pose": {"xyz": [1.2, 0.2, 0.75]},
                           "solids": [{"mesh": {"file": "crate.stl"}}]})
    cell = load_cell(_write(tmp_path, data))
    crate = cell.objects[cell.object_index("crate")]
    assert len(crate.solid.faces) == 6
    np.testing.assert_allclose(cell.snapshot().pose("crate")[:3, 3], [1.2, 0.2, 0.75])

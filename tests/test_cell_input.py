"""Bad and hostile cell files and meshes: one clear error each, naming the file, the field and
the value, quickly and without a traceback (issue 14)."""

from __future__ import annotations

import copy
import math
import time
from dataclasses import replace

import numpy as np
import pytest
import yaml

from cellsight import load_cell
from cellsight.errors import CellFileError, CellsightError, GeometryError, short_repr
from cellsight.geometry.polygon import check_polygon
from cellsight.model import Cell
from cellsight.model.loader import builtin_cell_path
from cellsight.model.yaml_input import MAX_CELL_BYTES, MAX_YAML_DEPTH

BUILTIN = yaml.safe_load(builtin_cell_path().read_text())


def _write(tmp_path, data, name="cell.yaml") -> str:
    path = tmp_path / name
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return str(path)


def _refused(path: str, pattern: str) -> str:
    with pytest.raises(CellFileError, match=pattern) as info:
        load_cell(path)
    message = str(info.value)
    assert message.startswith(path) and "\n" not in message and len(message) < 600
    assert "np.float" not in message
    return message


def _laughs(levels: int = 9) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]")
    return "\n".join(lines) + f"\ncameras: *a{levels - 1}\n"


def test_nested_aliases_are_refused_quickly(tmp_path) -> None:
    start = time.perf_counter()
    _refused(_write(tmp_path, _laughs()), r"field 'line \d+': got 'more than 2000000 values'; "
                                          r"expected at most 2000000 values once aliases are")
    assert time.perf_counter() - start < 5.0


def test_aliases_of_a_reasonable_size_still_load(tmp_path) -> None:
    cell = load_cell(_write(tmp_path, builtin_cell_path().read_text()))  # it uses anchors
    assert [r.name for r in cell.robots] == ["R7AX", "R6AX"]


def test_yaml_merge_keys_load_as_pyyaml_loads_them(tmp_path) -> None:
    """``<<: *anchor`` (a camera like another, but for its name): the keys merged, the
    mapping's own winning, as ``yaml.safe_load`` reads them; a key repeated in one mapping is
    still refused."""
    text = builtin_cell_path().read_text().replace(
        "  - name: cam2\n    width: 768\n", "  - <<: *cam1\n    name: cam2\n    width: 768\n"
    ).replace("  - name: cam1\n", "  - &cam1\n    name: cam1\n")
    assert yaml.safe_load(text)["cameras"][1]["name"] == "cam2"
    cell = load_cell(_write(tmp_path, text))
    assert [c.name for c in cell.cameras] == ["cam1", "cam2"]
    assert not np.allclose(cell.cameras[0].T_base_cam, cell.cameras[1].T_base_cam)
    merged = text.replace("    name: cam2\n", "    name: cam2\n    name: cam3\n")
    _refused(_write(tmp_path, merged, "twice.yaml"), "duplicate key 'name'")


@pytest.mark.parametrize(("text", "pattern"), [
    ("name: " + "[" * 20000 + "]" * 20000 + "\n",
     f"got 'deeper nesting'; expected collections nested at most {MAX_YAML_DEPTH} levels"),
    ("name: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n", f"nested at most {MAX_YAML_DEPTH}"),
    ("a: &a [*a]\ncameras: *a\n",
     "alias inside the collection it names'; expected no recursive values"),
], ids=["brackets", "braces", "recursive-alias"])
def test_deep_or_recursive_yaml_is_refused(tmp_path, text, pattern) -> None:
    _refused(_write(tmp_path, text), pattern)


def test_a_huge_file_is_refused_before_reading(tmp_path) -> None:
    path = tmp_path / "huge.yaml"
    with path.open("wb") as f:
        f.truncate(MAX_CELL_BYTES + 1)
    _refused(str(path), r"field '<file>'.*bytes'; expected a cell file of at most")


def test_non_utf8_file_is_named(tmp_path) -> None:
    _refused(_write(tmp_path, b"name: caf\xe9\ncameras: []\n"),
             r"field 'line 1': got b'\\xe9.*expected UTF-8 text")


def test_a_control_character_is_a_yaml_error(tmp_path) -> None:
    _refused(_write(tmp_path, "name: a\x00b\n"), r"expected valid YAML")


def test_error_values_are_short_and_plain() -> None:
    assert short_repr([np.float64(0.5), np.int64(3)]) == "[0.5, 3]"
    assert len(short_repr(list(range(10**6)))) <= 60
    nested = [1]
    for _ in range(30):
        nested = [nested] * 10
    assert len(short_repr(nested)) <= 60


def _with_mesh(tmp_path, name: str, content: bytes | str) -> str:
    mesh = tmp_path / name
    mesh.write_bytes(content if isinstance(content, bytes) else content.encode())
    data = copy.deepcopy(BUILTIN)
    data["static"].append({"name": "crate", "solids": [{"mesh": {"file": name}}]})
    return _write(tmp_path, data)


TETRA = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 {z}\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"


@pytest.mark.parametrize(("name", "content", "pattern"), [
    ("junk.obj", "hello world\n\x01 junk\n", r"junk.obj holds no triangles"),
    ("empty.stl", b"", r"empty.stl holds no triangles"),
    ("notes.txt", "just text", r"notes.txt: type '.txt' is not one of .stl, .obj"),
    ("nan.obj", TETRA.format(z="nan"), r"nan.obj: vertex 4 is not finite"),
    ("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", r"index.obj: not a readable mesh"),
], ids=["garbage-obj", "empty", "not-a-mesh", "nan-vertex", "bad-index"])
def test_bad_meshes_are_refused_naming_the_file(tmp_path, name, content, pattern) -> None:
    _refused(_with_mesh(tmp_path, name, content), r"static\[\d+\]\.solids\[0\].*" + pattern)


def test_a_good_obj_tetrahedron_stays_closed(tmp_path) -> None:
    cell = load_cell(_with_mesh(tmp_path, "tet.obj", TETRA.format(z=1)))
    crate = cell.objects[cell.object_index("crate")].solid
    assert crate.closed and len(crate.faces) == 4


def _edit(fn) -> dict:
    data = copy.deepcopy(BUILTIN)
    fn(data)
    return data


CASES = [
    ("no workpieces", lambda d: d.update(workpieces=[]),
     r"field 'workpieces': got \[\]; expected at least one workpiece"),
    ("grasping robot without a tool", lambda d: (d["robots"][1].pop("tool"),
                                                 d["experiments"].update(robot="R6AX")),
     r"field 'experiments.robot': got 'R6AX'; expected a robot with a tool.*has no tool"),
    ("boolean width", lambda d: d["cameras"][0].update(width=True),
     r"cameras\[0\]\.width': got True; expected Input should be a valid integer"),
    ("float height", lambda d: d["cameras"][0].update(height=576.5),
     r"cameras\[0\]\.height': got 576.5"),
    ("boolean size", lambda d: d["workpieces"][0]["solid"]["prism"].update(height=True),
     r"prism\.height': got True; expected .*a number, not a boolean"),
    ("slash in a camera name", lambda d: d["cameras"][0].update(name="../cam"),
     r"cameras\[0\]\.name': got '\.\./cam'; expected .*letters, digits"),
    ("static named like a link", lambda d: d["static"][0].update(name="R7AX.link2"),
     r"field 'static\[0\]\.name': got 'R7AX.link2'; expected a name no other occluder has; "
     r"robots\[0\]\.links\[1\] is already named"),
    ("workpiece named like a jaw", lambda d: d["workpieces"][0].update(name="R6AX.gripper.jaw1"),
     r"workpieces\[0\]\.name'.*robots\[1\]\.tool is already named"),
    ("bow-tie face", lambda d: d["workpieces"][0].update(solid={
        "vertices": [[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2, 3]],
        "closed": False}), r"face 0: edges 0 and 2 intersect \(polygon is not simple: "
                           r"self-intersecting\)"),
    ("eye on the target", lambda d: d["cameras"][0].update(look_at={
        "eye": [1, 1, 1], "target": [1, 1, 1]}),
     r"cameras\[0\]'.*look_at: eye \[1.0, 1.0, 1.0\] and target \[1.0, 1.0, 1.0\] coincide"),
    ("home out of limits, plain numbers", lambda d: d["robots"][0].update(
        home=[9.0, 0, 0, 0, 0, 0, 0]), r"robots\[0\]\.home': got \[9.0, 0.0, 0.0"),
]


@pytest.mark.parametrize(("case", "edit", "pattern"), CASES, ids=[c[0] for c in CASES])
def test_refused_cells_name_file_field_and_value(tmp_path, case, edit, pattern) -> None:
    _refused(_write(tmp_path, _edit(edit)), pattern)


def test_bow_tie_is_not_called_collinear() -> None:
    bow_tie = np.array([[0.0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]])
    with pytest.raises(GeometryError, match="self-intersecting"):
        check_polygon(bow_tie, "face 0")
    with pytest.raises(GeometryError, match="collinear"):
        check_polygon(np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]), "face 1")


@pytest.mark.parametrize("opening", [-0.01, math.nan, math.inf, 0.5, "wide"])
def test_bad_jaw_openings_are_refused(opening) -> None:
    cell = load_cell()
    with pytest.raises(CellsightError, match=r"robot R7AX: jaw opening .* expected a finite "
                                             r"number in \[0, 0.09\] m"):
        cell.snapshot(openings={"R7AX": opening})


def test_jaw_openings_within_noise_are_clipped() -> None:
    snap = load_cell().snapshot(openings={"R7AX": -1e-7})
    assert snap.openings["R7AX"] == 0.0


def test_grasping_robot_without_a_tool_is_named_by_the_scenario() -> None:
    from cellsight.experiments.scenario import scenario

    cell = load_cell()
    r6 = replace(cell.robot("R6AX"), tool=None)
    odd = Cell(cell.name, [cell.robot("R7AX"), r6], cell.workpieces, cell.static, cell.cameras,
               source="cell.yaml", experiments=replace(cell.experiments, robot="R6AX"))
    with pytest.raises(CellFileError, match=r"cell.yaml: field 'experiments.robot': got 'R6AX'"):
        scenario(odd, 1)

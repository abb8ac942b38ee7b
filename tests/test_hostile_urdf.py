"""Hostile URDFs (issue 23): each is refused with one line naming the cell file, its ``urdf``
field and the URDF (with the element at fault), exit status 2, nothing else on stderr."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from test_urdf import _PRIMITIVES

from cellsight.cli import main
from cellsight.errors import CellFileError, CellsightError
from cellsight.model.loader import load_cell

# test_urdf.py's two-joint robot with every kind of geometry (lengths m), with a comment, an XML
# declaration and a namespaced attribute, which are fine.
_URDF = ('<?xml version="1.0"?>\n<!-- toy robot -->\n'
         + _PRIMITIVES.replace('<robot name="toy">',
                               '<robot name="toy" xmlns:xacro="http://wiki.ros.org/xacro">'))
_CORNERS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
_FACES = "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"
_CELL = """
packages: {toy: toy}
robots:
  - name: T
    urdf: {file: toy/toy.urdf}
    home: [0.0, 0.0]
workpieces:
  - name: part
    solid: {box: {size: [0.1, 0.1, 0.1]}, features: [a, b, c, d, e, f, g, h]}
    pose: {xyz: [1.0, 0.0, 0.0]}
cameras:
  - {name: c, width: 64, height: 48, fx: 50, look_at: {eye: [3, 0, 1], target: [0, 0, 0]}}
"""


def _block(side: float) -> str:
    """An OBJ cube of the given side."""
    return "".join(f"v {x * side} {y * side} {z * side}\n" for x, y, z in _CORNERS) + _FACES


def _cell(tmp_path: Path, urdf: str, mesh_side: float = 0.1) -> Path:
    """A cell file whose robot T is the URDF text ``urdf`` (folder ``toy``, with the mesh)."""
    (tmp_path / "toy").mkdir(parents=True, exist_ok=True)
    (tmp_path / "toy" / "toy.urdf").write_text(urdf)
    (tmp_path / "toy" / "block.obj").write_text(_block(mesh_side))
    (tmp_path / "cell.yaml").write_text(_CELL)
    return tmp_path / "cell.yaml"


def _edited(old: str, new: str) -> str:
    """The toy URDF with ``old`` (which it holds) replaced by ``new``."""
    assert old in _URDF
    return _URDF.replace(old, new)


def _refused(tmp_path: Path, capsys, urdf: str, field: str, words: str,
             mesh_side: float = 0.1) -> str:
    """Checks the CLI and the loader refuse the URDF: one stderr line naming the cell file,
    ``robots[0].urdf.<field>``, the URDF and ``words``; exit 2. Returns the line."""
    cell = _cell(tmp_path, urdf, mesh_side)
    assert main(["visibility", "--cell", str(cell)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.endswith("\n"), err
    for part in (str(cell), f"'robots[0].urdf.{field}'", str(tmp_path / "toy" / "toy.urdf"),
                 words):
        assert part in err, (part, err)
    with pytest.raises(CellsightError) as info:
        load_cell(cell)
    assert isinstance(info.value, CellFileError) and info.value.field == f"robots[0].urdf.{field}"
    assert words in str(info.value)
    return err


def test_the_toy_urdf_loads(tmp_path: Path) -> None:
    robot = load_cell(_cell(tmp_path, _URDF)).robot("T")
    assert robot.chain.kinds == ("prismatic", "revolute")


def test_a_urdf_cut_off_mid_file_is_refused(tmp_path: Path, capsys) -> None:
    cut = _URDF[: _URDF.index('<sphere radius')]  # inside the last link
    _refused(tmp_path, capsys, cut, "file", "not well-formed XML")


_LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE robot [\n<!ENTITY a0 "lol">\n'
           + "".join(f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">\n' for i in range(1, 10))
           + "]>\n")


_UNREADABLE = [
    ("not a URDF, not XML at all", "not well-formed XML"),
    (_LAUGHS + _URDF.split("\n", 1)[1].replace('name="toy"', 'name="&a9;"'),
     "not well-formed XML ("),  # libxml2 says amplification or reference loop, by its state
    ('<!DOCTYPE robot [<!ENTITY r "toy">]>\n' + _URDF.split("\n", 1)[1], "has a DOCTYPE"),
    (_edited('name="toy"', 'name="&undefined;"'), "Entity 'undefined' not defined"),
]


@pytest.mark.parametrize(("urdf", "words"), _UNREADABLE)
def test_unreadable_urdfs_are_refused(tmp_path: Path, capsys, urdf: str, words: str) -> None:
    _refused(tmp_path, capsys, urdf, "file", words)


# Run in a fresh interpreter, whose stderr is the real one (pytest captures logging and
# warnings): yourdfpy logs its fallback parser's complaints, Python shows warnings there.
_SCRIPT = """
import logging, sys, warnings
import yourdfpy
from cellsight.cli import main
from cellsight.model.loader import load_cell

load = yourdfpy.URDF.load
def noisy(*args, **kwargs):
    logging.getLogger("yourdfpy.urdf").error("yourdfpy log record")
    warnings.warn("yourdfpy warning", stacklevel=1)
    return load(*args, **kwargs)
yourdfpy.URDF.load = staticmethod(noisy)
load_cell(sys.argv[1])
yourdfpy.URDF.load = load
sys.exit(max(main(["visibility", "--cell", cell]) for cell in sys.argv[2:]))
"""


def test_stderr_holds_one_line_per_refused_urdf_and_no_parser_noise(tmp_path: Path) -> None:
    cut = _URDF[: _URDF.index('<sphere radius')]
    cells = [_cell(tmp_path / str(k), urdf)
             for k, urdf in enumerate([_URDF, cut, *(u for u, _ in _UNREADABLE)])]
    out = subprocess.run([sys.executable, "-c", _SCRIPT, *map(str, cells)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.splitlines()
    assert len(lines) == len(cells) - 1, out.stderr
    for line, cell in zip(lines, cells[1:], strict=True):
        assert line.startswith(f"cellsight: error: {cell}: field 'robots[0].urdf.file'"), line


@pytest.mark.parametrize(("urdf", "mesh_side", "field", "words"), [
    (_edited('<origin xyz="0 0 0.2"', '<origin xyz="0 0 200"'), 0.1, "file",
     "link 'tip' is up to 200.9 m from the root link"),
    (_edited('lower="-0.5" upper="0.5"', 'lower="-500" upper="500"'), 0.1, "file",
     "link 'tip' is up to 500.6 m from the root link"),
    (_URDF, 100.0, "geometry", "link 'arm', collision 0 reaches"),
    (_edited('scale="1 2 1"', 'scale="1000 1000 1000"'), 0.1, "geometry",
     "link 'arm', collision 0 reaches"),
])
def test_lengths_that_are_not_metres_are_refused(tmp_path: Path, capsys, urdf: str,
                                                 mesh_side: float, field: str,
                                                 words: str) -> None:
    err = _refused(tmp_path, capsys, urdf, field, words, mesh_side)
    assert "lengths must be metres" in err


@pytest.mark.parametrize(("urdf", "words"), [
    (_edited("</robot>", '<link name="arm"><collision><geometry><box size="1 1 1"/>'
             "</geometry></collision></link></robot>"), "two links named 'arm'"),
    (_edited('<joint name="tip_fixed"', '<joint name="spin"'), "two joints named 'spin'"),
])
def test_duplicate_link_and_joint_names_are_refused(tmp_path: Path, capsys, urdf: str,
                                                    words: str) -> None:
    _refused(tmp_path, capsys, urdf, "file", words)


@pytest.mark.parametrize(("old", "new", "words"), [
    ('radius="0.05"', 'radius="-0.05"', "cylinder radius must be positive, got -0.05"),
    ('radius="0.05"', 'radius="0"', "cylinder radius must be positive, got 0.0"),
    ('length="0.1"', 'length="0"', "cylinder length must be positive, got 0.0"),
    ('radius="0.03"', 'radius="-0.03"', "sphere radius must be positive, got -0.03"),
])
def test_cylinders_and_spheres_not_of_positive_size_are_refused(tmp_path: Path, capsys,
                                                                old: str, new: str,
                                                                words: str) -> None:
    _refused(tmp_path, capsys, _edited(old, new), "geometry", words)


@pytest.mark.parametrize(("old", "new", "words"), [
    ('<origin xyz="0.1 0 0"/>', '<origin xyz="nan 0 0"/>',
     "link 'arm', collision 0, origin xyz='nan 0 0' is not 3 finite number(s)"),
    ('<origin xyz="0 0 0.2" rpy="0 0.3 0"/>', '<origin xyz="0 0 0.2" rpy="0 inf 0"/>',
     "joint 'spin', origin rpy='0 inf 0' is not 3 finite number(s)"),
    ('<axis xyz="0 1 1"/>', '<axis xyz="0 NaN 1"/>',
     "joint 'spin', axis xyz='0 NaN 1' is not 3 finite number(s)"),
    ('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0"/>',
     "joint 'tip_fixed', origin xyz='0.3 0' is not 3 finite number(s)"),
    ('size="0.2 0.2 0.1"', 'size="0.2 nan 0.1"',
     "link 'base', collision 0, geometry, box size='0.2 nan 0.1' is not 3 finite"),
    ('scale="1 2 1"', 'scale="1 inf 1"', "mesh scale='1 inf 1' is not 1 or 3 finite"),
    ('lower="-0.5"', 'lower="-inf"', "joint 'slide', limit lower='-inf' is not 1 finite"),
])
def test_non_finite_urdf_numbers_name_the_element(tmp_path: Path, capsys, old: str, new: str,
                                                  words: str) -> None:
    _refused(tmp_path, capsys, _edited(old, new), "file", words)



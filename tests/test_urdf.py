"""URDF robots (issue 11): a UR5 from example-robot-data in a cell file, beside DH robots.

Pinocchio is the independent oracle for the kinematics; MuJoCo's ray casts for visibility."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.control.clik import Clik
from cellsight.errors import CellFileError
from cellsight.model.urdf import load_urdf_robot
from cellsight.model.urdf_files import resolve_uri
from cellsight.occlusion.backends import visibility_predictor
from cellsight.world.world import World

pin = pytest.importorskip("pinocchio")
DATA = Path(__file__).parent / "data"
CELL = DATA / "ur5_cell.yaml"
UR5 = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
LINKS = ("world", "base_link", "shoulder_link", "upper_arm_link", "forearm_link",
         "wrist_1_link", "wrist_2_link", "wrist_3_link", "ee_link", "tool0")


@pytest.fixture(scope="module")
def cell():
    return load_cell(CELL)


def _pin(path: Path):
    model = pin.buildModelFromUrdf(str(path))
    return model, model.createData()


def _pin_frames(model, data, q: np.ndarray) -> dict[str, np.ndarray]:
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    return {f.name: data.oMf[i].homogeneous for i, f in enumerate(model.frames)}


def test_forward_kinematics_of_every_link_matches_pinocchio(cell):
    robot = cell.robot("UR5")
    path = resolve_uri(UR5, {}, Path("."))
    model, data = _pin(path)
    assert model.nq == robot.n_joints == 6
    ur5 = load_urdf_robot(path, "UR5")
    rng = np.random.default_rng(11)
    for _ in range(50):
        q = robot.chain.random_q(rng)
        want = _pin_frames(model, data, q)
        frames = robot.chain.fkine(q)
        for i, name in enumerate(robot.chain.link_names):
            np.testing.assert_allclose(frames[i], want[name], atol=1e-9, rtol=0)
        np.testing.assert_allclose(frames[-1] @ ur5.T_last_flange, want["tool0"], atol=1e-9,
                                   rtol=0)
        # the gripper mounts on tool0 (the cell file's mount is the identity)
        np.testing.assert_allclose(robot.tool_pose(q), robot.T_base_robot @ want["tool0"],
                                   atol=1e-9, rtol=0)


def test_jacobian_matches_pinocchio(cell):
    robot = cell.robot("UR5")
    model, data = _pin(resolve_uri(UR5, {}, Path(".")))
    fid = model.getFrameId("wrist_3_link")
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = robot.chain.random_q(rng)
        J = robot.chain.jacobian(q)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        J_pin = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J, J_pin, atol=1e-9, rtol=0)


def test_cell_file_loads_with_urdf_link_labels(cell):
    robot = cell.robot("UR5")
    labels = {o.label for o in cell.objects if o.robot == "UR5"}
    assert {f"UR5.{n}" for n in LINKS[1:9]} <= labels | {"UR5.world"}
    assert "UR5.upper_arm_link" in labels and "UR5.gripper" in labels
    assert robot.chain.kinds == ("revolute",) * 6
    snap = cell.snapshot({"UR5": robot.final})
    k = cell.object_index("UR5.upper_arm_link")
    np.testing.assert_allclose(snap.poses[k], robot.link_poses(robot.final)[2], atol=1e-12)


def test_visibility_cli_on_the_ur5_cell():
    exe = Path(sys.executable).with_name("cellsight")
    out = subprocess.run([str(exe), "visibility", "--cell", str(CELL), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    views = json.loads(out.stdout)
    assert [v["camera"] for v in views["part"]] == ["cam1", "cam2"]


def test_mujoco_body_poses_equal_the_link_poses(cell):
    world = World(cell)
    rng = np.random.default_rng(3)
    robot = cell.robot("UR5")
    worst = 0.0
    for _ in range(30):
        q = robot.chain.random_q(rng)
        opening = rng.uniform(0.0, robot.tool.max_opening)
        world.step({"UR5": q}, {"UR5": opening})
        joints = world.true_joints()
        np.testing.assert_array_equal(joints["UR5"], q)
        snap = cell.snapshot(joints, world.true_part_poses(), world.jaw_openings())
        links = [k for k, o in enumerate(cell.objects) if o.kind == "link"]
        worst = max(worst, float(np.abs(world.truth.object_poses()[links]
                                        - snap.poses[links]).max()))
    assert worst < 1e-9


def test_predictor_agrees_with_mujoco_ray_casts(cell):
    """Random UR5 configurations and part poses on the table: the predictor's answer equals
    MuJoCo's ray-cast truth for every feature in view, except near another object's silhouette
    (``near_occluder``: a ray grazing an edge, decided by float32 mesh vertices in MuJoCo)."""
    robot = cell.robot("UR5")
    world, predictor = World(cell), visibility_predictor(cell)
    part = cell.workpiece("part")
    rng = np.random.default_rng(2)
    compared, disagree, hidden_by_arm = 0, 0, 0
    for k in range(40):  # half anywhere in the limits, half near HOME (over the part)
        q = robot.chain.random_q(rng) if k % 2 else robot.home + rng.uniform(-0.6, 0.6, 6)
        T = part.T_base_part.copy()
        T[:2, 3] += rng.uniform(-0.25, 0.25, 2)
        world.step({"UR5": q}, {})
        world.place_part("part", T)
        truth = world.true_views()["part"]
        views = predictor.predict(world.true_joints(), {"part": T}, world.jaw_openings())["part"]
        for want, got in zip(truth, views, strict=True):
            inside = want.status == 0
            clear = inside & ~got.near_occluder
            compared += int(clear.sum())
            disagree += int((want.visible[clear] != got.visible[clear]).sum())
            hidden_by_arm += sum(r.startswith("UR5.") and r != "UR5.gripper"
                                 for r in got.reason)
    assert compared > 800 and hidden_by_arm > 10, (compared, hidden_by_arm)
    assert disagree == 0


def test_clik_converges_on_the_ur5(cell):
    robot = cell.robot("UR5")
    clik = Clik(robot)
    rng = np.random.default_rng(4)
    for _ in range(5):
        q_goal = robot.home + rng.uniform(-0.4, 0.4, 6)
        T_goal = robot.tcp_pose(q_goal)
        q = robot.home.copy()
        for _ in range(2500):
            q = clik.step(q, T_goal)
        T = robot.tcp_pose(q)
        assert np.linalg.norm(T[:3, 3] - T_goal[:3, 3]) < 1e-4
        R = T_goal[:3, :3] @ T[:3, :3].T
        assert np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)) < 1e-3


_PRIMITIVES = """<robot name="toy">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <joint name="slide" type="prismatic"><parent link="base"/><child link="carriage"/>
    <origin xyz="0 0 0.1" rpy="0.1 0 0.2"/><axis xyz="1 0 0"/>
    <limit lower="-0.5" upper="0.5" effort="1" velocity="1"/></joint>
  <link name="carriage"><collision><origin xyz="0 0 0.05"/>
    <geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="spin" type="continuous"><parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.2" rpy="0 0.3 0"/><axis xyz="0 1 1"/></joint>
  <link name="arm"><collision><origin xyz="0.1 0 0"/>
    <geometry><mesh filename="package://toy/block.obj" scale="1 2 1"/></geometry></collision>
  </link>
  <joint name="tip_fixed" type="fixed"><parent link="arm"/><child link="tip"/>
    <origin xyz="0.3 0 0"/></joint>
  <link name="tip"><collision><geometry><sphere radius="0.03"/></geometry></collision></link>
</robot>
"""
_BLOCK_OBJ = """v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nv 0 0 0.1\nv 0.1 0 0.1\nv 0.1 0.1 0.1
v 0 0.1 0.1\nf 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"""


def _toy_cell(tmp_path: Path, robot_extra: str = "", urdf: str = "toy/toy.urdf") -> Path:
    (tmp_path / "toy").mkdir(exist_ok=True)
    (tmp_path / "toy" / "toy.urdf").write_text(_PRIMITIVES)
    (tmp_path / "toy" / "block.obj").write_text(_BLOCK_OBJ)
    text = f"""
packages: {{toy: toy}}
robots:
  - name: T
    urdf: {{file: {urdf}}}
    home: [0.0, 0.0]
{robot_extra}
workpieces:
  - name: part
    solid: {{box: {{size: [0.1, 0.1, 0.1]}}, features: [a, b, c, d, e, f, g, h]}}
    pose: {{xyz: [1.0, 0.0, 0.0]}}
cameras:
  - {{name: c, width: 64, height: 48, fx: 50, look_at: {{eye: [3, 0, 1], target: [0, 0, 0]}}}}
"""
    (tmp_path / "cell.yaml").write_text(text)
    return tmp_path / "cell.yaml"


def test_primitives_prismatic_continuous_and_packages_map(tmp_path):
    cell = load_cell(_toy_cell(tmp_path))
    robot = cell.robot("T")
    assert robot.chain.kinds == ("prismatic", "revolute")
    np.testing.assert_allclose(robot.chain.qlim[1], [-2 * np.pi, 2 * np.pi])
    names = {o.name: o for o in cell.objects}
    assert {"T.base", "T.carriage", "T.arm", "T.tip"} <= set(names)
    assert len(names["T.carriage"].solid.faces) == 26  # 24-gon prism
    np.testing.assert_allclose(np.ptp(names["T.arm"].solid.vertices, axis=0), [0.1, 0.2, 0.1])
    model, data = _pin(tmp_path / "toy" / "toy.urdf")
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = robot.chain.random_q(rng)
        q_pin = np.array([q[0], np.cos(q[1]), np.sin(q[1])])  # continuous: (cos, sin)
        want = _pin_frames(model, data, q_pin)
        frames = robot.chain.fkine(q)
        for i, name in enumerate(robot.chain.link_names):
            np.testing.assert_allclose(frames[i], want[name], atol=1e-9, rtol=0)
    world = World(cell)
    q = np.array([0.2, 1.0])
    world.step({"T": q}, {})
    snap = cell.snapshot(world.true_joints())
    np.testing.assert_allclose(world.truth.object_poses(), snap.poses, atol=1e-9)


@pytest.mark.parametrize(("extra", "urdf", "field", "words"), [
    ("", "toy/missing.urdf", "robots[0].urdf.file", "does not exist"),
    ("", "package://nowhere/toy.urdf", "robots[0].urdf.file", "unknown package 'nowhere'"),
    ("    links: [{a: 0.1}]", "toy/toy.urdf", "robots[0]", "exactly one of 'links'"),
    ("    base_solids: [{box: {size: [1, 1, 1]}}]", "toy/toy.urdf", "robots[0]",
     "'base_solids' only"),
])
def test_bad_urdf_robots_name_the_file_and_field(tmp_path, extra, urdf, field, words):
    path = _toy_cell(tmp_path, extra, urdf)
    with pytest.raises(CellFileError) as info:
        load_cell(path)
    assert info.value.field == field and str(path) in str(info.value)
    assert words in str(info.value)


def test_bad_mesh_and_flange_name_the_urdf(tmp_path):
    path = _toy_cell(tmp_path)
    (tmp_path / "toy" / "block.obj").unlink()
    (tmp_path / "toy" / "toy.urdf").write_text(_PRIMITIVES)
    text = path.read_text()
    path.write_text(text)
    (tmp_path / "toy" / "block.obj").write_text("")
    with pytest.raises(CellFileError) as info:
        load_cell(path)
    assert info.value.field == "robots[0].urdf.geometry" and "toy.urdf" in str(info.value)
    assert "link 'arm'" in str(info.value)
    path = _toy_cell(tmp_path)
    path.write_text(path.read_text().replace("urdf: {file: toy/toy.urdf}",
                                             "urdf: {file: toy/toy.urdf, flange: carriage}"))
    with pytest.raises(CellFileError) as info:
        load_cell(path)
    assert info.value.field == "robots[0].urdf.flange" and "'tip'" in str(info.value)


def _in_inches(urdf: str) -> str:
    """The toy URDF with every length in inches: origins, sizes, radii, lengths, the
    prismatic limits and the mesh's scale (the mesh file itself stays in metres)."""
    def scaled(match: re.Match) -> str:
        values = " ".join(f"{float(v) / 0.0254:.12g}" for v in match.group(2).split())
        return f'{match.group(1)}"{values}"'
    pattern = r'(<origin xyz=|size=|radius=|length=|lower=|upper=|scale=)"([^"]*)"'
    return re.sub(pattern, scaled, urdf)


def test_a_urdf_in_inches_loads_in_metres_with_its_unit(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "in").mkdir()
    metres = load_cell(_toy_cell(tmp_path / "m"))
    inches = _toy_cell(tmp_path / "in", urdf="toy/toy_in.urdf")
    (tmp_path / "in" / "toy" / "toy_in.urdf").write_text(_in_inches(_PRIMITIVES))
    text = inches.read_text()
    inches.write_text(text.replace("urdf: {file: toy/toy_in.urdf}",
                                   "urdf: {file: toy/toy_in.urdf, scale: inch}"))
    scaled = load_cell(inches)
    a, b = metres.robot("T"), scaled.robot("T")
    np.testing.assert_allclose(b.chain.qlim, a.chain.qlim, atol=1e-12)
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = a.chain.random_q(rng)
        np.testing.assert_allclose(b.chain.fkine(q), a.chain.fkine(q), atol=1e-12)
    solids = {o.name: o.solid.vertices for o in metres.objects}
    for o in scaled.objects:
        np.testing.assert_allclose(o.solid.vertices, solids[o.name], atol=1e-12)
    # without its unit the same file is 39.37x too large: refused, naming the way out
    inches.write_text(text)
    with pytest.raises(CellFileError, match=r"43.31 m from the root link.*scale: inch"):
        load_cell(inches)

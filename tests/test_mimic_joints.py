"""Mimic joints (issue 59): a URDF hand's fingers, one mimicking the other, are the robot's
gripper. The Franka Panda's ``panda.urdf`` as example-robot-data ships it loads, moves its
fingers in the model, the world and the exports, and crosses the views in experiments 1-3 of
``examples/cells/iiwa_panda.yaml``. The oracle is yourdfpy's forward kinematics of the same
file, which applies the mimic itself."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yourdfpy
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.cli import main
from cellsight.errors import CellFileError
from cellsight.export import frames as tf
from cellsight.model.urdf import load_urdf_robot
from cellsight.model.urdf_files import UrdfError, installed_package_folder
from cellsight.recording.names import TopicMap, joint_positions
from cellsight.recording.series import _targets
from cellsight.runfolder import FrameLog

PANDA_CELL = Path(__file__).resolve().parent.parent / "examples" / "cells" / "iiwa_panda.yaml"
PANDA_FOLDER = installed_package_folder("example-robot-data") / "robots" / "panda_description"
FINGERS = ("panda_leftfinger", "panda_rightfinger")
# A leader finger's share of its range, 0 or from 1e-5: the oracle does not apply a joint value
# within 1e-8 of the one before (yourdfpy's EQUALITY_TOLERANCE): drawn at 1.8e-9 rad, the
# finger stayed at 0 there while ours moved, 1.3e-9 m apart.
_LEADER = st.one_of(st.just(0.0), st.floats(1e-5, 1.0))


@pytest.fixture(scope="module")
def cell():
    return load_cell(PANDA_CELL)


@pytest.fixture(scope="module")
def oracle():
    return yourdfpy.URDF.load(str(PANDA_FOLDER / "urdf" / "panda.urdf"), load_meshes=False,
                              build_collision_scene_graph=False, load_collision_meshes=False)


def _finger_poses_oracle(oracle, robot, q, opening) -> list[np.ndarray]:
    """The fingers' links in the cell's base frame by yourdfpy, the leader at opening / 2; a
    fresh scene of the parsed model each time (a scene updated from one configuration to the
    next can keep a transform of the one before, a few nm off)."""
    cfg = dict(zip(robot.chain.joint_names, q, strict=True))
    cfg["panda_finger_joint1"] = opening / 2
    fresh = yourdfpy.URDF(robot=oracle.robot, load_meshes=False,
                          build_collision_scene_graph=False, load_collision_meshes=False)
    fresh.update_cfg(cfg)
    return [robot.T_base_robot @ fresh.get_transform(link, "panda_link0") for link in FINGERS]


@pytest.mark.parametrize("file", ["panda.urdf", "panda_collision.urdf"])
def test_the_panda_loads_as_shipped_with_its_hand_as_the_gripper(file):
    model = load_urdf_robot(PANDA_FOLDER / "urdf" / file, "PANDA")
    assert model.chain.n == 7 and model.chain.joint_names[-1] == "panda_joint7"
    leader, mimic = model.fingers
    assert (leader.joint, mimic.joint) == ("panda_finger_joint1", "panda_finger_joint2")
    assert (mimic.multiplier, mimic.offset) == (1.0, 0.0) and leader.limits == (0.0, 0.04)


def test_the_cell_gives_the_panda_its_fingers(cell):
    robot = cell.robot("PANDA")
    tool = robot.tool
    assert tool.max_opening == pytest.approx(0.08)  # twice the leader's 4 cm
    assert [j.joint for j in tool.jaws] == ["panda_finger_joint1", "panda_finger_joint2"]
    names = [o.name for o in cell.objects if o.name.startswith("PANDA.")]
    assert "PANDA.panda_hand" in names and names[-2:] == ["PANDA.gripper.jaw1",
                                                         "PANDA.gripper.jaw2"]
    assert "PANDA.panda_leftfinger" not in names  # the fingers are the jaws, not links


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7), _LEADER.map(lambda u: 0.08 * u))
def test_the_fingers_follow_the_leader_as_yourdfpy_has_them(cell, oracle, u, opening):
    robot = cell.robot("PANDA")
    lo, hi = robot.chain.qlim.T
    q = lo + np.array(u) * (hi - lo)
    T_tool = robot.tool_pose(q)
    ours = [T_tool @ T for T in robot.tool.jaw_poses(opening)]
    for T, T_ref in zip(ours, _finger_poses_oracle(oracle, robot, q, opening), strict=True):
        assert np.abs(T - T_ref).max() < 1e-9
    # the cell's snapshot places the jaws' solids there too
    snap = cell.snapshot(joints={"PANDA": q}, openings={"PANDA": opening})
    for k, T in enumerate(ours):
        assert np.abs(snap.poses[cell.object_index(f"PANDA.gripper.jaw{k + 1}")] - T).max() \
            < 1e-9


def _hand_urdf(folder: Path, mimic: str, finger_parent: str = "hand") -> Path:
    """A two-joint arm with a two-finger hand (boxes), the second finger's joint given by
    ``mimic``."""
    box = '<collision><geometry><box size="0.02 0.01 0.04"/></geometry></collision>'
    text = textwrap.dedent(f"""\
        <robot name="toy">
          <link name="base">{box}</link><link name="upper">{box}</link>
          <link name="fore">{box}</link><link name="hand">{box}</link>
          <link name="f1">{box}</link><link name="f2">{box}</link>
          <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/>
            <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
          <joint name="j2" type="revolute"><parent link="upper"/><child link="fore"/>
            <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2"/></joint>
          <joint name="wrist" type="fixed"><parent link="fore"/><child link="hand"/>
            <origin xyz="0 0 0.3" rpy="0 0 0.5"/></joint>
          <joint name="g1" type="prismatic"><parent link="{finger_parent}"/><child link="f1"/>
            <origin xyz="0 0.002 0.05"/><axis xyz="0 1 0"/><limit lower="0" upper="0.03"/>
          </joint>
          <joint name="g2" type="prismatic"><parent link="{finger_parent}"/><child link="f2"/>
            <origin xyz="0 -0.002 0.05" rpy="0 0 3.141592653589793"/><axis xyz="0 1 0"/>
            <limit lower="0" upper="0.1"/>{mimic}</joint>
        </robot>""")
    path = folder / "toy.urdf"
    path.write_text(text)
    return path


@settings(max_examples=25, deadline=None)
@given(st.floats(0.5, 2.0), st.floats(-0.004, 0.004), st.floats(-2, 2), _LEADER)
def test_a_mimic_s_multiplier_and_offset_are_followed(tmp_path_factory, multiplier, offset, q2,
                                                    u):
    folder = tmp_path_factory.mktemp("toy")
    path = _hand_urdf(folder, f'<mimic joint="g1" multiplier="{multiplier}" '
                              f'offset="{offset}"/>')
    model = load_urdf_robot(path, "TOY")
    from cellsight.model.urdf import finger_gripper

    tool = finger_gripper(model.fingers, model.T_last_flange, (0, 0, 0), path)
    q_leader = 0.03 * u
    opening = tool.opening_of(q_leader)
    assert tool.jaw_values(opening) == pytest.approx((q_leader, multiplier * q_leader + offset))
    oracle = yourdfpy.URDF.load(str(path), load_meshes=False,
                                build_collision_scene_graph=False, load_collision_meshes=False)
    oracle.update_cfg({"j1": 0.3, "j2": q2, "g1": q_leader})
    q = np.array([0.3, q2])
    T_tool = model.chain.fkine(q)[-1] @ model.T_last_flange @ tool.T_flange_tool
    for link, T in zip(("f1", "f2"), tool.jaw_poses(opening), strict=True):
        assert np.abs(T_tool @ T - oracle.get_transform(link, "base")).max() < 1e-9


@pytest.mark.parametrize(("mimic", "parent", "said"), [
    ('<mimic joint="j2"/>', "hand", "only between a gripper's two fingers"),
    ('<mimic joint="nope"/>', "hand", "'nope', which is not a joint of the file"),
    ('<mimic joint="g1" multiplier="-1"/>', "hand", "do not move apart"),
    ('<mimic joint="g1"/>', "upper", "must hang off links fixed to the last actuated link"),
])
def test_mimics_that_are_not_a_hand_are_refused_by_name(tmp_path, mimic, parent, said):
    path = _hand_urdf(tmp_path, mimic, parent)
    with pytest.raises((UrdfError, CellFileError)) as err:
        model = load_urdf_robot(path, "TOY")
        from cellsight.model.urdf import finger_gripper

        finger_gripper(model.fingers, model.T_last_flange, (0, 0, 0), path)
    assert said in str(err.value) and str(path) in str(err.value)


def _cell_text(tool: str) -> str:
    text = PANDA_CELL.read_text()
    return text.replace("    tool: {fingers: urdf, tcp: [0.0, 0.0, 0.045]}", tool, 1)


@pytest.mark.parametrize(("tool", "field", "said"), [
    ("    tool: {palm: [{box: {size: [0.1, 0.1, 0.1]}}], jaw: {box: {size: [0.01, 0.01, 0.05]}},"
     " max_opening: 0.05}", "robots[1].tool", "has its own fingers"),
])
def test_a_second_gripper_on_a_hand_is_refused(tmp_path, tool, field, said):
    path = tmp_path / "cell.yaml"
    path.write_text(_cell_text(tool))
    with pytest.raises(CellFileError) as err:
        load_cell(path)
    assert err.value.field == field and said in str(err.value)


def test_fingers_asked_of_a_robot_without_any_are_refused(tmp_path):
    text = PANDA_CELL.read_text()
    start = text.index("    tool: &gripper")
    end = text.index("\n", text.index("      tcp:", start)) + 1
    path = tmp_path / "cell.yaml"
    path.write_text(text[:start] + "    tool: {fingers: urdf}\n" + text[end:])
    with pytest.raises(CellFileError) as err:
        load_cell(path)
    assert err.value.field == "robots[0].tool.fingers" and "has none" in str(err.value)


def test_no_tool_given_takes_the_hand(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(_cell_text(""))
    tool = load_cell(path).robot("PANDA").tool
    assert tool is not None and tool.jaws[1].joint == "panda_finger_joint2"
    assert np.array_equal(tool.tcp, np.zeros(3))


def test_the_world_moves_the_fingers_as_yourdfpy_has_them(cell, oracle):
    from cellsight.world.world import World

    world = World(cell)
    robot = cell.robot("PANDA")
    m, d = world.scene.model, world.scene.data
    for opening in (0.08, 0.03, 0.0):
        world.grippers.set_opening("PANDA", opening)
        world.scene.sync()
        assert world.jaw_openings()["PANDA"] == pytest.approx(opening)
        expected = _finger_poses_oracle(oracle, robot, robot.home, opening)
        for k, T_ref in enumerate(expected):
            body = m.body(f"PANDA/jaw{k + 1}").id
            assert np.abs(d.xpos[body] - T_ref[:3, 3]).max() < 1e-6
            assert np.abs(d.xmat[body].reshape(3, 3) - T_ref[:3, :3]).max() < 1e-6
    world.close()


def test_the_exports_name_the_fingers_and_a_recording_reads_them_back(cell, oracle):
    robot = cell.robot("PANDA")
    names, values = joint_positions(cell, {"PANDA": robot.home}, {"PANDA": 0.05})
    assert names[-2:] == ["PANDA/panda_finger_joint1", "PANDA/panda_finger_joint2"]
    assert values[-2:] == pytest.approx([0.025, 0.025])
    moving = dict(((parent, child), T) for parent, child, T
                  in tf.robot_transforms(robot, robot.home, 0.05))
    T_tool = robot.tool_pose(robot.home)
    for link, T_ref in zip(FINGERS, _finger_poses_oracle(oracle, robot, robot.home, 0.05),
                           strict=True):
        T = T_tool @ moving[("PANDA/tool", f"PANDA/{link}")]
        assert np.abs(T - T_ref).max() < 1e-9
    targets = _targets(cell, TopicMap())
    assert targets["PANDA/panda_finger_joint1"] == ("leader", "PANDA")
    assert targets["PANDA/panda_finger_joint2"] == ("mimic", "PANDA")
    assert robot.tool.opening_of(0.025) == pytest.approx(0.05)


@pytest.mark.slow
@pytest.mark.parametrize("experiment", [1, 2, 3])
def test_the_panda_crosses_in_experiments_1_to_3(tmp_path, capsys, experiment):
    out = tmp_path / "run"
    duration = {1: "2", 2: "2", 3: "11"}[experiment]  # experiment 3: cam2 blinded from 9.5 s
    code = main(["run", str(experiment), "--cell", str(PANDA_CELL), "--sensor", "ideal",
                 "--duration", duration, "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["crossing_robot"] == ("PANDA" if experiment == 3 else None)
    assert metrics["lost_in_view_s"] == 0.0
    assert metrics["position_rmse_mm"] < 1.0
    log = FrameLog.read(out / "frames.csv")
    q = np.column_stack([log.floats(f"q_PANDA_{i}") for i in range(1, 8)])
    moved = float(np.abs(np.diff(q, axis=0)).max())
    if experiment < 3:
        assert moved == 0.0  # the crossing robot stays at HOME
    else:  # PANDA's hand on cam2's lines of sight (the designer's judge: at most 1 seen)
        assert moved > 0.0
        late = log.floats("t") > 10.0

        def seen(column: str) -> np.ndarray:  # a feature mask per frame, '1' where seen
            return np.array([mask.count("1") for mask in log.text(column)])[late]

        assert seen("vis_true_c2").max() <= 1 and seen("vis_pred_c2").max() <= 1
        assert seen("vis_true_c1").min() >= 8  # cam1 still sees the part

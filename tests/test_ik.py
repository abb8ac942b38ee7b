"""Inverse kinematics (cellsight.control.ik, ``cellsight ik``): every branch found is checked by
forward kinematics (the robot's own ``tcp_pose``), the configuration a pose was made from is
found again in its branch, a branch the joint limits forbid is reported as not reached, and a
pose out of reach gets one clear error."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight import load_cell
from cellsight.cli import main
from cellsight.control.ik import BRANCH_FLAGS, IKError, branch_of, solve_ik
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.kinematics import DHChain
from cellsight.model.grasp import grasp_pose


def _check_every_solution(robot, T_goal, result) -> None:
    for s in result.solutions:
        T = robot.tcp_pose(s.q)
        assert np.linalg.norm(T[:3, 3] - T_goal[:3, 3]) < 1e-6
        assert Rotation.from_matrix(T[:3, :3].T @ T_goal[:3, :3]).magnitude() < 1e-6
        qlim = robot.chain.qlim
        assert np.all(qlim[:, 0] <= s.q) and np.all(s.q <= qlim[:, 1])
        assert np.allclose(s.limit_margin, np.minimum(s.q - qlim[:, 0], qlim[:, 1] - s.q))
        assert branch_of(robot, s.q) == s.branch and s.sigma_min > 0


@pytest.mark.parametrize(("cell_name", "robot_name"), [(None, "R6AX"), ("ur-cell", "UR5A")])
def test_every_branch_reaches_the_pose_and_the_true_one_is_found(cell_name, robot_name):
    robot = load_cell(cell_name).robot(robot_name)
    rng = np.random.default_rng(3)
    for _ in range(3):
        # a configuration well inside the limits and away from singularities
        while True:
            q_true = robot.home + rng.uniform(-0.5, 0.5, robot.n_joints)
            qlim = robot.chain.qlim
            if np.all((qlim[:, 0] + 0.1 < q_true) & (q_true < qlim[:, 1] - 0.1)):
                break
        T_goal = robot.tcp_pose(q_true)
        result = solve_ik(robot, T_goal)
        _check_every_solution(robot, T_goal, result)
        assert len(result.solutions) + len(result.unreached) == 8
        assert len({tuple(s.branch.values()) for s in result.solutions}) == len(result.solutions)
        mine = [s for s in result.solutions if s.branch == branch_of(robot, q_true)]
        # a 6-axis arm has one solution per branch (up to full turns of a joint on a UR)
        assert len(mine) == 1
        turns = (mine[0].q - q_true) / (2 * np.pi)
        assert np.allclose(turns, np.round(turns), atol=1e-5)


def test_a_branch_the_limits_forbid_is_reported_not_reached():
    robot = load_cell().robot("R6AX")
    T_goal = robot.tcp_pose(robot.home)
    free = solve_ik(robot, T_goal)
    assert {s.branch["wrist"] for s in free.solutions} == {"flip", "noflip"}
    # joint 5 kept on one side of zero: the wrist cannot flip
    links = list(robot.chain.links)
    links[4] = replace(links[4], qlim=(0.05, 2.0))
    tight = replace(robot, chain=DHChain(links, robot.chain.name))
    result = solve_ik(tight, T_goal)
    _check_every_solution(tight, T_goal, result)
    wrists = {s.branch["wrist"] for s in result.solutions}
    assert len(wrists) == 1 and result.solutions
    flipped = [b for b in result.unreached if b["wrist"] != next(iter(wrists))]
    assert len(flipped) == 4
    assert all(set(b) == set(BRANCH_FLAGS) for b in result.unreached)


def test_a_pose_out_of_reach_is_one_clear_error():
    robot = load_cell().robot("R6AX")
    T = robot.tcp_pose(robot.home)
    T[:3, 3] += [4.0, 0.0, 0.0]
    with pytest.raises(IKError, match=r"R6AX cannot put its TCP .* closest of 51 attempts "
                                      r"stays \d+\.\d mm"):
        solve_ik(robot, T)
    with pytest.raises(IKError, match="finite 4x4"):
        solve_ik(robot, np.full((4, 4), np.nan))


def test_the_command_holds_a_part_and_says_what_the_cameras_see(capsys):
    pose = '{"part": {"xyz": [0.6, 0.0, 0.62], "rpy": [0, 0, 0.35]}}'
    assert main(["ik", "--robot", "R7AX", "--part-pose", pose, "--json", "--seeds", "8"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == "R7AX" and out["solutions"]
    cell = load_cell()
    robot, part = cell.robot("R7AX"), cell.workpiece("part")
    T_part = pose_from_xyz_rpy([0.6, 0.0, 0.62], [0, 0, 0.35])
    T_tcp = T_part @ grasp_pose(part, robot.tool)
    for s in out["solutions"]:
        held = robot.tcp_pose(np.array(s["q"]))
        assert np.linalg.norm(held[:3, 3] - T_tcp[:3, 3]) < 1e-4  # q printed to 4 decimals
        assert [v["camera"] for v in s["cameras"]] == [c.name for c in cell.cameras]
        assert all(v["inside"] == 16 and v["margin_px"] > 0 and 0 < v["visible"] <= 16
                   for v in s["cameras"])
    assert main(["ik", "--robot", "nobody", "--tcp-pose", '{"xyz": [0.5, 0, 0.5]}']) == 2
    assert "nobody" in capsys.readouterr().err

"""``cellsight check`` (cellsight.experiments.cellcheck): the built-in cells pass, and broken
copies of the dual-arm cell get one error line each for what is broken: a robot 25.4x too
large, HOME on a joint limit, FINAL holding the part out of view, a crossing that blinds
nothing, a workpiece in millimetres, a conveyor out of reach, a grasp on or into the
conveyor."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.cli import main
from cellsight.experiments.cellcheck import check_cell
from cellsight.kinematics import DHChain
from cellsight.model import Cell


def _with(cell: Cell, robots=None, workpieces=None, experiments=None) -> Cell:
    return Cell(cell.name, robots or cell.robots, workpieces or cell.workpieces, cell.static,
                cell.cameras, cell.source, experiments or cell.experiments)


def _robot(cell: Cell, name: str, **changes) -> Cell:
    return _with(cell, robots=[replace(r, **changes) if r.name == name else r
                               for r in cell.robots])


def _errors(cell: Cell) -> list[str]:
    return [f.line for f in check_cell(cell) if f.level == "error"]


@pytest.fixture(scope="module")
def cell() -> Cell:
    return load_cell()


@pytest.mark.parametrize("name", [None, "ur-cell", "kr16-cell", "iiwa-cell"])
def test_the_built_in_cells_pass(name):
    cell = load_cell(name)
    findings = check_cell(cell)
    assert [f.line for f in findings if f.level != "ok"] == []
    # the grasp 3 mm above the part's mid-height: the jaws' tips 3 mm over the conveyor
    clear = [f.line for f in findings if "clears the static objects" in f.line]
    assert len(clear) == 1 and float(re.search(r"least ([0-9.]+) cm", clear[0])[1]) >= 0.25
    blinds = sorted(f.line.split(" from ")[0] for f in findings if "blinds" in f.line)
    crosser = cell.experiments.crossing_robot
    assert blinds == [f"experiment 3: {crosser} blinds cam1", f"experiment 3: {crosser} blinds "
                      f"cam2"], blinds
    assert any(f.line.startswith("reach: ") and "16 positions" in f.line for f in findings)


def test_a_conveyor_out_of_reach_is_found_where_it_leaves_the_reach(cell):
    """The conveyor carried on 4 m along x: the arm (R7AX on its track, 3.06 m reach at most)
    cannot follow the part past the track's end; the first position missed is named, and it
    lies past where the track's end plus the arm's reach leaves the part."""
    points = cell.experiments.conveyor_points
    far = np.vstack([points, points[-1] + [4.0, 0.0]])
    errors = [e for e in _errors(_with(cell, experiments=replace(
        cell.experiments, conveyor_points=far))) if e.startswith("reach: ")]
    assert errors and all("cannot get within the task's tolerances (5 mm, 2 deg)" in e
                          for e in errors)
    first = float(re.search(r"the part ([0-9]+) cm along the conveyor", errors[0])[1]) / 100
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    part_xy = points[-1] + [first - length, 0.0]
    r7 = cell.robot("R7AX")
    track_end = r7.T_base_robot[:3, :3] @ [0, 0, r7.chain.qlim[0, 1]] + r7.T_base_robot[:3, 3]
    assert first > length and np.linalg.norm(part_xy - track_end[:2]) > 0.5


def test_a_grasp_at_mid_height_touching_the_conveyor_is_a_warning(cell):
    """The grasp 3 mm lower, at the part's mid-height: the jaws' tips on the conveyor (a
    collision each time in a world of MuJoCo's actuators)."""
    part = cell.workpieces[0]
    T = part.T_part_grasp.copy()
    T[2, 3] -= 0.003
    findings = check_cell(_with(cell, workpieces=[replace(part, T_part_grasp=T)]))
    warned = [f.line for f in findings if f.level != "ok"]
    assert len(warned) == 1 and "gripper.jaw" in warned[0] and "into conveyor by" in warned[0]
    assert float(re.search(r"by ([0-9.]+) mm", warned[0])[1]) <= 0.05, warned


def test_a_grasp_into_the_conveyor_is_found(cell):
    """The grasp 2 cm below mid-height: the jaws would go 2 cm into the conveyor at every
    grasp, more than the task's 5 mm tolerance."""
    part = cell.workpieces[0]
    T = part.T_part_grasp.copy()
    T[2, 3] -= 0.023
    errors = _errors(_with(cell, workpieces=[replace(part, T_part_grasp=T)]))
    deep = [e for e in errors if "into conveyor" in e]
    assert len(deep) == 1 and "contacts push the arm back; raise the grasp" in deep[0]
    depth = float(re.search(r"by ([0-9.]+) mm", deep[0])[1])
    assert 19.5 <= depth <= 20.5


def test_a_robot_in_inches_is_found(cell):
    r6 = cell.robot("R6AX")
    links = [replace(k, a=k.a * 25.4, d=k.d * 25.4) for k in r6.chain.links]
    errors = _errors(_robot(cell, "R6AX", chain=DHChain(links, r6.chain.name)))
    units = [e for e in errors if "robot R6AX: reaches" in e]
    assert len(units) == 1 and "inches (x 39.3701)" in units[0]


def test_home_on_a_limit_is_found(cell):
    r7 = cell.robot("R7AX")
    home = r7.home.copy()
    home[3] = r7.chain.qlim[3, 1]
    errors = _errors(_robot(cell, "R7AX", home=home))
    assert errors[0] == (f"robot R7AX: HOME: joint 4 = {home[3]:.6g} is on its limit "
                         f"[{r7.chain.qlim[3, 0]:.6g}, {r7.chain.qlim[3, 1]:.6g}]")
    # the arm so turned also takes the held part out of camera 1's view: said too
    assert all("held at R7AX's HOME" in e for e in errors[1:])


def test_final_holding_the_part_out_of_view_is_found(cell):
    r7 = cell.robot("R7AX")
    final = r7.final.copy()
    final[0] -= 0.9  # the track carries the held part far aside
    errors = _errors(_robot(cell, "R7AX", final=final))
    assert errors and all("part held at R7AX's FINAL" in e and "px out of" in e
                          for e in errors)


def test_a_crossing_that_blinds_nothing_is_found(cell):
    r6 = cell.robot("R6AX")
    still = tuple((t, r6.home.copy()) for t, _ in cell.experiments.crossing_waypoints)
    errors = _errors(_with(cell, experiments=replace(cell.experiments,
                                                     crossing_waypoints=still)))
    assert len(errors) == 1 and errors[0].startswith("experiment 3: R6AX's crossing blinds no")


def test_a_part_in_millimetres_is_found(cell):
    part = cell.workpieces[0]
    solid = replace(part.solid, vertices=part.solid.vertices * 1000.0)
    errors = [e for e in _errors(_with(cell, workpieces=[replace(part, solid=solid)]))
              if "workpiece" in e]
    assert len(errors) == 1 and "millimetres (x 1000)" in errors[0]


def test_the_command_prints_one_line_per_problem_and_fails(tmp_path, capsys):
    assert main(["check"]) == 0
    out = capsys.readouterr().out
    assert "0 error(s), 0 warning(s)" in out and out.count("ok ") >= 10
    text = Path(load_cell().source).read_text()
    home = "home: [0.499, -0.051, 0.259, 0.65, 0.0, 0.664, -0.051]"
    assert home in text
    broken = tmp_path / "cell.yaml"
    broken.write_text(text.replace(home, "home: [0.499, -0.051, 0.259, 0.65, 0.0, 0.664, 4.7]"))
    assert main(["check", "--cell", str(broken), "--quiet"]) == 1
    lines = capsys.readouterr().out.strip().splitlines()
    # HOME's wrist on its limit: the arm cannot turn the held part to FINAL from there either
    assert len(lines) == 3 and "HOME: joint 7 = 4.7 is on its limit" in lines[0]
    assert "FINAL's TCP pose holding the part" in lines[1]
    assert lines[2].endswith("2 error(s), 0 warning(s)")


def test_a_crossing_into_the_other_robot_is_found(cell):
    """R6AX's base moved 0.5 m towards R7AX: its crossing runs into R7AX's arm (MuJoCo's
    distance between their solids below zero)."""
    T = cell.robot("R6AX").T_base_robot.copy()
    T[1, 3] -= 0.5
    errors = _errors(_robot(cell, "R6AX", T_base_robot=T))
    near = [e for e in errors if "keeps" in e]
    assert len(near) == 1 and "closest: R7AX." in near[0] and near[0].endswith("under 5 cm")
    assert float(near[0].split("keeps ")[1].split(" cm")[0]) < 2.0


def test_a_gripper_inside_the_wrist_is_found():
    """The KR16's gripper mounted 65.5 mm short of the flange (a URDF whose flange link sits at
    the wrist centre, the tutorial's first user met one): a warning naming the mount."""
    cell = load_cell("kr16-cell")
    robot = cell.robot("KR16A")
    short = robot.tool.T_flange_tool.copy()
    short[:3, 3] -= 0.0655 * short[:3, 2]
    moved = _robot(cell, "KR16A", tool=replace(robot.tool, T_flange_tool=short))
    warnings = [f.line for f in check_cell(moved, crossing=False)
                if f.level == "warning" and not f.line.startswith("reach: ")]
    assert len(warnings) == 1 and warnings[0].startswith("robot KR16A: link_6 reaches 66 mm past")
    assert "tool.mount" in warnings[0]


def test_a_base_in_mid_air_is_found(cell):
    """R6AX's base lifted 30 cm off what it stands on: a warning naming the robot and the gap;
    lifted 1 cm (within SUPPORT_M), nothing."""
    for lift, warned in ((0.30, True), (0.01, False)):
        T = cell.robot("R6AX").T_base_robot.copy()
        T[2, 3] += lift
        lines = [f.line for f in check_cell(_robot(cell, "R6AX", T_base_robot=T),
                                            crossing=False)
                 if f.level == "warning" and "stands on nothing" in f.line]
        assert bool(lines) == warned, lines
        if warned:
            assert len(lines) == 1 and lines[0].startswith("robot R6AX: its base stands on")
            assert "bottom is 30.0 cm above" in lines[0]


def test_a_second_robot_whose_home_hides_the_part_is_found(cell):
    # R6AX's HOME moved to its crossing pose over cam2's line of sight: experiments 1 and 2
    # would run with cam2 blinded throughout
    _, q_block = cell.experiments.crossing_waypoints[2]
    blocking = _robot(cell, "R6AX", home=q_block)
    warned = [f.line for f in check_cell(blocking, crossing=False)
              if f.level == "warning" and "at HOME hides" in f.line]
    assert len(warned) == 1 and warned[0].startswith("R6AX at HOME hides features from cam2: ")
    assert "with the part at its start" in warned[0]
    assert not [f for f in check_cell(cell, crossing=False) if f.level != "ok"
                and "at HOME hides" in f.line]

"""The built-in ur-cell (issue 11): two UR5 from example-robot-data, three cameras; built-in cells
by name (``load_cell("ur-cell")``, ``--cell ur-cell``, ``cellsight cells``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.cli import main
from cellsight.control.clik import Clik
from cellsight.errors import CellFileError
from cellsight.experiments.scenario import scenario
from cellsight.model.loader import BUILTIN_CELLS, builtin_cell_path
from cellsight.occlusion.backends import visibility_predictor
from cellsight.world.paths import JointTask
from cellsight.world.world import World

GRASP_T = 11.5  # about when UR5A grasps the part (README: approach 4-11.5 s)
LIFT = 0.10  # GraspTask's lift height
CLEARANCE = 0.05  # least distance between UR5B and UR5A or the part (m)


@pytest.fixture(scope="module")
def cell():
    return load_cell("ur-cell")


@pytest.fixture(scope="module")
def exp3(cell):
    return scenario(cell, 3)


def test_ur_cell_loads_by_name(cell):
    assert [r.name for r in cell.robots] == ["UR5A", "UR5B"]
    assert [c.name for c in cell.cameras] == ["cam1", "cam2", "cam3"]
    assert all((c.width, c.height) == (768, 576) for c in cell.cameras)
    assert cell.experiments.robot == "UR5A" and cell.experiments.crossing_robot == "UR5B"
    assert cell.source == str(builtin_cell_path("ur-cell"))
    assert load_cell("dual-arm").source == load_cell().source == str(builtin_cell_path())
    names = r"built-in cell \(dual-arm, ur-cell, kr16-cell, iiwa-cell, line-cell\)"
    with pytest.raises(CellFileError, match=names):
        load_cell("no-such-cell")


def test_cells_command_lists_both(capsys):
    assert main(["cells"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == list(BUILTIN_CELLS) == [
        "dual-arm", "ur-cell", "kr16-cell", "iiwa-cell", "line-cell"]
    assert "UR5A, UR5B" in lines[1] and "cam1, cam2, cam3" in lines[1]
    assert "R7AX, R6AX" in lines[0] and "dual_arm_cell.yaml" in lines[0]
    assert main(["visibility", "--cell", "ur-cell", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) >= {"part"}
    assert main(["visibility", "--cell", "nope"]) == 2
    assert "dual-arm, ur-cell, kr16-cell, iiwa-cell" in capsys.readouterr().err


def test_home_and_final_hold_the_part_in_every_view(cell):
    """HOME: the held part 17 cm over the conveyor's near edge; FINAL: on the table; in
    both, every camera sees at least 6 of its points; the still part too."""
    robot, part = cell.robot("UR5A"), cell.workpiece("part")
    predictor = visibility_predictor(cell)
    for q, z in ((robot.home, 0.62 + 0.167), (robot.final, 0.55)):
        robot.chain.check_q(q, check_limits=True)
        T_part = robot.tcp_pose(q) @ np.linalg.inv(part.T_part_grasp)
        assert T_part[2, 3] == pytest.approx(z, abs=2e-3)
        views = predictor.predict({"UR5A": q}, {"part": T_part}, {"UR5A": 0.04})["part"]
        assert min(v.count for v in views) >= 6, [v.count for v in views]
    views = predictor.predict({}, {}, {})["part"]
    assert min(v.count for v in views) >= 10


def _part_pose(exp3, t: float) -> np.ndarray:
    """The part on the conveyor until about the grasp, lifted by UR5A from 19.5 s to 22.5 s."""
    T = exp3.workpiece.T_base_part.copy()
    T[:2, 3] = exp3.conveyor.position(min(t, GRASP_T))
    T[2, 3] += LIFT * np.clip((t - 19.5) / 3.0, 0.0, 1.0)
    return T


def test_crossing_hides_the_part_during_approach_and_manipulate(cell, exp3):
    """The predictor along UR5B's waypoints: UR5B hides points from some camera during the
    approach and grasp, and again while UR5A lifts the part; never from every camera."""
    task = JointTask(cell.robot("UR5B").home, exp3.tasks["UR5B"])
    predictor = visibility_predictor(cell)
    hidden_at = []
    for t in np.arange(6.0, 27.0, 0.5):
        views = predictor.predict({"UR5B": task.at(t)}, {"part": _part_pose(exp3, t)},
                                  {"UR5A": 0.09})["part"]
        by_b = [sum(r.startswith("UR5B.") for r in v.reason) for v in views]
        assert min(by_b) == 0  # some camera always clear of UR5B
        if max(by_b) >= 8:
            hidden_at.append(t)
    assert any(8.0 < t < GRASP_T for t in hidden_at), hidden_at
    assert any(19.5 < t < 23.0 for t in hidden_at), hidden_at


def _ur5a_poses(cell, exp3) -> list[tuple[np.ndarray, np.ndarray]]:
    """UR5A's joints (from the CLIK) and the part's pose at the moments UR5A is nearest to
    UR5B's path: HOME, 5 cm over the part, grasping it, lifting it."""
    robot, part = cell.robot("UR5A"), exp3.workpiece
    clik, q = Clik(robot, redundancy="none"), robot.home.copy()
    poses = [(robot.home, robot.tcp_pose(robot.home) @ np.linalg.inv(part.T_part_grasp))]
    for t, up in ((8.0, 0.05), (GRASP_T, 0.0), (21.0, 0.0), (22.5, 0.0)):
        T_part = _part_pose(exp3, t)
        T_goal = T_part @ part.T_part_grasp
        T_goal[2, 3] += up
        for _ in range(1500):
            q = clik.step(q, T_goal)
        assert np.linalg.norm(robot.tcp_pose(q)[:3, 3] - T_goal[:3, 3]) < 1e-3
        poses.append((q.copy(), T_part))
    return poses


def test_crossing_keeps_clear_of_the_grasping_arm_and_the_part(cell, exp3):
    """MuJoCo's geom distances between UR5B and (UR5A, its gripper, the part) along UR5B's
    waypoints every 0.25 s, against UR5A at each of its poses near UR5B's path: >= 5 cm."""
    import mujoco  # after cellsight.world, which sets MuJoCo's GL backend

    world = World(cell)
    m, d = world.scene.model, world.scene.data
    names = [m.geom(i).name for i in range(m.ngeom)]
    mine = [i for i, n in enumerate(names) if n.startswith("UR5B.")]
    others = [i for i, n in enumerate(names) if n.startswith("UR5A.") or n == "part"]
    task = JointTask(cell.robot("UR5B").home, exp3.tasks["UR5B"])
    fromto, least = np.zeros(6), np.inf
    for qa, T_part in _ur5a_poses(cell, exp3):
        for t in np.arange(0.0, 27.0, 0.25):
            world.step({"UR5A": qa, "UR5B": task.at(t)}, {})
            world.place_part("part", T_part)
            world.scene.sync()
            least = min(least, min(mujoco.mj_geomDistance(m, d, i, j, 1.0, fromto)
                                   for i in mine for j in others))
    world.close()
    assert least >= CLEARANCE, least


def test_short_ideal_run_acquires_the_part(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "1", "--cell", "ur-cell", "--sensor", "ideal", "--duration", "2",
                 "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cell"].endswith("ur_cell.yaml") and metrics["cameras"] == ["cam1", "cam2",
                                                                               "cam3"]
    assert metrics["first_estimate_s"] is not None and metrics["first_estimate_s"] < 1.0
    assert metrics["lost_in_view_s"] == 0.0
    assert metrics["position_rmse_mm"] < 1.0

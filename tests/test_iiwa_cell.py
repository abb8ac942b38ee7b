"""The built-in iiwa-cell: two KUKA LBR iiwa 14 R820 (7 axes) from rtb-data (URDF, collision
meshes), three cameras, a conveyor; loaded by name (``load_cell("iiwa-cell")``,
``--cell iiwa-cell``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.cli import main
from cellsight.model.loader import builtin_cell_path


@pytest.fixture(scope="module")
def cell():
    return load_cell("iiwa-cell")


def test_iiwa_cell_loads_by_name(cell):
    assert [r.name for r in cell.robots] == ["IIWA_A", "IIWA_B"]
    assert [c.name for c in cell.cameras] == ["cam1", "cam2", "cam3"]
    assert all((c.width, c.height) == (768, 576) for c in cell.cameras)
    assert cell.experiments.robot == "IIWA_A" and cell.experiments.crossing_robot == "IIWA_B"
    assert cell.source == str(builtin_cell_path("iiwa-cell"))
    robot = cell.robot("IIWA_A")
    assert robot.chain.n == 7  # joint_a1 .. joint_a7
    assert cell.robot("IIWA_B").chain.n == 7
    # HOME holds the part 17 cm over the conveyor's near edge, FINAL on the table, both
    # at least 25 deg inside every joint's limits
    part = cell.workpiece("part")
    qlim = robot.chain.qlim
    for q, z in ((robot.home, 0.62 + 0.167), (robot.final, 0.55)):
        robot.chain.check_q(q, check_limits=True)
        assert np.degrees(np.minimum(q - qlim[:, 0], qlim[:, 1] - q)).min() > 25.0
        T_part = robot.tcp_pose(q) @ np.linalg.inv(part.T_part_grasp)
        assert T_part[2, 3] == pytest.approx(z, abs=2e-3)


def test_short_ideal_run_acquires_the_part(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "1", "--cell", "iiwa-cell", "--sensor", "ideal", "--duration", "2",
                 "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cell"].endswith("iiwa_cell.yaml")
    assert metrics["cameras"] == ["cam1", "cam2", "cam3"]
    assert metrics["first_estimate_s"] is not None and metrics["first_estimate_s"] < 1.0
    assert metrics["lost_in_view_s"] == 0.0
    assert metrics["position_rmse_mm"] < 1.0

"""``cellsight design-crossing`` (cellsight.experiments.crossing_design) on the built-in cell and
the tutorial's kr16-cell: the paper's pattern asked for (camera 2 blind during the approach and
grasp, camera 1 during the lift) is what experiment 3 then shows in the simulator's own ray
casts, and the crossing robot keeps 10 cm from the other robot and the part along the run
(MuJoCo's distances)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.experiments import RunConfig, run_experiment
from cellsight.experiments.cellcheck import check_cell
from cellsight.experiments.crossing_design import Block, design_crossing
from cellsight.experiments.task_path import TaskPath
from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.runfolder import FrameLog
from cellsight.world import ReplayWorld

CASES = {
    "dual-arm": ("R7AX", "R6AX", [Block("cam2", 8.5, 15.0), Block("cam1", 20.0, 22.5)]),
    "kr16-cell": ("KR16A", "KR16B", [Block("cam2", 9.5, 15.0), Block("cam1", 21.0, 22.5)]),
}
pytestmark = pytest.mark.slow  # four runs of the task


@pytest.fixture(scope="module", params=list(CASES))
def designed(request, tmp_path_factory):
    name = request.param
    grasping, crossing, blocks = CASES[name]
    cell = load_cell(name)
    folder = tmp_path_factory.mktemp(f"design-{name}")
    # the blocks end by 22.5 s: the runs stop at 26 s, past the crossing's last waypoint
    run_experiment(RunConfig(2, folder / "e2", cell=name, sensor="ideal", duration=26.0,
                             progress=False, video_every=0))
    design = design_crossing(cell, blocks, TaskPath(folder / "e2"))
    cell_file = folder / "crossed.yaml"
    text = Path(cell.source).read_text()
    section = re.search(r"^  crossing:\n(?:(?:    .*)?\n?)*", text, flags=re.MULTILINE)
    cell_file.write_text(text[:section.start()] + design.yaml(crossing) + "\n"
                         + text[section.end():])
    crossed = load_cell(cell_file)
    assert crossed.experiments.crossing_waypoints[1][0] == pytest.approx(design.waypoints[1][0],
                                                                         abs=0.01)
    run_experiment(RunConfig(3, folder / "e3", cell=cell_file, sensor="ideal", duration=26.0,
                             progress=False, video_every=0))
    return design, crossed, folder / "e3", CASES[name]


def test_the_cameras_are_blind_when_asked_in_the_simulators_truth(designed):
    design, _, run, (_, crossing, blocks) = designed
    log = FrameLog.read(run / "frames.csv")
    t = log.floats("t")
    for block, most in zip(blocks, (2, 0), strict=True):
        c = int(block.camera[-1])
        during = (t >= block.t0) & (t <= block.t1)
        seen = log.bits(f"vis_true_c{c}")[during].sum(axis=1)
        assert during.sum() > 20 and seen.max() <= most, (block, seen.max())
    metrics = json.loads((run / "metrics.json").read_text())
    # the crossing touches nothing; the grasping robot's own approach may graze the conveyor
    # (2.3 mm at 10.9 s with one noise draw of the ideal sensor, none with another: the
    # grasp's clearance over the conveyor is a fraction of a millimetre), which is not the
    # design's doing
    touched = [c["bodies"] for c in metrics["collisions"]
               if any(b.startswith(f"{crossing}.") for b in c["bodies"])]
    assert metrics["grasp_success"] and not touched, touched
    assert design.yaml(crossing).startswith(f"  crossing:\n    robot: {crossing}")
    # where it blinds a camera outside the blocks: named, outside that camera's blocks (1 s)
    for cam, t0, t1 in design.elsewhere:
        assert t0 <= t1 and not any(b.camera == cam and b.t0 - 1 <= t0 <= b.t1 + 1
                                    for b in blocks)
    assert design.elsewhere_s == pytest.approx(sum(t1 - t0 + 0.2 for _, t0, t1 in
                                                   design.elsewhere), abs=1e-9)


def _least_distance_along(crossed, run: Path, grasping: str, crossing: str) -> float:
    """The crossing robot's least distance (m) to the grasping robot and the part over a run's
    logged states (every third frame), straight from MuJoCo."""
    import mujoco  # after cellsight.world, which chooses MuJoCo's OpenGL back-end

    log = FrameLog.read(run / "frames.csv")
    world = ReplayWorld(crossed)
    m, d = world.scene.model, world.scene.data
    names = [m.geom(g).name for g in range(m.ngeom)]
    mine = [g for g, n in enumerate(names) if n.startswith(f"{crossing}.")]
    others = [g for g, n in enumerate(names) if n.startswith(f"{grasping}.") or n == "part"]
    joints = {r: log.joints(r) for r in (grasping, crossing)}
    part = log.poses("true")
    fromto, least = np.zeros(6), np.inf
    for k in range(0, log.n, 3):
        world.show_state({r: q[k] for r, q in joints.items()},
                         {"part": pose_from_xyz_rpy(part[k, :3], part[k, 3:])})
        least = min(least, min(mujoco.mj_geomDistance(m, d, i, j, 1.0, fromto)
                               for i in mine for j in others))
    world.close()
    return least


def test_the_crossing_keeps_ten_centimetres_along_the_run(designed):
    design, crossed, run, (grasping, crossing, _) = designed
    least = _least_distance_along(crossed, run, grasping, crossing)
    assert least >= 0.10 and design.clearance_m >= 0.10


def test_check_along_the_task_finds_the_runs_clearance(designed):
    """``cellsight check --path RUN`` puts the part and the grasping robot where the run had
    them: its clearance is the run's (within the two samplings, 0.2 s against 3 frames)."""
    _, crossed, run, (grasping, crossing, _) = designed
    line = next(f.line for f in check_cell(crossed, path=TaskPath(run)) if "keeps" in f.line)
    assert line.startswith(f"experiment 3 (along the task): {crossing} keeps ")
    found = float(re.search(r"keeps ([0-9.]+) cm", line)[1]) / 100
    least = _least_distance_along(crossed, run, grasping, crossing)
    assert abs(found - least) <= 0.01, (found, least)

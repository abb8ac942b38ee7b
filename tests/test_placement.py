"""Camera placement (issue 15): candidates on the shell, the scoring's visibility against the
segment oracle, its pose information against finite differences of OpenCV's projection, the
choice's local optimality, the cell file, and ``cellsight place-cameras`` end to end."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest
from oracle import cell_scene, segment_oracle

from cellsight.camera import Camera
from cellsight.cli import main
from cellsight.model.loader import load_cell
from cellsight.placement.candidates import Shell, shell_candidates, work_area
from cellsight.placement.cellfile import write_cell_file
from cellsight.placement.choose import choose_cameras, placement_loss, position_sigma_mm
from cellsight.placement.scoring import CandidateScores, score_candidates
from cellsight.placement.task import TaskFrames

SIGMA_PX = 0.5


@pytest.fixture(scope="module")
def cell():
    return load_cell(None)


@pytest.fixture(scope="module")
def task(cell):
    """12 frames: the robots near HOME, the part slid along the conveyor and turned."""
    rng = np.random.default_rng(3)
    part = cell.workpieces[0]
    n = 12
    joints = {}
    for robot in cell.robots:
        lim = robot.chain.qlim
        q = robot.home + rng.normal(0.0, 0.15, (n, robot.n_joints))
        joints[robot.name] = np.clip(q, lim[:, 0], lim[:, 1])
    poses = np.repeat(part.T_base_part[None], n, axis=0)
    poses[:, 0, 3] += np.linspace(-0.2, 0.2, n)
    c, s = np.cos(np.linspace(0, 1, n)), np.sin(np.linspace(0, 1, n))
    turn = np.zeros((n, 3, 3))
    turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1], turn[:, 2, 2] = c, -s, s, c, 1
    poses[:, :3, :3] = turn @ poses[:, :3, :3]
    return TaskFrames(np.arange(n) / 26.0, np.array(["approach"] * n, dtype=object), joints,
                      part.name, poses, {}, cell.source, Path("."))


@pytest.fixture(scope="module")
def candidates(cell, task):
    return shell_candidates(cell, task, cell.cameras[0],
                            Shell(radii=(1.5, 1.9), elevations=(25, 50, 75), azimuth_step=30.0))


@pytest.fixture(scope="module")
def scores(cell, task, candidates):
    return score_candidates(cell, task, candidates, SIGMA_PX, chunk=5, progress=False)


def test_candidates_sit_on_the_shell_and_look_at_the_work_area(cell, task, candidates):
    lo, hi = work_area(task)
    target = 0.5 * (lo + hi)
    assert 20 <= len(candidates) < 2 * 3 * 12
    for cam in candidates:
        offset = cam.center - target
        assert min(abs(np.linalg.norm(offset) - r) for r in (1.5, 1.9)) < 1e-9
        axis = cam.T_base_cam[:3, 2]
        assert np.allclose(axis, -offset / np.linalg.norm(offset), atol=1e-9)
        assert abs(cam.T_base_cam[2, 0]) < 1e-9  # image x horizontal
        assert np.array_equal(cam.K, cell.cameras[0].K)


def test_scoring_sees_what_the_segment_oracle_sees(cell, task, candidates, scores):
    checked = hidden = 0
    for k in (0, 5, 11):
        snapshot = cell.snapshot(*task.state(k))
        polygons, _, features = cell_scene(cell, snapshot, task.part)
        for c in range(0, len(candidates), 4):
            cam = candidates[c]
            inside = cam.sees(features)
            oracle = segment_oracle(polygons, features, cam.center, 2e-3, prune=True)
            sure = inside & ~oracle.ambiguous
            assert np.array_equal(scores.visible[k, c][sure], oracle.visible[sure])
            assert not scores.visible[k, c][~inside].any()
            checked += int(sure.sum())
            hidden += int((sure & ~oracle.visible).sum())
    assert checked > 300 and hidden > 30


def _projected(cam, points):
    rvec, _ = cv2.Rodrigues(cam.T_cam_base[:3, :3])
    px, _ = cv2.projectPoints(points, rvec, cam.T_cam_base[:3, 3], cam.K, np.zeros(5))
    return px.reshape(-1, 2)


def test_information_is_the_finite_difference_jacobian_of_opencv_projection(
        cell, task, candidates, scores):
    part = cell.workpiece(task.part)
    k = 7
    T = task.part_poses[k]
    for c in (0, len(candidates) // 3, len(candidates) - 1):
        vis = scores.visible[k, c]
        if vis.sum() < 3:
            continue
        cam = candidates[c]
        points = part.feature_points[vis] @ T[:3, :3].T + T[:3, 3]
        jac = np.zeros((2 * len(points), 6))
        h = 1e-6
        for i in range(6):
            d = np.zeros(6)
            d[i] = h
            moved = (points - T[:3, 3]) @ cv2.Rodrigues(d[3:])[0].T + T[:3, 3] + d[:3]
            back = (points - T[:3, 3]) @ cv2.Rodrigues(-d[3:])[0].T + T[:3, 3] - d[:3]
            jac[:, i] = ((_projected(cam, moved) - _projected(cam, back)) / (2 * h)).ravel()
        expected = jac.T @ jac / SIGMA_PX**2
        assert np.allclose(scores.info[k, c], expected, rtol=2e-3, atol=1e-3 * expected.max())


def test_choice_cannot_be_bettered_by_one_exchange_and_beats_a_random_pair(scores):
    placement = choose_cameras(scores, 2)
    C = len(scores.cameras)
    for i in range(2):
        for other in range(C):
            trial = list(placement.chosen)
            if other in trial:
                continue
            trial[i] = other
            assert placement_loss(scores, trial).loss >= placement.loss - 1e-9
    losses = [placement_loss(scores, pair).loss for pair in itertools.combinations(range(C), 2)]
    assert placement.loss <= np.percentile(losses, 5)


def test_sigma_falls_as_cameras_add_information(scores):
    one = placement_loss(scores, [0]).sigma_mm
    two = placement_loss(scores, [0, 1]).sigma_mm
    assert np.all(two <= one + 1e-9)
    assert np.allclose(position_sigma_mm(np.zeros((1, 6, 6))), 1e3 * np.sqrt(3) * 0.1)


def test_cell_file_holds_the_chosen_cameras(cell, candidates, tmp_path):
    chosen = [candidates[1], candidates[-2]]
    loaded = load_cell(write_cell_file(cell.source, chosen, tmp_path / "cell.yaml"))
    assert [c.name for c in loaded.cameras] == ["cam1", "cam2"]
    for got, want in zip(loaded.cameras, chosen, strict=True):
        assert np.allclose(got.T_base_cam, want.T_base_cam, atol=1e-6)
        assert np.array_equal(got.K, want.K)
    assert [r.name for r in loaded.robots] == [r.name for r in cell.robots]


def test_scores_refuse_mixed_lenses(cell, task, candidates):
    first = candidates[0]
    other = Camera(first.K * [[0.9], [0.9], [1]], first.width, first.height,
                   first.T_base_cam, name="shorter lens")
    with pytest.raises(ValueError, match="intrinsics"):
        score_candidates(cell, task, [candidates[0], other], progress=False)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    """A second of experiment 3 (ideal sensor): a task with the joint columns."""
    run = tmp_path_factory.mktemp("placement") / "run"
    assert main(["run", "3", "--sensor", "ideal", "--duration", "1.0", "--out", str(run),
                 "--quiet"]) == 0
    return run


def test_place_cameras_command_writes_cell_and_report(short_run, tmp_path):
    out = tmp_path / "placement"
    assert main(["place-cameras", "--task", str(short_run), "--out", str(out), "--cameras", "2",
                 "--radii", "1.6", "--elevations", "30", "60", "--azimuth-step", "45",
                 "--quiet"]) == 0
    placed = load_cell(out / "cell.yaml")
    assert len(placed.cameras) == 2
    report = (out / "report.md").read_text()
    assert "chosen" in report and "cell's cameras" in report
    assert (out / "fig_task.png").stat().st_size > 10_000


@pytest.mark.parametrize("args, needle", [
    (["--task", "nowhere"], "--task"),
    (["--task", "{run}", "--cameras", "0"], "--cameras"),
    (["--task", "{run}", "--template", "cam9"], "--template"),
    (["--task", "3", "--verify-sensors", "lidar"], "--verify-sensors"),
    (["--task", "3", "--elevations", "95"], "--elevations"),
    (["--task", "3", "--every", "0"], "--every")])
def test_place_cameras_bad_input_is_one_clear_line(short_run, tmp_path, capsys, args, needle):
    args = [a.replace("{run}", str(short_run)) for a in args]
    status = main(["place-cameras", "--out", str(tmp_path), "--quiet", *args])
    assert status == 2
    assert needle in capsys.readouterr().err


def test_scores_are_the_same_in_chunks_and_whole(cell, task, candidates, scores):
    whole = score_candidates(cell, task, candidates[:5], SIGMA_PX, chunk=100, progress=False)
    assert isinstance(whole, CandidateScores)
    assert np.array_equal(whole.visible, scores.visible[:, :5])
    assert np.allclose(whole.info, scores.info[:, :5])

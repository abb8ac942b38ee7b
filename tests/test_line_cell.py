"""The built-in line cell: several parts on the conveyor, picked in turn, each logged and scored.

Oracles: the conveyor paths' own positions (the belt keeps the parts' spacing), the world's
truth read from MuJoCo, the cell file's names, and distances computed by hand for the swaps.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight.control.sequence import PickSequence
from cellsight.control.task import Phase
from cellsight.errors import CellFileError, CellsightError
from cellsight.experiments import RunConfig, scenario
from cellsight.experiments.cellcheck import check_cell
from cellsight.experiments.runner import ExperimentRun, run_experiment
from cellsight.experiments.scenario import place_pose
from cellsight.experiments.simulated import pick_task
from cellsight.model.loader import builtin_cell_path, load_cell
from cellsight.realism.draws import ScenarioShift
from cellsight.runfolder.framelog import FrameLog
from cellsight.runfolder.picks import identity_swaps, part_log_name
from cellsight.sweep.grid import RunSpec, SweepAxes, sweep_grid
from cellsight.sweep.lines import lines_markdown, passing_markdown, passing_summary, pick_summary
from cellsight.world import World

PICKS = ["u1", "l1", "u2", "l2"]
PASSING = ["u3", "l3"]


@pytest.fixture(scope="module")
def cell():
    return load_cell("line-cell")


def _variant(tmp_path: Path, **experiments) -> Path:
    """The line cell's file with its ``experiments`` section changed."""
    data = yaml.safe_load(builtin_cell_path("line-cell").read_text())
    data["experiments"].update(experiments)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_line_cell_picks_four_parts_of_two_shapes_seen_by_six_cameras(cell):
    assert [p.name for p in cell.picked_workpieces()] == PICKS
    assert {len(p.feature_points) for p in cell.picked_workpieces()} == {16, 12}
    assert len(cell.cameras) == 6 and len(cell.robots) == 2
    findings = check_cell(cell)
    assert not [f.line for f in findings if f.level == "error"]


@pytest.mark.parametrize("picks, field, expected", [
    (["u1", "nope"], r"experiments\.picks\[1\]': got 'nope'", "one of the workpieces"),
    (["u1", "l1", "u1"], r"experiments\.picks\[2\]': got 'u1'", "not picked before"),
    ([], r"experiments\.picks': got \[\]", "at least one"),
])
def test_a_wrong_pick_is_refused_naming_the_field_and_value(tmp_path, picks, field, expected):
    with pytest.raises(CellFileError, match=field) as info:
        load_cell(_variant(tmp_path, picks=picks))
    assert expected in str(info.value) and "cell.yaml" in str(info.value)


def test_picks_and_a_workpiece_together_are_refused(tmp_path):
    with pytest.raises(CellFileError, match=r"experiments\.picks.*not both"):
        load_cell(_variant(tmp_path, workpiece="u1"))


@settings(max_examples=25, deadline=None)
@given(turn=st.floats(-0.3, 0.3), scale=st.floats(0.5, 1.5),
       shifts=st.lists(st.tuples(st.floats(-0.01, 0.01), st.floats(-0.01, 0.01)),
                       min_size=4, max_size=4),
       t=st.floats(0.0, 60.0))
def test_the_belt_carries_every_pick_keeping_its_place(cell, turn, scale, shifts, t):
    """Each pick's path is the first's moved by the turned nominal gap and the difference of
    the seed's start shifts: the same speed, the same places, at every time."""
    part_shifts = {name: np.array(s) for name, s in zip(PICKS, shifts, strict=True)}
    shift = ScenarioShift(shift=part_shifts["u1"], speed_scale=scale, turn=turn,
                          part_shifts=part_shifts)
    sc = scenario(cell, 2, shift)
    assert [c.workpiece for c in sc.conveyors] == PICKS + PASSING
    c, s = np.cos(turn), np.sin(turn)
    first = cell.workpiece("u1").T_base_part[:2, 3]
    for path, name in zip(sc.conveyors[:4], PICKS, strict=True):
        gap = (cell.workpiece(name).T_base_part[:2, 3] - first) @ np.array([[c, s], [-s, c]])
        expected = gap + part_shifts[name] - part_shifts["u1"]
        np.testing.assert_allclose(path.position(t) - sc.conveyors[0].position(t), expected,
                                   atol=1e-12)
        assert path.speed == sc.conveyors[0].speed == pytest.approx(0.01 * scale)


@pytest.mark.parametrize("experiment", [2, 3])
def test_the_passing_parts_enter_the_views_from_upstream_and_leave_them_downstream(
        cell, experiment):
    """Each passing part starts with none of its feature points in any camera's image, has
    every one of them in some camera's image half way, and none at the end of its travel; the
    picks stay as they were. Oracle: the cameras' own projection (``Camera.sees``)."""
    sc = scenario(cell, experiment)
    assert [p.name for p in sc.passing] == PASSING and [p.name for p in sc.picks] == PICKS
    for path in sc.conveyors[4:]:
        part = cell.workpiece(path.workpiece)
        end = path.t_start + path.length / path.speed

        def seen(t, part=part, path=path):
            T = part.T_base_part.copy()
            T[:2, 3] = path.position(t)
            points = part.feature_points @ T[:3, :3].T + T[:3, 3]
            return np.array([cam.sees(points) for cam in cell.cameras]).any(axis=0)

        assert not seen(0.0).any() and not seen(end).any()
        assert seen(0.5 * (path.t_start + end)).all()
    assert scenario(cell, 1).passing == ()


@pytest.mark.parametrize("passing, field, expected", [
    ({"parts": ["u1"]}, r"passing\.parts\[0\]': got 'u1'", "does not pick"),
    ({"parts": ["u3", "u3"]}, r"passing\.parts\[1\]': got 'u3'", "not listed before"),
    ({"parts": ["nope"]}, r"passing\.parts\[0\]': got 'nope'", "one of the workpieces"),
    ({"parts": ["u3"], "travel": [0.0, 0.0]}, r"travel", "at least"),
])
def test_a_wrong_passing_part_is_refused_naming_the_field_and_value(tmp_path, passing, field,
                                                                  expected):
    spec = {"travel": [2.0, 0.0], "speed": 0.03, **passing}
    with pytest.raises(CellFileError, match=field) as info:
        load_cell(_variant(tmp_path, passing=spec))
    assert expected in str(info.value) and "cell.yaml" in str(info.value)


def test_experiment_1_leaves_the_parts_still_and_the_world_moves_them_in_2(cell):
    assert scenario(cell, 1).conveyors == ()
    sc = scenario(cell, 2)
    world = World(cell, conveyor=sc.conveyors)
    start = world.true_part_poses()
    while world.time < 3.0:
        world.step({}, {})
    now = world.true_part_poses()
    for path in sc.conveyors:
        np.testing.assert_allclose(now[path.workpiece][:2, 3], path.position(world.time),
                                   atol=1e-9)
        np.testing.assert_allclose(now[path.workpiece][2, 3], start[path.workpiece][2, 3])
    moved = [now[n][:2, 3] - start[n][:2, 3] for n in PICKS]
    assert np.linalg.norm(moved[0]) == pytest.approx(0.03, abs=1e-3)
    np.testing.assert_allclose(moved, [moved[0]] * 4, atol=1e-12)


class _Task:
    """A stand-in grasping task: done once told so (the sequence's own logic is tested)."""

    def __init__(self, part):
        self.part, self.phase, self.stage = part, Phase.WAITING, "start"
        self.attempts, self.transitions, self.events = 1, [], []
        self.servo = type("Servo", (), {"t0": None})()
        self.finish_at: float | None = None

    def update_vision(self, t, *args, **kwargs):
        self.servo.t0 = t if self.servo.t0 is None else self.servo.t0
        if self.phase is not Phase.DONE and self.finish_at is not None and t >= self.finish_at:
            self.transitions.append((t, self.phase, Phase.DONE, "done"))
            self.phase = Phase.DONE

    def phase_intervals(self, t_end):
        starts = [(Phase.WAITING, self.servo.t0)] + [(to, t) for t, _, to, _ in self.transitions]
        ends = [t for _, t in starts[1:]] + [t_end]
        return [(p, a, b) for (p, a), b in zip(starts, ends, strict=True)]


def test_the_sequence_hands_over_to_the_next_pick_when_one_is_done(cell):
    made = []

    def task_for(part):
        made.append(_Task(part))
        made[-1].finish_at = 1.0 + len(made)
        return made[-1]

    parts = cell.picked_workpieces()[:2]
    seq = PickSequence(parts, task_for)
    for t in np.arange(0.0, 5.0, 0.5):
        seq.update_vision(t, None, np.zeros(7), False)
        assert seq.part is parts[min(1, int(t >= 2.0))]
    assert seq.phase is Phase.DONE and seq.index == 1 and seq.attempts == 2
    assert seq.phase_intervals(5.0) == [(Phase.WAITING, 0.0, 2.0), (Phase.WAITING, 2.0, 3.0),
                                        (Phase.DONE, 3.0, 5.0)]


def test_identity_swaps_count_estimates_nearer_another_part():
    truths = np.array([[[0.0, 0.0, 0.0]] * 4, [[0.05, 0.0, 0.0]] * 4])  # (P=2, N=4, 3)
    estimate = np.array([[0.001, 0, 0], [0.04, 0, 0], [0.02, 0, 0], [np.nan] * 3])
    frames = np.array([True, True, True, True])
    # frame 1: 40 mm from its own, 10 mm from the other: a swap; frame 2: nearer its own
    assert identity_swaps(estimate, truths, 0, frames) == 1
    assert identity_swaps(estimate, truths, 0, np.array([True, False, True, True])) == 0
    assert identity_swaps(estimate, truths[:1], 0, frames) == 0  # one part: nothing to swap


def test_the_ideal_sensor_is_refused_on_a_line(tmp_path):
    with pytest.raises(CellsightError, match=r"ideal sensor sees one part.*--sensor rendered"):
        ExperimentRun(RunConfig(2, tmp_path / "run", cell="line-cell", sensor="ideal",
                                progress=False))


def test_a_short_line_run_logs_and_scores_every_pick(cell, tmp_path):
    out = tmp_path / "run"
    metrics = run_experiment(RunConfig(2, out, cell="line-cell", duration=1.0, progress=False,
                                       video_every=0))
    assert metrics["workpiece"] == "u1" and metrics["features"] == 16
    assert [p["part"] for p in metrics["picks"]] == PICKS
    assert not metrics["grasp_success"]  # nothing picked in a second
    paths = {c.workpiece: c for c in scenario(cell, 2).conveyors}
    for name in PICKS:
        log = FrameLog.read(out / part_log_name(PICKS, name))
        assert log.n == metrics["frames"] and log.n_features == len(
            cell.workpiece(name).feature_points)
        t = log.floats("t")
        true_xy = log.poses("true")[:, :2]
        np.testing.assert_allclose(true_xy, [paths[name].position(x) for x in t], atol=2e-6)
        assert set(log.text("phase")) == {"waiting"}  # u1's task waits, the others' turns
    figures = json.loads((out / "metrics.json").read_text())["picks"]
    assert all(f["identity_swaps"] == 0 and f["position_rmse_mm"] < 1.0 for f in figures)
    passing = metrics["passing"]  # upstream, out of every view: waiting, nothing estimated
    assert [p["part"] for p in passing] == PASSING
    assert all(p["entered_s"] is None and p["acquired_after_s"] is None for p in passing)
    for name in PASSING:
        log = FrameLog.read(out / part_log_name(PICKS, name))
        assert set(log.text("phase")) == {"passing"} and set(log.text("status")) == {"waiting"}


@pytest.mark.slow
def test_a_passing_part_is_tracked_from_entering_the_views(tmp_path):
    """Experiment 2, lab, the first 16 s: u3 enters the views about 9 s in; it is estimated
    within 1.5 s of being wholly in one camera's image (the search for a part out of view runs
    every second), within 3 mm while it says ``tracking``, never taken for another part, and
    no frame says ``tracking`` before it entered. Oracle: the world's truth in its log."""
    out = tmp_path / "run"
    metrics = run_experiment(RunConfig(2, out, cell="line-cell", realism="lab", seed=1,
                                       duration=16.0, progress=False, video_every=0))
    u3 = next(p for p in metrics["passing"] if p["part"] == "u3")
    assert 5.0 < u3["entered_s"] < u3["whole_in_view_s"] < 15.0, u3
    assert u3["acquired_after_s"] is not None and u3["acquired_after_s"] < 1.5, u3
    assert u3["max_error_tracking_mm"] < 3.0 and u3["identity_swaps"] == 0, u3
    assert u3["tracking_out_of_view_frames"] == 0
    assert all(p["identity_swaps"] == 0 for p in metrics["picks"])


def _pick(part, picked, rmse, tracking, wrong, swaps):
    return {"part": part, "picked": picked, "position_rmse_arm_mm": rmse,
            "position_rmse_mm": rmse + 1.0, "max_error_tracking_mm": tracking,
            "confident_wrong_frames": wrong, "identity_swaps": swaps}


def test_a_sweeps_lines_are_summed_up_per_run_and_per_group():
    specs = [RunSpec("line-cell", 3, "rendered", "kinematic", seed, realism="lab")
             for seed in (0, 1)]
    results = [{"picks": [_pick("u1", True, 0.4, 2.0, 0, 0), _pick("l1", True, 0.8, 12.5, 3, 2)]},
               {"picks": [_pick("u1", True, 0.6, 1.0, 0, 0), _pick("l1", None, 1.2, 4.0, 0, 0)]}]
    assert pick_summary(results[0]) == {
        "picks": 2, "picks_picked": 2, "picks_worst_rmse_arm_mm": 0.8, "picks_worst_rmse_mm": 1.8,
        "picks_max_error_tracking_mm": 12.5, "picks_confident_wrong_frames": 3,
        "picks_identity_swaps": 2}
    assert pick_summary({"position_rmse_mm": 1.0}) == {}
    row = lines_markdown(specs, results).splitlines()[2]
    # every part picked 1 of 2 runs, 3 of 4 parts; mean arm RMSE (0.4+0.8+0.6+1.2)/4 = 0.75
    assert row.split(" | ")[6:] == ["2", "1/2", "3/4", "0.75", "1.20", "12.50", "1 (3)", "2 |"]
    assert lines_markdown(specs, [{}, {}]) == ""


def _passing(part, after, rmse, tracking, out_of_view, swaps):
    return {"part": part, "entered_s": None if after == "never" else 10.0,
            "acquired_after_s": None if after in ("never", None) else after,
            "position_rmse_arm_mm": rmse, "max_error_tracking_mm": tracking,
            "tracking_out_of_view_frames": out_of_view, "identity_swaps": swaps}


def test_a_sweeps_passing_parts_are_summed_up_per_run_and_per_group():
    specs = [RunSpec("line-cell", 3, "rendered", "kinematic", seed, realism="lab")
             for seed in (0, 1)]
    results = [{"passing": [_passing("u3", 3.0, 1.0, 2.0, 0, 0),
                            _passing("l3", None, None, None, 0, 0)]},
               {"passing": [_passing("u3", 1.0, 0.5, 9.0, 2, 1),
                            _passing("l3", "never", None, None, 0, 0)]}]
    assert passing_summary(results[1]) == {
        "passing": 2, "passing_entered": 1, "passing_acquired": 1,
        "passing_worst_acquired_after_s": 1.0, "passing_worst_rmse_arm_mm": 0.5,
        "passing_max_error_tracking_mm": 9.0, "passing_tracking_out_of_view_frames": 2,
        "passing_identity_swaps": 1}
    assert passing_summary({"picks": []}) == {}
    row = passing_markdown(specs, results).splitlines()[2]
    # 3 of 4 entered, 2 of those 3 estimated: after 3.0 and 1.0 s (median 2.0, worst 3.0)
    assert row.split(" | ")[6:] == ["2", "3/4", "2/3", "2.0", "3.0", "0.75", "1.00", "9.00",
                                    "2", "1 |"]
    assert passing_markdown(specs, [{}, {}]) == ""


def test_each_pick_is_put_down_one_place_step_further(cell):
    """The k-th pick's release pose is FINAL's TCP pose moved by k steps (the cell file's
    ``place_step``), its orientation FINAL's; the first is put down at FINAL."""
    robot = cell.robot("R7AX")
    final = robot.tcp_pose(robot.final)
    step = np.array(cell.experiments.place_step)
    assert place_pose(cell, robot, 0) is None and np.linalg.norm(step) > 0.1
    for k in (1, 2, 3):
        T = place_pose(cell, robot, k)
        np.testing.assert_allclose(T[:2, 3], final[:2, 3] + k * step, atol=1e-12)
        np.testing.assert_allclose(T[2:, 3], final[2:, 3])
        np.testing.assert_allclose(T[:3, :3], final[:3, :3])
    sc = scenario(cell, 3)
    source_tasks = [pick_task(cell, sc, part) for part in sc.picks]
    places = np.array([task.T_final[:2, 3] for task in source_tasks])
    assert np.all(np.linalg.norm(np.diff(places, axis=0), axis=1) > 0.1)  # apart, one by one


def test_a_camera_may_miss_a_key_pose_only_while_two_others_hold_it_whole(cell, tmp_path):
    """On the line, cam4 (upstream, at the belt's start) does not see u1 put down by FINAL:
    fine while two other cameras hold it whole; with cam4 and one other camera, an error."""
    line = [f for f in check_cell(cell) if f.line.startswith("u1 held at R7AX's FINAL")]
    cam4 = next(f for f in line if "cam4's image" in f.line)
    assert cam4.level == "ok" and "out of cam4's image" in cam4.line
    assert "other cameras hold it whole" in cam4.line
    data = yaml.safe_load(builtin_cell_path("line-cell").read_text())
    data["cameras"] = [c for c in data["cameras"] if c["name"] in ("cam2", "cam4")]
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump(data))
    two = [f for f in check_cell(load_cell(path)) if f.line.startswith("u1 held at R7AX's FINAL")]
    assert [f.level for f in two if "cam4's image" in f.line] == ["error"]


def test_a_sweep_of_a_line_with_the_ideal_sensor_is_refused_before_it_runs():
    axes = SweepAxes(cells=["line-cell"], experiments=[3], sensors=["rendered", "ideal"],
                     variants=["kinematic"], seeds=[0])
    with pytest.raises(CellsightError, match=r"--sensors: line-cell is a line \(4 picks\)"):
        sweep_grid(axes)
    assert len(sweep_grid(replace(axes, sensors=["rendered"]))) == 1


def test_a_lying_part_is_held_to_the_fastest_belt_of_the_cell(cell):
    """The line's passing parts ride at 3 cm/s (the picks at 1 cm/s): a lying part's rates are
    bounded by twice the faster belt and 1 cm/s, 7 cm/s, not 3 cm/s, which would hold a
    passing part drawn 20 % fast back behind itself. The passing parts' tracks know their
    travel (where they come into the views), the picks' do not."""
    from cellsight.tracking.setup import build_tracker

    tracker = build_tracker(cell)
    speed = tracker.config.support_speed[0]
    assert speed == pytest.approx(2 * 0.03 + 0.01)
    assert speed > 1.2 * cell.experiments.passing_speed
    travels = {name: track.travel for name, track in tracker.tracks.items()}
    assert {name for name, way in travels.items() if way is not None} == {"u3", "l3"}
    assert np.allclose(travels["u3"], cell.experiments.passing_travel)

"""The run session (cellsight.session) and docs/guides/sources-and-sinks.md: the guide's own
sink against frames.csv, a camera driver as a source against the simulator's truth (the
guide's driver, played by the world), the built-in parts against the protocols, and a sink that
fails."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig
from cellsight.experiments.runner import ExperimentRun
from cellsight.export.live import LiveSink
from cellsight.recording.recorder import RecordingSink
from cellsight.runfolder import FrameLog, read_metrics
from cellsight.session import FrameSink, FrameSource
from cellsight.session.driver import DriverFrame, DriverSource, track_driver
from cellsight.world import World

EXAMPLE = Path(__file__).resolve().parent.parent / "docs" / "guides" / "estimates_csv.py"


def _example_sink():
    spec = importlib.util.spec_from_file_location("estimates_csv", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.EstimatesCsv()


def test_the_docs_sink_writes_the_estimates_of_frames_csv(tmp_path: Path):
    assert len(EXAMPLE.read_text().split("\n\nif __name__")[0].splitlines()) <= 40
    config = RunConfig(1, tmp_path / "run", sensor="ideal", duration=1.5, progress=False)
    ExperimentRun(config, sinks=[_example_sink()]).run()
    frames = FrameLog.read(tmp_path / "run" / "frames.csv")
    with (tmp_path / "run" / "estimates.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == frames.n > 30
    assert [r["status"] for r in rows] == frames.text("status")
    for axis in "xyz":
        ours = np.array([float(r[axis]) if r[axis] else np.nan for r in rows])
        assert np.allclose(ours, frames.floats(f"est_{axis}"), atol=1e-6, equal_nan=True)


class _WorldDriver:
    """A live cell's driver, played by the simulated world: its rendered images, encoders and
    jaws, and the part's true pose as a motion capture would give it."""

    def __init__(self, world: World, frames: int) -> None:
        self.world, self.left = world, frames

    def read(self) -> DriverFrame | None:
        if self.left == 0:
            return None
        self.left -= 1
        world = self.world
        frame = DriverFrame(world.time, world.render(), world.measured_joints(),
                            world.jaw_openings(), None, world.true_part_poses()["part"])
        for _ in range(19):  # the next frame 19 control steps (38 ms) on
            world.step()
        return frame


def test_a_camera_driver_is_tracked_against_the_truth(tmp_path: Path):
    cell = load_cell()
    world = World(cell, seed=0)
    metrics = track_driver(cell, _WorldDriver(world, 12), tmp_path / "live")
    frames = FrameLog.read(tmp_path / "live" / "frames.csv")
    assert frames.n == 12 and metrics["frames_tracked"] == 12
    assert metrics["sensor"] == "driver" and metrics["tracker"] == "kinematic"
    error = np.linalg.norm(frames.poses("est")[:, :3] - frames.poses("true")[:, :3], axis=1)
    tracked = np.isfinite(error)
    assert tracked.sum() >= 10 and np.nanmax(error) < 3e-3  # m
    assert set(frames.text("phase")) == {"recorded"}
    assert metrics["position_rmse_mm"] < 1.0 and metrics["wrong_accepted"] == 0


def test_a_driver_frame_with_the_wrong_camera_count_is_refused(tmp_path: Path):
    cell = load_cell()

    class OneCamera:
        def read(self) -> DriverFrame:
            return DriverFrame(0.0, [None], {r.name: np.zeros(r.n_joints) for r in cell.robots})

    with pytest.raises(CellsightError, match="1 image.*2 cameras"):
        track_driver(cell, OneCamera(), tmp_path / "bad")
    assert "error" in read_metrics(tmp_path / "bad")


def test_the_built_in_sources_and_sinks_follow_the_protocols(tmp_path: Path):
    run = ExperimentRun(RunConfig(2, tmp_path / "r", duration=1.0, progress=False,
                                  record=tmp_path / "r.mcap", live="127.0.0.1:0"))
    sinks = run.sinks()
    assert any(isinstance(s, RecordingSink) for s in sinks)
    assert any(isinstance(s, LiveSink) for s in sinks)
    assert all(isinstance(s, FrameSink) for s in sinks)
    assert isinstance(run.source, FrameSource)
    assert isinstance(DriverSource(run.cell, _WorldDriver(run.world, 0)), FrameSource)
    assert not isinstance(object(), FrameSink)


class _FailingSink:
    def __init__(self) -> None:
        self.closed = None

    def start(self, run) -> None:
        self.run = run

    def frame(self, record) -> None:
        if record.frame.k == 3:
            raise OSError(28, "No space left on device", str(self.run.out / "mine.bin"))

    def close(self, completed: bool) -> None:
        self.closed = completed


def test_a_failing_sink_ends_the_run_with_everything_else_written(tmp_path: Path):
    sink = _FailingSink()
    config = RunConfig(1, tmp_path / "run", sensor="ideal", duration=2.0, progress=False)
    with pytest.raises(OSError, match="No space"):
        ExperimentRun(config, sinks=[sink]).run()
    metrics = read_metrics(tmp_path / "run")
    assert "No space left on device" in metrics["error"] and sink.closed is False
    assert FrameLog.read(tmp_path / "run" / "frames.csv").n == 4  # frame 3 written before it
    assert (tmp_path / "run" / "report.html").is_file()

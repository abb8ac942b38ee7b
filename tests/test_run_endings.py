"""How a run ends (issue 14): by SIGTERM or SIGINT (at a frame boundary, whole rows, metrics and
report written, exit status 128 + signal), by a crash (recorded, one line, exit status 1), and
into a folder that held an older run (refused, or cleared with ``--overwrite``)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import cellsight.experiments
from cellsight import load_cell
from cellsight.cli import main
from cellsight.experiments import ExperimentRun, RunConfig, scenario
from cellsight.runfolder import RunFolderError
from cellsight.runfolder.framelog import columns
from cellsight.world import World

IDEAL = ["--sensor", "ideal", "--quiet"]


class _Crashing:
    """A world whose control step raises after ``after`` steps."""

    def __init__(self, world: World, after: int) -> None:
        self._world, self._left = world, after

    def step(self, *args, **kwargs) -> None:
        self._left -= 1
        if self._left < 0:
            raise RuntimeError("motor driver lost")
        self._world.step(*args, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self._world, name)


def _crashing_run(config: RunConfig) -> ExperimentRun:
    sc = scenario(load_cell(), config.experiment)
    world = World(load_cell(), seed=config.seed, conveyor=sc.conveyor, tasks=sc.tasks)
    return ExperimentRun(config, world=_Crashing(world, after=300))


def _rows(folder: Path) -> list[list[str]]:
    with (folder / "frames.csv").open(newline="") as f:
        rows = list(csv.reader(f))
    joints = {r.name: r.n_joints for r in load_cell().robots}
    assert rows[0] == columns(2, joints) and all(len(r) == len(rows[0]) for r in rows)
    return rows[1:]


def test_a_crash_is_recorded_and_handlers_come_back(tmp_path: Path) -> None:
    before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]
    run = _crashing_run(RunConfig(1, tmp_path, sensor="ideal", duration=5.0, progress=False))
    with pytest.raises(RuntimeError, match="motor driver lost"):
        run.run()
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == before
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["interrupted"] is False and "signal" not in metrics
    assert metrics["error"] == "RuntimeError: motor driver lost"
    assert metrics["frames"] == len(_rows(tmp_path)) > 0
    assert (tmp_path / "report.html").stat().st_size > 0
    assert "failed at t = " in (tmp_path / "run.log").read_text()


@pytest.mark.slow
def test_the_cli_words_a_crash_in_one_line(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(cellsight.experiments, "run_experiment",
                        lambda config: _crashing_run(config).run())
    monkeypatch.delenv("CELLSIGHT_DEBUG", raising=False)
    assert main(["run", "1", "--out", str(tmp_path), *IDEAL]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "the run failed at t = 0.6 s: RuntimeError: motor driver lost" in err
    assert f"partial results in {tmp_path}" in err
    monkeypatch.setenv("CELLSIGHT_DEBUG", "1")
    with pytest.raises(RuntimeError):
        main(["run", "1", "--out", str(tmp_path), *IDEAL, "--overwrite"])


def test_the_api_refuses_a_used_folder_and_overwrite_clears_it(tmp_path: Path) -> None:
    (tmp_path / "views.mp4").write_bytes(b"older rendered run")
    (tmp_path / "fig_error.png").write_bytes(b"png")
    (tmp_path / "keyframes").mkdir()
    (tmp_path / "keyframes" / "grasp.png").write_bytes(b"png")
    with pytest.raises(RunFolderError, match="pass overwrite=True"):
        ExperimentRun(RunConfig(1, tmp_path, sensor="ideal", duration=1.0, progress=False))
    assert (tmp_path / "views.mp4").is_file()
    with pytest.raises(cellsight.errors.CellsightError, match="RunConfig.duration"):
        RunConfig(1, tmp_path, duration=float("nan"))
    assert main(["run", "1", "--out", str(tmp_path), *IDEAL, "--duration", "1",
                 "--overwrite"]) == 0
    assert not (tmp_path / "views.mp4").exists()
    assert not (tmp_path / "keyframes" / "grasp.png").exists()
    assert "views.mp4" not in (tmp_path / "report.html").read_text()


def _run_and_signal(out: Path, signals: list[signal.Signals]) -> subprocess.CompletedProcess:
    """Start a long ideal run, wait for a few frames, send ``signals[0]``; keep sending the
    others (cycling) while metrics and report are being written."""
    env = {**os.environ, "CELLSIGHT_DEBUG": "0"}
    proc = subprocess.Popen([sys.executable, "-m", "cellsight.cli", "run", "1", "--out",
                             str(out), *IDEAL, "--duration", "60"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    frames, deadline = out / "frames.csv", time.monotonic() + 120
    while not (frames.is_file() and frames.read_text().count("\n") > 4):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.05)
    proc.send_signal(signals[0])
    k = 1
    while proc.poll() is None and len(signals) > 1 and not (out / "report.html").exists():
        proc.send_signal(signals[k % len(signals)])
        k += 1
        time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.mark.parametrize(("signals", "code"), [
    ([signal.SIGTERM], 143),
    ([signal.SIGINT, signal.SIGINT, signal.SIGTERM], 130),  # later signals change nothing
])
@pytest.mark.slow
def test_a_signal_ends_the_run_cleanly(signals, code: int, tmp_path: Path) -> None:
    done = _run_and_signal(tmp_path, signals)
    name = signals[0].name
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr
    assert f"cellsight: interrupted by {name} at t = " in done.stderr
    assert f"s; partial results in {tmp_path}" in done.stderr
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["interrupted"] is True and metrics["signal"] == name
    assert metrics["frames"] == len(_rows(tmp_path)) >= 4 and metrics["t_end_s"] < 60
    assert (tmp_path / "report.html").stat().st_size > 0
    assert f"interrupted by {name}" in (tmp_path / "run.log").read_text()

"""Hostile input to ``sweep`` and ``place-cameras`` (issue 23, items 8, 9, 16, 17): every
argument is checked before anything is created (one line naming the argument, exit 2, no
folder made), a folder's files are replaced only with ``--overwrite``, and SIGTERM ends a sweep
like Ctrl-C: one line, exit 143, no worker process left, the finished runs reused next time."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from cellsight.cli import main
from cellsight.sweep.engine import Terminated, map_jobs, sigterm_interrupts
from cellsight.sweep.grid import reusable_metrics

SWEEP = ["sweep", "--experiments", "1", "--sensors", "ideal", "--duration", "0.1", "--quiet"]
PLACE = ["place-cameras", "--task", "3", "--quiet"]


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("args, needle", [
    (["--duration", "-1"], "--duration: expected a positive, finite number of seconds, got -1.0"),
    (["--duration", "nan"], "--duration: expected a positive, finite number of seconds, got nan"),
    (["--duration", "inf"], "--duration"),
    (["--jobs", "0"], "--jobs: expected a whole number >= 1, got 0"),
    (["--scheduler-timeout", "nan"], "--scheduler-timeout"),
    (["--cells", "no_such_cell.yaml"], "--cells: no_such_cell.yaml"),
    (["--realism", "no_such_profile"], "--realism: no_such_profile"),
    (["--seeds", "-1"], "--seeds: expected one or more whole numbers >= 0, got [-1]"),
    (["--variant-seeds", "0"], "--variant-seeds: expected a whole number >= 1, got 0"),
    (["--experiments", "4"], "--experiments"),
    (["--structure", "octree"], "--structure: expected"),
])
def test_sweep_checks_every_argument_before_writing(args, needle, tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main([*SWEEP, "--out", str(out), *args]) == 2
    assert needle in _one_line(capsys)
    assert not out.exists()


def test_sweep_refuses_an_out_that_is_or_lies_under_a_file(tmp_path, capsys):
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    assert main([*SWEEP, "--out", str(file)]) == 2
    line = _one_line(capsys)  # a long path is shortened in the middle
    assert "--out: '" in line and "notes" in line and "is not a folder" in line
    assert main([*SWEEP, "--out", str(file / "sweep")]) == 2
    assert "is under" in _one_line(capsys)
    assert file.read_text() == "mine"


@pytest.mark.slow  # about a minute: two sweeps (make test-slow)
def test_sweep_keeps_a_summary_that_is_not_a_sweeps_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "summary.md").write_text("my notes")
    assert main([*SWEEP, "--out", str(out), "--jobs", "1"]) == 2
    assert "holds summary.md; pass --overwrite" in _one_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == ["summary.md"]
    assert main([*SWEEP, "--out", str(out), "--jobs", "1", "--overwrite"]) == 0
    assert (out / "summary.md").read_text() != "my notes"
    assert main([*SWEEP, "--out", str(out), "--jobs", "1"]) == 0  # an earlier sweep: resumed


def _sleep(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def _pool_workers(before: set[int]) -> list[psutil.Process]:
    """This process's pool workers (spawned children) that were not among the pids ``before``."""
    return [p for p in psutil.Process().children(recursive=True)
            if p.pid not in before and "spawn_main" in " ".join(p.cmdline())]


def test_an_interrupted_pool_ends_its_workers_at_once():
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    jobs = map_jobs(_sleep, [0.0, 60.0, 60.0, 60.0], workers=2, progress=False)
    assert next(jobs) == (0, 0.0)
    workers = _pool_workers(before)
    start = time.monotonic()
    jobs.close()  # what an interrupt does to the sweep's loop
    assert time.monotonic() - start < 5.0
    assert workers and not any(_alive(p) for p in workers)


@pytest.mark.parametrize("sig, raised", [(signal.SIGINT, KeyboardInterrupt),
                                         (signal.SIGTERM, Terminated)])
def test_a_signal_while_the_pool_is_waited_on_is_raised_as_itself(sig, raised):
    """A signal landing inside ``concurrent.futures``' locks once came out as "RuntimeError:
    release unlocked lock": it is now raised between waits, as the interrupt it is, with the
    workers ended and the handlers as they were."""
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    jobs = map_jobs(_sleep, [0.0, 60.0, 60.0], workers=2, progress=False)
    assert next(jobs) == (0, 0.0)
    workers = _pool_workers(before)
    timer = threading.Timer(0.5, os.kill, (os.getpid(), sig))
    timer.start()
    with pytest.raises(raised) as caught:
        next(jobs)
    timer.join()
    assert type(caught.value) is raised
    assert workers and not any(_alive(p) for p in workers)
    assert {s: signal.getsignal(s) for s in handlers} == handlers


def test_sigterm_raises_terminated_in_the_main_thread_and_the_handler_comes_back():
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated), sigterm_interrupts():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
    assert signal.getsignal(signal.SIGTERM) == previous


def _alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.2)


@pytest.mark.slow
@pytest.mark.parametrize("jobs", [2, 1])
def test_sigterm_ends_a_sweep_like_ctrl_c(jobs, tmp_path):
    """Once a run has finished and another is running, SIGTERM to the sweep: exit 143 within
    seconds, one line on stderr, none of its processes left (pool workers, the resource
    tracker), the finished run reusable and the interrupted one marked so."""
    out = tmp_path / "sweep"
    env = dict(os.environ, NUMBA_NUM_THREADS="1", MUJOCO_GL="egl")
    sweep = subprocess.Popen(
        [sys.executable, "-m", "cellsight.cli", "sweep", "--out", str(out), "--experiments", "1",
         "--sensors", "ideal", "--duration", "2", "--seeds", "0", "1", "2", "3", "--jobs",
         str(jobs), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        finished = lambda: [p.parent for p in out.glob("*/*/metrics.json")]  # noqa: E731
        running = lambda: [p.parent for p in out.glob("*/*/frames.csv")  # noqa: E731
                           if p.parent not in finished()]
        _wait_for(lambda: finished() and running() or sweep.poll() is not None, 180,
                  "a finished run and a running one")
        assert sweep.poll() is None, sweep.communicate()
        children = psutil.Process(sweep.pid).children(recursive=True)
        done = finished()
        sweep.send_signal(signal.SIGTERM)
        _, err = sweep.communicate(timeout=15)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    lines = err.decode().strip().splitlines()
    assert sweep.returncode == 143, lines
    assert lines == [f"cellsight: sweep interrupted by SIGTERM; finished runs in {out} are "
                     f"reused next time"]
    _wait_for(lambda: not any(_alive(p) for p in children), 5, "the sweep's children to end")
    assert all(reusable_metrics(folder) is not None for folder in done)
    assert not (out / "summary.md").exists()


@pytest.mark.parametrize("args, needle", [
    (["--cameras", "1000"], "--cameras: expected at most 360"),
    (["--cameras", "0"], "--cameras: expected a whole number >= 1, got 0"),
    (["--every", "0"], "--every"),
    (["--jobs", "0"], "--jobs: expected a whole number >= 1, got 0"),
    (["--radii", "0"], "--radii"),
    (["--radii", "nan"], "--radii"),
    (["--elevations", "0"], "--elevations"),
    (["--elevations", "90"], "elevations in (0, 90) deg"),
    (["--azimuth-step", "0"], "--azimuth-step"),
    (["--azimuth-step", "400"], "a step in (0, 360] deg"),
    (["--azimuth-step", "0.001"], "candidate viewpoints; expected at most 10000"),
    (["--verify-seeds", "-1"], "--verify-seeds: expected seeds >= 0"),
    (["--verify-seeds", "1", "1"], "--verify-seeds: expected each value once"),
    (["--verify-sensors", "lidar"], "--verify-sensors"),
    (["--verify-duration", "nan"], "--verify-duration"),
    (["--task", "nowhere"], "--task: 'nowhere' is neither an experiment"),
    (["--task", "4"], "--task: '4'"),
    (["--cell", "no_such_cell.yaml"], "--cell: "),
    (["--template", "cam9"], "--template: no camera 'cam9'"),
])
def test_place_cameras_checks_every_argument_before_creating_out(args, needle, tmp_path,
                                                                 capsys):
    out = tmp_path / "placement"
    assert main([*PLACE, "--out", str(out), *args]) == 2
    assert needle in _one_line(capsys)
    assert not out.exists()


def test_place_cameras_refuses_an_out_that_is_a_file(tmp_path, capsys):
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    assert main([*PLACE, "--out", str(file)]) == 2
    assert "--out" in _one_line(capsys) and file.read_text() == "mine"


def test_place_cameras_refuses_a_cell_file_it_would_overwrite(tmp_path, capsys):
    from cellsight.model.loader import cell_path

    out = tmp_path / "placement"
    out.mkdir()
    (out / "cell.yaml").write_text(cell_path("dual-arm").read_text())
    assert main([*PLACE, "--out", str(out), "--cell", str(out / "cell.yaml"),
                 "--overwrite"]) == 2
    assert "--cell: " in _one_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == ["cell.yaml"]


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("hostile_placement") / "run"
    assert main(["run", "3", "--sensor", "ideal", "--duration", "0.5", "--out", str(run),
                 "--quiet"]) == 0
    return run


def test_place_cameras_replaces_files_in_out_only_with_overwrite(short_run, tmp_path, capsys):
    out = tmp_path / "placement"
    out.mkdir()
    (out / "report.md").write_text("my report")
    args = ["place-cameras", "--task", str(short_run), "--out", str(out), "--cameras", "1",
            "--radii", "1.6", "--elevations", "45", "--azimuth-step", "90", "--quiet"]
    assert main(args) == 2
    assert "holds report.md; pass --overwrite" in _one_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]
    assert main([*args, "--cameras", "5"]) == 2  # 4 viewpoints: refused before writing
    assert "--cameras: expected at most 4" in _one_line(capsys)
    assert main([*args, "--overwrite"]) == 0
    assert (out / "report.md").read_text() != "my report"
    assert (out / "cell.yaml").is_file()


@pytest.mark.parametrize("stop, status, name", [(Terminated("SIGTERM"), 143, "SIGTERM"),
                                                (KeyboardInterrupt(), 130, "SIGINT")])
def test_place_cameras_stopped_by_a_signal_is_one_line(stop, status, name, monkeypatch,
                                                       tmp_path, capsys):
    from cellsight.placement import run

    def stopped(args):
        raise stop

    monkeypatch.setattr(run, "place_cameras", stopped)
    assert main([*PLACE, "--out", str(tmp_path)]) == status
    assert f"place-cameras interrupted by {name}" in _one_line(capsys)

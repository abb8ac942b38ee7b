"""Run folders validated on read (issue 59, family 4): what reads a run back (``check
--path``, ``design-crossing --path``, ``diagnose``, ``export``) refuses, naming the folder and
the field, a run killed before its end, one interrupted where the whole task is needed, a run of
the wrong experiment, of another cell, and a frames.csv edited since the run (its SHA-256 in
metrics.json, checked here against hashlib's own); and a --block span outside the run."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from cellsight import load_cell
from cellsight.cli import main
from cellsight.experiments import RunConfig, run_experiment
from cellsight.experiments.task_path import TaskPath
from cellsight.runfolder import RunDataError
from cellsight.runfolder.replay import load_run


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    for number, duration in ((2, 3.0), (1, 1.0)):
        run_experiment(RunConfig(number, root / f"e{number}", sensor="ideal", duration=duration,
                                 progress=False, video_every=0))
    return {"e2": root / "e2", "e1": root / "e1"}


def _copy(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "copy"))


def test_the_run_records_its_frames_digest(runs):
    metrics = json.loads((runs["e2"] / "metrics.json").read_text())
    assert metrics["frames_sha256"] == hashlib.sha256(
        (runs["e2"] / "frames.csv").read_bytes()).hexdigest()
    assert len(TaskPath(runs["e2"], load_cell()).t) > 10


def test_a_killed_run_is_refused(runs, tmp_path, capsys):
    run = _copy(runs["e2"], tmp_path)
    (run / "metrics.json").unlink()
    with pytest.raises(RunDataError, match="has frames.csv but no metrics.json: the run did "
                                           "not finish"):
        TaskPath(run)
    assert main(["check", "--path", str(run)]) == 2
    assert "--path: " in capsys.readouterr().err
    assert main(["diagnose", str(run)]) == 2
    assert "RUN_DIR: " in capsys.readouterr().err


def test_an_interrupted_run_is_refused_where_the_whole_task_is_needed(runs, tmp_path):
    run = _copy(runs["e2"], tmp_path)
    metrics = json.loads((run / "metrics.json").read_text())
    (run / "metrics.json").write_text(json.dumps({**metrics, "interrupted": True}))
    with pytest.raises(RunDataError, match=r"the run did not finish \(interrupted at t = "):
        TaskPath(run)


def test_a_run_of_another_experiment_is_refused(runs):
    with pytest.raises(RunDataError, match="field 'experiment' = 1: a run of experiment 1; "
                                           "this needs experiment 2 or 3"):
        TaskPath(runs["e1"])


def test_a_run_of_another_cell_is_refused(runs):
    with pytest.raises(RunDataError, match="field 'cell_sha256': the run was of .*"
                                           "dual_arm_cell.yaml', not of .*ur_cell.yaml'"):
        TaskPath(runs["e2"], load_cell("ur-cell"))


@pytest.mark.parametrize("edit", ["value", "row", "truncate"])
def test_a_frames_file_edited_since_the_run_is_refused_by_every_reader(runs, tmp_path, edit,
                                                                       capsys):
    run = _copy(runs["e2"], tmp_path)
    frames = run / "frames.csv"
    lines = frames.read_text().splitlines(keepends=True)
    if edit == "value":
        lines[5] = lines[5].replace("0", "1", 1)
    elif edit == "row":
        del lines[7]
    else:
        lines = lines[:-3]
    frames.write_text("".join(lines))
    wanted = "changed since the run wrote it (its SHA-256 differs from metrics.json's"
    for read in (TaskPath, load_run):
        with pytest.raises(RunDataError, match=r"frames\.csv: " + wanted.replace("(", r"\(")):
            read(run)
    assert main(["diagnose", str(run)]) == 2
    assert wanted in capsys.readouterr().err


def test_a_block_outside_the_run_is_refused(runs, capsys):
    assert main(["design-crossing", "--path", str(runs["e2"]), "--block", "cam2", "9.5-15"]) == 2
    err = capsys.readouterr().err
    assert "--block cam2: 9.5-15 s is outside the run's frames (0-3" in err

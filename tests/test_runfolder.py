"""The run folder's home (cellsight.runfolder): metrics.json written and read back through its
schema, its errors naming the file and the field, and the cell digest that follows the files a
cell file points to (a sweep reuses a run only for the same cell)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellsight.cli import main
from cellsight.experiments import RunConfig
from cellsight.experiments.identity import run_identity
from cellsight.model.loader import load_cell
from cellsight.runfolder import (
    METRICS_VERSION,
    RunDataError,
    cell_digest,
    finished_metrics,
    read_metrics,
    write_metrics,
)
from cellsight.sweep.grid import reusable_metrics

METRICS = {"experiment": 3, "seed": 4, "sensor": "rendered", "position_rmse_mm": 2.5,
           "phases": {"grasp": {"position_rmse_mm": 1.0}}, "timing_ms": {"total": 3.1},
           "phase_intervals": [["approach", 0.0, 12.5]], "interrupted": False,
           "a_field_of_a_later_version": [1, 2]}


def test_metrics_are_written_with_their_version_and_read_back_as_they_were(tmp_path: Path):
    written = write_metrics(tmp_path, METRICS)
    assert written == {"metrics_version": METRICS_VERSION, **METRICS}
    assert read_metrics(tmp_path) == written
    assert json.loads((tmp_path / "metrics.json").read_text()) == written
    assert finished_metrics(tmp_path) == written


@pytest.mark.parametrize(("field", "value", "message"), [
    ("seed", "four", "field 'seed': expected a whole number, got 'four'"),
    ("seed", True, "field 'seed': expected a whole number, got True"),
    ("position_rmse_mm", "2.5", "field 'position_rmse_mm': expected a number, got '2.5'"),
    ("phases", {"grasp": 2}, "field 'phases.grasp': expected an object, got 2"),
    ("cameras", "cam1", "field 'cameras': expected a list, got 'cam1'"),
    ("metrics_version", METRICS_VERSION + 1, "written by a newer cellsight"),
])
def test_a_wrong_field_is_named_on_reading_and_refused_on_writing(
        tmp_path: Path, field: str, value: object, message: str) -> None:
    (tmp_path / "metrics.json").write_text(json.dumps({**METRICS, field: value}))
    with pytest.raises(RunDataError, match=message) as caught:
        read_metrics(tmp_path)
    assert str(tmp_path / "metrics.json") in str(caught.value)
    assert finished_metrics(tmp_path) is None
    if field != "metrics_version":
        out = tmp_path / "out"
        out.mkdir()
        with pytest.raises(RunDataError, match=message):
            write_metrics(out, {**METRICS, field: value})
        assert not (out / "metrics.json").exists()


def test_a_partial_run_reads_as_no_metrics_only_when_asked(tmp_path: Path):
    assert read_metrics(tmp_path, missing_ok=True) == {}
    with pytest.raises(RunDataError, match="no metrics.json here"):
        read_metrics(tmp_path)
    with pytest.raises(RunDataError, match="no such run folder"):
        read_metrics(tmp_path / "nowhere")


def test_interrupted_or_failed_runs_are_not_finished(tmp_path: Path):
    for ending in ({"interrupted": True, "signal": "SIGINT"}, {"error": "ValueError: x"}):
        write_metrics(tmp_path, {**METRICS, **ending})
        assert finished_metrics(tmp_path) is None


def test_the_cell_digest_follows_the_calibration_files_a_cell_points_to(tmp_path: Path):
    """A cell whose cameras come from calibration files (``cellsight cameras --write``): the
    digest changes when one of them is rewritten, though the cell file is the same, and the
    sweep then no longer reuses a run made with the old file."""
    assert main(["cameras", "--write", str(tmp_path / "cal")]) == 0
    cell_file = tmp_path / "cal" / "cell.yaml"
    cell = load_cell(cell_file)
    intrinsics = [Path(f) for f in cell.files if "intrinsics" in Path(f).name]
    assert len(intrinsics) == len(cell.cameras) == 2
    before = cell_digest(cell)
    (tmp_path / "run").mkdir()
    config = RunConfig(1, tmp_path / "run", cell=cell_file, sensor="ideal")
    write_metrics(tmp_path / "run", {**METRICS, "identity": run_identity(config)})
    assert reusable_metrics(tmp_path / "run", run_identity(config)) is not None

    intrinsics[0].write_text(intrinsics[0].read_text() + "\n# re-calibrated\n")
    after = cell_digest(load_cell(cell_file))
    assert after != before and cell_file.read_bytes() == Path(cell.source).read_bytes()
    assert reusable_metrics(tmp_path / "run", run_identity(config)) is None


def test_the_cell_digest_of_a_urdf_cell_covers_the_urdf_and_its_meshes():
    cell = load_cell("ur-cell")
    names = [Path(f).name for f in cell.files]
    assert any(n.endswith(".urdf") for n in names)
    assert sum(n.endswith((".stl", ".dae", ".obj")) for n in names) >= 6  # each arm link
    assert all(Path(f).is_file() for f in cell.files)

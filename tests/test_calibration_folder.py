"""A calibration folder: taken over by ``cellsight calibrate --overwrite`` (only what the
command writes is cleared, anything else stops it), and applied to its cell (and only to it)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight.calibration.output import OUTPUTS, is_calibration_output
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose, make_pose
from cellsight.runfolder import check_out_folder, make_out_folder
from cellsight.runfolder.folder import RunFolderError


def _earlier(folder: Path) -> None:
    (folder / "cameras").mkdir(parents=True)
    (folder / "cameras" / "cam1.yaml").write_text("%YAML:1.0\n")
    for name in OUTPUTS - {"cameras"}:
        (folder / name).write_text("x")


def test_an_earlier_calibration_is_cleared_only_with_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "cal"
    _earlier(out)
    with pytest.raises(RunFolderError, match="--out: .* is not empty .*--overwrite"):
        check_out_folder(out, False, "--out", "--overwrite", is_calibration_output)
    stale = check_out_folder(out, True, "--out", "--overwrite", is_calibration_output)
    assert {p.name for p in stale} == set(OUTPUTS)
    make_out_folder(out, stale, "--out")
    assert out.is_dir() and not any(out.iterdir())


@pytest.mark.parametrize("stranger", ["notes.txt", "cameras/link"])
def test_a_folder_holding_anything_else_is_not_overwritten(tmp_path: Path, stranger) -> None:
    out = tmp_path / "cal"
    _earlier(out)
    if stranger == "cameras/link":
        (out / "cameras" / "link").symlink_to(tmp_path)
    else:
        (out / stranger).write_text("mine")
    with pytest.raises(RunFolderError, match="not a run's output; not overwriting"):
        check_out_folder(out, True, "--out", "--overwrite", is_calibration_output)
    assert (out / "calibration.json").exists()


def _calibration_json(folder: Path, cell, reference: str, moved: np.ndarray,
                      world: dict) -> None:
    """A calibration.json as cellsight calibrate writes it: every camera and other base of
    ``cell`` in the reference robot's frame, moved by ``moved`` (the calibration's finding)."""
    from cellsight.runfolder import cell_digest

    T_ref_b = invert_pose(cell.robot(reference).T_base_robot)
    data = {"schema": 1, "cell": cell.source, "cell_sha256": cell_digest(cell),
            "reference_robot": reference, "world": world, "joint_offsets_estimated": True,
            "cameras": {c.name: {"width": c.width, "height": c.height, "K": c.K.tolist(),
                                 "dist": c.dist5.tolist(),
                                 "T_ref_cam": (moved @ T_ref_b @ c.T_base_cam).tolist()}
                        for c in cell.cameras},
            "robots": {r.name: {"T_ref_robot": (moved @ T_ref_b @ r.T_base_robot).tolist()}
                       for r in cell.robots if r.name != reference}}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "calibration.json").write_text(json.dumps(data))


def test_a_calibration_moves_the_cells_cameras_and_bases_and_only_fits_its_cell(
        tmp_path: Path) -> None:
    """The calibrated cell's cameras and other bases are the calibration's, carried into the
    cell's base frame through the cell file's reference robot (the oracle: the same moves
    applied to the cell file's poses directly); a calibration of another cell, or of another
    world, is refused or not reused."""
    from cellsight.calibration.command import finished_calibration
    from cellsight.calibration.folder import calibrated_cell
    from cellsight.model.loader import cell_path, load_cell

    cell = load_cell("dual-arm")
    reference = cell.experiments.robot
    moved = make_pose(Rotation.from_euler("xyz", [0.05, -0.02, 0.03], degrees=True).as_matrix(),
                      [0.001, -0.002, 0.0005])
    _calibration_json(tmp_path / "cal", cell, reference, moved, {"realism": "lab", "seed": 3})
    out = calibrated_cell(cell, tmp_path / "cal")
    T_base_ref = cell.robot(reference).T_base_robot
    shift = T_base_ref @ moved @ invert_pose(T_base_ref)  # the move, in the cell's base frame
    for before, after in zip(cell.cameras, out.cameras, strict=True):
        np.testing.assert_allclose(after.T_base_cam, shift @ before.T_base_cam, atol=1e-12)
        np.testing.assert_allclose(after.K, before.K)
    for before, after in zip(cell.robots, out.robots, strict=True):
        expected = before.T_base_robot if before.name == reference else (
            shift @ before.T_base_robot)
        np.testing.assert_allclose(after.T_base_robot, expected, atol=1e-12)
    assert finished_calibration(tmp_path / "cal", "dual-arm", "lab", 3)
    assert not finished_calibration(tmp_path / "cal", "dual-arm", "lab", 4)
    assert not finished_calibration(tmp_path / "cal", "dual-arm", "harsh", 3)
    data = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    (tmp_path / "cal" / "calibration.json").write_text(json.dumps(
        {**data, "joint_offsets_estimated": False}))  # made with other settings than a sweep's
    assert not finished_calibration(tmp_path / "cal", "dual-arm", "lab", 3)
    (tmp_path / "cal" / "calibration.json").write_text(json.dumps(data))
    edited = tmp_path / "edited.yaml"
    edited.write_text(cell_path("dual-arm").read_text() + "\n# a camera moved\n")
    assert not finished_calibration(tmp_path / "cal", str(edited), "lab", 3)
    with pytest.raises(CellsightError, match="cell_sha256: calibrated for .*run cellsight "
                                             "calibrate on this cell"):
        calibrated_cell(load_cell(str(edited)), tmp_path / "cal")

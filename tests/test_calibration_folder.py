"""A calibration folder taken over by ``cellsight calibrate --overwrite``: only what the command
writes is cleared, anything else stops it."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellsight.calibration.output import OUTPUTS, is_calibration_output
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

"""Hostile writes (issue 23, items 6 and 18): a full disk or a read-only folder while cellsight
writes. Every file goes through :mod:`cellsight.runfolder.writes`: the failure is one line
naming the file and why, exit status 2 (1 for a run that failed after starting), no traceback;
nothing half-written takes a file's name, and a run whose files could not all be written says
so in its ``metrics.json`` (or has none), so that a sweep never reuses it as finished.

The full disk is injected (an ``OSError(ENOSPC)`` from the write), read-only folders are made
with ``chmod`` (skipped as root, whom it does not stop) and also injected (``os.access``)."""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path

import pytest

from cellsight.cli import main
from cellsight.errors import CellsightError
from cellsight.runfolder import (
    WriteError,
    check_out_folder,
    finished_metrics,
    read_metrics,
    write_file,
    write_metrics,
)
from cellsight.runfolder import writes as writes_module
from cellsight.runfolder.framelog import FrameWriter
from cellsight.runfolder.writes import AtomicFile, RunWrites, staged

RUN = ["run", "1", "--sensor", "ideal", "--quiet", "--duration", "0.5"]
FULL = os.strerror(errno.ENOSPC)  # "No space left on device"


def _enospc() -> OSError:
    return OSError(errno.ENOSPC, FULL)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("cellsight: error: ") and "Traceback" not in err, err
    assert "Logging error" not in err and len(err.strip().splitlines()) == 1, err
    return err


def _fill_disk_for(monkeypatch, name: str) -> None:
    """Every whole-file write of a file called ``name`` fails as on a full disk."""
    real = AtomicFile.write

    def write(self: AtomicFile, data: bytes) -> int:
        if self.path.name == name:
            self._file.write(data[: len(data) // 2])  # half of it reaches the disk
            raise self._failing(_enospc())
        return real(self, data)

    monkeypatch.setattr(AtomicFile, "write", write)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.name.endswith(".tmp"))


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("CELLSIGHT_DEBUG", raising=False)


# ------------------------------------------------------------------------ the one place


def test_a_failed_whole_file_write_leaves_the_file_as_it_was(tmp_path: Path, monkeypatch):
    path = tmp_path / "metrics.json"
    path.write_text("before")
    _fill_disk_for(monkeypatch, "metrics.json")
    with pytest.raises(WriteError, match=rf"metrics.json: cannot write it \({FULL}\)"):
        write_file(path, "after" * 1000)
    assert path.read_text() == "before" and _leftovers(tmp_path) == []


def test_a_failed_replace_removes_the_temporary_file(tmp_path: Path, monkeypatch):
    def replace(src, dst):
        raise _enospc()

    monkeypatch.setattr(writes_module.os, "replace", replace)
    with pytest.raises(WriteError, match=FULL):
        write_file(tmp_path / "report.html", "<html>")
    assert list(tmp_path.iterdir()) == []


def test_files_written_together_are_all_there_or_none(tmp_path: Path, monkeypatch):
    (tmp_path / "a.txt").write_text("old a")
    with pytest.raises(RuntimeError), staged(tmp_path) as stage:
        (stage / "a.txt").write_text("new a")
        raise RuntimeError("the second file failed")
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]
    real = os.replace

    def replace(src, dst):
        if Path(dst).name == "b.txt":
            raise _enospc()
        real(src, dst)

    monkeypatch.setattr(writes_module.os, "replace", replace)
    with pytest.raises(WriteError, match=rf"b.txt: cannot write it \({FULL}\)"), \
            staged(tmp_path) as stage:
        (stage / "a.txt").write_text("new a")
        (stage / "b.txt").write_text("new b")
    assert [p.name for p in tmp_path.iterdir()] == []  # a.txt moved in, then taken out again


def test_a_run_folder_with_a_killed_runs_temporary_file_can_be_overwritten(tmp_path: Path):
    (tmp_path / "frames.csv").write_text("t\n")
    (tmp_path / ".metrics.json.0a1b2c3d.tmp").write_text("{")
    assert len(check_out_folder(tmp_path, overwrite=True)) == 2
    (tmp_path / ".notes.txt.0a1b2c3d.tmp").write_text("someone else's")
    with pytest.raises(CellsightError, match="not a run's output"):
        check_out_folder(tmp_path, overwrite=True)


def test_frames_and_logs_name_their_file_when_the_disk_is_full(tmp_path: Path, monkeypatch):
    writer = FrameWriter(tmp_path / "frames.csv", 1)
    writer.write({"t": 0.0})
    monkeypatch.setattr(writer, "_file", _FullFile(writer._file))
    with pytest.raises(WriteError, match=rf"frames.csv: cannot write it \({FULL}\)"):
        writer.write({"t": 0.1})
    writes = RunWrites(tmp_path)
    handler = writes.log_file("run.log")
    handler.stream = _FullFile(handler.stream)
    logger = logging.getLogger("cellsight.test_hostile_writes")
    logger.addHandler(handler)
    try:
        logger.warning("one")
        logger.warning("two")
    finally:
        logger.removeHandler(handler)
    writes.close(handler.baseFilename, handler.close)
    assert writes.failures == [f"{tmp_path / 'run.log'}: cannot write it ({FULL})"]


class _FullFile:
    """A text file on a full disk: every write and flush fails."""

    def __init__(self, file) -> None:
        self._file = file

    def write(self, text: str) -> int:
        raise _enospc()

    def flush(self) -> None:
        raise _enospc()

    def close(self) -> None:
        self._file.close()


# -------------------------------------------------------------------------------- runs


def _failed_run(tmp_path: Path, capsys, code: int) -> tuple[Path, str]:
    out = tmp_path / "run"
    assert main([*RUN, "--out", str(out)]) == code
    return out, _one_error_line(capsys)


@pytest.mark.parametrize("name", ["report.html", "fig_error.png"])
def test_a_run_whose_report_cannot_be_written_is_not_finished(name, tmp_path, capsys,
                                                              monkeypatch):
    """Item 6: metrics.json, written last, says the run failed and names the file."""
    _fill_disk_for(monkeypatch, name)
    out, err = _failed_run(tmp_path, capsys, 1)
    assert f"{name}: cannot write it ({FULL}); partial results in {out}" in err
    metrics = read_metrics(out)
    assert metrics["interrupted"] is False
    assert metrics["error"] == f"{out / name}: cannot write it ({FULL})"
    assert finished_metrics(out) is None
    assert not (out / name).exists() and _leftovers(out) == []
    assert metrics["frames"] > 0 and "metrics:" in (out / "run.log").read_text()


def test_a_run_whose_metrics_cannot_be_written_leaves_none(tmp_path, capsys, monkeypatch):
    _fill_disk_for(monkeypatch, "metrics.json")
    out, err = _failed_run(tmp_path, capsys, 2)
    assert f"metrics.json: cannot write it ({FULL})" in err
    assert not (out / "metrics.json").exists() and _leftovers(out) == []
    assert finished_metrics(out) is None
    assert (out / "report.html").is_file() and (out / "frames.csv").stat().st_size > 0


def test_a_full_disk_mid_run_keeps_the_rows_written_before(tmp_path, capsys, monkeypatch):
    real, rows = FrameWriter._written, []

    def written(self, write):
        rows.append(1)
        if len(rows) > 6:  # the header and five rows reach the disk
            def write():
                raise _enospc()
        real(self, write)

    monkeypatch.setattr(FrameWriter, "_written", written)
    out, err = _failed_run(tmp_path, capsys, 1)
    assert "the run failed at t = 0." in err and f"frames.csv: cannot write it ({FULL})" in err
    metrics = read_metrics(out)
    assert f"{out / 'frames.csv'}: cannot write it ({FULL})" in metrics["error"]
    assert metrics["frames"] == 5 and finished_metrics(out) is None
    assert "failed at t = " in (out / "run.log").read_text()


def test_a_run_whose_log_or_pictures_cannot_be_written_says_so(tmp_path, capsys, monkeypatch):
    """run.log's writes fail in the logging module, OpenCV cannot encode a key frame: both
    are recorded, neither prints a traceback."""
    from cellsight.experiments import keyframes

    monkeypatch.setattr(writes_module._LogFile, "flush", lambda self: _FullFile.flush(self))
    monkeypatch.setattr(keyframes.cv2, "imencode", lambda *args: (False, None))
    out, err = _failed_run(tmp_path, capsys, 1)
    assert f"run.log: cannot write it ({FULL})" in err
    error = read_metrics(out)["error"]
    assert f"{out / 'run.log'}: cannot write it ({FULL})" in error
    assert f"{out / 'keyframes' / 'start.png'}: cannot write it" in error
    assert finished_metrics(out) is None


def test_a_run_that_wrote_everything_is_finished(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*RUN, "--out", str(out)]) == 0
    metrics = finished_metrics(out)
    assert metrics is not None and "error" not in metrics and _leftovers(out) == []
    assert (out / "report.html").stat().st_mtime <= (out / "metrics.json").stat().st_mtime


def test_metrics_are_written_whole_by_their_one_writer(tmp_path, monkeypatch):
    write_metrics(tmp_path, {"experiment": 1})
    _fill_disk_for(monkeypatch, "metrics.json")
    with pytest.raises(WriteError):
        write_metrics(tmp_path, {"experiment": 2})
    assert read_metrics(tmp_path)["experiment"] == 1


# ------------------------------------------------------------------- read-only folders


def _read_only(monkeypatch, folder: Path) -> None:
    """``folder`` refuses writes, as ``os.access`` sees it (whoever runs the test)."""
    real = os.access
    monkeypatch.setattr(os, "access", lambda path, mode, *a, **k: (
        False if Path(path) == folder and mode & os.W_OK else real(path, mode, *a, **k)))


@pytest.mark.parametrize("how", ["chmod", "injected"])
def test_a_read_only_out_is_refused_in_one_line(how, tmp_path, capsys, monkeypatch):
    out = tmp_path / "empty"
    out.mkdir()
    if how == "chmod":
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only folders")
        out.chmod(0o555)
    else:
        _read_only(monkeypatch, out)
    try:
        assert main([*RUN, "--out", str(out)]) == 2
        assert "cannot write in it (Permission denied)" in _one_error_line(capsys)
        assert main([*RUN, "--out", str(out / "new")]) == 2
        assert f"cannot create it in {str(out)!r}" in _one_error_line(capsys)
        assert main(["show", "--out", str(out)]) == 2
        assert "--out: " in _one_error_line(capsys)
        assert main(["cameras", "--write", str(out)]) == 2
        assert "--write: " in _one_error_line(capsys)
        assert list(out.iterdir()) == []
    finally:
        out.chmod(0o755)


def test_show_onto_a_file_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("mine")
    assert main(["show", "--out", str(tmp_path / "file")]) == 2
    assert "is not a folder" in _one_error_line(capsys)
    assert (tmp_path / "file").read_text() == "mine"


def test_show_on_a_full_disk_writes_no_picture(tmp_path, capsys, monkeypatch):
    real = writes_module.AtomicFile.write

    def write(self, data):
        if self.path.name == "view_cam2.png":
            raise self._failing(_enospc())
        return real(self, data)

    monkeypatch.setattr(writes_module.AtomicFile, "write", write)
    out = tmp_path / "pictures"
    assert main(["show", "--out", str(out)]) == 2
    assert f"cannot write the pictures ({FULL})" in _one_error_line(capsys)
    assert not out.exists()  # the folder made for them is gone too
    monkeypatch.setattr(writes_module.AtomicFile, "write", real)
    assert main(["show", "--out", str(out)]) == 0  # not refused: nothing was left


# ------------------------------------------------------------------ export and cameras


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main([*RUN, "--out", str(out)]) == 0
    return out


def test_export_on_a_full_disk_leaves_no_truncated_file(finished_run, tmp_path, capsys,
                                                        monkeypatch):
    mcap = tmp_path / "run.mcap"
    real, sizes = AtomicFile.write, []

    def write(self: AtomicFile, data: bytes) -> int:
        sizes.append(len(data))
        if sum(sizes) > 4000:
            raise self._failing(_enospc())
        return real(self, data)

    monkeypatch.setattr(AtomicFile, "write", write)
    export = ["export", str(finished_run), "--mcap", str(mcap), "--no-images", "--quiet"]
    assert main(export) == 2
    err = _one_error_line(capsys)
    assert f"--mcap: cannot write {str(mcap)!r} ({FULL}); it is left as it was" in err
    assert list(tmp_path.iterdir()) == []
    mcap.write_bytes(b"an earlier export")
    sizes.clear()
    assert main([*export, "--overwrite"]) == 2
    assert mcap.read_bytes() == b"an earlier export" and _leftovers(tmp_path) == []
    monkeypatch.setattr(AtomicFile, "write", real)
    assert main([*export, "--overwrite"]) == 0
    assert mcap.read_bytes()[:8] == b"\x89MCAP0\r\n" and _leftovers(tmp_path) == []


@pytest.mark.parametrize("fmt", ["opencv-yaml", "ros"])
def test_cameras_on_a_full_disk_write_nothing_and_a_rerun_is_not_refused(fmt, tmp_path, capsys,
                                                                        monkeypatch):
    real = Path.write_text

    def write_text(self, *args, **kwargs):
        if self.name == "cam2_handeye.yaml":
            raise _enospc()
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)
    out = tmp_path / "calibration" / "files"
    assert main(["cameras", "--write", str(out), "--format", fmt]) == 2
    err = _one_error_line(capsys)
    assert f"{out / 'cam2_handeye.yaml'}: cannot write the file ({FULL})" in err
    assert not (tmp_path / "calibration").exists()  # the folders made for it are gone too
    monkeypatch.setattr(Path, "write_text", real)
    assert main(["cameras", "--write", str(out), "--format", fmt]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["cam1_intrinsics.yaml", "cam1_handeye.yaml", "cam2_intrinsics.yaml",
         "cam2_handeye.yaml", "cameras.yaml", "cell.yaml"])
    assert "cameras:" in (out / "cameras.yaml").read_text()


def test_a_kept_cell_that_cannot_be_written_stops_the_run_in_one_line(tmp_path, capsys,
                                                                      monkeypatch):
    _fill_disk_for(monkeypatch, "run_cell.yaml")
    out = tmp_path / "run"
    assert main([*RUN, "--out", str(out)]) == 2
    assert f"run_cell.yaml: cannot write it ({FULL})" in _one_error_line(capsys)
    assert not (out / "metrics.json").exists() and _leftovers(tmp_path) == []

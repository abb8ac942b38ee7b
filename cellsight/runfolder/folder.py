"""The output folder of a run: which files a run writes (:data:`RUN_FILES`), and the check that
a folder can take a new run without losing anything that is not a run's output
(:func:`check_out_folder`, then :func:`make_out_folder`)."""

from __future__ import annotations

import errno
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

from cellsight.errors import CellsightError
from cellsight.runfolder.writes import TEMP_SUFFIX

RUN_FILE_DOCS = {
    "frames.csv": "one row per vision frame: poses, visibility, selection, measurements, "
                  "health, stage times (:mod:`.framelog`)",
    "metrics.json": "the run's facts and figures (:mod:`.metrics`); written last, so a folder "
                    "without it is not a finished run",
    "run.log": "the run's log, written as it goes",
    "report.html": "the report: figures, camera views, the video, the wrong corners",
    "keyframes.json": "the key frames: their times and what each shows",
    "views.mp4": "the cameras' views as a video",
    "run_cell.yaml": "the run's cell, kept so that the run replays without the original file "
                     "(:mod:`.cell_copy`)",
    "keyframes/*.png": "camera images at the key frames, features and windows drawn",
    "parts/*/frames.csv": "on a line, each pick's frame log but the first's (which is "
                          "frames.csv; :mod:`.picks`)",
    "fig_*.png": "the report's figures",
}
"""Every file a run writes into its folder, and what it holds."""
RUN_FILES = frozenset(name for name in RUN_FILE_DOCS if "*" not in name)
"""The files a run writes into its folder, besides ``keyframes/*.png`` and ``fig_*.png``."""


class RunFolderError(CellsightError, ValueError):
    """The output folder cannot take a run: a file, under a file, or holding other things."""


def _run_file_name(name: str) -> bool:
    """``name`` is one of :data:`RUN_FILES` or a ``fig_*.png``."""
    return name in RUN_FILES or (name.startswith("fig_") and name.endswith(".png"))


def is_run_output(path: Path) -> bool:
    """``path`` (in a run folder) is something a run writes: a file of :data:`RUN_FILES`, a
    ``fig_*.png``, the temporary file of one left by a killed run (``.<name>.<random>.tmp``,
    :mod:`cellsight.runfolder.writes`), the ``keyframes`` folder holding only ``*.png``
    files, or a line's ``parts`` folder holding only folders of a ``frames.csv`` (no links)."""
    if path.is_symlink():
        return False
    if path.is_dir() and path.name == "parts":
        return all(part.is_dir() and not part.is_symlink() and all(
            _frame_log(f) for f in part.iterdir()) for part in path.iterdir())
    if path.is_dir():
        return path.name == "keyframes" and all(
            p.suffix == ".png" and p.is_file() and not p.is_symlink() for p in path.iterdir())
    name = path.name
    if name.startswith(".") and name.endswith(TEMP_SUFFIX):
        name = name[1:].removesuffix(TEMP_SUFFIX).rpartition(".")[0]
    return path.is_file() and _run_file_name(name)


def _frame_log(path: Path) -> bool:
    """``path`` is a pick's ``frames.csv`` or a killed run's temporary file of one."""
    name = path.name
    if name.startswith(".") and name.endswith(TEMP_SUFFIX):
        name = name[1:].removesuffix(TEMP_SUFFIX).rpartition(".")[0]
    return name == "frames.csv" and path.is_file() and not path.is_symlink()


def _shown(out: Path) -> str:
    """A folder's name for a message: quoted, cut to 80 characters in the middle (its start and
    its last names, the telling part, stay)."""
    text = str(out)
    return repr(text) if len(text) <= 80 else repr(text[:30] + "..." + text[-47:])


def check_folder(out: Path, arg: str) -> bool:
    """Check that ``out`` is a folder this process may write into, or can be made one (it is
    not a file, not under one, and the folder it would be made in takes it); returns whether
    it exists. A :class:`RunFolderError` naming ``arg`` (the option)."""
    existing = next(p for p in (out, *out.parents) if p.exists() or p.is_symlink())
    if not existing.is_dir():
        where = "is not a folder" if existing == out else f"is under {str(existing)!r}, a file"
        raise RunFolderError(f"{arg}: {_shown(out)} {where}; expected a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "write in it" if existing == out else f"create it in {_shown(existing)}"
        raise RunFolderError(f"{arg}: {_shown(out)}: cannot {what} ({_why_not(existing)}); "
                             f"choose another folder")
    return existing == out


def _why_not(folder: Path) -> str:
    """Why this process cannot write in ``folder``: a read-only file system, or permission."""
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):  # no statvfs (Windows)
        read_only = False
    return os.strerror(errno.EROFS if read_only else errno.EACCES)


def check_new_files(out: Path, names: Sequence[str], overwrite: bool, arg: str) -> None:
    """Check, touching nothing, that the folder ``out`` (:func:`check_folder`) can take the
    files ``names``: it holds none of them, or ``overwrite`` replaces them."""
    check_folder(Path(out), arg)
    if not overwrite and (there := [n for n in names if (Path(out) / n).exists()]):
        raise RunFolderError(f"{arg}: {_shown(out)} already holds {', '.join(there)}; pass "
                             f"--overwrite to replace them")


def check_out_folder(out: Path, overwrite: bool, arg: str = "RunConfig.out",
                     flag: str = "overwrite=True",
                     is_output: Callable[[Path], bool] = is_run_output) -> list[Path]:
    """Check, touching nothing, that the folder ``out`` can take a new run: absent (then
    creatable: not under a file), empty, or, with ``overwrite``, holding only an earlier run's
    outputs (``is_output``: by default :func:`is_run_output`; another command's own), which are
    returned for the caller to clear. Otherwise a :class:`RunFolderError` naming ``arg`` (the
    option), the folder and, to pass, ``flag``."""
    out = Path(out)
    shown = _shown(out)
    try:
        entries = sorted(out.iterdir()) if check_folder(out, arg) else []
        if entries and not overwrite:
            raise RunFolderError(f"{arg}: {shown} is not empty ({len(entries)} entries); pass "
                                 f"{flag} or choose another folder")
        stranger = next((p for p in entries if not is_output(p)), None)
    except OSError as exc:
        raise RunFolderError(f"{arg}: {shown}: not a usable folder ({exc.strerror})") from exc
    if stranger is not None:
        raise RunFolderError(f"{arg}: {shown} holds {stranger.name!r}, not a run's output; not "
                             f"overwriting: move it or choose another folder")
    return entries


def make_out_folder(out: Path, stale: list[Path], arg: str = "RunConfig.out") -> None:
    """Remove ``stale`` (an earlier run's outputs, :func:`check_out_folder`), create ``out``."""
    try:
        for path in stale:
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunFolderError(f"{arg}: {str(out)!r}: cannot clear or create it "
                             f"({exc.strerror})") from exc

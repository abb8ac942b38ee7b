"""``cellsight cameras``: a cell's cameras as a table, or written as calibration files.

``cellsight cameras [--cell NAME|FILE]`` prints one row per camera: name, image size, fx, fy,
cx, cy (px), distortion (k1 k2 p1 p2 k3) and the optical centre in the base frame (m); when
the output is not a terminal (a pipe, a file) nothing wraps: a row is one line. ``--json``
prints the cameras as a JSON list instead (:func:`camera_records`).

``cellsight cameras [--cell NAME|FILE] --write DIR [--format opencv-yaml|opencv-xml|ros]``
writes, per camera, an intrinsics file and a hand-eye pose file in the chosen format
(:mod:`cellsight.model.calibration`):

- ``opencv-yaml`` / ``opencv-xml``: ``<name>_intrinsics.yaml|xml`` (OpenCV FileStorage:
  ``image_width``, ``image_height``, ``camera_matrix``, ``distortion_coefficients``, and
  ``projection_matrix`` for a camera that kept its calibration file's ``P``) and
  ``<name>_handeye.yaml|xml`` (``R_base_camera``, ``t_base_camera``);
- ``ros``: ``<name>_intrinsics.yaml`` (ROS camera_info; ``projection_matrix``: the kept ``P``,
  else ``[K | 0]``) and ``<name>_handeye.yaml`` (easy_handeye, ``robot_base_frame: base``, the
  cell's base frame);

and, to load them back, ``cameras.yaml`` (the ``cameras:`` section that refers to them, to
paste into a cell file) and ``cell.yaml`` (the whole cell with that section; its other files,
meshes, URDFs and package folders, named by absolute paths so that it loads from ``DIR``).
Files already in ``DIR`` are kept unless ``--overwrite`` is given. The files are written
together (:func:`cellsight.runfolder.writes.staged`): all of them, or, when one cannot be written
(a full disk), none (a folder made for them is removed again), so a second try is not refused.

The command's ``register(sub)`` adds it to ``cellsight``'s sub-commands.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from cellsight.commands.text import CELL_HELP
from cellsight.errors import CellsightError
from cellsight.model.yaml_input import with_absolute_paths

if TYPE_CHECKING:  # imported where used: `cellsight --help` stays quick (no OpenCV)
    from rich.console import Console

    from cellsight.camera import Camera
    from cellsight.model.schema import CellSpec

BASE_FRAME = "base"  # the cell's base frame's name in easy_handeye files
#: --format -> (extension, intrinsics format, hand-eye format) of the files written
FORMATS = {
    "opencv-yaml": (".yaml", "opencv", "opencv"),
    "opencv-xml": (".xml", "opencv", "opencv"),
    "ros": (".yaml", "ros", "easy_handeye"),
}
CELL_FILE, CAMERAS_FILE = "cell.yaml", "cameras.yaml"
PIPED_WIDTH = 10_000  # characters: the table's width limit when stdout is not a terminal


def camera_files(name: str, fmt: str) -> tuple[str, str]:
    """The intrinsics and hand-eye file names of camera ``name`` in format ``fmt``."""
    ext = FORMATS[fmt][0]
    return f"{name}_intrinsics{ext}", f"{name}_handeye{ext}"


def write_camera(camera: Camera, out: Path, fmt: str) -> tuple[Path, Path]:
    """One camera's intrinsics and hand-eye files in ``out``; returns their paths."""
    from cellsight.model.calibration import (
        write_easy_handeye,
        write_opencv_hand_eye,
        write_opencv_intrinsics,
        write_ros_camera_info,
    )

    intrinsics, hand_eye = (out / f for f in camera_files(camera.name, fmt))
    if FORMATS[fmt][1] == "ros":
        write_ros_camera_info(intrinsics, camera)
        write_easy_handeye(hand_eye, camera.T_base_cam, BASE_FRAME,
                           f"{camera.name}_optical_frame")
    else:
        write_opencv_intrinsics(intrinsics, camera)
        write_opencv_hand_eye(hand_eye, camera.T_base_cam)
    return intrinsics, hand_eye


def camera_entries(cameras: list[Camera], fmt: str) -> list[dict]:
    """The ``cameras:`` entries of a cell file referring to the files of :func:`write_camera`
    (names relative to the folder they are in)."""
    _, calibration, hand_eye = FORMATS[fmt]
    entries = []
    for camera in cameras:
        intrinsics, pose = camera_files(camera.name, fmt)
        entries.append({"name": camera.name,
                        "calibration": {"file": intrinsics, "format": calibration},
                        "hand_eye": {"file": pose, "format": hand_eye}})
    return entries


def _dump(data: object) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def write_cameras(cell_file: Path, raw: dict, cameras: list[Camera], out: Path, fmt: str,
                  overwrite: bool = False) -> list[Path]:
    """Every camera's files (:func:`write_camera`), ``cameras.yaml`` and ``cell.yaml`` (the
    cell file ``cell_file``, of mapping ``raw``, with its cameras from those files) in
    ``out``; existing files are refused unless ``overwrite``. Returns the paths written. All of
    them are written, or none: a failure is one error naming the file and why."""
    if fmt not in FORMATS:
        raise CellsightError(f"--format: got {fmt!r}; expected one of {', '.join(FORMATS)}")
    if len({c.name.lower() for c in cameras}) != len(cameras):
        raise CellsightError("--write: camera names that differ only in case would share "
                             f"files: {[c.name for c in cameras]}")
    names = [f for c in cameras for f in camera_files(c.name, fmt)] + [CAMERAS_FILE, CELL_FILE]
    from cellsight.runfolder.folder import check_new_files

    check_new_files(out, names, overwrite, "--write")
    from cellsight.runfolder.writes import make_folders, remove_folders

    try:
        made = make_folders(out)  # removed again when the files cannot be written
    except OSError as exc:
        raise CellsightError(f"--write: cannot make the folder {out} ({exc.strerror})") from exc
    try:
        _write_files(cell_file, raw, cameras, out, fmt)
    except BaseException:
        remove_folders(made)
        raise
    return [out / name for name in names]


def _write_files(cell_file: Path, raw: dict, cameras: list[Camera], out: Path,
                 fmt: str) -> None:
    """The files of :func:`write_cameras`, all written into a temporary folder in ``out``
    first, then moved into ``out`` together (:func:`~cellsight.runfolder.writes.staged`)."""
    from cellsight.runfolder.writes import staged, write_file

    with staged(out) as stage:
        try:
            for camera in cameras:
                write_camera(camera, stage, fmt)
            entries = camera_entries(cameras, fmt)
            cell = with_absolute_paths(raw, cell_file.resolve().parent)
            cell["cameras"] = entries
            for name, data in ((CAMERAS_FILE, {"cameras": entries}), (CELL_FILE, cell)):
                header = f"# {name} written by 'cellsight cameras' from {cell_file}\n"
                write_file(stage / name, header + _dump(data))
        except CellsightError as exc:  # the file by the name it was to have, not the stage's
            raise CellsightError(str(exc).replace(str(stage), str(out))) from exc


def _distortion(camera: Camera) -> str:
    return "none" if camera.dist is None else " ".join(f"{v:.4g}" for v in camera.dist)


def camera_rows(cameras: list[Camera]) -> list[tuple[str, ...]]:
    """Table rows: name, size, fx, fy, cx, cy (px), distortion, position (m)."""
    return [(c.name, f"{c.width}x{c.height}", *(f"{v:.2f}" for v in
             (c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2])), _distortion(c),
             "[" + ", ".join(f"{v:.3f}" for v in c.center) + "]") for c in cameras]


def camera_records(cell_file: Path, spec: CellSpec, cameras: list[Camera]) -> list[dict]:
    """``--json``: per camera its ``name``, ``width`` and ``height`` (px), ``K`` (3x3, px),
    ``dist`` (k1 k2 p1 p2 k3, or None), ``P`` (3x4, px: its calibration file's, or None for
    ``[K | 0]``), ``T_base_cam`` (4x4, m: the optical frame in the cell's base frame), and the
    files it comes from (absolute paths): ``source_file`` (the calibration file, or the cell
    file that gives the intrinsics), ``hand_eye_file`` (or None) and ``cell_file``."""
    specs = {cs.name: cs for cs in spec.cameras}
    folder = cell_file.resolve().parent
    records = []
    for c in cameras:
        cs = specs[c.name]
        records.append({
            "name": c.name, "width": c.width, "height": c.height, "K": c.K.tolist(),
            "dist": None if c.dist is None else c.dist.tolist(),
            "P": None if c.P is None else c.P.tolist(), "T_base_cam": c.T_base_cam.tolist(),
            "source_file": str(folder / cs.calibration.file if cs.calibration is not None
                               else cell_file.resolve()),
            "hand_eye_file": None if cs.hand_eye is None else str(folder / cs.hand_eye.file),
            "cell_file": str(cell_file.resolve())})
    return records


def _console() -> Console:
    """A console that wraps nothing: text lines are never broken (soft wrap), and a table is
    as wide as its rows when stdout is not a terminal (rich would use 80 columns)."""
    from rich.console import Console

    console = Console(soft_wrap=True)
    return console if console.is_terminal else Console(soft_wrap=True, width=PIPED_WIDTH)


def cmd_cameras(args: argparse.Namespace) -> int:
    from rich.markup import escape
    from rich.table import Table

    from cellsight.model.loader import build_cell, cell_path, parse_cell_text
    from cellsight.model.yaml_input import read_cell_text

    path = cell_path(args.cell)
    spec, raw = parse_cell_text(read_cell_text(path), str(path), path.parent)
    cameras = build_cell(spec, str(path), path.parent).cameras
    if args.json:
        print(json.dumps(camera_records(path, spec, cameras), indent=2))
        return 0
    console = _console()
    if args.write is not None:
        for written in write_cameras(path, raw, cameras, Path(args.write), args.format,
                                     args.overwrite):
            console.print(f"wrote [bold]{escape(str(written))}[/bold]")
        return 0
    console.print(f"cameras of [bold]{escape(str(path))}[/bold]")
    table = Table()
    for column in ("camera", "size", "fx", "fy", "cx", "cy", "distortion k1 k2 p1 p2 k3",
                   "position (m)"):
        table.add_column(column, justify="left" if column in ("camera", "size") else "right")
    for row in camera_rows(cameras):
        table.add_row(*map(escape, row))
    console.print(table)
    return 0


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``cameras`` to ``cellsight``'s sub-commands; returns its parser."""
    cameras = sub.add_parser("cameras", help="the cell's cameras: a table, or calibration files "
                                             "(--write)")
    cameras.add_argument("--cell", help=CELL_HELP)
    output = cameras.add_mutually_exclusive_group()
    output.add_argument("--json", action="store_true",
                        help="print the cameras as JSON (name, size, K, dist, P, T_base_cam, "
                             "the files they come from) instead of a table")
    output.add_argument("--write", metavar="DIR",
                         help="write each camera's intrinsics and hand-eye files, cameras.yaml "
                              "and cell.yaml (which loads them) in DIR")
    cameras.add_argument("--format", choices=tuple(FORMATS), default="opencv-yaml",
                         help="files to write: OpenCV FileStorage YAML (default) or XML, or ROS "
                              "camera_info + easy_handeye YAML")
    cameras.add_argument("--overwrite", action="store_true",
                         help="replace files of the same names already in DIR")
    cameras.set_defaults(func=cmd_cameras)
    return cameras

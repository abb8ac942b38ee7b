"""What ``cellsight calibrate`` writes into its folder, all together or nothing
(:func:`cellsight.runfolder.writes.staged`):

- ``cameras/<name>.yaml`` (OpenCV FileStorage intrinsics), ``cameras/<name>_camera_info.yaml``
  (ROS camera_info) and ``cameras/<name>_hand_eye.yaml`` (easy_handeye: the camera's optical
  frame in the reference robot's base frame), which the cell loader reads;
- ``cell.yaml``: the cell file with its cameras taken from those files (``hand_eye`` in the
  reference robot's frame) and the other robots' bases calibrated, its other files named by
  absolute paths;
- ``calibration.json`` (:mod:`.folder` reads it back): each estimate in the reference frame,
  its standard deviations, the residuals (px) per camera and view, and, in the simulated
  world, each estimate's error against the world's truth (:mod:`.score`);
- ``residuals.png``: the reprojection residuals per camera and pose, and ``report.html``.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from cellsight.calibration.folder import CALIBRATION_FILE, SCHEMA_VERSION  # noqa: E402
from cellsight.calibration.solution import Solution, View  # noqa: E402
from cellsight.geometry.transforms import xyz_rpy_from_pose  # noqa: E402
from cellsight.model import Cell  # noqa: E402
from cellsight.model.calibration import (  # noqa: E402
    write_easy_handeye,
    write_opencv_intrinsics,
    write_ros_camera_info,
)
from cellsight.model.yaml_input import load_yaml, read_cell_text, with_absolute_paths  # noqa: E402
from cellsight.runfolder.digest import cell_digest  # noqa: E402
from cellsight.runfolder.writes import staged, write_figure, write_file  # noqa: E402

OUTPUTS = frozenset({"cameras", "cell.yaml", CALIBRATION_FILE, "residuals.png", "report.html"})
"""The names :func:`write_calibration` writes into its folder."""


def is_calibration_output(path: Path) -> bool:
    """``path`` (in a calibration folder) is something :func:`write_calibration` writes: one of
    :data:`OUTPUTS`, the ``cameras`` folder holding only files (no links)."""
    if path.is_symlink() or path.name not in OUTPUTS:
        return False
    if path.is_dir():
        return path.name == "cameras" and all(p.is_file() and not p.is_symlink()
                                              for p in path.iterdir())
    return path.is_file()


def _rounded(value: object) -> object:
    if isinstance(value, np.ndarray):
        return np.round(value, 9).tolist()
    if isinstance(value, float):
        return round(value, 9)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value


def _std(pose) -> dict:
    return {"position_mm": _rounded(pose.position_mm), "rotation_deg": _rounded(pose.rotation_deg)}


def calibration_record(cell: Cell, reference: str, solution: Solution, views: list[View],
                       facts: dict) -> dict:
    """``calibration.json``'s content (module docstring); ``facts``: how it was made (the
    world, the board, the poses) and, in the simulated world, ``errors`` against the truth."""
    cameras = {}
    for c, (cam, std) in enumerate(zip(solution.cameras, solution.camera_std, strict=True)):
        cameras[cam.name] = {
            "width": cam.width, "height": cam.height, "K": _rounded(cam.K),
            "dist": _rounded(cam.dist5), "T_ref_cam": _rounded(cam.T_base_cam),
            "rms_px": _rounded(float(solution.camera_rms_px[c])),
            "views": sum(v.camera == c for v in views),
            "std": {**_std(std.pose), "focal_percent": _rounded(std.focal_pct),
                    "principal_point_px": _rounded(std.principal_px)}}
    robots = {name: {"T_ref_robot": _rounded(T),
                     "std": None if name == reference else _std(solution.robot_std[name]),
                     "T_flange_board": _rounded(solution.T_flange_board.get(name)),
                     "joint_offsets": _rounded(solution.joint_offsets.get(name)),
                     "joint_offsets_identifiable":
                         solution.joint_offsets_identifiable.get(name, np.zeros(0)).tolist()}
              for name, T in solution.T_ref_robot.items()}
    return {"schema": SCHEMA_VERSION, "cell": cell.source, "cell_sha256": cell_digest(cell),
            "reference_robot": reference, "rms_px": _rounded(solution.rms_px),
            "cameras": cameras, "robots": robots, **facts,
            "views": [{"camera": cell.cameras[v.camera].name, "robot": v.robot,
                       "pose": v.pose, "corners": len(v.ids),
                       "rms_px": _rounded(float(solution.view_rms_px[i]))}
                      for i, v in enumerate(views)]}


def _cell_file(cell: Cell, reference: str, solution: Solution) -> str:
    """``cell.yaml`` (module docstring) from the cell file's text."""
    source = Path(cell.source)
    raw = with_absolute_paths(load_yaml(read_cell_text(source), str(source)), source.parent)
    for entry in raw.get("cameras", []):
        name = entry["name"]
        entry.clear()
        entry.update(name=name, calibration=f"cameras/{name}.yaml",
                     hand_eye={"file": f"cameras/{name}_hand_eye.yaml", "robot": reference})
    bases = {r.name: r.T_base_robot for r in cell.robots}
    for entry in raw.get("robots", []):
        name = entry.get("name")
        if name in solution.T_ref_robot and name != reference:
            xyz, rpy = xyz_rpy_from_pose(bases[reference] @ solution.T_ref_robot[name])
            entry["base"] = {"xyz": np.round(xyz, 9).tolist(), "rpy": np.round(rpy, 9).tolist()}
    return (f"# {cell.name}, calibrated by cellsight calibrate (cameras and robot bases; "
            f"from {source})\n" + yaml.safe_dump(raw, sort_keys=False))


def _residual_figure(cell: Cell, solution: Solution, views: list[View]):
    figure, axes = plt.subplots(1, len(cell.cameras), figsize=(5 * len(cell.cameras), 4),
                                squeeze=False)
    for c, ax in enumerate(axes[0]):
        mine = [i for i, v in enumerate(views) if v.camera == c]
        for i in mine:
            r = solution.residuals_px[i]
            ax.scatter(r[:, 0], r[:, 1], s=4, label=f"{views[i].robot} pose {views[i].pose}")
        ax.set_title(f"{cell.cameras[c].name}: {len(mine)} views, RMS "
                     f"{solution.camera_rms_px[c]:.3f} px")
        ax.set_xlabel("residual x (px)")
        ax.set_ylabel("residual y (px)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    figure.tight_layout()
    return figure


def _report(record: dict) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{c['views']}</td><td>{c['rms_px']:.3f}</td>"
        + "".join(f"<td>{v:.3f}</td>" for v in
                  ((record.get("errors") or {}).get("cameras", {}).get(name) or {}).values())
        + "</tr>" for name, c in record["cameras"].items())
    head = "".join(f"<th>{html.escape(k)}</th>" for k in
                   next(iter((record.get("errors") or {}).get("cameras", {}).values()), {}))
    return (f"<!doctype html><meta charset=utf-8><title>cellsight calibration</title>"
            f"<h1>Calibration of {html.escape(str(record['cell']))}</h1>"
            f"<p>{html.escape(record['verdict'])}</p>"
            f"<table border=1 cellpadding=4><tr><th>camera</th><th>views</th><th>RMS px</th>"
            f"{head}</tr>{rows}</table><p><img src=residuals.png width=100%></p>"
            f"<pre>{html.escape(json.dumps(record.get('errors', {}), indent=1))}</pre>")


def write_calibration(out: Path, cell: Cell, reference: str, solution: Solution,
                      views: list[View], facts: dict) -> dict:
    """Write the folder (module docstring) into ``out`` (made by the caller); returns the
    record written as ``calibration.json``."""
    record = calibration_record(cell, reference, solution, views, facts)
    with staged(out) as stage:
        (stage / "cameras").mkdir()
        for cam in solution.cameras:
            write_opencv_intrinsics(stage / "cameras" / f"{cam.name}.yaml", cam)
            write_ros_camera_info(stage / "cameras" / f"{cam.name}_camera_info.yaml", cam)
            write_easy_handeye(stage / "cameras" / f"{cam.name}_hand_eye.yaml", cam.T_base_cam,
                               robot_base_frame=reference)
        if Path(cell.source).is_file():
            write_file(stage / "cell.yaml", _cell_file(cell, reference, solution))
        write_file(stage / CALIBRATION_FILE, json.dumps(record, indent=1))
        figure = _residual_figure(cell, solution, views)
        write_figure(stage / "residuals.png", figure)
        plt.close(figure)
        write_file(stage / "report.html", _report(record))
    return record

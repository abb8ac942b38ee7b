"""`cellsight show`: a 3D picture of the cell and each camera's projected wireframe.

The camera views draw every solid's edges as the camera sees them (OpenCV pixels, image frame
drawn), the workpieces in colour with their feature points numbered; when visibility is given,
visible features are green and hidden ones red with the occluder's name.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from cellsight.camera import MIN_DEPTH_M  # noqa: E402
from cellsight.geometry.transforms import transform_points  # noqa: E402
from cellsight.model.cell import Cell, Snapshot  # noqa: E402
from cellsight.runfolder.writes import (  # noqa: E402
    make_folders,
    remove_folders,
    staged,
    write_figure,
)

KIND_COLOURS = {"link": "#f28e2b", "tool": "#4e79a7", "workpiece": "#e15759", "static": "#bab0ac"}


def plot_cell_3d(snapshot: Snapshot, path: Path) -> Path:
    """Shaded 3D view of every solid and the cameras' optical axes; saved as PNG."""
    cell = snapshot.cell
    fig = plt.figure(figsize=(9, 7))
    ax = fig.add_subplot(projection="3d")
    for obj, T in zip(cell.objects, snapshot.poses, strict=True):
        polys = [transform_points(T, p) for p in obj.solid.polygons()]
        ax.add_collection3d(Poly3DCollection(polys, facecolor=KIND_COLOURS[obj.kind],
                                             edgecolor="k", linewidths=0.2, alpha=0.55))
    for cam in cell.cameras:
        c, z = cam.center, cam.T_base_cam[:3, 2]
        ax.scatter(*c, color="k", marker="^", s=40)
        ax.plot(*np.column_stack([c, c + 0.6 * z]), color="k", lw=1)
        ax.text(*c, f" {cam.name}", fontsize=9)
    ax.set(xlabel="x [m]", ylabel="y [m]", zlabel="z [m]", title=f"{cell.name}")
    ax.set_xlim(-0.6, 2.2)
    ax.set_ylim(-1.4, 1.4)
    ax.set_zlim(0, 2.2)
    ax.set_box_aspect((2.8, 2.8, 2.2))
    ax.view_init(elev=25, azim=-60)
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)
    return path


def draw_wireframe(ax, snapshot: Snapshot, camera: int) -> None:
    """Draw every solid's edges projected into one camera on a matplotlib axis (pixels)."""
    cell = snapshot.cell
    cam = cell.cameras[camera]
    for obj, T in zip(cell.objects, snapshot.poses, strict=True):
        colour = KIND_COLOURS[obj.kind]
        lw = 1.2 if obj.kind == "workpiece" else 0.6
        for poly in obj.solid.polygons():
            pts = transform_points(T, poly)
            if not (cam.depth(pts) > MIN_DEPTH_M).all():
                continue
            uv = cam.project(pts)
            uv = np.vstack([uv, uv[:1]])
            ax.plot(uv[:, 0], uv[:, 1], color=colour, lw=lw)
    ax.set_xlim(-0.5, cam.width - 0.5)
    ax.set_ylim(cam.height - 0.5, -0.5)
    ax.set_aspect("equal")


def plot_camera_view(snapshot: Snapshot, camera: int, path: Path, visibility=None) -> Path:
    """One camera's wireframe with the workpieces' features numbered; saved as PNG.

    ``visibility``: optional mapping workpiece name -> per-camera object with ``visible``
    (bool per feature) and ``reason`` (str per feature), as the occlusion predictor returns.
    """
    cell = snapshot.cell
    cam = cell.cameras[camera]
    fig, ax = plt.subplots(figsize=(7.68, 5.76))
    ax.set_facecolor("#202020")
    draw_wireframe(ax, snapshot, camera)
    for part in cell.workpieces:
        pts = transform_points(snapshot.part_poses[part.name], part.feature_points)
        uv = cam.project(pts)
        vis = None if visibility is None else visibility[part.name][camera]
        for j, name in enumerate(part.feature_names):
            if not np.all(np.isfinite(uv[j])):
                continue
            colour = "#ffd92f" if vis is None else ("#59d659" if vis.visible[j] else "#ff40ff")
            ax.plot(*uv[j], "o", ms=4, color=colour)
            ax.annotate(name.lstrip("f"), uv[j], xytext=(3, -3), textcoords="offset points",
                        color=colour, fontsize=8)
    title = f"{cam.name}: {cam.width}x{cam.height}, f = {cam.focal_px:.0f} px"
    if visibility is not None:
        n_vis = sum(int(v[camera].visible.sum()) for v in visibility.values())
        title += f" - {n_vis} features visible (green), hidden (magenta)"
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    write_figure(path, fig, dpi=100)
    plt.close(fig)
    return path


def show_files(cell: Cell) -> list[str]:
    """The names of the files :func:`show_cell` writes for ``cell``."""
    return ["cell_3d.png"] + [f"view_{cam.name}.png" for cam in cell.cameras]


def show_cell(snapshot: Snapshot, out_dir: Path, visibility=None) -> list[Path]:
    """Write the 3D view and one wireframe per camera (:func:`show_files`) into ``out_dir``;
    returns the paths. All of them, or none when one cannot be written (a full disk:
    :func:`~cellsight.runfolder.writes.staged`; the folders made for them are removed again)."""
    made = make_folders(out_dir)
    names = show_files(snapshot.cell)
    try:
        with staged(out_dir) as stage:
            plot_cell_3d(snapshot, stage / names[0])
            for k, name in enumerate(names[1:]):
                plot_camera_view(snapshot, k, stage / name, visibility)
    except BaseException:
        remove_folders(made)
        raise
    return [out_dir / name for name in names]

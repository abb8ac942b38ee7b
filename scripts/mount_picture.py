"""What a gripper's ``mount`` does, drawn from a cell file: the last links and the gripper of a
robot at HOME, seen along the tool's x axis (tool y to the right, the approach z up), with the
cell's mount and with the mount moved along z, and what ``cellsight check`` says of each.

    python scripts/mount_picture.py [--cell kr16-cell] [--robot KR16A] [--shift-mm -65.5]
        [--out docs/mount.png]

Each solid is drawn as the outline of its vertices projected on the tool's (y, z) plane."""

from __future__ import annotations

import argparse
import textwrap
from dataclasses import replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import ConvexHull  # noqa: E402

from cellsight import load_cell  # noqa: E402
from cellsight.experiments.cellcheck import check_cell  # noqa: E402
from cellsight.geometry.transforms import make_pose  # noqa: E402

LINKS_SHOWN = 2  # the flange link and the one before it


def _outline(ax, vertices: np.ndarray, T_tool: np.ndarray, colour: str, label: str) -> None:
    """The solid's vertices (base frame) in the tool frame, projected on (y, z), outlined."""
    local = (vertices - T_tool[:3, 3]) @ T_tool[:3, :3]
    yz = 1e3 * local[:, 1:]
    hull = ConvexHull(yz)
    ax.fill(*yz[hull.vertices].T, color=colour, alpha=0.55, label=label, lw=1.0, ec="k")


def _panel(ax, cell, name: str, title: str) -> None:
    robot = next(r for r in cell.robots if r.name == name)
    T_tool = robot.tool_pose(robot.home)
    poses = robot.link_poses(robot.home)
    for frame, link, solids in robot.link_groups()[-LINKS_SHOWN:]:
        for solid in solids:
            v = solid.vertices @ poses[frame][:3, :3].T + poses[frame][:3, 3]
            _outline(ax, v, T_tool, "0.7", link)
    tool = robot.tool
    for solid in tool.palm:
        _outline(ax, solid.vertices @ T_tool[:3, :3].T + T_tool[:3, 3], T_tool, "tab:blue",
                 "palm")
    for jaw, T_jaw in zip(tool.jaws, tool.jaw_poses(tool.max_opening), strict=True):
        T = T_tool @ T_jaw
        _outline(ax, jaw.solid.vertices @ T[:3, :3].T + T[:3, 3], T_tool, "tab:orange", "jaw")
    ax.annotate("", (0, 40), (0, 0), arrowprops={"arrowstyle": "->", "color": "k", "lw": 2})
    ax.annotate("", (40, 0), (0, 0), arrowprops={"arrowstyle": "->", "color": "k", "lw": 2})
    ax.text(2, 42, "tool z (approach)", fontsize=8)
    ax.text(42, 2, "tool y", fontsize=8)
    lines = [f.line for f in check_cell(cell, crossing=False)
             if f.level != "ok" and robot.name in f.line and "mount" in f.line]
    said = "check: " + (lines[0] if lines else "nothing to say of the mount")
    ax.set_title(title + "\n" + "\n".join(textwrap.wrap(said, 70)), fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("tool y (mm)")
    ax.set_ylabel("tool z (mm)")
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax.legend(unique.values(), unique.keys(), fontsize=7, loc="lower right")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cell", default="kr16-cell")
    parser.add_argument("--robot", default="KR16A")
    parser.add_argument("--shift-mm", type=float, default=-65.5,
                        help="the mount moved along the tool's z (mm) in the second panel")
    parser.add_argument("--out", default="docs/mount.png")
    args = parser.parse_args()
    cell = load_cell(args.cell)
    robot = cell.robot(args.robot)
    shifted = replace(robot.tool, T_flange_tool=robot.tool.T_flange_tool
                      @ make_pose(None, (0.0, 0.0, args.shift_mm / 1e3)))
    moved = load_cell(args.cell)
    moved.robots = [replace(r, tool=shifted) if r.name == robot.name else r
                    for r in moved.robots]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.5))
    _panel(axes[0], cell, robot.name, f"{cell.name}: the cell file's mount")
    _panel(axes[1], moved, robot.name, f"the mount moved {args.shift_mm:g} mm along tool z")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

"""``cellsight calibrate``: the cell's cameras (intrinsics and poses) and robot bases, from a
calibration board on the robots' flanges (:mod:`cellsight.calibration`), in the simulated world
a seed draws or (later) from a recording of a real cell's calibration motion."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.commands.text import CELL_HELP


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight calibrate`` to the sub-commands."""
    cal = sub.add_parser(
        "calibrate", help="calibrate the cameras and robot bases with a board on the flanges",
        description="Calibrate every camera (intrinsics and pose) and every robot's base in one "
                    "frame, the grasping robot's base, from a ChArUco board bolted to each "
                    "robot's flange in turn: the command plans the poses (reachable, free of "
                    "collisions, the board in view), the robot moves through them, the board's "
                    "corners are detected, and one least-squares fit over all cameras, poses "
                    "and robots finishes OpenCV's first estimates. Writes the cameras as "
                    "OpenCV and ROS calibration files, a cell file that uses them, "
                    "calibration.json and report.html.")
    cal.add_argument("--cell", help=CELL_HELP)
    cal.add_argument("--realism", default="lab", metavar="PROFILE",
                     help="the simulated world to calibrate (as cellsight run --realism; "
                          "default lab)")
    cal.add_argument("--seed", type=int, default=0,
                     help="the world's seed: the same cameras, robots and noise as "
                          "'cellsight run --seed N' (0)")
    cal.add_argument("--out", required=True, help="output folder")
    cal.add_argument("--board", metavar="FILE",
                     help="the board as a YAML file (squares, square_m, marker_m, dictionary, "
                          "mount); default: 7 x 5 squares of 30 mm, DICT_5X5_100, on the "
                          "flange's face")
    cal.add_argument("--poses", type=int, default=8, metavar="N",
                     help="poses planned per camera and robot (default 8, at least 6)")
    cal.add_argument("--joint-offsets", action="store_true",
                     help="also estimate each robot's joint zero offsets, and report whether "
                          "they are identifiable")
    cal.add_argument("--quiet", action="store_true", help="no progress bar")
    cal.add_argument("--overwrite", action="store_true",
                     help="clear --out first if it holds an earlier calibration")
    cal.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from cellsight.calibration.command import calibrate_command

    return calibrate_command(args.cell, args.realism, args.seed, Path(args.out), args.board,
                             args.poses, args.joint_offsets, not args.quiet, args.overwrite)

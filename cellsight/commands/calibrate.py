"""``cellsight calibrate``: the cell's cameras (intrinsics and poses) and robot bases, from a
calibration board on the robots' flanges (:mod:`cellsight.calibration`), in the simulated world
a seed draws or from a recording of a cell's calibration motion."""

from __future__ import annotations

import argparse
from pathlib import Path

from cellsight.calibration import POSES_PER_CAMERA
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
                    "calibration.json and report.html. Given a RECORDING of a calibration "
                    "motion (MCAP or rosbag2: images and joint states, as cellsight track reads "
                    "them; --record makes one), calibrates from it instead.")
    cal.add_argument("recording", nargs="?",
                     help="an .mcap file or a rosbag2 folder of a calibration motion (default: "
                          "the simulated world of --realism and --seed)")
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
    cal.add_argument("--poses", type=int, default=POSES_PER_CAMERA, metavar="N",
                     help=f"poses planned per camera and robot (default {POSES_PER_CAMERA}, "
                          f"at least 6)")
    cal.add_argument("--joint-offsets", action=argparse.BooleanOptionalAction, default=True,
                     help="estimate each robot's joint zero offsets too, and report whether "
                          "they are identifiable (default on: the encoders' offsets otherwise "
                          "bend the board's poses into the cameras' estimates)")
    cal.add_argument("--record", metavar="FILE",
                     help="also record the simulated calibration motion as a real cell would "
                          "(images, joint states) in an MCAP file, for cellsight calibrate FILE")
    cal.add_argument("--record-jpeg", type=int, metavar="QUALITY",
                     help="record the images as JPEG of this quality (1-100; default lossless)")
    cal.add_argument("--topics", metavar="FILE",
                     help="with a RECORDING: a YAML topic map, as cellsight track's")
    cal.add_argument("--sync-tolerance", type=float, default=0.019, metavar="S",
                     help="with a RECORDING: images of several cameras stamped within S seconds "
                          "form one frame (default 0.019)")
    cal.add_argument("--quiet", action="store_true", help="no progress bar")
    cal.add_argument("--overwrite", action="store_true",
                     help="clear --out first if it holds an earlier calibration")
    cal.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from cellsight.calibration.command import CalibrateRequest, calibrate_command
    from cellsight.errors import CellsightError

    if args.record_jpeg is not None and args.record is None:
        raise CellsightError("--record-jpeg: needs --record FILE")
    return calibrate_command(CalibrateRequest(
        Path(args.out), args.cell, args.recording, args.realism, args.seed, args.board,
        args.poses, args.joint_offsets, args.record, args.record_jpeg, args.topics,
        args.sync_tolerance, not args.quiet, args.overwrite))

"""The tracker's options of ``cellsight run`` and ``cellsight track``: one set of arguments,
read into a :class:`~cellsight.trackers.TrackerChoice`."""

from __future__ import annotations

import argparse

from cellsight.trackers import EXPERIMENTAL, TRACKERS, TrackerChoice


def add_tracker_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--tracker``, ``--no-occlusion-prediction`` and ``--experimental``."""
    parser.add_argument("--tracker", choices=TRACKERS, default="kinematic",
                        help="kinematic (default): the images, plus the arm's measured motion "
                             "while it holds the part, the part's support before and after, and "
                             "the cameras registered to the gripper; plain: the paper's tracker, "
                             "from the images alone (for comparison)")
    parser.add_argument("--no-occlusion-prediction", action="store_true",
                        help="windows on every model point inside the image (no occlusion "
                             "prediction)")
    parser.add_argument("--experimental", action="append", choices=EXPERIMENTAL, default=[],
                        metavar="OPTION",
                        help="an experimental tracker option, not shown to help in the 20-seed "
                             "tables (repeatable): camera-offsets (each camera's calibration "
                             "error estimated as an image offset, 5 px prior), "
                             "unknown-occluders (learn where objects the cell file does not "
                             "know hide the part)")


def tracker_choice(args: argparse.Namespace) -> TrackerChoice:
    """The choice the arguments of :func:`add_tracker_arguments` make."""
    return TrackerChoice(args.tracker, not args.no_occlusion_prediction,
                         frozenset(args.experimental))

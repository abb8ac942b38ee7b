"""``cellsight track --cell CELL RECORDING --out DIR``: the tracker over a recording (an MCAP
file or a rosbag2 folder) into a run folder (:mod:`cellsight.recording.track`)."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from cellsight.commands.metric_rows import metric_rows
from cellsight.commands.text import CELL_HELP
from cellsight.commands.tracker_args import add_tracker_arguments, tracker_choice
from cellsight.errors import CellsightError


def register(sub: argparse._SubParsersAction) -> None:
    track = sub.add_parser(
        "track", help="track the workpieces through a recording (MCAP or rosbag2)",
        description="Track the cell's workpieces through a recording of its cameras and joints "
                    "(an MCAP file or a rosbag2 folder of ROS 2 messages: /<cam>/image_raw or "
                    "/<cam>/image_raw/compressed, /joint_states named ROBOT/JOINT, optional "
                    "/<cam>/camera_info and /<part>/true_pose; --topics maps other names) into "
                    "a run folder: frames.csv, run.log, report.html, metrics.json.")
    track.add_argument("recording", help="an .mcap file or a rosbag2 folder")
    track.add_argument("--cell", help=CELL_HELP)
    track.add_argument("--out", required=True, help="output folder")
    track.add_argument("--topics", metavar="FILE",
                       help="a YAML topic map for a recording that names things otherwise "
                            "(cameras, camera_info, joint_states, joints, openings, "
                            "ignore_joints, truth)")
    track.add_argument("--sync-tolerance", type=float, default=0.019, metavar="S",
                       help="images of several cameras stamped within S seconds form one frame "
                            "(default 0.019, half a 26 Hz period)")
    track.add_argument("--calibration-from-bag", action="store_true",
                       help="use the recording's CameraInfo (K, D) instead of the cell's when "
                            "they disagree (default: a disagreement is an error)")
    track.add_argument("--mcap", metavar="FILE",
                       help="also write the tracked run as an MCAP file for Foxglove and ROS 2 "
                            "tools (cellsight export --no-images, stamped at the recording's "
                            "time: TF, the estimate, windows and corners, visibility markers, "
                            "the tracker's status)")
    track.add_argument("--live", nargs="?", const="127.0.0.1:8765", metavar="[HOST:]PORT",
                       help="stream the tracking to Foxglove as it happens, at the recording's "
                            "own pace: a Foxglove WebSocket server (default 127.0.0.1:8765)")
    track.add_argument("--part", help="the workpiece logged in frames.csv (default: the first)")
    add_tracker_arguments(track)
    track.add_argument("--quiet", action="store_true", help="no progress bar")
    track.add_argument("--overwrite", action="store_true",
                       help="clear --out first if it holds an earlier run, and replace --mcap")
    track.set_defaults(func=cmd_track)


def _check_not_the_recording(mcap: Path, recording: Path) -> None:
    """``--mcap`` may not be the recording itself, nor a file in a rosbag2 folder."""
    target, source = mcap.resolve(), recording.resolve()
    if target == source or source in target.parents:
        raise CellsightError(f"--mcap: {str(mcap)!r} is the recording being tracked; choose "
                             f"another file")


def cmd_track(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cellsight.export.mcap_run import ExportOptions, export_mcap
    from cellsight.export.rosbag import check_output
    from cellsight.recording.track import TrackOptions, track_recording
    from cellsight.report.run_report import format_value

    options = TrackOptions(topics=args.topics, tolerance_s=args.sync_tolerance,
                           calibration_from_bag=args.calibration_from_bag, part=args.part,
                           tracker=tracker_choice(args), overwrite=args.overwrite,
                           progress=not args.quiet, live=args.live)
    if args.mcap is not None:
        _check_not_the_recording(Path(args.mcap), Path(args.recording))
        check_output(args.mcap, args.overwrite, Path(args.out))
    result = track_recording(args.cell, args.recording, Path(args.out), options)
    if result.metrics.get("signal"):
        name = result.metrics["signal"]
        print(f"cellsight: interrupted by {name} after {result.frames} frames; partial results "
              f"in {result.out}", file=sys.stderr)
        return 128 + signal.Signals[name].value
    if args.mcap is not None:
        export_mcap(result.out, args.mcap, ExportOptions(
            start_time=result.metrics["time_origin_ns"], overwrite=args.overwrite,
            progress=not args.quiet))
    table = Table(title=f"tracked {result.frames} frames of {args.recording}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in metric_rows(result.metrics).items():
        table.add_row(key, format_value(value))
    console = Console()
    console.print(table)
    console.print(f"wrote {result.out}/ (report.html, frames.csv, metrics.json, run.log)"
                  + (f" and {args.mcap}" if args.mcap else ""), soft_wrap=True)
    return 0

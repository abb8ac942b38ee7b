"""``cellsight export RUN_DIR --mcap FILE``: the command line of :mod:`cellsight.export`, the
images rendered again by the simulated world (:mod:`cellsight.world.replay_images`).

:func:`register` adds the command to the ``cellsight`` parser's sub-commands. Exit status 0
when the whole run was written; 130 (SIGINT) or 143 (SIGTERM) when stopped early, the file
then holding the frames written before (closed properly, readable).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from contextlib import contextmanager
from datetime import datetime, timezone

CELL_HELP = ("the run's cell, a built-in cell's name or a YAML cell file (default: the one "
             "named by the run's metrics.json)")


def register(sub) -> argparse.ArgumentParser:
    """Add ``export`` to the sub-parsers ``sub`` of the ``cellsight`` parser."""
    export = sub.add_parser(
        "export", help="a run folder as an MCAP file of ROS 2 messages (ROS 2 tools, Foxglove)",
        description="Write a run folder (cellsight run) as an MCAP file of ROS 2 messages: "
                    "/tf and latched /tf_static (REP 103/105 frames under 'world': robots from "
                    "the logged joints, the part's true and estimated poses, the cameras' "
                    "optical frames), /joint_states, /robot_description (URDF robots), "
                    "/<cam>/image_raw (or image_raw/compressed) and /<cam>/camera_info, "
                    "/<part>/true_pose and est_pose, /<cam>/visibility markers, /diagnostics. "
                    "Stamps: --start-time plus the run's time t.")
    export.add_argument("run_dir", help="output folder of a run (cellsight run --out)")
    export.add_argument("--mcap", required=True, metavar="FILE", help="the MCAP file to write")
    export.add_argument("--every", type=int, default=1, metavar="N",
                        help="camera images and camera info every N-th vision frame (default 1)")
    export.add_argument("--no-images", action="store_true",
                        help="no camera images (no rendering; camera info stays)")
    export.add_argument("--jpeg", type=int, metavar="QUALITY",
                        help="camera images as JPEG of this quality (1-100) on "
                             "/<cam>/image_raw/compressed instead of raw mono8 on image_raw")
    export.add_argument("--start-time", default="0", metavar="TIME",
                        help="ROS time of the run's t = 0: ISO 8601 (2024-05-01T12:00:00Z; "
                             "without an offset, UTC) or ns since the Unix epoch (default 0: "
                             "1970, which tf2 may read as stamp 0, 'the latest')")
    export.add_argument("--cell", help=CELL_HELP)
    export.add_argument("--overwrite", action="store_true", help="replace FILE if it exists")
    export.add_argument("--quiet", action="store_true", help="no progress bar")
    export.set_defaults(func=cmd_export)
    return export


@contextmanager
def _sigterm_stops():
    """While exporting, SIGTERM ends it like Ctrl-C: the file is closed with what it has."""
    from cellsight.export.mcap_run import Stop

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise Stop("SIGTERM")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def cmd_export(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsight.export.mcap_run import ExportOptions, Stop, export_mcap
    from cellsight.world.replay_images import ReplayImages

    options = ExportOptions(every=args.every, jpeg=args.jpeg, start_time=args.start_time,
                            cell=args.cell, overwrite=args.overwrite, progress=not args.quiet)
    try:
        with _sigterm_stops():
            result = export_mcap(args.run_dir, args.mcap, options,
                                 None if args.no_images else ReplayImages)
    except Stop as stop:  # before the file was opened: nothing written
        print(f"cellsight: interrupted by {stop.args[0]} before writing {args.mcap}",
              file=sys.stderr)
        return 128 + signal.Signals[stop.args[0]].value
    console = Console()
    table = Table(title="topics written")
    for column in ("topic", "type", "messages"):
        table.add_column(column, justify="right" if column == "messages" else "left")
    for topic, (kind, count) in result.topics.items():
        table.add_row(escape(topic), kind, str(count))
    console.print(table)
    size = result.path.stat().st_size / 2**20
    start = datetime.fromtimestamp(result.start_ns // 10**9, timezone.utc).isoformat()
    span = (f", t = {result.t_first:.3f} .. {result.t_last:.3f} s (stamps: t from "
            f"{result.start_ns} ns, {start})" if result.frames else "")
    what = (f"{result.path} ({size:.1f} MiB): {result.frames} of {result.total} frames{span}")
    if result.stopped_by:
        print(f"cellsight: interrupted by {result.stopped_by}; {what}, readable", file=sys.stderr)
        return 128 + signal.Signals[result.stopped_by].value
    console.print(f"wrote {escape(what)}", soft_wrap=True)
    return 0

"""``cellsight place-cameras``: its command line (the work is in :mod:`.run`, imported when
the command runs). SIGINT or SIGTERM stops it with one line and exit status 130 or 143 (the
verify runs' pool ended too)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight place-cameras`` to the command line's subcommands."""
    p = sub.add_parser("place-cameras", help="choose camera poses that serve the tracker best "
                       "over a task; writes a cell file and a report")
    p.add_argument("--cell", help="a built-in cell's name or a cell file (default: the task "
                   "run's cell)")
    p.add_argument("--task", required=True, help="a run folder (cellsight run ... --out), or "
                   "an experiment number 1-3, run first with the ideal sensor into OUT/task")
    p.add_argument("--cameras", type=int, help="how many cameras (default: as many as the "
                   "cell has)")
    p.add_argument("--out", type=Path, default=Path("out/placement"), help="output folder")
    p.add_argument("--every", type=int, default=1, help="use every N-th vision frame (1)")
    p.add_argument("--radii", type=float, nargs="+", default=[1.4, 1.7, 2.0],
                   help="shell radii around the work area's centre (m)")
    p.add_argument("--elevations", type=float, nargs="+", default=[20, 35, 50, 65, 80],
                   help="elevations above the work area's centre (deg)")
    p.add_argument("--azimuth-step", type=float, default=15.0, help="deg (15)")
    p.add_argument("--template", help="the cell camera whose lens the candidates copy (first)")
    p.add_argument("--verify-seeds", type=int, nargs="*", default=[],
                   help="run the task's experiment with these seeds, with the cell's cameras "
                        "and with the chosen ones, and compare")
    p.add_argument("--verify-sensors", nargs="+", default=["ideal"], help="rendered / ideal")
    p.add_argument("--verify-duration", type=float, help="simulated seconds of each verify run "
                   "(default: the whole task)")
    p.add_argument("--jobs", type=int, default=2, help="local worker processes (verify runs)")
    p.add_argument("--scheduler", help="a Dask scheduler's address for the scoring and runs")
    p.add_argument("--overwrite", action="store_true", help="replace cell.yaml, report.md, "
                   "fig_*.png, task/ and verify/ in --out (a finished task run there is reused)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_place_cameras)


def cmd_place_cameras(args: argparse.Namespace) -> int:
    from cellsight.placement.run import place_cameras
    from cellsight.sweep.engine import sigterm_interrupts, stop_status

    try:
        with sigterm_interrupts():
            return place_cameras(args)
    except KeyboardInterrupt as stop:
        name, status = stop_status(stop)
        print(f"cellsight: place-cameras interrupted by {name}; finished runs in {args.out} "
              f"are reused with --overwrite", file=sys.stderr)
        return status

"""``cellsight view [--cell NAME|FILE] [RUN_DIR]``: the interactive 3D view in a web browser.

:func:`register` adds the ``view`` sub-command to the ``cellsight`` parser.
"""

from __future__ import annotations

import argparse
import math
import time

from cellsight.errors import CellsightError

DESCRIPTION = ("interactive 3D view of the cell in a web browser (viser): robots, cameras' "
               "frustums and images, the features coloured by predicted visibility; with a "
               "run's folder, a timeline replaying it")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", nargs="?", metavar="RUN_DIR",
                   help="output folder of 'cellsight run' to replay (frames.csv, metrics.json)")
    p.add_argument("--cell", help="a built-in cell's name (see 'cellsight cells') or a YAML "
                                  "cell file; with RUN_DIR, instead of the cell the run names")
    p.add_argument("--joints", help='JSON (or a JSON file): {"R7AX": [q1, ...], ...}; robots '
                                    "left out stay at HOME (not with RUN_DIR)")
    p.add_argument("--part-pose", help='JSON (or file): {"part": {"xyz": [..], "rpy": [..]}} '
                                       "(not with RUN_DIR)")
    p.add_argument("--openings", help='JSON (or file): {"R7AX": 0.03}: jaw openings (m); '
                                      "grippers left out are open (not with RUN_DIR)")
    p.add_argument("--time", type=float, metavar="S",
                   help="with RUN_DIR: start the timeline at the frame nearest S seconds")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (127.0.0.1)")
    p.add_argument("--port", type=int, default=8080,
                   help="port to serve on (8080; 0: any free port)")
    p.add_argument("--serve-for", type=float, metavar="SECONDS",
                   help="serve this long, then exit (default: until Ctrl-C)")


def register(sub) -> argparse.ArgumentParser:
    """Add ``view`` to the sub-parsers ``sub`` of the ``cellsight`` command."""
    view = sub.add_parser("view", help=DESCRIPTION, description=DESCRIPTION)
    add_arguments(view)
    view.set_defaults(func=cmd_view)
    return view


def _check(args: argparse.Namespace) -> None:
    if args.run_dir is not None and (args.joints is not None or args.part_pose is not None
                                     or args.openings is not None):
        raise CellsightError("--joints / --part-pose / --openings: not with RUN_DIR (the run's "
                             "log gives the joints, poses and openings of every frame)")
    if args.run_dir is None and args.time is not None:
        raise CellsightError("--time: only with RUN_DIR")
    if args.time is not None and not math.isfinite(args.time):
        raise CellsightError(f"--time: expected a finite number of seconds, got {args.time}")
    if args.serve_for is not None and not (args.serve_for >= 0 and math.isfinite(args.serve_for)):
        raise CellsightError(f"--serve-for: expected a finite number of seconds >= 0, got "
                             f"{args.serve_for}")


def start_view(args: argparse.Namespace):
    """The :class:`~cellsight.view.app.ViewApp` the arguments describe, serving."""
    from cellsight.model.arguments import parse_joints, parse_openings, parse_part_poses
    from cellsight.model.loader import load_cell
    from cellsight.view.app import ViewApp
    from cellsight.view.replay import RunReplay
    from cellsight.view.states import static_state

    _check(args)
    common = {"host": args.host, "port": args.port}
    if args.run_dir is not None:
        replay = RunReplay(args.run_dir, args.cell)
        return ViewApp(replay.cell, replay=replay, start_time=args.time, **common)
    cell = load_cell(args.cell)
    state = static_state(cell, parse_joints(args.joints), parse_part_poses(args.part_pose),
                         openings=parse_openings(args.openings))
    return ViewApp(cell, state=state, **common)


def cmd_view(args: argparse.Namespace) -> int:
    app = start_view(args)
    what = f"run {args.run_dir}" if args.run_dir is not None else app.cell.name
    print(f"cellsight view: {what} at {app.url}", flush=True)
    try:
        if args.serve_for is None:
            print("(Ctrl-C to stop)", flush=True)
            while True:
                time.sleep(3600)
        time.sleep(args.serve_for)
    except KeyboardInterrupt:  # Ctrl-C: the normal way to stop serving
        print("cellsight view: stopped", flush=True)
    finally:
        app.close()
    return 0

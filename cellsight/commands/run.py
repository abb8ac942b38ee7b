"""``cellsight run N``: one of the paper's experiments end to end in the simulated cell
(:mod:`cellsight.experiments.runner`), its output folder checked before anything runs, a
summary table at the end. A run that fails after starting leaves its partial results and exits
with status 1; one ended by SIGINT or SIGTERM exits with 128 + the signal's number."""

from __future__ import annotations

import argparse
import math
import signal
import sys
from pathlib import Path

from cellsight.commands.metric_rows import metric_rows
from cellsight.commands.text import CELL_HELP, debug, one_line
from cellsight.commands.tracker_args import add_tracker_arguments, tracker_choice
from cellsight.errors import CellsightError
from cellsight.visibility import OBJECT_BVH, STRUCTURES


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight run`` to the sub-commands."""
    run = sub.add_parser("run", help="run one of the paper's experiments end to end")
    run.add_argument("experiment", type=int, choices=(1, 2, 3),
                     help="1: part still; 2: part on the conveyor; 3: as 2, with R6AX crossing")
    run.add_argument("--cell", help=CELL_HELP)
    run.add_argument("--seed", type=int, default=0, help="seed of every random thing (0)")
    run.add_argument("--out", help="output folder (default out/experiment<N>)")
    run.add_argument("--sensor", choices=("rendered", "ideal"), default="rendered",
                     help="rendered: MuJoCo images + corner extraction (default); ideal: true "
                          "projections + Gaussian pixel noise")
    add_tracker_arguments(run)
    run.add_argument("--calibration", metavar="DIR",
                     help="a cellsight calibrate folder: the tracker and the task use its "
                          "cameras and robot bases (the simulated world stays the seed's)")
    run.add_argument("--realism", default="exact", metavar="PROFILE",
                     help="how the simulated world departs from the cell file: exact (default: "
                          "it is the cell file), lab, harsh, one knob group alone (harsh/cameras), "
                          "or a YAML file (FILE or FILE:NAME; see cellsight/data/realism.yaml)")
    run.add_argument("--structure", choices=STRUCTURES, default=OBJECT_BVH,
                     help="occlusion predictor: per-object hierarchies (default) or the "
                          "paper's per-frame BSP tree")
    run.add_argument("--duration", type=float,
                     help="simulated seconds (default: until the task is done)")
    run.add_argument("--full-frames", action="store_true",
                     help="render every camera's whole image every frame (default: only the "
                          "region of the windows the tracker reads, and whole images where it "
                          "needs them; the same pixels)")
    run.add_argument("--no-video", action="store_true",
                     help="no views.mp4 (drawn beside the run, it takes a core's share: on two "
                          "cores without a GPU the line's run took 1.09x real time with it, "
                          "0.88x without)")
    run.add_argument("--record", metavar="FILE",
                     help="record the sensor data as a real cell would (images, joint states, "
                          "the part's true pose) in an MCAP file, for cellsight track")
    run.add_argument("--record-jpeg", type=int, metavar="QUALITY",
                     help="record the images as JPEG of this quality (1-100; default lossless)")
    run.add_argument("--live", nargs="?", const="127.0.0.1:8765", metavar="[HOST:]PORT",
                     help="stream the run to Foxglove as it happens: a Foxglove WebSocket "
                          "server (default 127.0.0.1:8765)")
    run.add_argument("--no-check", action="store_true",
                     help="run even when the cell file fails cellsight check's quick checks "
                          "(units, joint limits, key poses in view)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--overwrite", action="store_true",
                     help="clear --out first if it holds an earlier run (only a run's outputs; "
                          "a non-empty --out is refused without it)")
    run.set_defaults(func=cmd_run)


def _check_run_args(args: argparse.Namespace) -> Path:
    """Every check of ``cellsight run``'s arguments, before anything is written; returns the
    output folder."""
    from cellsight.runfolder import check_out_folder

    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise CellsightError(f"--duration: expected a positive, finite number of seconds, got "
                             f"{args.duration}")
    if args.seed < 0:
        raise CellsightError(f"--seed: expected a whole number >= 0, got {args.seed}")
    out = Path(args.out or f"out/experiment{args.experiment}")
    check_out_folder(out, args.overwrite, "--out", "--overwrite")
    if args.record_jpeg is not None and args.record is None:
        raise CellsightError("--record-jpeg: needs --record FILE")
    if not args.no_check:
        _check_cell(args.cell)
    return out


def _check_cell(cell_arg: str | None) -> None:
    """``cellsight check``'s checks of the cell file that need no simulation (size and units,
    joint limits, key poses in view): errors are refused before anything runs, all named in
    one line."""
    from cellsight.experiments.cellcheck import check_cell
    from cellsight.model.loader import load_cell

    cell = load_cell(cell_arg)
    errors = [f.line for f in check_cell(cell, crossing=False) if f.level == "error"]
    if errors:
        raise CellsightError(f"{cell.source}: {len(errors)} problem(s) (cellsight check; "
                             f"--no-check runs anyway): " + "; ".join(errors))


def _run_failed(exc: Exception, out: Path) -> int:
    """A run that crashed after starting (it wrote ``metrics.json`` with the error): one line,
    exit status 1; a failure before the run started is re-raised (:func:`main` words it)."""
    from cellsight.runfolder import RunDataError, read_metrics

    if debug():
        raise exc
    try:
        t_end = read_metrics(out).get("t_end_s")
    except RunDataError:  # no metrics.json: the run never started
        raise exc from None
    t = math.nan if t_end is None else t_end
    print(f"cellsight: error: the run failed at t = {t:.1f} s: "
          f"{one_line(f'{type(exc).__name__}: {exc}')}; partial results in {out} "
          f"(CELLSIGHT_DEBUG=1 shows the traceback)", file=sys.stderr)
    return 1


def cmd_run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsight.experiments import RunConfig, run_experiment
    from cellsight.report.run_report import format_value

    out = _check_run_args(args)
    config = RunConfig(
        experiment=args.experiment, out=out, cell=args.cell, seed=args.seed,
        sensor=args.sensor, tracker=tracker_choice(args), duration=args.duration,
        progress=not args.quiet,
        full_frames=args.full_frames, video_every=0 if args.no_video else RunConfig.video_every,
        overwrite=args.overwrite, realism=args.realism, structure=args.structure,
        record=None if args.record is None else Path(args.record), record_jpeg=args.record_jpeg,
        live=args.live, calibration=None if args.calibration is None else Path(args.calibration),
    )
    try:
        metrics = run_experiment(config)
    except Exception as exc:
        return _run_failed(exc, out)
    if metrics.get("signal"):
        name = metrics["signal"]
        print(f"cellsight: interrupted by {name} at t = {metrics.get('t_end_s', math.nan):.1f} s; "
              f"partial results in {out}", file=sys.stderr)
        return 128 + signal.Signals[name].value
    table = Table(title=f"experiment {args.experiment}: {metrics['description']}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in metric_rows(metrics).items():
        table.add_row(key, format_value(value))
    console = Console()
    console.print(table)
    console.print(escape(f"ended by {metrics.get('ended_by')}; the task "
                         f"{metrics.get('final_phase')}"
                         + (f"; its last setback at {metrics['last_setback']}"
                            if metrics.get("last_setback") else "")), soft_wrap=True)
    console.print(f"wrote [bold]{out}[/bold]: frames.csv, metrics.json, run.log, report.html"
                  + (f"; the recording [bold]{args.record}[/bold]" if args.record else ""))
    return 0



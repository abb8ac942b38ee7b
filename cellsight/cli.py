"""The ``cellsight`` command line.

Commands: ``show`` (pictures of the cell and each camera's view), ``visibility`` (which feature
points each camera sees, and why not), ``run`` (the paper's experiments), ``compare`` (two runs'
metrics side by side), ``cells`` (the built-in cells: ``--cell`` takes a name or a file). Every
error on bad input is printed as one line naming its source (exit status 2); a crash as one line
too (exit status 1; ``CELLSIGHT_DEBUG=1`` shows the traceback); a run ended by SIGINT or SIGTERM
exits with 130 or 143 after writing its partial results.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from pathlib import Path

import numpy as np

from cellsight import cameras_cli
from cellsight.errors import CellsightError
from cellsight.export import command as export_command
from cellsight.model.arguments import parse_joints, parse_part_poses
from cellsight.placement import command as placement_command
from cellsight.realism import command as realism_command
from cellsight.sweep import command as sweep_command
from cellsight.view import command as view_command
from cellsight.visibility import OBJECT_BVH, STRUCTURES


def _debug() -> bool:
    """``CELLSIGHT_DEBUG`` is set (and not 0): crashes show their traceback."""
    return os.environ.get("CELLSIGHT_DEBUG", "0") not in ("", "0")


def _one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line (whitespace runs collapsed), cut to ``limit`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _short(value, limit: int = 60) -> str:
    """``repr`` of a value, cut to ``limit`` characters for an error message."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def cmd_show(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.predictor import VisibilityPredictor
    from cellsight.report.show import show_cell

    cell = load_cell(args.cell)
    snapshot = cell.snapshot(parse_joints(args.joints), parse_part_poses(args.part_pose))
    visibility = VisibilityPredictor(cell).predict_snapshot(snapshot)
    paths = show_cell(snapshot, Path(args.out), visibility)
    console = Console()
    for path in paths:
        console.print(f"wrote [bold]{path}[/bold]")
    return 0


def cmd_visibility(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cellsight.model.loader import load_cell
    from cellsight.occlusion.predictor import VisibilityPredictor

    cell = load_cell(args.cell)
    result = VisibilityPredictor(cell).predict(parse_joints(args.joints),
                                               parse_part_poses(args.part_pose))
    if args.json:
        out = {
            part: [
                {
                    "camera": v.camera,
                    "features": [
                        {"name": name, "visible": bool(v.visible[j]),
                         "pixel": None if not np.isfinite(v.pixels[j]).all()
                         else [round(float(x), 3) for x in v.pixels[j]],
                         "reason": v.reason[j] or None}
                        for j, name in enumerate(cell.workpiece(part).feature_names)
                    ],
                }
                for v in views
            ]
            for part, views in result.items()
        }
        print(json.dumps(out, indent=2))
        return 0
    console = Console()
    for part, views in result.items():
        names = cell.workpiece(part).feature_names
        for v in views:
            table = Table(title=f"{part} seen by {v.camera}: {v.count} of {len(names)} visible")
            for col in ("feature", "visible", "u (px)", "v (px)", "hidden by"):
                table.add_column(col, justify="right" if col.endswith(")") else "left")
            for j, name in enumerate(names):
                u, w = v.pixels[j]
                table.add_row(name, "[green]yes[/green]" if v.visible[j] else "[red]no[/red]",
                              f"{u:.1f}", f"{w:.1f}", v.reason[j])
            console.print(table)
    return 0


SUMMARY_KEYS = (
    "experiment", "seed", "realism", "structure", "sensor", "occlusion_prediction",
    "kinematic_prior", "frames",
    "grasp_success", "grasp_position_error_mm", "in_view_fraction", "lost_in_view_s",
    "position_rmse_mm", "orientation_rmse_deg", "max_position_error_mm", "pnp_position_rmse_mm",
    "pnp_orientation_rmse_deg", "visibility_accuracy", "visibility_accuracy_all",
    "false_visible", "false_hidden", "measurements", "rejected_measurements",
    "wrong_measurements", "wrong_accepted", "pixels_grabbed_fraction",
    "extraction_error_px_median", "frames_dropped", "collision_count", "wall_s",
)


PHASE_SUMMARY_KEYS = ("position_rmse_mm", "max_position_error_mm", "orientation_rmse_deg",
                      "lost_in_view_s")


def _metric_rows(metrics: dict) -> dict[str, object]:
    """The scalar metrics, the per-phase errors flattened to ``<phase>_<metric>`` and the
    stage timings to ``timing_<stage>_ms``."""
    rows = {k: metrics.get(k) for k in SUMMARY_KEYS}
    for phase, figures in (metrics.get("phases") or {}).items():
        rows.update({f"{phase}_{k}": figures.get(k) for k in PHASE_SUMMARY_KEYS})
    rows.update({f"timing_{k}_ms": v for k, v in (metrics.get("timing_ms") or {}).items()})
    return rows


def _check_run_args(args: argparse.Namespace) -> Path:
    """Every check of ``cellsight run``'s arguments, before anything is written; returns the
    output folder."""
    from cellsight.experiments.runner import check_out_folder

    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise CellsightError(f"--duration: expected a positive, finite number of seconds, got "
                             f"{args.duration}")
    if args.seed < 0:
        raise CellsightError(f"--seed: expected a whole number >= 0, got {args.seed}")
    out = Path(args.out or f"out/experiment{args.experiment}")
    check_out_folder(out, args.overwrite, "--out", "--overwrite")
    return out


def _run_failed(exc: Exception, out: Path) -> int:
    """A run that crashed after starting (it wrote ``metrics.json`` with the error): one line,
    exit status 1; a failure before the run started is re-raised (:func:`main` words it)."""
    metrics_path = out / "metrics.json"
    if _debug() or not metrics_path.is_file():
        raise exc
    try:
        t = float(json.loads(metrics_path.read_text()).get("t_end_s"))
    except (ValueError, TypeError, AttributeError):
        t = math.nan
    print(f"cellsight: error: the run failed at t = {t:.1f} s: "
          f"{_one_line(f'{type(exc).__name__}: {exc}')}; partial results in {out} "
          f"(CELLSIGHT_DEBUG=1 shows the traceback)", file=sys.stderr)
    return 1


def cmd_run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cellsight.experiments import RunConfig, run_experiment
    from cellsight.report.run_report import format_value

    out = _check_run_args(args)
    config = RunConfig(
        experiment=args.experiment, out=out, cell=args.cell, seed=args.seed,
        sensor=args.sensor, occlusion_prediction=not args.no_occlusion_prediction,
        kinematic_prior=args.kinematic_prior, duration=args.duration, progress=not args.quiet,
        overwrite=args.overwrite, realism=args.realism, structure=args.structure,
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
    for key, value in _metric_rows(metrics).items():
        table.add_row(key, format_value(value))
    console = Console()
    console.print(table)
    console.print(f"wrote [bold]{out}[/bold]: frames.csv, metrics.json, run.log, report.html")
    return 0


def _load_metrics(folder: str) -> dict:
    """``<folder>/metrics.json`` as a dict, else one clear line naming the file: missing, not
    UTF-8, not JSON, not an object, or with ``phases`` / ``timing_ms`` not objects."""
    path = Path(folder) / "metrics.json"
    try:
        data = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError) as exc:
        raise CellsightError(f"{path}: no metrics.json here (is {folder} a run's output "
                             f"folder?)") from exc
    except (OSError, ValueError) as exc:  # a folder, unreadable, a NUL in the name
        reason = getattr(exc, "strerror", None) or str(exc)
        raise CellsightError(f"{path}: cannot read it ({reason})") from exc
    try:
        metrics = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise CellsightError(f"{path}: not UTF-8 text") from exc
    except json.JSONDecodeError as exc:
        raise CellsightError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from exc
    except (ValueError, RecursionError) as exc:  # a number too long, nested too deeply
        raise CellsightError(f"{path}: not usable JSON ({_one_line(exc, 80)})") from exc
    if not isinstance(metrics, dict):
        raise CellsightError(f"{path}: expected a JSON object of metrics, got "
                             f"{type(metrics).__name__} {_short(metrics)}")
    phases = metrics.get("phases")
    for key, value in [("phases", phases), ("timing_ms", metrics.get("timing_ms"))] + [
            (f"phases.{k}", v) for k, v in (phases.items() if isinstance(phases, dict) else [])]:
        if value is not None and not isinstance(value, dict):
            raise CellsightError(f"{path}: field {key!r}: expected an object, got "
                                 f"{_short(value)}")
    return metrics


def _ratio(a, b) -> str:
    """``b / a`` to 3 digits for two numbers (not bools), else empty."""
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (a, b))
    try:
        return f"{b / a:.3g}" if numeric and a else ""
    except (OverflowError, ZeroDivisionError):
        return ""


def cmd_compare(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from cellsight.report.run_report import format_value

    def cell(value) -> str:  # a metric as text, its brackets shown, not read as rich markup
        try:
            return escape(_one_line(format_value(value), 80))
        except ValueError:  # an integer too long to print
            return "?"

    a, b = _load_metrics(args.run_a), _load_metrics(args.run_b)
    rows_a, rows_b = _metric_rows(a), _metric_rows(b)
    table = Table(title="cellsight compare")
    table.add_column("metric")
    table.add_column(escape(args.run_a), justify="right")
    table.add_column(escape(args.run_b), justify="right")
    table.add_column("B / A", justify="right")
    for key in list(rows_a) + [k for k in rows_b if k not in rows_a]:
        va, vb = rows_a.get(key), rows_b.get(key)
        table.add_row(escape(_one_line(key, 80)), cell(va), cell(vb), _ratio(va, vb))
    Console().print(table)
    return 0


CELL_HELP = ("a built-in cell's name (dual-arm, the default; ur-cell: see 'cellsight cells') "
             "or a YAML cell file")


def cmd_cells(args: argparse.Namespace) -> int:
    """One line per built-in cell: name, file, robots, cameras, description."""
    from cellsight.model.loader import BUILTIN_CELLS, parse_cell_text
    from cellsight.model.yaml_input import read_cell_text

    rows = []
    for cell in BUILTIN_CELLS.values():
        spec, _ = parse_cell_text(read_cell_text(cell.path), str(cell.path), cell.path.parent)
        rows.append((cell.name, str(cell.path), "robots: " + ", ".join(r.name for r in spec.robots),
                     "cameras: " + ", ".join(c.name for c in spec.cameras), cell.description))
    widths = [max(len(row[k]) for row in rows) for k in range(4)]
    for row in rows:
        print("  ".join([*(v.ljust(w) for v, w in zip(row[:4], widths, strict=True)), row[4]]))
    return 0


def _add_run(sub: argparse._SubParsersAction) -> None:
    """``cellsight run``'s arguments."""
    run = sub.add_parser("run", help="run one of the paper's experiments end to end")
    run.add_argument("experiment", type=int, choices=(1, 2, 3),
                     help="1: part still; 2: part on the conveyor; 3: as 2, with R6AX crossing")
    run.add_argument("--cell", help=CELL_HELP)
    run.add_argument("--seed", type=int, default=0, help="seed of every random thing (0)")
    run.add_argument("--out", help="output folder (default out/experiment<N>)")
    run.add_argument("--sensor", choices=("rendered", "ideal"), default="rendered",
                     help="rendered: MuJoCo images + corner extraction (default); ideal: true "
                          "projections + Gaussian pixel noise")
    run.add_argument("--no-occlusion-prediction", action="store_true",
                     help="windows on every model point inside the image (no BSP)")
    run.add_argument("--kinematic-prior", action="store_true",
                     help="once the jaws hold the part, predict it by the gripper's measured "
                          "motion (off by default: the paper tracks from images alone)")
    run.add_argument("--realism", default="exact", metavar="PROFILE",
                     help="how the simulated world departs from the cell file: exact (default: "
                          "it is the cell file), lab, harsh, one knob group alone (harsh/cameras), "
                          "or a YAML file (FILE or FILE:NAME; see cellsight/data/realism.yaml)")
    run.add_argument("--structure", choices=STRUCTURES, default=OBJECT_BVH,
                     help="occlusion predictor: per-object hierarchies (default) or the "
                          "paper's per-frame BSP tree")
    run.add_argument("--duration", type=float,
                     help="simulated seconds (default: until the task is done)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--overwrite", action="store_true",
                     help="clear --out first if it holds an earlier run (only a run's outputs; "
                          "a non-empty --out is refused without it)")
    run.set_defaults(func=cmd_run)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellsight", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    def cell_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--cell", help=CELL_HELP)
        p.add_argument("--joints", help='JSON (or a JSON file): {"R7AX": [q1, ...], ...}; '
                                         "robots left out stay at HOME")
        p.add_argument("--part-pose", help='JSON (or file): {"part": {"xyz": [..], "rpy": [..]}}')

    show = sub.add_parser("show", help="picture of the cell and each camera's projected view")
    cell_args(show)
    show.add_argument("--out", default="out/show", help="output folder (default out/show)")
    show.set_defaults(func=cmd_show)

    vis = sub.add_parser("visibility", help="which feature points each camera sees, and why not")
    cell_args(vis)
    vis.add_argument("--json", action="store_true", help="print JSON instead of tables")
    vis.set_defaults(func=cmd_visibility)

    _add_run(sub)

    cells = sub.add_parser("cells", help="list the built-in cells (names for --cell)")
    cells.set_defaults(func=cmd_cells)

    compare = sub.add_parser("compare", help="two runs' metrics side by side")
    compare.add_argument("run_a", help="output folder of a run")
    compare.add_argument("run_b", help="output folder of another run")
    compare.set_defaults(func=cmd_compare)
    sweep_command.register(sub)
    realism_command.register(sub)
    placement_command.register(sub)
    export_command.register(sub)
    view_command.register(sub)
    cameras_cli.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (CellsightError, KeyError) as exc:
        print(f"cellsight: error: {_one_line(exc, 500)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cellsight: interrupted (SIGINT)", file=sys.stderr)
        return 130
    except Exception as exc:
        if _debug():
            raise
        print(f"cellsight: error: {_one_line(f'{type(exc).__name__}: {exc}')} "
              f"(CELLSIGHT_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

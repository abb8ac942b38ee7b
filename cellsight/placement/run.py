"""What ``cellsight place-cameras`` does (:mod:`.command` parses it): choose K camera poses for
a task (:mod:`cellsight.placement`), write a cell file with them and a report, and optionally
run the task's experiment with the cell's own cameras and with the chosen ones on the sweep
engine to compare how they track."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from rich.console import Console

from cellsight.control import Phase
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.model.cell import Cell
from cellsight.model.loader import cell_path, load_cell
from cellsight.placement.candidates import shell_candidates
from cellsight.placement.cellfile import write_cell_file
from cellsight.placement.choose import choose_cameras, placement_loss
from cellsight.placement.report import plot_candidates, plot_task, set_figures, write_report
from cellsight.placement.scoring import CandidateScores, score_candidates
from cellsight.placement.task import TaskFrames
from cellsight.runfolder import load_run
from cellsight.sweep.command import run_sweep
from cellsight.sweep.grid import SENSORS, RunSpec, reusable_metrics

VERIFY_KEYS = ("grasp_success", "position_rmse_mm", "max_position_error_mm",
               "orientation_rmse_deg", "lost_in_view_s", "pnp_position_rmse_mm",
               "visibility_accuracy", "measurements")


def check_arguments(args: argparse.Namespace) -> None:
    """The checks that need nothing loaded, before anything runs or is written."""
    if bad := [s for s in args.verify_sensors if s not in SENSORS]:
        raise CellsightError(f"--verify-sensors: expected {' or '.join(SENSORS)}, got {bad}")
    for name in ("cameras", "every"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise CellsightError(f"--{name}: expected a whole number >= 1, got {value}")
    if any(s < 0 for s in args.verify_seeds):
        raise CellsightError(f"--verify-seeds: expected seeds >= 0, got {args.verify_seeds}")
    numbers = [*args.radii, *args.elevations, args.azimuth_step]
    if not all(np.isfinite(numbers)) or min(args.radii) <= 0 or args.azimuth_step <= 0 or not (
            all(0 < e < 90 for e in args.elevations)):
        raise CellsightError(f"--radii, --elevations, --azimuth-step: expected radii > 0 m, "
                             f"elevations in (0, 90) deg and a step > 0 deg, got {args.radii}, "
                             f"{args.elevations}, {args.azimuth_step}")


def task_folder(args: argparse.Namespace) -> Path:
    """The run folder of ``--task``: as given, or OUT/task after running the experiment."""
    if args.task in ("1", "2", "3"):
        folder = args.out / "task"
        if reusable_metrics(folder, str(cell_path(args.cell))) is None:
            run_experiment(RunConfig(int(args.task), folder, cell=args.cell, sensor="ideal",
                                     progress=not args.quiet, overwrite=True))
        return folder
    folder = Path(args.task)
    if not (folder / "frames.csv").is_file():
        raise CellsightError(f"--task: {args.task!r} is neither an experiment (1-3) nor a run "
                             f"folder with frames.csv")
    return folder


def score_each(cell: Cell, task: TaskFrames, progress: bool) -> CandidateScores:
    """The cell's own cameras scored one by one (their lenses may differ)."""
    parts = [score_candidates(cell, task, [cam], progress=progress) for cam in cell.cameras]
    return CandidateScores(list(cell.cameras), np.concatenate([p.visible for p in parts], 1),
                           np.concatenate([p.info for p in parts], 1))


def _template(cell: Cell, name: str | None):
    if name is None:
        return cell.cameras[0]
    for cam in cell.cameras:
        if cam.name == name:
            return cam
    raise CellsightError(f"--template: no camera {name!r} in the cell (cameras: "
                         f"{[c.name for c in cell.cameras]})")


def verification(args, source: str, placed: Path, experiment: int) -> list[str]:
    """Run the experiment with both camera sets (sweep engine); the comparison table."""
    specs = [RunSpec(cell, experiment, sensor, "pred", seed, args.verify_duration)
             for sensor in args.verify_sensors for seed in args.verify_seeds
             for cell in (source, str(placed))]
    results = run_sweep(specs, args.out / "verify", args.jobs, args.scheduler, not args.quiet)
    lines = ["| sensor | metric (mean over seeds " + ", ".join(map(str, args.verify_seeds))
             + ") | cell's cameras | chosen cameras |", "|---|---|---|---|"]
    for sensor in args.verify_sensors:
        runs = [(s, m) for s, m in zip(specs, results, strict=True) if s.sensor == sensor]
        keys = list(VERIFY_KEYS) + [f"{p}.position_rmse_mm" for p in Phase.working()]
        for key in keys:
            means = []
            for cell in (source, str(placed)):
                values = [_metric(m, key) for s, m in runs if s.cell == cell]
                values = [v for v in values if v is not None]
                means.append(f"{np.mean(values):.4g}" if values else "–")
            lines.append(f"| {sensor} | {key} | {means[0]} | {means[1]} |")
    return lines


def _metric(metrics: dict, key: str):
    if "." in key:
        phase, name = key.split(".")
        return (metrics.get("phases") or {}).get(phase, {}).get(name)
    value = metrics.get(key)
    return float(value) if isinstance(value, int | float) else None


def place_cameras(args: argparse.Namespace) -> int:
    """Run ``cellsight place-cameras`` with its parsed arguments; the exit status."""
    check_arguments(args)
    args.out.mkdir(parents=True, exist_ok=True)
    folder = task_folder(args)
    run = load_run(folder, args.cell)
    task, cell = TaskFrames.of(run, args.every), run.cell
    k = len(cell.cameras) if args.cameras is None else args.cameras
    candidates = shell_candidates(cell, task, _template(cell, args.template), args.radii,
                                  args.elevations, args.azimuth_step)
    if not 1 <= k <= len(candidates):
        raise CellsightError(f"--cameras: expected 1..{len(candidates)} (the candidates), got {k}")
    scores = score_candidates(cell, task, candidates, scheduler=args.scheduler,
                              progress=not args.quiet)
    chosen = choose_cameras(scores, k)
    own = score_each(cell, task, not args.quiet)
    placed = write_cell_file(cell.source, [candidates[i] for i in chosen.chosen],
                             args.out / "cell.yaml")
    sets = [set_figures("cell's cameras", cell, task, placement_loss(own, range(len(own.cameras)))),
            set_figures("chosen", load_cell(placed), task, chosen)]
    single = np.array([placement_loss(scores, [c]).loss for c in range(len(candidates))])
    plot_task(args.out / "fig_task.png", task, sets)
    plot_candidates(args.out / "fig_candidates.png", task, scores, single, chosen, cell.cameras)
    metrics_experiment = int(run.metrics["experiment"])
    rows = (verification(args, cell.source, placed, metrics_experiment)
            if args.verify_seeds else [])
    header = [f"# Camera placement: {k} cameras for experiment {metrics_experiment} on "
              f"{cell.name}", "", f"Task: {folder} ({task.n} frames); {len(candidates)} "
              f"candidates; {scores.pairs} frame x candidate pairs scored. Chosen: "
              + ", ".join(candidates[i].name for i in chosen.chosen) + f"; cell file {placed}."]
    report = write_report(args.out, header, task, sets, rows)
    print(report.read_text())
    Console().print(f"wrote [bold]{args.out}[/bold]: cell.yaml, report.md, fig_task.png, "
                  "fig_candidates.png")
    return 0

"""What ``cellsight place-cameras`` does (:mod:`.command` parses it): choose K camera poses for
a task (:mod:`cellsight.placement`), write a cell file with them and a report, and optionally
run the task's experiment with the cell's own cameras and with the chosen ones on the sweep
engine to compare how they track.

Every argument is checked before anything is written (:func:`check_arguments`, then
:func:`check_out`: ``--out`` holds none of the files and folders the command writes, unless
``--overwrite``; with it a finished task run in OUT/task is reused); ``--task`` as a run folder
is read, and the candidates counted against ``--cameras``, before ``--out`` is created."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from rich.console import Console

from cellsight.control import Phase
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.experiments.identity import run_identity
from cellsight.model.cell import Cell
from cellsight.model.loader import cell_path, load_cell
from cellsight.placement.candidates import Shell, shell_candidates
from cellsight.placement.cellfile import write_cell_file
from cellsight.placement.choose import choose_cameras, placement_loss
from cellsight.placement.report import plot_candidates, plot_task, set_figures, write_report
from cellsight.placement.scoring import CandidateScores, score_candidates
from cellsight.placement.task import TaskFrames
from cellsight.runfolder import check_out_folder, load_run
from cellsight.runfolder.folder import check_folder, check_new_files
from cellsight.sweep.command import run_sweep
from cellsight.sweep.engine import raise_if_stopped
from cellsight.sweep.grid import SENSORS, RunSpec, reusable_metrics

VERIFY_KEYS = ("grasp_success", "position_rmse_mm", "max_position_error_mm",
               "orientation_rmse_deg", "lost_in_view_s", "pnp_position_rmse_mm",
               "visibility_accuracy", "measurements")


OUT_FILES = ("cell.yaml", "report.md", "fig_task.png", "fig_candidates.png")
"""The files written into ``--out`` (besides the folders ``task`` and ``verify``)."""
TASK_EXPERIMENTS = ("1", "2", "3")
MAX_CANDIDATES = 10_000
"""Most candidate viewpoints (radii x elevations x azimuths) a placement scores."""


def check_arguments(args: argparse.Namespace) -> None:
    """The checks that need nothing loaded, before anything runs or is written."""
    if bad := [s for s in args.verify_sensors if s not in SENSORS]:
        raise CellsightError(f"--verify-sensors: expected {' or '.join(SENSORS)}, got {bad}")
    for name in ("verify_sensors", "verify_seeds"):
        if len(set(values := getattr(args, name))) < len(values):
            raise CellsightError(f"--{name.replace('_', '-')}: expected each value once, got "
                                 f"{values}")
    for name in ("cameras", "every", "jobs"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise CellsightError(f"--{name}: expected a whole number >= 1, got {value}")
    if any(s < 0 for s in args.verify_seeds):
        raise CellsightError(f"--verify-seeds: expected seeds >= 0, got {args.verify_seeds}")
    if (d := args.verify_duration) is not None and not (math.isfinite(d) and d > 0):
        raise CellsightError(f"--verify-duration: expected a positive, finite number of "
                             f"seconds, got {d!r}")
    _check_shell(args)
    if args.task not in TASK_EXPERIMENTS and not (Path(args.task) / "frames.csv").is_file():
        raise CellsightError(f"--task: {args.task!r} is neither an experiment (1-3) nor a run "
                             f"folder with frames.csv")


def _check_shell(args: argparse.Namespace) -> None:
    """The candidates' shell: radii > 0 m, elevations in (0, 90) deg (at 90 every azimuth is
    the one point overhead, where the camera's image x has no horizontal), a step in (0, 360]
    deg, at most :data:`MAX_CANDIDATES` viewpoints and at least ``--cameras``."""
    numbers = [*args.radii, *args.elevations, args.azimuth_step]
    if not all(np.isfinite(numbers)) or min(args.radii) <= 0 or not (
            0 < args.azimuth_step <= 360) or not all(0 < e < 90 for e in args.elevations):
        raise CellsightError(f"--radii, --elevations, --azimuth-step: expected radii > 0 m, "
                             f"elevations in (0, 90) deg and a step in (0, 360] deg, got "
                             f"{args.radii}, {args.elevations}, {args.azimuth_step}")
    viewpoints = len(args.radii) * len(args.elevations) * math.ceil(360.0 / args.azimuth_step)
    if viewpoints > MAX_CANDIDATES:
        raise CellsightError(f"--radii, --elevations, --azimuth-step: {viewpoints} candidate "
                             f"viewpoints; expected at most {MAX_CANDIDATES} (fewer values or "
                             f"a larger step)")
    if args.cameras is not None and args.cameras > viewpoints:
        raise CellsightError(f"--cameras: expected at most {viewpoints} (the candidate "
                             f"viewpoints of --radii, --elevations, --azimuth-step), got "
                             f"{args.cameras}")


def check_out(args: argparse.Namespace) -> None:
    """Check, touching nothing, that ``--out`` can take what the command writes: a folder or
    creatable, holding none of :data:`OUT_FILES` nor the folders ``task`` (an experiment as
    ``--task``) and ``verify`` (``--verify-seeds``) unless ``--overwrite``; with it, OUT/task
    holds only a run's outputs."""
    experiment = args.task in TASK_EXPERIMENTS
    names = [*OUT_FILES, *(["task"] if experiment else []),
             *(["verify"] if args.verify_seeds else [])]
    check_new_files(args.out, names, args.overwrite, "--out")
    if experiment:
        check_out_folder(args.out / "task", True, "--out")
    check_folder(args.out / "verify", "--out")
    if args.cell is None:
        return
    try:
        source = cell_path(args.cell)
    except CellsightError as exc:
        raise CellsightError(f"--cell: {exc}") from exc
    placed = args.out / "cell.yaml"
    if source.resolve() == placed.resolve():
        raise CellsightError(f"--cell: {str(source)!r} is the cell file this command writes "
                             f"(--out/cell.yaml); copy it elsewhere or choose another --out")
    if args.verify_seeds and source.stem == "cell":
        raise CellsightError(f"--cell: {str(source)!r} has the name of the chosen cameras' "
                             f"cell.yaml, and the verify runs name their folders by the cell "
                             f"file's name; copy it under another name")


def _make_out(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CellsightError(f"--out: {str(out)!r}: cannot create it ({exc.strerror})") from exc


def load_task(args: argparse.Namespace):
    """The run of ``--task``: the run folder as given, or OUT/task after running the
    experiment there (reused when finished on the same cell). ``--cell`` and ``--template``
    are checked before ``--out`` is created."""
    if args.task not in TASK_EXPERIMENTS:
        return load_run(Path(args.task), args.cell)
    try:
        cell = load_cell(args.cell)
    except CellsightError as exc:
        raise CellsightError(f"--cell: {exc}") from exc
    _template(cell, args.template)
    _make_out(args.out)
    folder = args.out / "task"
    config = RunConfig(int(args.task), folder, cell=args.cell, sensor="ideal",
                       progress=not args.quiet, overwrite=True)
    if reusable_metrics(folder, run_identity(config)) is None:
        raise_if_stopped(run_experiment(config))
    return load_run(folder, args.cell)


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
    results = run_sweep(specs, args.out / "verify", args.jobs, args.scheduler, not args.quiet,
                        overwrite=True)  # --out checked first (check_out)
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
    check_out(args)
    run = load_task(args)
    folder = run.folder
    task, cell = TaskFrames.of(run, args.every), run.cell
    k = len(cell.cameras) if args.cameras is None else args.cameras
    candidates = shell_candidates(cell, task, _template(cell, args.template),
                                  Shell(args.radii, args.elevations, args.azimuth_step))
    if not 1 <= k <= len(candidates):
        raise CellsightError(f"--cameras: expected 1..{len(candidates)} (the candidates), got {k}")
    _make_out(args.out)
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

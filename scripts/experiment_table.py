"""Run the paper's three experiments over sensors, seeds and with/without occlusion prediction,
and print the README's tables of their metrics (Markdown): the whole task, then per phase.

    .venv/bin/python scripts/experiment_table.py [--out out/table] [--seeds 0 1 2] [--jobs 2]

Without occlusion prediction, and with the kinematic prior (experiment 3 only), the first seed
only. Each run writes its own folder ``<out>/e<N>_<sensor>_<variant>_s<seed>``; runs already
done (a readable metrics.json, neither interrupted nor failed) are reused, the others run again
into their folder (``overwrite``: cleared first when it holds only a run's outputs). Ctrl-C
stops every run at its next frame; run again to go on.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from rich.progress import Progress

COLUMNS = (
    ("grasp_success", "grasp", "{}"),
    ("in_view_fraction", "in view", "{:.2f}"),
    ("lost_in_view_s", "lost s", "{:.2f}"),
    ("position_rmse_mm", "pos. RMSE mm", "{:.2f}"),
    ("max_position_error_mm", "max pos. mm", "{:.2f}"),
    ("orientation_rmse_deg", "orient. RMSE deg", "{:.2f}"),
    ("pnp_position_rmse_mm", "PnP pos. RMSE mm", "{:.2f}"),
    ("visibility_accuracy", "visibility acc.", "{:.4f}"),
    ("wrong_measurements", "wrong", "{}"),
    ("wrong_accepted", "wrong accepted", "{}"),
    ("grasp_position_error_mm", "grasp err. mm", "{:.2f}"),
)
PHASE_COLUMNS = ("approach", "grasp", "manipulate", "release")


def run_one(args: tuple[int, str, bool, bool, int, Path]) -> dict:
    from cellsight.experiments import RunConfig, run_experiment

    experiment, sensor, prediction, prior, seed, folder = args
    done = folder / "metrics.json"
    try:
        metrics = json.loads(done.read_text())
    except (OSError, ValueError):  # not run yet, or cut short while writing
        metrics = None
    if isinstance(metrics, dict) and not metrics.get("interrupted") and not metrics.get("error"):
        return metrics
    return run_experiment(RunConfig(experiment, folder, seed=seed, sensor=sensor,
                                    occlusion_prediction=prediction, kinematic_prior=prior,
                                    progress=False, overwrite=True))


def fmt(metrics: dict, key: str, pattern: str) -> str:
    value = metrics.get(key)
    return "–" if value is None else pattern.format(value)


def _run_cells(run: tuple) -> list[str]:
    """The first four cells of a row: experiment, sensor, variant, seed."""
    experiment, sensor, prediction, prior, seed, _ = run
    variant = "**off**" if not prediction else ("on + kinematic prior" if prior else "on")
    return [str(experiment), sensor, variant, str(seed)]


def run_all(runs: list[tuple], jobs: int, out: Path) -> list[dict]:
    """The metrics of every run, ``jobs`` at a time. On Ctrl-C (which each worker's run takes
    as the end of its loop) the runs not started are dropped, and the script exits 130."""
    results = []
    pool = ProcessPoolExecutor(jobs)
    try:
        with Progress() as progress:
            bar = progress.add_task("experiments", total=len(runs))
            for metrics in pool.map(run_one, runs):
                results.append(metrics)
                progress.advance(bar)
    except KeyboardInterrupt:
        pool.shutdown(cancel_futures=True)
        print(f"interrupted; finished runs in {out} are reused next time", file=sys.stderr)
        sys.exit(130)
    pool.shutdown()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/table"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--sensors", nargs="+", default=["rendered", "ideal"])
    parser.add_argument("--experiments", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    runs = []
    variants = (("pred", True, False), ("nopred", False, False), ("prior", True, True))
    for experiment, sensor, (variant, prediction, prior), seed in itertools.product(
            args.experiments, args.sensors, variants, args.seeds):
        if variant != "pred" and seed != args.seeds[0]:
            continue  # the comparisons: default seed only
        if prior and experiment != 3:
            continue  # the kinematic prior matters where one camera sees the held part
        name = f"e{experiment}_{sensor}_{variant}_s{seed}"
        runs.append((experiment, sensor, prediction, prior, seed, args.out / name))
    results = run_all(runs, args.jobs, args.out)
    header = ["exp.", "sensor", "occlusion prediction", "seed"] + [c[1] for c in COLUMNS]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for run, metrics in zip(runs, results, strict=True):
        cells = _run_cells(run) + [fmt(metrics, key, pattern) for key, _, pattern in COLUMNS]
        print("| " + " | ".join(cells) + " |")
    print("\nPosition RMSE / max (mm) per phase:\n")
    header = ["exp.", "sensor", "occlusion prediction", "seed", *PHASE_COLUMNS]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for run, metrics in zip(runs, results, strict=True):
        cells = _run_cells(run)
        phases = metrics.get("phases") or {}
        cells += [f"{fmt(phases.get(p, {}), 'position_rmse_mm', '{:.2f}')} / "
                  f"{fmt(phases.get(p, {}), 'max_position_error_mm', '{:.2f}')}"
                  for p in PHASE_COLUMNS]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()

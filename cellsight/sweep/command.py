"""``cellsight sweep``: the experiments over cells x experiments x sensors x variants x seeds,
resumable, on a local process pool (``--jobs``) or a Dask cluster (``--scheduler``), with a
summary table and plots (:mod:`.summary`).

Every argument is checked (the cells and realism profiles loaded, ``--out`` a folder or
creatable) before anything is written. An ``--out`` holding an earlier sweep (``sweep.json``)
is resumed; one holding a ``summary.*`` but no ``sweep.json`` is refused unless
``--overwrite``. SIGINT or SIGTERM stops the sweep (the pool's workers ended too) with one line
and exit status 130 or 143; the finished runs are reused next time."""

from __future__ import annotations

import argparse
import json
import math
import sys
from contextlib import closing
from pathlib import Path

from cellsight.errors import CellsightError
from cellsight.runfolder.writes import write_file
from cellsight.sweep.grid import SENSORS, VARIANTS, RunSpec, SweepAxes, sweep_grid
from cellsight.visibility import OBJECT_BVH, STRUCTURES


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight sweep`` to the command line's subcommands."""
    p = sub.add_parser("sweep", help="experiments over cells x experiments x sensors x "
                       "variants x seeds, resumable, locally or on a Dask cluster")
    p.add_argument("--out", type=Path, default=Path("out/sweep"),
                   help="output folder: one folder per run, sweep.json, summary.* "
                        "(default out/sweep); runs already finished there are reused")
    p.add_argument("--cells", nargs="+", default=["dual-arm"],
                   help="built-in cell names or cell files (default dual-arm)")
    p.add_argument("--experiments", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--sensors", nargs="+", default=list(SENSORS), help="rendered and/or ideal")
    p.add_argument("--variants", nargs="+", default=["kinematic"],
                   help="trackers: " + ", ".join(VARIANTS) + " (default kinematic: the default "
                        "tracker; plain: the paper's; calibrated: the default on the cell "
                        "calibrated by cellsight calibrate in each seed's world; the others: the "
                        "default with one change)")
    p.add_argument("--realism", nargs="+", default=["exact"], metavar="PROFILE",
                   help="the world's realism profiles: exact, lab, harsh, one knob group "
                        "alone (harsh/cameras), or YAML files (FILE or FILE:NAME; default exact)")
    p.add_argument("--structure", nargs="+", default=[OBJECT_BVH], metavar="STRUCTURE",
                   help=f"the occlusion predictor's structures: {' and/or '.join(STRUCTURES)} "
                        "(the paper's per-frame BSP; default object-bvh)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--variant-seeds", type=int,
                   help="run the variants after the first on the first N seeds only")
    p.add_argument("--duration", type=float, help="simulated seconds per run (default: the "
                   "whole task)")
    p.add_argument("--jobs", type=int, default=2, help="local worker processes (default 2)")
    p.add_argument("--scheduler", help="address of a Dask scheduler (tcp://host:8786): run on "
                   "its workers instead of a local pool")
    p.add_argument("--scheduler-timeout", type=float, default=20.0,
                   help="seconds to try reaching the scheduler (default 20)")
    p.add_argument("--overwrite", action="store_true", help="replace summary.* in an --out "
                   "that holds no earlier sweep (one with sweep.json is resumed, and its "
                   "sweep.json and summary.* replaced, without it)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)


SWEEP_FILES = ("sweep.json", "summary.md", "summary.csv", "summary.png")
"""The files a sweep writes at the top of its ``--out``, besides one folder per run."""


def check_sweep_out(out: Path, overwrite: bool) -> None:
    """Check, touching nothing, that ``--out`` can take the sweep: a folder or creatable (not
    a file, not under one); one holding an earlier sweep (``sweep.json``) is resumed, any
    other must hold none of :data:`SWEEP_FILES` unless ``overwrite``."""
    from cellsight.runfolder.folder import check_folder, check_new_files

    if check_folder(out, "--out") and not (out / "sweep.json").is_file():
        check_new_files(out, SWEEP_FILES, overwrite, "--out")


def check_pool(jobs: int, connect_s: float) -> None:
    """``--jobs`` >= 1 and ``--scheduler-timeout`` a positive, finite number of seconds."""
    if jobs < 1:
        raise CellsightError(f"--jobs: expected a whole number >= 1, got {jobs}")
    if not (math.isfinite(connect_s) and connect_s > 0):
        raise CellsightError(f"--scheduler-timeout: expected a positive, finite number of "
                             f"seconds, got {connect_s!r}")


def run_sweep(specs: list[RunSpec], out: Path, jobs: int = 2, scheduler=None,
              progress: bool = True, connect_s: float = 20.0,
              overwrite: bool = False) -> list[dict]:
    """Run (or reuse) every run of ``specs`` into ``out``; write ``sweep.json`` first and the
    summary last; return the metrics in ``specs`` order (``"error"`` for a failed run).
    ``out`` and the pool's settings are checked (:func:`check_sweep_out`, :func:`check_pool`)
    before anything is written. A run stopped by SIGINT or SIGTERM stops the sweep: the signal
    comes back as ``KeyboardInterrupt`` (:class:`~.engine.Terminated` for SIGTERM)."""
    from cellsight.sweep.engine import map_jobs, raise_if_stopped
    from cellsight.sweep.grid import run_spec
    from cellsight.sweep.summary import write_summary

    out = Path(out)
    check_pool(jobs, connect_s)
    check_sweep_out(out, overwrite)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_file(out / "sweep.json", json.dumps(
            [{**vars(s), "folder": str(s.folder)} for s in specs], indent=1))
    except OSError as exc:
        raise CellsightError(f"--out: {str(out)!r}: cannot create it or write sweep.json "
                             f"there ({exc.strerror})") from exc
    results: list[dict | None] = [None] * len(specs)
    jobs_done = map_jobs(run_spec, [(s, out) for s in specs], workers=jobs, scheduler=scheduler,
                         progress=progress, label="sweep", connect_s=connect_s,
                         on_crash=_crashed)
    with closing(jobs_done):  # an interrupt ends the pool now, not when collected
        for i, metrics in jobs_done:
            raise_if_stopped(metrics)  # a run that took the signal itself stops the sweep
            results[i] = metrics
    write_summary(out, specs, results)
    return results


def _crashed(job: tuple[RunSpec, Path]) -> dict:
    """The result of a run whose worker process died under it twice (the sweep goes on)."""
    return {"error": f"the worker process died twice running {job[0].folder} (a crash in "
                     f"native code; its Python stack is on the sweep's stderr)"}


def cmd_sweep(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cellsight.sweep.engine import sigterm_interrupts, stop_status

    check_pool(args.jobs, args.scheduler_timeout)
    axes = SweepAxes(args.cells, args.experiments, args.sensors, args.variants, args.seeds,
                     args.realism, args.structure)
    specs = sweep_grid(axes, args.variant_seeds, args.duration)
    check_sweep_out(args.out, args.overwrite)
    console = Console()
    try:
        with sigterm_interrupts():
            results = run_sweep(specs, args.out, args.jobs, args.scheduler, not args.quiet,
                                args.scheduler_timeout, args.overwrite)
    except KeyboardInterrupt as stop:
        name, status = stop_status(stop)
        print(f"cellsight: sweep interrupted by {name}; finished runs in {args.out} are reused "
              f"next time", file=sys.stderr)
        return status
    failed = [(s, m) for s, m in zip(specs, results, strict=True) if m.get("error")]
    reused = sum(bool(m.get("reused")) for m in results)
    print((args.out / "summary.md").read_text())
    console.print(f"{len(specs)} runs ({reused} reused, {len(failed)} failed); wrote "
                  f"[bold]{args.out}[/bold]: summary.md, summary.csv, summary.png")
    for spec, m in failed:
        console.print(f"[red]failed[/red] {spec.folder}: {m['error']}", markup=True)
    return 1 if failed else 0

"""``cellsight sweep``: the experiments over cells x experiments x sensors x variants x seeds,
resumable, on a local process pool (``--jobs``) or a Dask cluster (``--scheduler``), with a
summary table and plots (:mod:`.summary`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cellsight.sweep.grid import SENSORS, VARIANTS, RunSpec, sweep_grid
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
    p.add_argument("--variants", nargs="+", default=["pred"],
                   help="tracker options: " + ", ".join(VARIANTS) + " (default pred)")
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
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)


def run_sweep(specs: list[RunSpec], out: Path, jobs: int = 2, scheduler=None,
              progress: bool = True, connect_s: float = 20.0) -> list[dict]:
    """Run (or reuse) every run of ``specs`` into ``out``; write ``sweep.json`` first and the
    summary last; return the metrics in ``specs`` order (``"error"`` for a failed run)."""
    from cellsight.sweep.engine import map_jobs
    from cellsight.sweep.grid import run_spec
    from cellsight.sweep.summary import write_summary

    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").write_text(json.dumps(
        [{**vars(s), "folder": str(s.folder)} for s in specs], indent=1))
    results: list[dict | None] = [None] * len(specs)
    for i, metrics in map_jobs(run_spec, [(s, out) for s in specs], workers=jobs,
                               scheduler=scheduler, progress=progress, label="sweep",
                               connect_s=connect_s):
        results[i] = metrics
    write_summary(out, specs, results)
    return results


def cmd_sweep(args: argparse.Namespace) -> int:
    from rich.console import Console

    specs = sweep_grid(args.cells, args.experiments, args.sensors, args.variants, args.seeds,
                       args.variant_seeds, args.duration, args.realism, args.structure)
    console = Console()
    try:
        results = run_sweep(specs, args.out, args.jobs, args.scheduler, not args.quiet,
                            args.scheduler_timeout)
    except KeyboardInterrupt:
        print(f"cellsight: sweep interrupted; finished runs in {args.out} are reused next time",
              file=sys.stderr)
        return 130
    failed = [(s, m) for s, m in zip(specs, results, strict=True) if m.get("error")]
    reused = sum(bool(m.get("reused")) for m in results)
    print((args.out / "summary.md").read_text())
    console.print(f"{len(specs)} runs ({reused} reused, {len(failed)} failed); wrote "
                  f"[bold]{args.out}[/bold]: summary.md, summary.csv, summary.png")
    for spec, m in failed:
        console.print(f"[red]failed[/red] {spec.folder}: {m['error']}", markup=True)
    return 1 if failed else 0

"""The tracker's time per frame over the built-in cell's whole rendered experiment 3 (issue 61):
inside the simulated run, and on the run's recording, as a real cell's tracker runs.

One ``cellsight run 3 --realism lab --seed 3 --record`` (MuJoCo renders the two cameras; the
tracker has its defaults) writes the run's images, joint states and jaw openings to an MCAP
file; ``cellsight track`` then tracks the recording, quiet, and again with as many busy
processes as the machine has cores. Per row, from the run folder's ``frames.csv``: the
tracker's time a frame (``t_total_ms``: every stage, extraction included; reading the cameras
not) as its median and p99, the median of each stage, and the position RMSE against the
world's truth.

Inside the simulated run the tracker shares its core with the world: MuJoCo's physics (19
steps a frame at 500 Hz) and the renderer run between its frames, and the renderer in the
middle of one (the windows are rendered when the tracker asks for them), so the tracker
starts each stage with caches the world has filled. On the recording only the images'
decoding runs between frames, as in a cell where the cameras deliver images to the
tracker's process.

    .venv/bin/python bench/bench_task_tracker.py
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from cellsight.cli import main as cellsight_cli
from cellsight.runfolder.framelog import FrameLog

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_many_parts import busy_cores  # noqa: E402

SEED = 3
STAGES = ("occlusion", "selection", "windowing", "extraction", "ekf")


def cellsight(args: list[str]) -> None:
    """``cellsight ARGS``, what it prints left out of the bench's tables."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = cellsight_cli(args)
    if code:
        raise SystemExit(f"cellsight {' '.join(args)} failed ({code})")


def figures(folder: Path) -> dict:
    """The tracker's figures of a run folder (module docstring)."""
    log = FrameLog.read(folder / "frames.csv")
    total = log.floats("t_total_ms")
    metrics = json.loads((folder / "metrics.json").read_text())
    return {"frames": len(total), "median_ms": float(np.median(total)),
            "p99_ms": float(np.percentile(total, 99)),
            "stages_ms": {s: float(np.median(log.floats(f"t_{s}_ms"))) for s in STAGES},
            "rmse_mm": metrics.get("position_rmse_mm")}


def main() -> None:
    from rich.console import Console
    from rich.table import Table

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        recording = folder / "experiment3.mcap"
        cellsight(["run", "3", "--realism", "lab", "--seed", str(SEED), "--no-video",
                   "--quiet", "--out", str(folder / "run"), "--record", str(recording)])
        rows = {"in the simulated run": figures(folder / "run")}
        cellsight(["track", str(recording), "--quiet", "--out", str(folder / "track")])
        rows["on its recording (cellsight track)"] = figures(folder / "track")
        with busy_cores() as count:
            cellsight(["track", str(recording), "--quiet", "--out", str(folder / "loaded")])
        rows[f"on its recording, {count} busy processes"] = figures(folder / "loaded")
    table = Table(title=f"Tracker per frame, built-in cell, experiment 3 rendered, lab, seed "
                        f"{SEED}, the whole task (ms)")
    for col in ("where", "frames", "median", "p99", *STAGES, "median / run's",
                "pos. RMSE mm"):
        table.add_column(col, justify="right")
    run = rows["in the simulated run"]
    for name, r in rows.items():
        table.add_row(name, str(r["frames"]), f"{r['median_ms']:.2f}", f"{r['p99_ms']:.2f}",
                      *(f"{r['stages_ms'][s]:.2f}" for s in STAGES),
                      f"{r['median_ms'] / run['median_ms']:.2f}", f"{r['rmse_mm']:.2f}")
    Console().print(table)


if __name__ == "__main__":
    main()

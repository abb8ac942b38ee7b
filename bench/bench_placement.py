"""Camera placement's scoring speed (issue 15): frame x candidate pairs per second.

The task: experiment 3 on the built-in cell (an ideal-sensor run, made once into
``out/bench/placement_task``), every ``EVERY``-th vision frame; the candidates: the default
shell of ``cellsight place-cameras`` (copies of cam1 around the work area). Measured on the
same frames and candidates:

- cellsight: :func:`cellsight.placement.score_candidates` — exact visibility of every feature
  from every candidate (the predictor's object hierarchies, all candidates at once) and the
  pose information each candidate's visible features give;
- MuJoCo ``mj_multiRay`` on the world's model (the same solids): visibility only, one call per
  candidate and frame for the features in its image (state set with ``mj_kinematics``).

Printed: pairs per second (best of 3, and once beside a busy loop on every core), the ratio,
and how many rays the two disagree on. Target: at least 10^5 pairs per second, also under
that load.

    .venv/bin/python bench/bench_placement.py [EVERY]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from bench_latency import busy_loops
from bench_ur_cell import PEER_TOLERANCE
from rich.console import Console
from rich.table import Table

from cellsight import threads
from cellsight.experiments import RunConfig, run_experiment
from cellsight.model.loader import load_cell
from cellsight.placement.candidates import shell_candidates
from cellsight.placement.scoring import score_candidates
from cellsight.placement.task import TaskFrames
from cellsight.runfolder import finished_metrics
from cellsight.world import ReplayWorld

OUT = Path(__file__).resolve().parent.parent / "out" / "bench"
EVERY = 2


def task_run() -> Path:
    """The experiment-3 run the bench places cameras for (made once)."""
    folder = OUT / "placement_task"
    if finished_metrics(folder) is None:
        run_experiment(RunConfig(3, folder, sensor="ideal", progress=False, overwrite=True))
    return folder


def mujoco_visible(cell, task: TaskFrames, cameras) -> tuple[np.ndarray, float]:
    """(N, C, F) visible by MuJoCo ray casts (features outside the image: False) and the
    seconds spent casting (state set and rays, not the world's construction)."""
    import mujoco  # after cellsight.world, which picks the OpenGL back-end

    world = ReplayWorld(cell)
    model, data = world.scene.model, world.scene.data
    F = len(cell.workpiece(task.part).feature_points)
    out = np.zeros((task.n, len(cameras), F), dtype=bool)
    geomid, dist = np.empty(F, np.int32), np.empty(F)
    seconds = 0.0
    for k in range(task.n):
        t0 = time.perf_counter()
        world.show_state(*task.state(k))
        T = task.part_poses[k]
        points = cell.workpiece(task.part).feature_points @ T[:3, :3].T + T[:3, 3]
        for c, cam in enumerate(cameras):
            seen = np.flatnonzero(cam.sees(points))
            if not seen.size:
                continue
            vec = points[seen] - cam.center
            length = np.linalg.norm(vec, axis=1)
            mujoco.mj_multiRay(model, data, cam.center, (vec / length[:, None]).ravel(), None,
                               1, -1, geomid[:seen.size], dist[:seen.size], None, seen.size,
                               float(length.max()) + 1.0)
            d = dist[:seen.size]
            out[k, c, seen] = ~((d >= 0) & (d < length - PEER_TOLERANCE))
        seconds += time.perf_counter() - t0
    world.close()
    return out, seconds


def main(every: int = EVERY) -> None:
    threads.apply()  # the threading policy, as the CLI applies it
    cell = load_cell(None)
    task = TaskFrames.read(task_run(), every)
    cameras = shell_candidates(cell, task, cell.cameras[0])
    score_candidates(cell, task, cameras[:2], progress=False)  # compile and load once
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scores = score_candidates(cell, task, cameras, progress=False)
        best = min(best, time.perf_counter() - t0)
    load = busy_loops()  # the same scoring on a busy machine (the threading policy's case)
    try:
        t0 = time.perf_counter()
        score_candidates(cell, task, cameras, progress=False)
        loaded = time.perf_counter() - t0
    finally:
        for process in load:
            process.kill()
            process.wait()
    peer, peer_s = mujoco_visible(cell, task, cameras)
    pairs = scores.pairs
    rays = int(peer.sum() + (scores.visible & ~peer).sum())
    differ = int((scores.visible != peer).sum())
    table = Table(title=f"place-cameras scoring: {task.n} frames x {len(cameras)} candidates "
                        f"= {pairs} pairs (built-in cell, experiment 3, every {every}. frame)")
    for col in ("method", "s", "pairs / s", "vs MuJoCo"):
        table.add_column(col, justify="left" if col == "method" else "right")
    table.add_row("cellsight (visibility + pose information)", f"{best:.2f}",
                  f"{pairs / best:,.0f}", f"{peer_s / best:.1f}x")
    table.add_row("cellsight, beside a busy loop on every core", f"{loaded:.2f}",
                  f"{pairs / loaded:,.0f}", f"{peer_s / loaded:.1f}x")
    table.add_row("MuJoCo mj_multiRay (visibility only)", f"{peer_s:.2f}",
                  f"{pairs / peer_s:,.0f}", "1.0x")
    Console(width=140).print(table)
    print(f"features visible per the two: {rays} rays; they disagree on {differ} "
          f"({differ / max(peer.size, 1):.2%} of all feature x pair slots)")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "placement.json").write_text(json.dumps({
        "frames": task.n, "candidates": len(cameras), "pairs": pairs,
        "cellsight_s": best, "cellsight_pairs_per_s": pairs / best,
        "cellsight_loaded_pairs_per_s": pairs / loaded, "mujoco_s": peer_s,
        "mujoco_pairs_per_s": pairs / peer_s, "disagreements": differ}, indent=1))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else EVERY)

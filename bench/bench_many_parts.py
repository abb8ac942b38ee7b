"""The tracker's time per frame as parts are added: 1, 2, 4 and 8 workpieces on a line seen by
six cameras (issue 61).

The cell (``bench/line_cell.yaml``): a conveyor carrying eight workpieces of two shapes (a U
prism of 16 points and an L prism of 12), three cameras each side of the line, two arms folded
at its ends; each camera sees about four parts, each part two to four cameras. For ``K``
parts, the cell keeps the first ``K``. In the simulated world (``exact``), every part moves
along the line at ``SPEED`` m/s; each frame MuJoCo renders the six cameras and the tracker
(:class:`~cellsight.tracking.Tracker`, its defaults, acquiring each part at its nominal pose)
takes the images, with the kinematic prior's supports as the default tracker has them (each
part lying on the belt: its height, roll and pitch; without them, one part of eight drifted off
within four frames of its acquisition, its windows wide enough for a neighbour's corner). The
cameras are read on demand, as in a rendered run: MuJoCo renders only the regions of the
windows, every tracked part's of a camera in one grab (:mod:`cellsight.world.shots`). Per
frame, from the ``SETTLE``-th on (every part acquired): the tracker's time
(every stage, extraction included; the grab not) as its median and p99, per part, and per part
and camera in view; the median of each stage, the grab's (the rendering of the windows)
apart; the parts tracked (updated by the images: ``tracking``, or ``degraded``, as a track is
for its first half second), and the RMS of the position
error against the poses the world was given, over every part and frame. Then the ``LOADED``
parts again under load: as many busy processes as the machine has cores, started before and
stopped after the run (the tracker shares the cores with them), its median and p99 against the
quiet run's.

    .venv/bin/python bench/bench_many_parts.py [FRAMES]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from cellsight import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.rates import VISION_HZ
from cellsight.tracking import Tracker
from cellsight.world.world import World

CELL = Path(__file__).with_name("line_cell.yaml")
PARTS = (1, 2, 4, 8)
FRAMES = 160  # vision frames a run (6.2 s): a p99 of fewer is little more than the worst frame
SETTLE = 5  # frames left out of the figures: the parts' acquisition
SPEED = 0.02  # m/s along the line (+x), as the built-in cell's conveyor
LOADED = 4  # parts of the run under load


def line_cell(parts: int, folder: Path):
    """The line cell with its first ``parts`` workpieces, written in ``folder``."""
    raw = yaml.safe_load(CELL.read_text())
    raw["workpieces"] = raw["workpieces"][:parts]
    path = folder / f"line_{parts}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return load_cell(path)


def measure(parts: int, frames: int = FRAMES) -> dict:
    """One run of ``frames`` frames with ``parts`` parts (module docstring)."""
    with tempfile.TemporaryDirectory() as folder:
        cell = line_cell(parts, Path(folder))
    world = World(cell)
    tracker = Tracker.from_cell(cell, visibility_predictor(cell))
    start = {p.name: p.T_base_part for p in cell.workpieces}
    joints = {r.name: r.home for r in cell.robots}
    totals, stages, errors, tracked, in_view = [], [], [], [], []
    try:
        for n in range(frames):
            t = n / VISION_HZ
            poses = {name: T.copy() for name, T in start.items()}
            for name, T in poses.items():
                T[0, 3] += SPEED * t
                world.place_part(name, T)
            world.step()
            frame = tracker.step(world.render(on_demand=True), joints, t, world.jaw_openings(),
                                 supports=start)
            if n < SETTLE:
                continue
            totals.append(frame.timings["total"])
            stages.append(frame.timings)
            for name, rec in frame.parts.items():
                tracked.append(str(rec.status) in ("tracking", "degraded"))  # updated
                in_view.append(int(rec.visible.any(axis=1).sum()))
                if rec.T_base_part is not None:
                    errors.append(np.linalg.norm(rec.T_base_part[:3, 3] - poses[name][:3, 3]))
    finally:
        world.close()
    totals_ms = 1e3 * np.array(totals)
    median = float(np.median(totals_ms))
    return {"parts": parts, "cameras": len(cell.cameras), "median_ms": median,
            "p99_ms": float(np.percentile(totals_ms, 99)), "per_part_ms": median / parts,
            "per_part_camera_us": 1e3 * median / (np.mean(in_view) * parts),
            "cameras_per_part": float(np.mean(in_view)),
            "stages_ms": {s: 1e3 * float(np.median([x[s] for x in stages]))
                          for s in stages[0] if s != "total"},
            "tracked": float(np.mean(tracked)),
            "rmse_mm": 1e3 * float(np.sqrt(np.mean(np.square(errors))))}


@contextmanager
def busy_cores() -> Iterator[int]:
    """As many busy processes as the machine has cores, for the ``with`` block; their count."""
    count = os.cpu_count() or 1
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
               for _ in range(count)]
    try:
        yield count
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()


def main(frames: int = FRAMES) -> None:
    from rich.console import Console
    from rich.table import Table

    rows = [measure(k, frames) for k in PARTS]
    table = Table(title=f"Tracker per frame, rendered, 6 cameras, {frames - SETTLE} frames "
                        "a row (ms; grab: rendering the windows, not in the median)")
    stages = list(rows[0]["stages_ms"])
    for col in ("parts", "median", "p99", "per part", "per part x camera (us)",
                "cameras a part", *stages, "tracking", "pos. RMSE mm"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(str(r["parts"]), f"{r['median_ms']:.2f}", f"{r['p99_ms']:.2f}",
                      f"{r['per_part_ms']:.2f}", f"{r['per_part_camera_us']:.0f}",
                      f"{r['cameras_per_part']:.1f}",
                      *(f"{r['stages_ms'][s]:.2f}" for s in stages),
                      f"{r['tracked']:.0%}", f"{r['rmse_mm']:.2f}")
    Console().print(table)
    quiet = next(r for r in rows if r["parts"] == LOADED)
    with busy_cores() as count:
        loaded = measure(LOADED, frames)
    load = Table(title=f"{LOADED} parts, quiet and with {count} busy processes on {count} cores "
                       "(ms)")
    for col in ("run", "median", "p99", "p99 / quiet p99"):
        load.add_column(col, justify="right")
    for name, r in (("quiet", quiet), ("under load", loaded)):
        load.add_row(name, f"{r['median_ms']:.2f}", f"{r['p99_ms']:.2f}",
                     f"{r['p99_ms'] / quiet['p99_ms']:.2f}")
    Console().print(load)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else FRAMES)

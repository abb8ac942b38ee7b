"""The tracker's time per frame on a quiet and on a busy machine (issue 25).

A rendered run of experiment 3 on the built-in cell (``exact`` world, ``DURATION`` s: the part
on the conveyor, R6AX crossing the views), in its own process as ``cellsight run`` does it.
Per frame, the tracker's time (``t_total_ms`` of ``frames.csv``: every stage, extraction
included, both cameras; the cameras' grab not included, :mod:`cellsight.tracking.timing`) and
the predictor's (``t_occlusion_ms``), in three conditions:

- quiet: nothing else running;
- beside a second run: the same run in another process at the same time;
- beside busy loops: one process spinning on every core.

Each condition twice: with the threading policy (:mod:`cellsight.threads`) and with the
policy before it, its peer (OpenMP's idle threads spinning, and the predictor's kernel
parallel over the cameras whatever the work). Printed: median, p99 and max
per frame (ms) of the row's runs pooled (``REPEATS`` runs a row, interleaved), each run's p99,
and the median wall time of the runs; the p99 under load against the quiet p99.

    .venv/bin/python bench/bench_latency.py [DURATION]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from cellsight import threads
from cellsight.runfolder.framelog import FrameLog

DURATION = 12.0  # s of simulated time per run (312 frames)
REPEATS = 3  # runs per row: one run's p99 moves by half between runs on a shared machine
OUT = Path(__file__).resolve().parent.parent / "out" / "bench"
CONDITIONS = ("quiet", "beside a second run", "beside busy loops")
POLICIES = ("threading policy", "before it: spinning, parallel kernel")

_CHILD = """
import sys
from pathlib import Path
from cellsight import threads
from cellsight.experiments import RunConfig, run_experiment
if sys.argv[3] == "old":
    import cellsight.occlusion.forest as forest
    forest.PARALLEL_MIN_POINTS = 0
else:
    threads.apply()
run_experiment(RunConfig(experiment=3, out=Path(sys.argv[1]), duration=float(sys.argv[2]),
                         progress=False, video_every=0, overwrite=True))
"""


def _run(out: Path, duration: float, old: bool) -> subprocess.Popen:
    """A run in its own process; ``old``: the threading of before the policy."""
    env = dict(os.environ)
    if old:  # OpenMP's threads spin as they did (cellsight sets PASSIVE only where unset)
        env.update(OMP_WAIT_POLICY="ACTIVE")
        for name in threads.environment(1):
            if name != "OMP_WAIT_POLICY":
                env.pop(name, None)
    return subprocess.Popen([sys.executable, "-c", _CHILD, str(out), str(duration),
                             "old" if old else "new"], env=env)


def busy_loops() -> list[subprocess.Popen]:
    """One process spinning on every core (kill them when done)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"])
            for _ in range(threads.cores())]


def measure(condition: str, old: bool, duration: float, folder: Path) -> dict:
    """Per-frame times (ms) of one run in ``condition`` (one of :data:`CONDITIONS`): the
    tracker's and the predictor's, the first frame left out, and the run's wall time (s)."""
    out = folder / f"{CONDITIONS.index(condition)}{'old' if old else 'new'}"
    load = busy_loops() if condition == "beside busy loops" else []
    if condition == "beside a second run":
        load.append(_run(out.with_name(out.name + "-second"), duration, old))
    try:
        if _run(out, duration, old).wait() != 0 or any(p.poll() for p in load):
            raise RuntimeError(f"the benchmark's run in {out} failed")
    finally:
        for process in load:
            process.kill()
            process.wait()
    log = FrameLog.read(out / "frames.csv")
    metrics = json.loads((out / "metrics.json").read_text())
    return {"tracker": log.floats("t_total_ms")[1:], "occlusion": log.floats("t_occlusion_ms")[1:],
            "wall_s": float(metrics["wall_s"])}


def summary(runs: list[dict]) -> dict:
    """The figures of a condition's runs: median, p99 and max of their frames pooled, each
    run's p99, the predictor's pooled p99 and the median wall time."""
    tracker = np.concatenate([r["tracker"] for r in runs])
    occlusion = np.concatenate([r["occlusion"] for r in runs])
    return {"median": float(np.median(tracker)), "p99": float(np.percentile(tracker, 99)),
            "max": float(tracker.max()), "occlusion_p99": float(np.percentile(occlusion, 99)),
            "p99_runs": [float(np.percentile(r["tracker"], 99)) for r in runs],
            "wall_s": float(np.median([r["wall_s"] for r in runs])),
            "frames": int(tracker.size)}


def main(duration: float = DURATION) -> None:
    runs: dict[str, dict[str, list]] = {p: {c: [] for c in CONDITIONS} for p in POLICIES}
    with tempfile.TemporaryDirectory() as tmp:
        _run(Path(tmp) / "warm", 1.0, False).wait()  # numba's caches, once
        for _ in range(REPEATS):  # interleaved: the machine's drift falls on every row alike
            for policy, old in zip(POLICIES, (False, True), strict=True):
                for c in CONDITIONS:
                    runs[policy][c].append(measure(c, old, duration, Path(tmp)))
    results = {p: {c: summary(r) for c, r in rows.items()} for p, rows in runs.items()}
    table = Table(title=f"tracker time per frame (ms), rendered experiment 3, {duration:g} s, "
                        f"{REPEATS} runs a row pooled, {threads.cores()} cores (first frame "
                        f"left out)")
    for col in ("threads", "condition", "median", "p99", "p99 of each run", "max",
                "p99 / quiet p99", "predictor p99", "run wall s"):
        table.add_column(col, justify="left" if col in ("threads", "condition") else "right")
    for policy, rows in results.items():
        quiet = rows["quiet"]["p99"]
        for condition, r in rows.items():
            table.add_row(policy, condition, f"{r['median']:.2f}", f"{r['p99']:.2f}",
                          " ".join(f"{x:.1f}" for x in r["p99_runs"]), f"{r['max']:.1f}",
                          f"{r['p99'] / quiet:.2f}x", f"{r['occlusion_p99']:.2f}",
                          f"{r['wall_s']:.1f}")
    Console(width=150).print(table)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "latency.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:2]))

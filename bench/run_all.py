"""Run every benchmark in bench/ and print their tables (``make bench``)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from cellsight import threads

BENCHES = ["bench_cell_occlusion", "bench_ur_cell", "bench_bsp_scaling", "bench_tracking",
           "bench_latency",
           "bench_kinematics", "bench_control", "bench_visible_mask", "bench_scale",
           "bench_placement"]


def main() -> None:
    threads.apply()  # the threading policy, as the CLI applies it
    sys.path.insert(0, str(Path(__file__).parent))
    for name in BENCHES:
        if not (Path(__file__).parent / f"{name}.py").exists():
            continue
        print(f"\n== {name}")
        importlib.import_module(name).main()


if __name__ == "__main__":
    main()

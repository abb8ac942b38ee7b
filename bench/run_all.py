"""Run every benchmark in bench/ and print their tables (``make bench``).

With ``--save FOLDER`` (``docs/results/bench`` for the docs), each benchmark's printed tables
are also written to ``FOLDER/<bench>.txt``, and ``FOLDER/<bench>.json`` says what made them:
the command, the git commit, the date, the machine's cores and what else ran meanwhile
(``--busy``). The docs' Benchmarks page (``docs/gen/results.py``) shows them.

    python bench/run_all.py [--only bench_visible_mask,...] [--save FOLDER] [--busy TEXT]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib
import io
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import cellsight
from cellsight import threads

BENCHES = ["bench_cell_occlusion", "bench_ur_cell", "bench_bsp_scaling", "bench_tracking",
           "bench_latency", "bench_many_parts", "bench_task_tracker",
           "bench_kinematics", "bench_control", "bench_visible_mask", "bench_scale",
           "bench_placement", "bench_search"]


class _Tee(io.TextIOBase):
    """Writes to the terminal and keeps a copy."""

    def __init__(self, terminal) -> None:
        self.terminal, self.copy = terminal, io.StringIO()

    def write(self, text: str) -> int:
        self.terminal.write(text)
        return self.copy.write(text)

    def flush(self) -> None:
        self.terminal.flush()


def _commit(root: Path) -> str:
    out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True)
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=",".join(BENCHES),
                        help="comma-separated benchmarks to run (default: all)")
    parser.add_argument("--save", type=Path, help="folder to write each benchmark's tables to")
    parser.add_argument("--busy", default="nothing else",
                        help="what else ran on the machine meanwhile (for meta.json)")
    args = parser.parse_args()
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in BENCHES]
    if unknown:
        parser.error(f"--only: unknown benchmark(s) {', '.join(unknown)}; "
                     f"known: {', '.join(BENCHES)}")
    if args.save is not None:
        args.save.mkdir(parents=True, exist_ok=True)
        os.environ["COLUMNS"] = "160"  # rich's tables at full width in the saved text
    threads.apply()  # the threading policy, as the CLI applies it
    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here))
    meta = {"command": "python bench/run_all.py " + " ".join(sys.argv[1:]),
            "version": cellsight.__version__, "commit": _commit(here.parent),
            "made": datetime.date.today().isoformat(), "cores": os.cpu_count(),
            "machine": f"{platform.machine()}, {platform.system()}",
            "busy": args.busy}
    for name in names:
        print(f"\n== {name}")
        tee = _Tee(sys.stdout)
        with contextlib.redirect_stdout(tee):
            importlib.import_module(name).main()
        if args.save is not None:
            (args.save / f"{name}.txt").write_text(tee.copy.getvalue())
            (args.save / f"{name}.json").write_text(json.dumps(meta, indent=1))


if __name__ == "__main__":
    main()

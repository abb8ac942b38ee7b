"""``make fuzz``: hostile and random input against the oracle and the error rules (issues 14, 23).

Runs the case kinds of ``tests/fuzzing.py`` (soups against the oracle, hostile soups, mutated
and damaged cell files, random command lines, the run folder's families of
``tests/fuzz_folders.py``, and damaged run folders read back, damaged or hostile recordings
tracked and damaged sweeps resumed, of ``tests/fuzz_inputs.py``), by default 114,500 cases in
all, on a process pool (one kind per process; each of the last three about 20 minutes on one
core), with a progress bar; every failure is appended to
``out/fuzz/failures.txt`` as it is found, and the summary to ``out/fuzz/summary.json``.
Exit status 1 when any case failed.

    python scripts/fuzz.py [--scale 1.0] [--seed 0] [--jobs 2] [--out out/fuzz] [--kinds a,b]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import Manager
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import fuzzing  # noqa: E402

CASES = {"soup": 50_000, "hostile_soup": 30_000, "cell_file": 10_000, "cell_text": 10_000,
         "cli": 5_000, "out_folder": 3_000, "replay": 500, "write_failure": 200,
         "run_folder": 3_000, "recording": 2_000, "sweep_resume": 800}


def _run(kind: str, cases: int, seed: int, queue, failures: str) -> dict:
    """One kind in a worker process; progress and failures go out as they happen."""
    import warnings

    warnings.simplefilter("ignore")  # overflow warnings from the hostile values are expected
    start = time.perf_counter()

    def progress(done: int) -> None:
        if done % 50 == 0 or done == cases:
            queue.put((kind, done))

    def on_failure(line: str) -> None:
        with open(failures, "a") as f:
            f.write(line + "\n")

    tally = fuzzing.run_kind(kind, cases, seed, progress, on_failure)
    return {"kind": kind, "cases": tally.cases, "refused": tally.refused,
            "queries": tally.queries, "hidden": tally.hidden, "ambiguous": tally.ambiguous,
            "failures": len(tally.failures), "seconds": round(time.perf_counter() - start, 1)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="multiplies every case count")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--out", default="out/fuzz", help="folder of the failures and summary")
    parser.add_argument("--kinds", default=",".join(CASES),
                        help="comma-separated case kinds to run (default: all)")
    args = parser.parse_args()
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in CASES]
    if unknown:
        parser.error(f"--kinds: unknown kind(s) {', '.join(unknown)}; known: {', '.join(CASES)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failures = out / "failures.txt"
    failures.write_text("")
    counts = {k: max(1, round(CASES[k] * args.scale)) for k in kinds}
    with Manager() as manager, ProcessPoolExecutor(args.jobs) as pool, Progress(
            TextColumn("{task.description:>12}"), BarColumn(), MofNCompleteColumn(),
            TimeElapsedColumn()) as progress:
        queue = manager.Queue()
        bars = {k: progress.add_task(k, total=n) for k, n in counts.items()}
        futures = [pool.submit(_run, k, n, args.seed, queue, str(failures))
                   for k, n in counts.items()]
        while not all(f.done() for f in futures) or not queue.empty():
            while not queue.empty():
                kind, done = queue.get()
                progress.update(bars[kind], completed=done)
            time.sleep(0.2)
        rows = [f.result() for f in futures]
    (out / "summary.json").write_text(json.dumps(rows, indent=1))
    table = Table(title=f"fuzz: {sum(r['cases'] for r in rows):,} cases (seed {args.seed})")
    for col in rows[0]:
        table.add_column(col, justify="left" if col == "kind" else "right")
    for row in rows:
        table.add_row(*(f"{v:,}" if isinstance(v, int) else str(v) for v in row.values()))
    Console().print(table)
    failed = sum(r["failures"] for r in rows)
    if failed:
        print(f"{failed} failures: {failures}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

"""Check that two sets of run folders give the same results: ``metrics.json`` in every key but
the timing, wall time, schema version and file paths and digests, and ``frames.csv`` in every
column but the stage timings (``t_*_ms``), row by row. Used to show that a refactor changes no
figure: run the same experiments before and after into two folders, then

    python scripts/compare_runs.py BEFORE_DIR AFTER_DIR

where each holds run folders of the same names (or pass two run folders). Prints one line per
run and IDENTICAL or DIFFERENT; exits 1 when different."""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from cellsight.runfolder import read_metrics

SKIPPED = {"wall_s", "timing_ms", "metrics_version", "cell", "realism_file", "cell_sha256",
           "cell_files", "frames_sha256"}


def _rows(folder: Path) -> list[list[str]]:
    with (folder / "frames.csv").open(newline="") as f:
        return list(csv.reader(f))


def compare(a: Path, b: Path) -> bool:
    """Print how run folders ``a`` and ``b`` differ; True when they do not."""
    ma, mb = read_metrics(a), read_metrics(b)
    keys = sorted(k for k in set(ma) | set(mb) if k not in SKIPPED and ma.get(k) != mb.get(k))
    ra, rb = _rows(a), _rows(b)
    keep = [i for i, c in enumerate(ra[0]) if not (c.startswith("t_") and c.endswith("_ms"))]
    rows = abs(len(ra) - len(rb)) + sum(
        [x[i] for i in keep] != [y[i] for i in keep] for x, y in zip(ra, rb, strict=False))
    print(f"{a.name}: metrics differing: {keys or 'none'}; frames.csv rows differing: {rows}; "
          f"same columns: {ra[0] == rb[0]}")
    return not keys and rows == 0 and ra[0] == rb[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    args = parser.parse_args()
    pairs = ([(args.before, args.after)] if (args.before / "metrics.json").exists() else
             [(p, args.after / p.name) for p in sorted(args.before.iterdir()) if p.is_dir()])
    same = all([compare(a, b) for a, b in pairs])
    print("IDENTICAL" if same else "DIFFERENT")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

"""The results pages, made from the sweeps' summaries and never typed by hand.

Each table is a folder ``docs/results/data/<name>/`` holding what ``cellsight sweep`` wrote
(``summary.csv``, ``summary.md``, ``summary.png``) and ``meta.json`` (the title, the command
that made it, the cellsight version and the git commit it ran at), copied there by
``scripts/publish_results.py``. A table whose commit is older than the code's last change
says so, naming the files of ``cellsight/`` changed since.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import subprocess
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cellsight.sweep.summary import LINES_HEADER as LINES
from cellsight.sweep.summary import PASSING_HEADER as PASSING

DATA = Path("docs") / "results" / "data"
BENCH = Path("docs") / "results" / "bench"
PHASES = ("approach", "grasp", "manipulate", "release")
FIGURES = (  # summary.csv column, header, decimals
    ("position_rmse_arm_mm", "pos. RMSE, arm frame mm", 2),
    ("position_rmse_mm", "pos. RMSE mm", 2),
    ("max_position_error_mm", "max pos. mm", 1),
    ("orientation_rmse_deg", "orient. RMSE °", 2),
    ("visibility_accuracy", "visibility acc.", 4),
    ("lost_in_view_s", "lost in view s", 2),
    ("confident_wrong_frames", "frames > 10 mm off while tracking", 1),
    ("wrong_accepted", "wrong corners accepted", 1),
)
"""The whole-task figures of a results table: the mean over seeds ± the standard deviation,
and the range."""


@dataclass(frozen=True)
class Table:
    """One published sweep: its folder, its rows and how it was made."""

    name: str
    folder: Path
    rows: list[dict[str, str]]
    meta: dict[str, str]


def tables(root: Path) -> list[Table]:
    """Every published sweep under ``root / DATA``, in the order of their ``meta.json``'s
    ``order`` (then by name)."""
    found = []
    for meta_file in sorted((root / DATA).glob("*/meta.json")):
        folder = meta_file.parent
        with open(folder / "summary.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        found.append(Table(folder.name, folder, rows, json.loads(meta_file.read_text())))
    return sorted(found, key=lambda t: (int(t.meta.get("order", 99)), t.name))


def _number(text: str | None) -> float | None:
    try:
        value = float(text) if text not in (None, "") else None
    except ValueError:
        return None
    return None if value is None or math.isnan(value) else value


def _spread(values: Iterable[float | None], decimals: int) -> str:
    """``mean ± sd (min–max)`` of the values measured; ``–`` when none."""
    got = [v for v in values if v is not None]
    if not got:
        return "–"
    mean = statistics.fmean(got)
    sd = statistics.stdev(got) if len(got) > 1 else 0.0
    text = f"{mean:.{decimals}f} ± {sd:.{decimals}f}"
    return text + f" ({min(got):.{decimals}f}–{max(got):.{decimals}f})" if len(got) > 1 else text


GROUP = ("cell", "realism", "experiment", "sensor", "variant", "structure")


def _groups(rows: list[dict[str, str]]) -> dict[tuple[str, ...], list[dict[str, str]]]:
    groups: dict[tuple[str, ...], list[dict[str, str]]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(k, "") for k in GROUP), []).append(row)
    return groups


def summary_table(rows: list[dict[str, str]], figures=FIGURES) -> str:
    """One line per group of runs (cell, realism, experiment, sensor, variant, structure):
    runs, failed runs, grasps, then each figure's spread over the seeds. A grouping column
    that is the same on every line is said once above the table instead."""
    present = [f for f in figures if any(_number(r.get(f[0])) is not None for r in rows)]
    groups = _groups(rows)
    varying = [i for i, _ in enumerate(GROUP) if len({key[i] for key in groups}) > 1]
    same = [f"{GROUP[i]} `{next(iter(groups))[i]}`" for i in range(len(GROUP))
            if i not in varying]
    head = [GROUP[i] for i in varying] + ["runs (failed)", "grasps"] + [h for _, h, _ in present]
    lines = [f"All runs: {', '.join(same)}.", ""] if same else []
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, runs in groups.items():
        done = [r for r in runs if r.get("status") == "done"]
        grasps = sum(r.get("grasp_success") == "True" for r in done)
        cells = [key[i] for i in varying] + [f"{len(runs)} ({len(runs) - len(done)})",
                                             f"{grasps}/{len(done)}"]
        cells += [_spread((_number(r.get(col)) for r in done), d) for col, _, d in present]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def phase_table(rows: list[dict[str, str]]) -> str:
    """Position RMSE (mm) per working phase, per group: mean ± sd over the seeds."""
    head = ["realism", "experiment", "variant"] + [f"{p} mm" for p in PHASES]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, runs in _groups(rows).items():
        done = [r for r in runs if r.get("status") == "done"]
        cells = [key[1], key[2], key[4]]
        cells += [_spread((_number(r.get(f"{p}_position_rmse_mm")) for r in done), 2)
                  for p in PHASES]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def code_changes_since(root: Path, commit: str) -> list[str] | None:
    """The files of ``cellsight/`` changed between ``commit`` and the working tree (None when
    git cannot tell: no repository, or the commit is unknown)."""
    try:
        out = subprocess.run(["git", "diff", "--name-only", commit, "--", "cellsight"],
                             cwd=root, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.split() if out.returncode == 0 else None


def provenance(root: Path, meta: dict[str, str]) -> str:
    """Which command and version made a table (its ``meta``), and whether the code changed
    since."""
    text = (f"Made by `{meta['command']}` with cellsight {meta['version']} at commit "
            f"`{meta['commit'][:12]}` on {meta['made']}.")
    changed = code_changes_since(root, meta["commit"])
    if changed is None:
        return text + "\n\n!!! warning \"Age unknown\"\n    git cannot tell whether the code " \
                      "changed since these runs.\n"
    if changed:
        shown = ", ".join(f"`{c.removeprefix('cellsight/')}`" for c in changed[:8])
        more = f" and {len(changed) - 8} more" if len(changed) > 8 else ""
        return text + (f"\n\n!!! warning \"Older than the code\"\n    {len(changed)} files of "
                       f"`cellsight/` changed since these runs ({shown}{more}); the figures may "
                       "differ at the current code.\n")
    return text + " The code has not changed since.\n"


def _section(body: list[str], header: str) -> list[str]:
    """The table under ``header`` in a ``summary.md`` (its lines up to the next blank one)."""
    rest = body[body.index(header) + 2:]  # the header, then a blank line
    return rest[:rest.index("")] if "" in rest else rest


def table_page(root: Path, table: Table) -> str:
    """One sweep's page: provenance, the spread per group, per phase, the plot, every run."""
    meta = table.meta
    lines = [f"# {meta['title']}", "", meta.get("description", ""), "",
             provenance(root, table.meta), "",
             "Each line is a group of runs over its seeds: mean ± standard deviation "
             "(smallest–largest). RMSE and max are over every frame with the part in view "
             "of the whole task.", "", summary_table(table.rows), "",
             "## Per phase", "", "Position RMSE (mm):", "", phase_table(table.rows)]
    body = (table.folder / "summary.md").read_text().strip().splitlines()
    if LINES in body:  # a line's runs: each part's own figures, grouped
        lines += ["## Each part", "", "Every part of the line, each picked in turn, with its "
                  "own figures:", "", *_section(body, LINES), ""]
    if PASSING in body:  # its parts passing through the views, not picked
        lines += ["## Parts passing through", "", "The parts the belt carries into the views "
                  "from upstream and out of them downstream, tracked and not picked:", "",
                  *_section(body, PASSING), ""]
    if (table.folder / "summary.png").is_file():
        lines += ["## Every seed", "", f"![{meta['title']}](data/{table.name}/summary.png)", ""]
    lines += ["## Every run", "", "??? note \"The sweep's own summary.md\"", ""]
    lines += [f"    {line}" if line else "" for line in body]
    return "\n".join(lines) + "\n"


def index_page(root: Path, found: list[Table]) -> str:
    """The results' front page: what each table measures and the headline figures."""
    lines = ["# Results", "",
             "Every table here is made by a script (`docs/gen/results.py`) from the summaries "
             "of `cellsight sweep` (`make experiments`, then `make results`); none is typed "
             "by hand. Each says which command and which version made it, and warns when the "
             "code has changed since. The speed of each part against its peers: "
             "[Benchmarks](benchmarks.md).", "", "## Headline figures", "", headline(found), "",
             "## Tables", "", "| table | runs | what it measures |", "|---|---|---|"]
    lines += [f"| [{t.meta['title']}]({t.name}.md) | {len(t.rows)} | "
              f"{t.meta.get('description', '')} |" for t in found]
    return "\n".join(lines) + "\n"


def headline(found: list[Table]) -> str:
    """The headline table (README and the results' front page): whole-task figures of
    experiment 3, one line per published world and tracker (the sweep's variant: ``pred`` in
    sweeps from before the kinematic tracker was the default was the plain tracker;
    ``calibrated`` is the default on the cell calibrated in each seed's world); a world and
    tracker already shown by an earlier sweep (``order``) is not shown again."""
    groups: dict[tuple[str, ...], list[dict[str, str]]] = {}
    for table in (t for t in found if t.meta.get("headline")):
        mine = _groups([r for r in table.rows if r.get("experiment") == "3"])
        shown = {(key[1], key[4]) for key in groups}
        groups.update({key: runs for key, runs in mine.items() if (key[1], key[4]) not in shown})
    if not groups:
        return "No published sweep is marked as a headline yet.\n"
    pick = [f for f in FIGURES if f[0] in (
        "position_rmse_arm_mm", "position_rmse_mm", "max_position_error_mm", "orientation_rmse_deg",
        "visibility_accuracy", "confident_wrong_frames")]
    head = ["world", "tracker", "runs", "grasps"] + [h for _, h, _ in pick]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, runs in groups.items():
        done = [r for r in runs if r.get("status") == "done"]
        grasps = sum(r.get("grasp_success") == "True" for r in done)
        variant = runs[0].get("variant", "")
        tracker = {"pred": "plain", "prior": "kinematic",
                   "calibrated": "kinematic, calibrated cell"}.get(variant, variant)
        cells = [f"`{key[1]}`", tracker, str(len(runs)), f"{grasps}/{len(done)}"]
        cells += [_spread((_number(r.get(col)) for r in done), d) for col, _, d in pick]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def bench_page(root: Path) -> str:
    """The benchmarks' page: each benchmark's printed tables as ``bench/run_all.py --save``
    wrote them (``docs/results/bench/<bench>.txt``), with the command, the commit and what else
    ran, and a warning when the code changed since."""
    lines = ["# Benchmarks", "",
             "Each benchmark of `bench/` prints its peers' times measured in the same run, and "
             "the ratios; these are its tables as `python bench/run_all.py --save "
             "docs/results/bench` printed them (`make bench` prints them without saving). "
             "Times are wall-clock medians unless a column says otherwise.", ""]
    found = sorted((root / BENCH).glob("*.txt"))
    if not found:
        return "\n".join(lines + ["No benchmark has been saved here yet.", ""])
    for text_file in found:
        meta = json.loads(text_file.with_suffix(".json").read_text())
        lines += [f"## `{text_file.stem}`", "", provenance(root, meta), "",
                  f"On {meta['cores']} cores ({meta['machine']}), {meta['busy']} running "
                  "beside it.", "", "```text", text_file.read_text().strip(), "```", ""]
    return "\n".join(lines)


def pages(root: Path) -> dict[str, str]:
    """Every results page by its path in the site."""
    found = tables(root)
    out = {"results/index.md": index_page(root, found), "results/benchmarks.md": bench_page(root)}
    out.update({f"results/{t.name}.md": table_page(root, t) for t in found})
    return out

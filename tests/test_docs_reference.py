"""The generated documentation against the code it is generated from: every command and
argument of the CLI, every field of the cell file's and the realism profile's schemas with its
unit, every column of ``frames.csv``, every file of a run folder; the results tables against
their summaries, computed another way; the README's headline table against the published
sweeps."""

from __future__ import annotations

import argparse
import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cellsight.cli import build_parser
from cellsight.model.schema import CellSpec
from cellsight.realism.profile import Profile
from cellsight.runfolder import RUN_FILES
from cellsight.runfolder.folder import RUN_FILE_DOCS
from cellsight.runfolder.framelog import COLUMN_DOCS, columns
from cellsight.runfolder.metrics import RunMetrics

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "docs" / "gen"))

import reference  # noqa: E402
import results  # noqa: E402


def test_the_cli_reference_has_every_command_and_argument() -> None:
    parser = build_parser()
    page = reference.cli_page(parser)
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(action.choices) >= 16
    for name, sub in action.choices.items():
        section = page.split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]
        for arg in sub._actions:
            if isinstance(arg, argparse._HelpAction) or arg.help == argparse.SUPPRESS:
                continue
            shown = arg.option_strings[0] if arg.option_strings else arg.dest
            assert f"`{shown}`" in section, f"{name}: {shown} missing from the CLI reference"
            if arg.help:
                assert reference.plain(arg.help.split("(")[0].strip())[:30] in section


@pytest.mark.parametrize("root", [CellSpec, Profile, RunMetrics])
def test_every_schema_field_is_in_its_reference_with_a_unit(root) -> None:
    page = reference.schema_page("t", "i", root)
    models = reference.models_of(root)
    assert len(models) >= (15 if root is CellSpec else 1)
    for model in models:
        section = page.split(f"\n## {model.__name__}\n", 1)[1].split("\n## ", 1)[0]
        for name, field in model.model_fields.items():
            row = next((line for line in section.splitlines()
                        if line.startswith(f"| `{name}` |")), None)
            assert row is not None, f"{model.__name__}.{name} missing from the reference"
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]]
            assert cells[3] and cells[4], f"{model.__name__}.{name}: no unit or no meaning"
            assert cells[3] == reference.field_unit(field)


def test_the_schema_reference_shows_types_defaults_and_units_as_declared() -> None:
    page = reference.schema_page("t", "i", CellSpec)
    pose = page.split("\n## PoseSpec\n", 1)[1].split("\n## ", 1)[0]
    assert re.search(r"\| `xyz` \| list\[float\] \| `\[0\.0, 0\.0, 0\.0\]` \| m \|", pose)
    assert re.search(r"\| `rpy` \| list\[float\] \| `\[0\.0, 0\.0, 0\.0\]` \| rad \|", pose)
    robot = page.split("\n## RobotSpec\n", 1)[1].split("\n## ", 1)[0]
    assert "[PoseSpec](#posespec)" in robot  # a field holding a model links to it


def _family(pattern: str) -> re.Pattern:
    """A COLUMN_DOCS name pattern as a regular expression: ``{a,b}`` either, ``{x}`` a name."""
    def part(match: re.Match) -> str:
        inner = match.group(1)
        return f"(?:{'|'.join(map(re.escape, inner.split(',')))})" if "," in inner else r"\w+"
    return re.compile(re.sub(r"\\\{([^}]*)\\\}", part, re.escape(pattern)))


def test_every_frames_csv_column_is_documented_once() -> None:
    header = columns(3, {"R7AX": 7, "UR5_B": 6})
    families = [_family(p) for p in COLUMN_DOCS]
    for column in header:
        matched = [p for p, f in zip(COLUMN_DOCS, families, strict=True) if f.fullmatch(column)]
        assert len(matched) == 1, f"{column}: documented by {matched}"
    used = {p for p, f in zip(COLUMN_DOCS, families, strict=True)
            if any(f.fullmatch(c) for c in header)}
    assert used == set(COLUMN_DOCS), f"documented, never written: {set(COLUMN_DOCS) - used}"
    for unit, text in COLUMN_DOCS.values():
        assert unit and len(text) > 10


def test_the_run_folder_reference_lists_every_file() -> None:
    assert RUN_FILES <= set(RUN_FILE_DOCS)
    page = reference.run_folder_page()
    for name in RUN_FILE_DOCS:
        assert f"`{name}`" in page
    for pattern in COLUMN_DOCS:
        assert f"`{pattern}`" in page


def test_the_api_pages_in_the_navigation_are_the_generated_ones() -> None:
    import ast

    source = (REPO / "docs" / "gen" / "pages.py").read_text()
    tree = ast.parse(source)
    api = next(n for n in tree.body if isinstance(n, ast.AnnAssign | ast.Assign)
               and "API" in ast.unparse(n.targets[0] if isinstance(n, ast.Assign) else n.target))
    modules = list(ast.literal_eval(api.value))
    nav = yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"]
    ref = next(e["Reference"] for e in nav if "Reference" in e)
    pages = next(e["Python API"] for e in ref if isinstance(e, dict) and "Python API" in e)
    listed = [next(iter(e.values())) for e in pages if isinstance(e, dict)]
    assert listed == [f"reference/api/{m}.md" for m in modules]
    for module in modules:
        __import__(module)


def _published(tmp_path: Path, rows: list[dict], commit: str = "0" * 40) -> Path:
    folder = tmp_path / results.DATA / "t"
    folder.mkdir(parents=True)
    with open(folder / "summary.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (folder / "summary.md").write_text("| a |\n|---|\n| 1 |\n")
    (folder / "meta.json").write_text(json.dumps({
        "title": "T", "description": "d", "headline": True, "command": "cellsight sweep",
        "version": "0.1.0", "commit": commit, "made": "2026-01-01"}))
    return tmp_path


def test_the_results_tables_are_the_summaries_spread_over_seeds(tmp_path) -> None:
    rng = np.random.default_rng(0)
    rmse = rng.uniform(0.5, 3.0, 20)
    rows = [{"cell": "dual-arm", "experiment": "3", "sensor": "rendered", "variant": "pred",
             "realism": "lab", "structure": "object-bvh", "seed": str(s),
             "status": "failed" if s == 19 else "done", "grasp_success": str(s != 3),
             "position_rmse_mm": repr(float(rmse[s])), "approach_position_rmse_mm": "1.0"}
            for s in range(20)]
    root = _published(tmp_path, rows)
    table = results.tables(root)[0]
    text = results.summary_table(table.rows)
    assert "All runs: cell `dual-arm`, realism `lab`" in text  # the same on every line
    line = next(x for x in text.splitlines() if x.startswith("| 20 (1)"))
    done = rmse[:19]
    expected = (f"{done.mean():.2f} ± {done.std(ddof=1):.2f} "
                f"({done.min():.2f}–{done.max():.2f})")
    assert "| 20 (1) | 18/19 |" in line and expected in line
    page = results.pages(root)["results/t.md"]
    assert "Age unknown" in page  # no repository there: the page says it cannot tell


def test_the_headline_shows_each_world_and_tracker_once_from_the_first_sweep() -> None:
    """Two headline sweeps that both ran the default tracker in `lab` (one of 4 seeds, one of
    2, beside a calibrated variant): the line is the first sweep's alone, not 6 runs merged."""
    def rows(variants: dict[str, int]) -> list[dict[str, str]]:
        return [{"cell": "dual-arm", "experiment": "3", "sensor": "rendered", "variant": v,
                 "realism": "lab", "structure": "object-bvh", "seed": str(s), "status": "done",
                 "grasp_success": "True", "position_rmse_mm": str(1.0 + s)}
                for v, n in variants.items() for s in range(n)]
    meta = {"headline": True}
    found = [results.Table("a", REPO, rows({"kinematic": 4}), {**meta, "order": 1}),
             results.Table("b", REPO, rows({"kinematic": 2, "calibrated": 2}),
                           {**meta, "order": 2})]
    lines = [x for x in results.headline(found).splitlines() if x.startswith("| `lab`")]
    assert [x.split(" | ")[1:3] for x in lines] == [["kinematic", "4"],
                                                    ["kinematic, calibrated cell", "2"]]


def test_a_table_older_than_the_code_says_so() -> None:
    first = subprocess.run(["git", "rev-list", "--max-parents=0", "HEAD"], cwd=REPO,
                           capture_output=True, text=True)
    if first.returncode:
        pytest.skip("not a git checkout")
    changed = results.code_changes_since(REPO, first.stdout.split()[0])
    assert changed and all(c.startswith("cellsight/") for c in changed)
    meta = {"command": "c", "version": "v", "commit": first.stdout.split()[0], "made": "d"}
    assert "Older than the code" in results.provenance(REPO, meta)


def test_the_benchmarks_page_shows_each_saved_bench_with_its_command(tmp_path: Path) -> None:
    """``bench/run_all.py --save`` output, as the docs' Benchmarks page shows it."""
    folder = tmp_path / results.BENCH
    assert "No benchmark has been saved" in results.bench_page(tmp_path)
    folder.mkdir(parents=True)
    (folder / "bench_x.txt").write_text("visible_mask 0.5 ms | Open3D 1.0 ms | ratio 0.50\n")
    (folder / "bench_x.json").write_text(json.dumps({
        "command": "python bench/run_all.py --only bench_x", "version": "0.1.0",
        "commit": "0" * 40, "made": "2026-11-29", "cores": 2, "machine": "x86_64, Linux",
        "busy": "nothing else"}))
    page = results.bench_page(tmp_path)
    assert "## `bench_x`" in page and "ratio 0.50" in page
    assert "`python bench/run_all.py --only bench_x`" in page and "On 2 cores" in page


def test_the_readme_tables_are_the_generated_ones() -> None:
    """The README's commands and headline figures are those of the code and the published
    sweeps (``scripts/publish_results.py readme`` writes them)."""
    script = _load_script()
    text = (REPO / "README.md").read_text()
    for begin, end, block in ((script.BEGIN, script.END, script.headline_block()),
                              (script.COMMANDS_BEGIN, script.COMMANDS_END,
                               script.commands_block())):
        start, stop = text.index(begin), text.index(end) + len(end)
        assert text[start:stop] == block, \
            "a README table is stale: run `.venv/bin/python scripts/publish_results.py readme`"


def _load_script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("publish_results",
                                                  REPO / "scripts" / "publish_results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

"""The sweeps behind the documentation's results pages (``docs/results/sweeps.yaml``).

``run [NAME ...]`` runs each sweep (``cellsight sweep --out out/NAME ARGS``, resumable; all of
them without names); ``publish [NAME ...]`` copies each finished sweep's ``summary.*`` into
``docs/results/data/NAME/`` with ``meta.json``: the title, the command, the cellsight version
and the git commit that made it, and the date. The pages themselves are generated from there
when the site is built (``docs/gen/results.py``); ``readme`` writes the README's headline table.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
SWEEPS = ROOT / "docs" / "results" / "sweeps.yaml"
DATA = ROOT / "docs" / "results" / "data"
README = ROOT / "README.md"
BEGIN, END = "<!-- headline:begin -->", "<!-- headline:end -->"
COMMANDS_BEGIN, COMMANDS_END = "<!-- commands:begin -->", "<!-- commands:end -->"
SUMMARY = ("summary.csv", "summary.md", "summary.png")


def sweeps() -> dict[str, dict]:
    """The sweeps by name, as ``docs/results/sweeps.yaml`` lists them."""
    return yaml.safe_load(SWEEPS.read_text())


def chosen(names: list[str]) -> dict[str, dict]:
    known = sweeps()
    unknown = [n for n in names if n not in known]
    if unknown:
        sys.exit(f"publish_results.py: no sweep {unknown} in {SWEEPS}; known: {', '.join(known)}")
    return {n: known[n] for n in names or known}


def command(name: str, sweep: dict, jobs: int | None = None) -> list[str]:
    """The ``cellsight sweep`` command line of a sweep."""
    words = ["cellsight", "sweep", "--out", f"out/{name}", *shlex.split(sweep["args"])]
    return words + (["--jobs", str(jobs)] if jobs else [])


def run(names: list[str], jobs: int) -> int:
    for name, sweep in chosen(names).items():
        words = command(name, sweep, jobs)
        print("$", shlex.join(words), flush=True)
        status = subprocess.call([str(ROOT / ".venv" / "bin" / words[0]), *words[1:]], cwd=ROOT)
        if status:
            return status
    return 0


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()


def publish(names: list[str], ran_at: str | None = None) -> int:
    """Copy the sweeps' summaries into the docs; ``ran_at``: the commit the sweeps ran at,
    when the code has been committed to since they started (default: HEAD)."""
    from cellsight import __version__

    commit = _git("rev-parse", ran_at or "HEAD")
    if ran_at is None and _git("status", "--porcelain", "--", "cellsight"):
        print("publish_results.py: cellsight/ has uncommitted changes; the tables will name "
              "the last commit, which is not the code that ran", file=sys.stderr)
    for name, sweep in chosen(names).items():
        source = ROOT / "out" / name
        if not (source / "summary.csv").is_file():
            print(f"publish_results.py: {source}: no summary.csv (run it first: "
                  f"publish_results.py run {name})", file=sys.stderr)
            if names:
                return 1
            continue
        target = DATA / name
        target.mkdir(parents=True, exist_ok=True)
        for file in SUMMARY:
            if (source / file).is_file():
                shutil.copyfile(source / file, target / file)
        meta = {"title": sweep["title"], "description": sweep.get("description", ""),
                "headline": bool(sweep.get("headline")), "order": sweep.get("order", 99),
                "command": shlex.join(command(name, sweep)), "version": __version__,
                "commit": commit, "made": datetime.date.today().isoformat()}
        (target / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
        print(f"published {name}: {target}")
    return readme()


def _generators():
    """``docs/gen``'s reference and results modules."""
    sys.path.insert(0, str(ROOT / "docs" / "gen"))
    import reference
    import results

    return reference, results


def commands_block() -> str:
    """The README's table of the commands, between its markers, from the argument parsers."""
    from cellsight.cli import build_parser

    reference, _ = _generators()
    return f"{COMMANDS_BEGIN}\n{reference.commands_table(build_parser())}{COMMANDS_END}"


def headline_block() -> str:
    """The README's headline table, between its markers, from the published sweeps."""
    _, pages = _generators()

    found = pages.tables(ROOT)
    made = sorted({t.meta["made"] for t in found if t.meta.get("headline")})
    note = (f"Experiment 3 (the part on the conveyor, the other arm crossing the views), "
            f"rendered images, mean ± sd (range) over the seeds (one run each), per tracker "
            f"(kinematic: the default; plain: the paper's; calibrated cell: the default on the "
            f"cell calibrated by `cellsight calibrate` in each seed's world); "
            f"made by `make experiments` ({', '.join(made) or 'not yet'}). "
            "Every table is on the docs' Results pages (`make docs`).")
    return f"{BEGIN}\n{pages.headline(found)}\n{note}\n{END}"


def readme() -> int:
    """Write the README's generated blocks (the commands, the headline figures)."""
    text = README.read_text()
    for begin, end, block in ((BEGIN, END, headline_block()),
                              (COMMANDS_BEGIN, COMMANDS_END, commands_block())):
        start, stop = text.index(begin), text.index(end) + len(end)
        text = text[:start] + block + text[stop:]
    README.write_text(text)
    print(f"wrote the commands and the headline table into {README}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    run_parser = sub.add_parser("run", help="run the sweeps (resumable)")
    run_parser.add_argument("names", nargs="*")
    run_parser.add_argument("--jobs", type=int, default=2)
    publish_parser = sub.add_parser("publish", help="copy finished sweeps' summaries into the docs")
    publish_parser.add_argument("names", nargs="*")
    publish_parser.add_argument("--ran-at", metavar="COMMIT",
                                help="the commit the sweeps ran at (default HEAD)")
    sub.add_parser("readme", help="write the README's commands and headline tables")
    args = parser.parse_args()
    if args.what == "run":
        return run(args.names, args.jobs)
    if args.what == "publish":
        return publish(args.names, args.ran_at)
    return readme()


if __name__ == "__main__":
    sys.exit(main())

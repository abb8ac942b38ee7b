"""``cellsight realism [PROFILE] [--seed N] [--cell FILE]``: a realism profile's knobs (each
group's meaning, every knob's setting against its ``exact`` default), and with ``--seed`` what
that seed draws on a cell (what ``metrics.json`` records as ``draws``)."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight realism`` to the command line's subcommands."""
    p = sub.add_parser("realism", help="a realism profile's knobs, and what a seed draws")
    p.add_argument("profile", nargs="?", default="lab",
                   help="exact, lab (default), harsh, or a YAML file (FILE or FILE:NAME)")
    p.add_argument("--seed", type=int, help="also print what this seed draws on the cell")
    p.add_argument("--cell", help="cell for --seed (default: the built-in dual-arm cell)")
    p.set_defaults(func=cmd_realism)


def _setting(value: object) -> str:
    if hasattr(value, "dist"):
        if value.dist == "normal":
            return f"normal, sigma {value.sigma:g}" + (f", mean {value.mean:g}" if value.mean
                                                       else "")
        if value.dist == "uniform":
            return f"uniform [{value.low:g}, {value.high:g}]"
        return f"{value.value:g}"
    if isinstance(value, bool):  # as the YAML file writes it
        return "true" if value else "false"
    return f"{value:g}" if isinstance(value, float | int) else str(value)


def cmd_realism(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cellsight.errors import CellsightError
    from cellsight.realism import draw_world, load_profile
    from cellsight.realism.profile import Profile

    if args.seed is not None and args.seed < 0:
        raise CellsightError(f"--seed: expected a whole number >= 0, got {args.seed}")
    profile = load_profile(args.profile)
    exact = Profile()
    console = Console()
    console.print(f"[bold]{profile.name}[/bold] ({profile.file}): {profile.description}")
    for group in Profile.model_fields:
        knobs = getattr(profile, group)
        if not hasattr(type(knobs), "model_fields"):
            continue
        table = Table(title=f"{group}: {' '.join(type(knobs).__doc__.split())}",
                      title_justify="left")
        for col in ("knob (unit in the name)", "setting", "exact (default)"):
            table.add_column(col)
        for name in type(knobs).model_fields:
            table.add_row(name, _setting(getattr(knobs, name)),
                          _setting(getattr(getattr(exact, group), name)))
        console.print(table)
    for source in profile.sources:
        console.print(f"source: {source}")
    if args.seed is not None:
        from cellsight.model.loader import load_cell

        draws = draw_world(profile, load_cell(args.cell), args.seed)
        print(json.dumps(draws.record, indent=1))
    return 0

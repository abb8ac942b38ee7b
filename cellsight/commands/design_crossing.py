"""``cellsight design-crossing --block CAM T0-T1 ...``: experiment 3's crossing designed for the
given blind spans (:mod:`cellsight.experiments.crossing_design`), printed as the cell file's
``crossing:`` section with what it blinds and its clearance."""

from __future__ import annotations

import argparse
import re

from cellsight.commands.text import CELL_HELP


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight design-crossing`` to the sub-commands."""
    design = sub.add_parser("design-crossing",
                            help="design experiment 3's crossing: blind each camera over a span")
    design.add_argument("--cell", help=CELL_HELP)
    design.add_argument("--block", nargs=2, action="append", required=True,
                        metavar=("CAMERA", "T0-T1"),
                        help="a camera to blind and when (s), e.g. --block cam2 8.5-15")
    design.add_argument("--path", metavar="RUN_DIR",
                        help="a run of experiment 2 giving the part's path and the grasping "
                             "robot's joints (default: one is run, ideal sensor)")
    design.add_argument("--clearance-cm", type=float, default=10.0,
                        help="least distance to the other robots and the part (10)")
    design.set_defaults(func=cmd_design_crossing)


def cmd_design_crossing(args: argparse.Namespace) -> int:
    import tempfile
    from pathlib import Path

    from cellsight.errors import CellsightError
    from cellsight.experiments.crossing_design import design_crossing
    from cellsight.experiments.task_path import TaskPath
    from cellsight.model.loader import load_cell

    cell = load_cell(args.cell)
    blocks = sorted((_block(cell, cam, span) for cam, span in args.block), key=lambda b: b.t0)
    if not args.clearance_cm >= 0:
        raise CellsightError(f"--clearance-cm: expected a number >= 0, got {args.clearance_cm}")
    with tempfile.TemporaryDirectory() as tmp:
        path = TaskPath.of_task(args.cell, args.path, Path(tmp), "design-crossing")
    for block in blocks:
        path.check_span(block.t0, block.t1, f"--block {block.camera}")
    design = design_crossing(cell, blocks, path, clearance_m=args.clearance_cm / 100)
    robot = cell.experiments.crossing_robot or next(r.name for r in cell.robots
                                                    if r.name != cell.experiments.robot)
    for block, left, of in zip(blocks, design.left, design.of, strict=True):
        print(f"{block.camera} {block.t0:g}-{block.t1:g} s: at most {left} of {of} features "
              f"visible")
    print(f"blinded elsewhere (outside the blocks, 1 s margin): {design.elsewhere_s:.1f} s "
          f"({design.elsewhere_text()})")
    print(f"clearance: {design.clearance_m * 100:.1f} cm (closest: {design.closest[0]} at "
          f"{design.closest[1]:.1f} s); palm {design.fraction:g} of the way to the camera")
    print(design.yaml(robot))
    return 0 if design.clearance_m * 100 >= args.clearance_cm else 1


def _block(cell, camera: str, span: str):
    from cellsight.errors import CellsightError
    from cellsight.experiments.crossing_design import Block

    names = [c.name for c in cell.cameras]
    if camera not in names:
        raise CellsightError(f"--block: camera {camera!r} is not in the cell ({names})")
    match = re.fullmatch(r"\s*([0-9.]+)\s*-\s*([0-9.]+)\s*", span)
    if match is None or not 0 < float(match[1]) < float(match[2]):
        raise CellsightError(f"--block {camera}: expected a span T0-T1 in seconds with "
                             f"0 < T0 < T1, got {span!r}")
    return Block(camera, float(match[1]), float(match[2]))

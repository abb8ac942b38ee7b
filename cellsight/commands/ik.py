"""``cellsight ik``: the joints that put a robot's tool centre point at a pose, or that hold a
workpiece at a pose (by its grasp), for every configuration branch
(:mod:`cellsight.control.ik`), each with its margin to every joint limit, its distance to a
singularity and, for a held part, what each camera sees of it there."""

from __future__ import annotations

import argparse
import json

import numpy as np

from cellsight.commands.text import CELL_HELP

MAX_SEEDS = 1000  # random starts of `ik` at most: about 30 s


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cellsight ik`` to the sub-commands."""
    ik = sub.add_parser("ik", help="inverse kinematics: every branch that reaches a TCP pose "
                                   "or holds a part at a pose, with its margins")
    ik.add_argument("--cell", help=CELL_HELP)
    ik.add_argument("--robot", help="the robot (default: the cell's first robot with a tool)")
    pose = ik.add_mutually_exclusive_group(required=True)
    pose.add_argument("--tcp-pose", help='the TCP pose, base frame: JSON (or a JSON file) '
                                         '{"xyz": [..], "rpy": [..]} (m, rad) or a 4x4')
    pose.add_argument("--part-pose", help='a part held at a pose by its grasp: JSON '
                                          '{"part": {"xyz": [..], "rpy": [..]}}')
    ik.add_argument("--seeds", type=int, default=48,
                    help=f"random starts besides HOME, FINAL and mid-range (48; at most "
                         f"{MAX_SEEDS}: about 30 ms each)")
    ik.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ik.set_defaults(func=cmd_ik)


def cmd_ik(args: argparse.Namespace) -> int:
    from cellsight.control.ik import solve_ik
    from cellsight.errors import CellsightError
    from cellsight.model.arguments import parse_part_poses, parse_tcp_pose
    from cellsight.model.loader import load_cell

    if not 0 <= args.seeds <= MAX_SEEDS:
        raise CellsightError(f"--seeds: expected a whole number from 0 to {MAX_SEEDS} (about "
                             f"30 ms each), got {args.seeds}")
    cell = load_cell(args.cell)
    robot = _robot(cell, args.robot)
    part = None
    if args.part_pose is not None:
        poses = parse_part_poses(args.part_pose)
        if len(poses) != 1:
            raise CellsightError(f"--part-pose: expected one workpiece, got {sorted(poses)}")
        (name, T_part), = poses.items()
        part = (cell.workpiece(name), T_part)
        T_tcp = T_part @ _grasp(cell.workpiece(name), robot)
    else:
        T_tcp = parse_tcp_pose(args.tcp_pose)
    result = solve_ik(robot, T_tcp, seeds=args.seeds)
    views = [_views(cell, robot, s.q, part) for s in result.solutions]
    rows = [_row(robot, s, v) for s, v in zip(result.solutions, views, strict=True)]
    if args.json:
        print(json.dumps({"robot": robot.name, "solutions": rows,
                          "unreached": result.unreached}, indent=2))
        return 0
    _print(robot.name, rows, result.unreached, [c.name for c in cell.cameras] if part else [])
    return 0


def _robot(cell, name: str | None):
    from cellsight.errors import CellsightError

    if name is not None:
        return cell.robot(name)
    with_tool = [r for r in cell.robots if r.tool is not None]
    if not with_tool:
        raise CellsightError("--robot: the cell has no robot with a tool; name one")
    return with_tool[0]


def _grasp(workpiece, robot) -> np.ndarray:
    """``T_part_tcp`` of the robot holding the part: the cell file's grasp, else the world's
    default top-down grasp."""
    from cellsight.errors import CellsightError
    from cellsight.model.grasp import grasp_pose

    if robot.tool is None and workpiece.T_part_grasp is None:
        raise CellsightError(f"--part-pose: robot {robot.name!r} has no tool to hold "
                             f"{workpiece.name!r}")
    return grasp_pose(workpiece, robot.tool)


def _views(cell, robot, q, part) -> list[dict]:
    """Per camera: the held part's features inside the image, the smallest margin to the
    image's border (px, negative: outside) and the features visible (the predictor, the other
    robots at HOME, the jaws closed on the part); none without a part."""
    if part is None:
        return []
    from cellsight.camera import border_distance
    from cellsight.occlusion.backends import visibility_predictor

    workpiece, T = part
    views = visibility_predictor(cell).predict({robot.name: q}, {workpiece.name: T},
                                              {robot.name: 0.0})[workpiece.name]
    out = []
    for cam, view in zip(cell.cameras, views, strict=True):
        margin = border_distance(cam, cam.project(workpiece.feature_points @ T[:3, :3].T
                                                  + T[:3, 3]))
        out.append({"camera": cam.name, "inside": int((margin >= 0).sum()),
                    "margin_px": round(float(margin.min()), 1), "visible": int(view.count)})
    return out


def _row(robot, s, views: list[dict]) -> dict:
    revolute = ~robot.chain.prismatic
    shown = np.where(revolute, np.degrees(s.q), s.q)
    margin = np.where(revolute, np.degrees(s.limit_margin), s.limit_margin)
    worst = int(np.argmin(margin / np.ptp(np.where(revolute[:, None], np.degrees(
        robot.chain.qlim), robot.chain.qlim), axis=1)))
    return {"branch": s.branch, "q": [round(float(x), 4) for x in s.q],
            "q_shown": [round(float(x), 2) for x in shown],
            "position_error_m": s.position_error_m, "rotation_error_rad": s.rotation_error_rad,
            "limit_margin": [round(float(x), 6) for x in s.limit_margin],
            "tightest_joint": worst + 1,
            "tightest_margin": f"{margin[worst]:.1f}{' deg' if revolute[worst] else ' m'}",
            "sigma_min": round(s.sigma_min, 4), "cameras": views}


def _print(robot: str, rows: list[dict], unreached: list[dict], cameras: list[str]) -> None:
    from rich.console import Console
    from rich.table import Table

    seeded = any("seed" in r["branch"] for r in rows)  # no branch flags: named by their start
    what = "solution(s) found from these starts" if seeded else "branch(es)"
    table = Table(title=f"{robot}: {len(rows)} {what} reach the pose (joints: deg, "
                        f"prismatic m)")
    for col in ("start" if seeded else "branch", "joints", "tightest limit", "sigma min", *cameras):
        table.add_column(col)
    for r in rows:
        cams = [f"{v['visible']} visible, {v['inside']} inside, margin {v['margin_px']:g} px"
                for v in r["cameras"]]
        table.add_row(r["branch"]["seed"] if seeded else
                      ", ".join(f"{k} {v}" for k, v in r["branch"].items()),
                      " ".join(f"{x:g}" for x in r["q_shown"]),
                      f"joint {r['tightest_joint']}: {r['tightest_margin']}",
                      f"{r['sigma_min']:g}", *cams)
    for b in unreached:
        table.add_row(", ".join(f"{k} {v}" for k, v in b.items()), "[red]not reached[/red]",
                      "", "", *[""] * len(cameras))
    Console(width=200).print(table)

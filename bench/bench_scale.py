"""Occlusion prediction at scale (issue 12): cells of growing size, real UR5 collision meshes,
cellsight against Open3D and MuJoCo on the same rays.

Cells: :func:`cellsight.occlusion.scale_cells.scale_cell` (UR5 arms around a table, 16-point
parts on it, cameras on a ring), swept one count at a time around the issue's target cell of
6 cameras, 4 arms and 3 parts: cameras 2, 4, 6, 8; arms 2, 3, 4, 5, 6; parts 1, 2, 3, 4.
``FRAMES`` random configurations each (``random_snapshots``: arms anywhere in their limits,
parts near their places or held in a gripper). Every method starts from the same snapshot
(object poses) and answers, for every feature of every part in every camera, whether it is
seen (the methods of ``bench_ur_cell.py``):

- cellsight ``object-bvh`` (default: static per-object hierarchies, queries moved) and
  ``frame-bsp`` (the paper's: exact cull, one BSP per frame), features only (``near_px=0``),
  0.1 mm surface tolerance like the peers'; ``object-bvh`` again with the tracker's
  near-occluder ring (16 more points per feature: 8 in front, 8 behind);
- Open3D ``RaycastingScene`` rebuilt per frame from the moved triangles;
- MuJoCo ``mj_multiRay`` on the world's model (mocap/joint bodies carrying the same meshes,
  pre-built per-mesh BVHs), ``mj_kinematics`` then one call per camera.

Times: ms per frame (all cameras), median and 99th percentile, best of ``REPEATS`` per
configuration. The growth exponent of a method in a count is the slope of log(median time)
against log(count) over its sweep (least squares); triangles grow with the arms. Writes
``out/bench/scale.json`` and the log-log plot ``out/bench/scale.png``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from bench_ur_cell import (
    PEER_TOLERANCE,
    cellsight_fn,
    compared,
    in_view,
    mujoco_fn,
    open3d_fn,
    timed,
)

from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.scale_cells import scale_cell
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.visibility import FRAME_BSP

FRAMES = 100
TARGET = (6, 4, 3)  # cameras, arms, parts
SWEEPS = {"cameras": [2, 4, 6, 8], "arms": [2, 3, 4, 5, 6], "parts": [1, 2, 3, 4]}
METHODS = ["cellsight object-bvh", "cellsight frame-bsp", "cellsight object-bvh + ring",
           "Open3D (rebuilt)", "MuJoCo mj_multiRay"]
OUT = Path("out/bench")


def configurations() -> list[tuple[int, int, int]]:
    """Every (cameras, arms, parts) of the sweeps, the target once."""
    out = []
    for axis, values in SWEEPS.items():
        for v in values:
            size = list(TARGET)
            size[list(SWEEPS).index(axis)] = v
            if tuple(size) not in out:
                out.append(tuple(size))
    return out


def measure(size: tuple[int, int, int], frames: int = FRAMES) -> dict:
    """One cell's row: its size, triangles, rays, and per method median / p99 ms and
    disagreements with cellsight's answers (features in the image)."""
    cell = scale_cell(*size)
    snapshots = random_snapshots(cell, frames, seed=7)
    same = {"surface_tolerance": PEER_TOLERANCE}
    base = visibility_predictor(cell, near_px=0.0, **same)
    fns = {
        "cellsight object-bvh": cellsight_fn(base),
        "cellsight frame-bsp": cellsight_fn(visibility_predictor(cell, near_px=0.0,
                                                                structure=FRAME_BSP, **same)),
        "cellsight object-bvh + ring": cellsight_fn(visibility_predictor(cell, **same)),
        "Open3D (rebuilt)": open3d_fn(base),
        "MuJoCo mj_multiRay": mujoco_fn(base),
    }
    results = timed(fns, snapshots)
    masks = in_view(base, snapshots)
    return {"cameras": size[0], "arms": size[1], "parts": size[2],
            "triangles": int(sum(len(f) - 2 for o in cell.objects for f in o.solid.faces)),
            "rays": int(np.mean([m.sum() for m in masks])),
            **compared(results, "cellsight object-bvh", masks)}


def exponents(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Per method, the fitted growth exponent of the median time in cameras, arms, parts and
    triangles (over the arms sweep)."""
    out = {}
    for method in METHODS:
        fits = {}
        for axis, values in SWEEPS.items():
            sweep = [r for r in rows if all(r[a] == TARGET[i] or a == axis
                                             for i, a in enumerate(SWEEPS))]
            sweep = [r for r in sweep if r[axis] in values]
            x = np.log([r[axis] for r in sweep])
            y = np.log([r[method]["median"] for r in sweep])
            fits[axis] = float(np.polyfit(x, y, 1)[0])
            if axis == "arms":
                tx = np.log([r["triangles"] for r in sweep])
                fits["triangles"] = float(np.polyfit(tx, y, 1)[0])
        out[method] = fits
    return out


def plot(rows: list[dict], path: Path) -> None:
    """Log-log plot: median ms per frame against cameras, arms (triangles) and parts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), sharey=True)
    for ax, axis in zip(axes, SWEEPS, strict=True):
        sweep = sorted((r for r in rows if all(r[a] == TARGET[i] or a == axis
                                               for i, a in enumerate(SWEEPS))),
                       key=lambda r: r[axis])
        x = [r[axis] for r in sweep]
        for method in METHODS:
            ax.loglog(x, [r[method]["median"] for r in sweep], "o-", label=method)
        ax.set_xticks(x, [str(v) if axis != "arms" else f"{v}\n{r['triangles'] // 1000}k tri"
                          for v, r in zip(x, sweep, strict=True)])
        ax.minorticks_off()
        others = ", ".join(f"{a} {TARGET[i]}" for i, a in enumerate(SWEEPS) if a != axis)
        ax.set_xlabel(f"{axis} ({others})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("median ms per frame (all cameras)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Occlusion prediction per frame, UR5 cells (real collision meshes), "
                 f"{FRAMES} random frames each")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(frames: int = FRAMES) -> None:
    """Measure every configuration (progress bar), print the tables, write json and plot."""
    from rich.console import Console
    from rich.progress import track
    from rich.table import Table

    rows = [measure(size, frames) for size in track(configurations(), description="cells")]
    console = Console(width=160)
    table = Table(title=f"Occlusion per frame at scale: median / p99 ms ({frames} random "
                        f"frames, best of 3); disagreements with cellsight object-bvh")
    for col in ("cams", "arms", "parts", "triangles", "rays", *METHODS, "bvh / MuJoCo"):
        table.add_column(col, justify="right")
    for r in rows:
        cells = [f"{r[m]['median']:.3f} / {r[m]['p99']:.3f}"
                 + (f" ({r[m]['disagree']})" if r[m]["disagree"] else "") for m in METHODS]
        ratio = r["cellsight object-bvh"]["median"] / r["MuJoCo mj_multiRay"]["median"]
        table.add_row(str(r["cameras"]), str(r["arms"]), str(r["parts"]),
                      f"{r['triangles']:,}", str(r["rays"]), *cells, f"{ratio:.2f}")
    console.print(table)
    fits = exponents(rows)
    growth = Table(title="Growth exponent of the median time (slope in log-log)")
    for col in ("method", *SWEEPS, "triangles"):
        growth.add_column(col, justify="left" if col == "method" else "right")
    for method, f in fits.items():
        growth.add_row(method, *(f"{f[a]:.2f}" for a in (*SWEEPS, "triangles")))
    console.print(growth)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "scale.json").write_text(json.dumps({"rows": rows, "exponents": fits}, indent=1))
    plot(rows, OUT / "scale.png")
    console.print(f"wrote {OUT / 'scale.json'} and {OUT / 'scale.png'}")


if __name__ == "__main__":
    import sys

    main(int(sys.argv[1]) if len(sys.argv) > 1 else FRAMES)

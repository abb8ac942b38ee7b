"""The placement's report: figures of a set of cameras over the task (exact visibility with
the cell's predictor, the tracker's selection quality), plots and ``report.md``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cellsight.control import Phase  # noqa: E402
from cellsight.model.cell import Cell  # noqa: E402
from cellsight.occlusion.backends import visibility_predictor
from cellsight.placement.candidates import work_area  # noqa: E402
from cellsight.placement.choose import MIN_POINTS, Placement  # noqa: E402
from cellsight.placement.scoring import CandidateScores  # noqa: E402
from cellsight.placement.task import TaskFrames  # noqa: E402
from cellsight.runfolder.writes import write_figure, write_file  # noqa: E402
from cellsight.tracking.selection import camera_resolution, select_features  # noqa: E402


@dataclass(frozen=True)
class SetFigures:
    """A camera set over the task, from the cell's own predictor: ``points`` (N,) features
    predicted visible (over the cameras), ``quality`` (N,) the tracker's selection quality
    ``J`` in [0, 1] (0 where nothing can be selected), and from the scoring ``sigma_mm`` (N,)
    and ``loss``."""

    name: str
    points: np.ndarray
    quality: np.ndarray
    sigma_mm: np.ndarray
    loss: float


def set_figures(name: str, cell: Cell, task: TaskFrames, placement: Placement) -> SetFigures:
    """The figures of the cell's cameras (:class:`SetFigures`); ``placement``: their scores."""
    predictor = visibility_predictor(cell)
    points, quality = np.zeros(task.n, dtype=int), np.zeros(task.n)
    for k in range(task.n):
        views = predictor.predict(*task.state(k))[task.part]
        visible = np.stack([v.visible for v in views])
        pixels = np.stack([v.pixels for v in views])
        rho = camera_resolution(cell.cameras, task.part_poses[k][:3, 3])
        points[k] = visible.sum()
        if visible.any():
            quality[k] = max(select_features(np.nan_to_num(pixels), visible, rho).quality, 0.0)
    return SetFigures(name, points, quality, placement.sigma_mm, placement.loss)


def _phase_rows(task: TaskFrames, sets: list[SetFigures]) -> list[str]:
    phases = [str(p) for p in Phase.working()]
    lines = ["| phase | frames | " + " | ".join(f"{s.name}: sigma mm / points / J"
                                                for s in sets) + " |",
             "|---|---|" + "---|" * len(sets)]
    for phase in phases:
        rows = task.phase == phase
        if rows.any():
            lines.append(f"| {phase} | {rows.sum()} | " + " | ".join(
                f"{s.sigma_mm[rows].mean():.3f} / {s.points[rows].mean():.1f} / "
                f"{s.quality[rows].mean():.2f}" for s in sets) + " |")
    return lines


def summary_rows(sets: list[SetFigures]) -> list[str]:
    """The whole-task table (Markdown lines)."""
    lines = ["| cameras | loss | mean sigma mm | p95 sigma mm | max sigma mm | mean points | "
             f"frames < {MIN_POINTS} points | mean J | min J |", "|---|" + "---|" * 8]
    for s in sets:
        lines.append(f"| {s.name} | {s.loss:.3f} | {s.sigma_mm.mean():.3f} | "
                     f"{np.percentile(s.sigma_mm, 95):.3f} | {s.sigma_mm.max():.3f} | "
                     f"{s.points.mean():.1f} | {int((s.points < MIN_POINTS).sum())} | "
                     f"{s.quality.mean():.3f} | {s.quality.min():.3f} |")
    return lines


def plot_task(path: Path, task: TaskFrames, sets: list[SetFigures]) -> None:
    """Per frame: predicted position error, features seen and selection quality per set."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for s, colour in zip(sets, ("#636363", "#d62728", "#1f77b4"), strict=False):
        axes[0].semilogy(task.t, s.sigma_mm, color=colour, lw=1, label=s.name)
        axes[1].plot(task.t, s.points, color=colour, lw=1)
        axes[2].plot(task.t, s.quality, color=colour, lw=1)
    axes[1].axhline(MIN_POINTS, color="k", lw=0.6, ls="--")
    for ax, label in zip(axes, ("predicted position\nerror (mm)", "features seen\n(all cameras)",
                                "selection\nquality J"), strict=True):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for phase in np.unique(task.phase):
        rows = np.flatnonzero(task.phase == phase)
        axes[0].annotate(phase, (task.t[rows[0]], 1.0), xycoords=("data", "axes fraction"),
                         va="bottom", fontsize=7)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[2].set_xlabel("t (s)")
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)


def plot_candidates(path: Path, task: TaskFrames, scores: CandidateScores,
                    single_loss: np.ndarray, chosen: Placement, builtin: list) -> None:
    """Top and side view of the candidates coloured by their loss alone, the chosen ones and
    the cell's own cameras, around the work area."""
    centres = np.array([c.center for c in scores.cameras])
    lo, hi = work_area(task)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, (i, j), name in ((axes[0], (0, 1), "top view (x, y)"),
                             (axes[1], (0, 2), "side view (x, z)")):
        sc = ax.scatter(centres[:, i], centres[:, j], c=single_loss, cmap="viridis_r", s=14,
                        norm=matplotlib.colors.LogNorm())
        ax.add_patch(plt.Rectangle((lo[i], lo[j]), hi[i] - lo[i], max(hi[j] - lo[j], 0.01),
                                   fill=False, color="k", lw=1))
        own = np.array([c.center for c in builtin])
        ax.plot(own[:, i], own[:, j], "ks", ms=8, label="cell's cameras")
        pick = centres[list(chosen.chosen)]
        ax.plot(pick[:, i], pick[:, j], "r*", ms=16, label="chosen")
        ax.set_title(name)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=axes, label="loss of the candidate alone")
    axes[0].legend(loc="lower left", fontsize=8)
    write_figure(path, fig, dpi=110)
    plt.close(fig)


def write_report(out: Path, header: list[str], task: TaskFrames, sets: list[SetFigures],
                 verification: list[str]) -> Path:
    """``report.md``: the header lines, the whole-task and per-phase tables, the figures and
    the verification runs' table (when there is one)."""
    lines = [*header, "", "## Over the whole task (every frame)", "", *summary_rows(sets), "",
             "## Per phase (means)", "", *_phase_rows(task, sets), "",
             "![task](fig_task.png)", "", "![candidates](fig_candidates.png)", ""]
    if verification:
        lines += ["## Experiment runs with each set of cameras", "", *verification, ""]
    path = Path(out) / "report.md"
    write_file(path, "\n".join(lines))
    return path

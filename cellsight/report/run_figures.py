"""A run's figures (for :mod:`.run_report`): its log read for plotting (:class:`Run`), the
trajectory, each camera's visibility, the error, the health, the visibility's agreement with
the truth and the stage timing, each a PNG in the run folder."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from cellsight.geometry.transforms import pose_errors
from cellsight.rates import VISION_HZ
from cellsight.runfolder.framelog import FrameLog, camera_column, timing_column
from cellsight.runfolder.metrics import read_metrics
from cellsight.runfolder.writes import write_figure
from cellsight.tracking.timing import STAGES

PHASE_COLOURS = {
    "waiting": "#bab0ac", "approach": "#4e79a7", "grasp": "#f28e2b", "manipulate": "#59a14f",
    "release": "#b07aa1", "done": "#76b7b2", "failed": "#e15759",
}
VISIBLE_COLOUR = "#2e7d32"
SELECTED_COLOUR = "#4e79a7"
MEASURED_COLOUR = "#1b2f4a"
FIXED_OCCLUDER_COLOURS = {"self": "#9e9e9e", "behind": "#5d6d7e", "outside": "#d7ccc8"}
OBJECT_PALETTE = ("#e15759", "#f28e2b", "#b07aa1", "#edc948", "#9c755f", "#ff9da7",
                  "#76b7b2", "#8c564b", "#bcbd22", "#17becf")
DEFAULT_FRAME_PERIOD = 1.0 / VISION_HZ  # s, used when a run has a single frame
STATUS_SHADES = {"degraded": "#d62728", "coasting": "#bdbdbd", "predicting": "#bdbdbd",
                 "lost": "#636363"}  # the statuses drawn behind the health figure


@dataclass
class Run:
    """A loaded run directory."""

    dir: Path
    frames: FrameLog
    metrics: dict
    cameras: list[str]
    n_features: int

    @cached_property
    def t(self) -> np.ndarray:
        """(N,) frame times, s."""
        return self.frames.floats("t")

    @cached_property
    def edges(self) -> np.ndarray:
        """(N + 1,) frame boundaries, s: frame k covers ``[edges[k], edges[k + 1])``."""
        t = self.t
        dt = float(np.median(np.diff(t))) if len(t) > 1 else DEFAULT_FRAME_PERIOD
        return np.append(t, t[-1] + dt) if len(t) else t


def report_inputs(run_dir: Path, metrics: dict | None = None) -> Run:
    """Read ``frames.csv`` and ``metrics.json`` (either may be absent in a partial run);
    ``metrics``: the run's metrics as they will be written (the run writes its
    ``metrics.json`` last), instead of the file."""
    run_dir = Path(run_dir)
    frames = FrameLog.read(run_dir / "frames.csv")
    if metrics is None:
        metrics = read_metrics(run_dir, missing_ok=True)
    cameras = list(metrics.get("cameras") or
                   [f"cam{c}" for c in range(1, frames.n_cameras + 1)])
    n_features = metrics.get("features") or frames.n_features
    return Run(run_dir, frames, metrics, cameras, int(n_features))


def runs_of(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop indices (stop exclusive) of the runs of True in a (N,) bool mask."""
    d = np.diff(np.concatenate([[0], np.asarray(mask, dtype=np.int8), [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def spans(mask: np.ndarray, edges: np.ndarray) -> list[tuple[float, float]]:
    """``(start, width)`` in s of every run of True frames, for ``broken_barh``."""
    starts, stops = runs_of(mask)
    return [(edges[a], edges[b] - edges[a]) for a, b in zip(starts, stops, strict=True)]


def phase_spans(run: Run) -> list[tuple[str, float, float]]:
    """``(phase, t_start, t_end)`` for each run of equal ``phase`` values, in s."""
    phases, edges = run.frames.text("phase"), run.edges
    out: list[tuple[str, float, float]] = []
    for k, p in enumerate(phases):
        if out and out[-1][0] == p:
            out[-1] = (p, out[-1][1], edges[k + 1])
        else:
            out.append((p, edges[k], edges[k + 1]))
    return out


def _time_axis(ax, run: Run) -> None:
    """Phases as light vertical bands behind the data; x limits the run's time span (s)."""
    for p, t0, t1 in phase_spans(run):
        ax.axvspan(t0, t1, color=PHASE_COLOURS.get(p, "#dddddd"), alpha=0.15, lw=0, zorder=0)
    if len(run.edges):
        ax.set_xlim(run.edges[0], run.edges[-1])


def _phase_legend(fig: Figure, run: Run) -> None:
    """One legend entry per phase present, along the top of the figure."""
    names = list(dict.fromkeys(p for p, _, _ in phase_spans(run)))
    handles = [Patch(color=PHASE_COLOURS.get(p, "#dddddd"), alpha=0.35, label=p or "?")
               for p in names]
    if handles:
        fig.legend(handles=handles, loc="upper center", ncol=len(handles), frameon=False,
                   fontsize=8, title="phase", title_fontsize=8)


def _figure(width: float, height: float) -> Figure:
    """A matplotlib figure rendered by Agg (no pyplot global state)."""
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    """Save a figure as PNG (100 dpi), leaving room for the phase legend on top; written
    whole or not at all (:func:`~cellsight.runfolder.writes.write_figure`)."""
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return write_figure(path, fig, dpi=100)


def _use_log(ax, *series: np.ndarray) -> None:
    """Log y axis when the finite data are all positive and exist."""
    data = np.concatenate([s[np.isfinite(s)] for s in series])
    if data.size and (data > 0).all():
        ax.set_yscale("log")


def position_error_mm(run: Run, prefix: str) -> np.ndarray:
    """(N,) distance between ``{prefix}_xyz`` and the true part position, mm (NaN if none)."""
    return 1000.0 * pose_errors(run.frames.poses(prefix), run.frames.poses("true"))[0]


def orientation_error_deg(run: Run, prefix: str) -> np.ndarray:
    """(N,) angle of ``R_true^T R_{prefix}``, deg (NaN where the estimate is missing)."""
    return np.degrees(pose_errors(run.frames.poses(prefix), run.frames.poses("true"))[1])


def occluder_colours(run: Run) -> dict[str, str]:
    """Colour of every occluder label in any camera's ``occ_pred``: 'self', 'behind' and
    'outside' fixed, object labels from a palette in sorted order (same across cameras)."""
    labels: set[str] = set()
    for c in range(1, len(run.cameras) + 1):
        labels.update(run.frames.labels(camera_column("occ_pred", c), run.n_features).ravel())
    objects = sorted(labels - set(FIXED_OCCLUDER_COLOURS) - {""})
    colours = {k: v for k, v in FIXED_OCCLUDER_COLOURS.items() if k in labels}
    colours.update({o: OBJECT_PALETTE[i % len(OBJECT_PALETTE)] for i, o in enumerate(objects)})
    return colours


def plot_trajectory(run: Run, path: Path) -> Path:
    """Paper Fig. 8/10: x, y, z (m) of the gripper TCP (solid), the EKF-estimated part
    (dashed) and the true part (thin grey) over time, phases shaded."""
    f, t = run.frames, run.t
    fig = _figure(10, 7.5)
    axes = fig.subplots(3, 1, sharex=True)
    for ax, k in zip(axes, "xyz", strict=True):
        _time_axis(ax, run)
        ax.plot(t, f.floats(f"true_{k}"), color="0.5", lw=0.8, label="part (true)")
        ax.plot(t, f.floats(f"gripper_{k}"), color="C0", lw=1.6, label="gripper")
        ax.plot(t, f.floats(f"est_{k}"), color="C3", lw=1.4, ls="--", label="part (estimated)")
        ax.set_ylabel(f"{k} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    _phase_legend(fig, run)
    return _save(fig, path)


def plot_visibility(run: Run, camera: int, colours: dict[str, str], path: Path) -> Path:
    """Paper Fig. 9/11 for camera ``camera`` (1-based): per feature, a bottom lane that is
    green where the feature is predicted visible and coloured by the predicted occluder where
    it is not, and a top lane that is blue where selected for a window, with a dark line where
    a corner was measured and black crosses where the measurement was rejected."""
    f, edges, n_f = run.frames, run.edges, run.n_features
    vis = f.bits(camera_column("vis_pred", camera), n_f)
    occ = f.labels(camera_column("occ_pred", camera), n_f)
    sel = f.bits(camera_column("sel", camera), n_f)
    meas = f.bits(camera_column("meas", camera), n_f)
    rej = f.bits(camera_column("rej", camera), n_f)
    fig = _figure(11, 1.6 + 0.36 * n_f)
    ax = fig.subplots()
    _time_axis(ax, run)
    present = [lab for lab in colours if (occ == lab).any()]
    for j in range(n_f):
        y = j + 1
        ax.broken_barh(spans(vis[:, j], edges), (y - 0.42, 0.36), facecolors=VISIBLE_COLOUR)
        for lab in present:
            ax.broken_barh(spans((occ[:, j] == lab) & ~vis[:, j], edges), (y - 0.42, 0.36),
                           facecolors=colours[lab])
        ax.broken_barh(spans(sel[:, j], edges), (y + 0.06, 0.36), facecolors=SELECTED_COLOUR)
        ax.broken_barh(spans(meas[:, j], edges), (y + 0.19, 0.10), facecolors=MEASURED_COLOUR)
    k, j = np.nonzero(rej)
    ax.plot(run.t[k], j + 1.24, "x", color="k", ms=4, mew=1, ls="none")
    handles = [Patch(color=VISIBLE_COLOUR, label="predicted visible (bottom)"),
               Patch(color=SELECTED_COLOUR, label="selected (top)"),
               Patch(color=MEASURED_COLOUR, label="measured"),
               Line2D([], [], marker="x", color="k", ls="none", label="rejected by gate")]
    handles += [Patch(color=colours[lab], label=f"occluded: {lab}") for lab in present]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    ax.set(xlabel="t [s]", ylabel="feature", ylim=(0.5, n_f + 0.5),
           title=f"{run.cameras[camera - 1]}: predicted visibility and selection")
    ax.set_yticks(range(1, n_f + 1))
    _phase_legend(fig, run)
    return _save(fig, path)


def plot_error(run: Run, path: Path) -> Path:
    """Position error (mm) and orientation error (deg) of the EKF estimate and the per-frame
    PnP baseline against the true pose over the whole run, the RMSEs from ``metrics.json``
    (every frame in view from the first estimate on) in the legend."""
    m, t = run.metrics, run.t
    fig = _figure(10, 6.5)
    axes = fig.subplots(2, 1, sharex=True)
    panels = [("position error [mm]", position_error_mm, "position_rmse_mm",
               "pnp_position_rmse_mm", "mm"),
              ("orientation error [deg]", orientation_error_deg, "orientation_rmse_deg",
               "pnp_orientation_rmse_deg", "deg")]
    for ax, (label, error, ekf_key, pnp_key, unit) in zip(axes, panels, strict=True):
        _time_axis(ax, run)
        ekf, pnp = error(run, "est"), error(run, "pnp")
        ax.plot(t, pnp, color="C1", lw=0.8, marker=".", ms=2, alpha=0.8,
                label=_rmse_label("PnP baseline", m.get(pnp_key), unit))
        ax.plot(t, ekf, color="C3", lw=1.3, label=_rmse_label("EKF", m.get(ekf_key), unit))
        _use_log(ax, ekf, pnp)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    _phase_legend(fig, run)
    return _save(fig, path)


def plot_health(run: Run, path: Path) -> Path:
    """The tracker's health over its sliding window (``nis_c*``, ``notfound_c*``,
    ``rejfrac_c*`` of frames.csv), one line per camera, with the frames whose status is
    degraded (red), coasting (light grey) or lost (dark grey) shaded behind."""
    f, t = run.frames, run.t
    status = [s.split(":")[0] for s in f.text("status")]
    fig = _figure(10, 6.5)
    axes = fig.subplots(3, 1, sharex=True)
    panels = [("NIS / dof", "nis"), ("not found (fraction)", "notfound"),
              ("rejected (fraction)", "rejfrac")]
    half = 0.5 * (float(np.median(np.diff(t))) if len(t) > 1 else 0.0)
    for ax, (label, column) in zip(axes, panels, strict=True):
        _time_axis(ax, run)
        for i, s in enumerate(status):
            if s in STATUS_SHADES:
                ax.axvspan(t[i] - half, t[i] + half, color=STATUS_SHADES[s], alpha=0.25, lw=0)
        for c, name in enumerate(run.cameras, start=1):
            ax.plot(t, f.floats(camera_column(column, c)), lw=1.0, label=name)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    _phase_legend(fig, run)
    return _save(fig, path)


def _rmse_label(name: str, rmse: float | None, unit: str) -> str:
    """Legend label with the RMSE when known."""
    return name if rmse is None else f"{name} (RMSE {rmse:.3g} {unit})"


def plot_visibility_agreement(run: Run, path: Path) -> Path:
    """Per camera: the number of predicted-visible and truly-visible (ray-cast) features over
    time, and below it every frame x feature where they disagree: false visible (predicted
    visible, truly hidden) red, false hidden blue, frames without a prediction grey."""
    f, edges, n_f, n_c = run.frames, run.edges, run.n_features, len(run.cameras)
    fig = _figure(10, 1.0 + 3.6 * n_c)
    axes = fig.subplots(2 * n_c, 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": [1.0, 1.2] * n_c})[:, 0]
    cmap = ListedColormap(["white", "#d62728", "#1f77b4", "#d9d9d9"])
    for c in range(1, n_c + 1):
        pred = f.bits(camera_column("vis_pred", c), n_f)
        true = f.bits(camera_column("vis_true", c), n_f)
        has_pred = f.present(camera_column("vis_pred", c))
        code = np.where(pred & ~true, 1, np.where(~pred & true, 2, 0))
        code[~has_pred] = 3
        top, bottom = axes[2 * c - 2], axes[2 * c - 1]
        _time_axis(top, run)
        top.step(run.t, np.where(has_pred, pred.sum(axis=1), np.nan), where="post",
                 color="C2", label="predicted visible")
        top.step(run.t, true.sum(axis=1), where="post", color="k", lw=0.8, ls="--",
                 label="truly visible")
        top.set(ylabel="# features", ylim=(-0.5, n_f + 0.5),
                title=f"{run.cameras[c - 1]}: false visible {int((code == 1).sum())}, "
                      f"false hidden {int((code == 2).sum())} of {int(has_pred.sum()) * n_f}")
        top.legend(loc="upper right", fontsize=8)
        top.grid(alpha=0.3)
        bottom.pcolormesh(edges, np.arange(n_f + 1) + 0.5, code.T, cmap=cmap, vmin=-0.5,
                          vmax=3.5)
        bottom.set(ylabel="feature", ylim=(0.5, n_f + 0.5))
    axes[-1].legend(handles=[Patch(color="#d62728", label="false visible"),
                             Patch(color="#1f77b4", label="false hidden"),
                             Patch(color="#d9d9d9", label="no prediction")],
                    loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    axes[-1].set_xlabel("t [s]")
    _phase_legend(fig, run)
    return _save(fig, path)


def plot_timing(run: Run, path: Path) -> Path:
    """Left: box plot of each pipeline stage's time per frame (ms); right: the total time per
    frame (ms) over time with its median."""
    f, t = run.frames, run.t
    fig = _figure(12, 4.5)
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 2]})
    data = {s: f.floats(timing_column(s)) for s in STAGES if s != "total"}  # total: right
    data = {s: v[np.isfinite(v)] for s, v in data.items() if np.isfinite(v).any()}
    if data:
        left.boxplot(list(data.values()), tick_labels=list(data), flierprops={"ms": 2})
        _use_log(left, *data.values())
    left.set(ylabel="time per frame [ms]", title="per stage")
    left.tick_params(axis="x", labelrotation=25)
    left.grid(alpha=0.3, axis="y", which="both")
    total = f.floats(timing_column("total"))
    _time_axis(right, run)
    right.plot(t, total, color="k", lw=0.8, label="total")
    if np.isfinite(total).any():
        right.axhline(np.nanmedian(total), color="C3", ls="--", lw=1,
                      label=f"median {np.nanmedian(total):.3g} ms")
    title = "total"
    if np.isfinite(total).sum() > 10:  # a run's first frames can take seconds (kernels load)
        top = 1.5 * np.nanpercentile(total, 99)
        right.set_ylim(0, top)
        if (above := int(np.sum(total > top))) > 0:
            title += f" ({above} frame{'s' * (above > 1)} above {top:.3g} ms, off the scale)"
    right.set(xlabel="t [s]", ylabel="total per frame [ms]", title=title)
    right.legend(loc="upper right", fontsize=8)
    right.grid(alpha=0.3)
    _phase_legend(fig, run)
    return _save(fig, path)

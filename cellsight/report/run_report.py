"""Figures and a self-contained HTML report built from a run directory.

A run directory (written by ``cellsight run``) holds ``frames.csv`` (one row per vision frame,
read with :class:`cellsight.runfolder.framelog.FrameLog`, whose module lists the columns),
``metrics.json`` and optionally ``keyframes.json`` with ``keyframes/*.png``, ``run.log`` and
``views.mp4``. :func:`write_report` writes the PNG figures next to them and ``report.html``
with every figure, key frame and (if small enough) the video embedded as base64 data URIs, so
the page can be moved or mailed on its own. It also works on a partial run (an interrupted
one: few frames, a short ``metrics.json``).

Conventions: time in s, positions in the base frame in m (errors in mm), roll-pitch-yaw in rad
with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (:mod:`cellsight.geometry.transforms`); frame ``k``
is drawn as covering ``[t_k, t_{k+1})``, the last one a median frame period long.
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from cellsight.errors import CellsightError
from cellsight.geometry.transforms import pose_errors
from cellsight.rates import VISION_HZ
from cellsight.report.corner_crops import wrong_corner_crops
from cellsight.runfolder.framelog import FrameLog, camera_column, timing_column
from cellsight.runfolder.metrics import read_metrics
from cellsight.runfolder.replay import run_cell
from cellsight.runfolder.writes import write_figure, write_file
from cellsight.runfolder.wrong_corners import wrong_corner_spans
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
VIDEO_EMBED_LIMIT = 25 * 1024 * 1024  # bytes; larger videos are linked, not embedded
DEFAULT_FRAME_PERIOD = 1.0 / VISION_HZ  # s, used when a run has a single frame
UNITS = ("mm", "deg", "px", "ms", "s")  # unit tokens in metric keys, e.g. error_px_median


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


# --------------------------------------------------------------------------- helpers


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


# --------------------------------------------------------------------------- figures


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


STATUS_SHADES = {"degraded": "#d62728", "coasting": "#bdbdbd", "predicting": "#bdbdbd",
                 "lost": "#636363"}  # the statuses drawn behind the health figure


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


def write_figures(run: Run) -> list[tuple[str, Path]]:
    """Every figure of a run as ``(title, path)``, written into the run directory."""
    if run.frames.n == 0:
        return []
    d = run.dir
    figures = [("Trajectories (gripper solid, estimated part dashed, true part grey)",
                plot_trajectory(run, d / "fig_trajectory.png")),
               ("Pose error of the EKF and the PnP baseline", plot_error(run, d / "fig_error.png")),
               ("Tracking health (shaded: degraded red, coasting light grey, lost dark grey)",
                plot_health(run, d / "fig_health.png"))]
    if run.n_features and run.cameras:
        colours = occluder_colours(run)
        for c, name in enumerate(run.cameras, start=1):
            figures.append((f"Visibility and selection, {name}",
                            plot_visibility(run, c, colours, d / f"fig_visibility_cam{c}.png")))
        figures.append(("Predicted vs true visibility", plot_visibility_agreement(
            run, d / "fig_visibility_agreement.png")))
    figures.append(("Timing", plot_timing(run, d / "fig_timing.png")))
    return figures


# --------------------------------------------------------------------------- HTML

CSS = """
body { font-family: system-ui, sans-serif; max-width: 1150px; margin: 2em auto; color: #222;
       padding: 0 1em; }
h1 { margin-bottom: 0.2em; } .sub { color: #555; margin-top: 0; }
.warn { background: #fff3cd; border: 1px solid #e0c36a; padding: 0.6em 1em; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.92em; }
td, th { border-bottom: 1px solid #ddd; padding: 0.25em 0.9em; text-align: left; }
td.v { text-align: right; font-variant-numeric: tabular-nums; } code { color: #333; }
figure { margin: 1em 0 2em; } img, video { max-width: 100%; border: 1px solid #ddd; }
figcaption { color: #444; font-size: 0.92em; margin-top: 0.3em; }
pre { background: #f6f6f6; padding: 1em; overflow-x: auto; font-size: 0.82em; }
"""


def _data_uri(path: Path, mime: str) -> str:
    """A file as a base64 data URI."""
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _unit(key: str) -> str:
    """Unit named by the last unit token of a metric key ('' if none)."""
    return next((tok for tok in reversed(key.split("_")) if tok in UNITS), "")


def format_value(value) -> str:
    """A metric value for the table: floats to 4 significant digits, bools yes/no, null '—'."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)


def metric_rows(metrics: dict) -> list[tuple[str, str]]:
    """``(key, formatted value with unit)`` for every scalar, list of scalars and dict of
    scalars (flattened as ``key.sub``) in ``metrics.json``; ``phases``, ``phase_intervals``
    and ``calibration_errors`` have their own tables."""
    rows = []
    for key, value in metrics.items():
        if key in ("phases", "phase_intervals", "calibration_errors"):
            continue
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for sub, v in items:
            text = format_value(v)
            unit = _unit(key) if text != "—" else ""
            rows.append((key if sub is None else f"{key}.{sub}", f"{text} {unit}".strip()))
    return rows


PHASE_COLUMNS = ("evaluated_frames", "position_rmse_mm", "max_position_error_mm",
                 "orientation_rmse_deg", "pnp_position_rmse_mm", "lost_in_view_s")


def _metrics_html(metrics: dict) -> str:
    """The metrics table and, if present, the per-phase table (time span and errors)."""
    if not metrics:
        return "<p>No metrics.json.</p>"
    rows = "".join(f"<tr><td><code>{html.escape(k)}</code></td><td class=v>{html.escape(v)}"
                   "</td></tr>" for k, v in metric_rows(metrics))
    out = f"<h2>Metrics</h2><table>{rows}</table>"
    spans = {str(p): (t0, t1) for p, t0, t1 in metrics.get("phase_intervals") or []}
    errors = metrics.get("phases") or {}
    names = list(spans) + [p for p in errors if p not in spans  # a phase the run never had
                           and (errors[p] or {}).get("evaluated_frames")]
    if names:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in ("phase", "start [s]", "end [s]")
                       + tuple(f"{k} [{_unit(k)}]".replace(" []", "") for k in PHASE_COLUMNS))
        body = "".join(
            f"<tr><td>{html.escape(p)}</td>"
            + "".join(f"<td class=v>{format_value(v)}</td>" for v in spans.get(p, (None, None)))
            + "".join(f"<td class=v>{format_value(errors.get(p, {}).get(k))}</td>"
                      for k in PHASE_COLUMNS) + "</tr>" for p in names)
        out += f"<h3>Phases</h3><table><tr>{head}</tr>{body}</table>"
    return out


def _figures_html(figures: list[tuple[str, Path]]) -> str:
    """Embedded figures with captions."""
    if not figures:
        return "<h2>Figures</h2><p>No frames recorded.</p>"
    items = "".join(f'<figure><img src="{_data_uri(p, "image/png")}" alt="{p.name}">'
                    f"<figcaption>{html.escape(title)} ({p.name})</figcaption></figure>"
                    for title, p in figures)
    return f"<h2>Figures</h2>{items}"


def _keyframes_html(run_dir: Path) -> str:
    """Key frames from ``keyframes.json`` (``file`` relative to the run directory, else looked
    up by name in ``keyframes/``); missing images are skipped."""
    path = run_dir / "keyframes.json"
    if not path.exists():
        return ""
    items = []
    for kf in json.loads(path.read_text()):
        name = str(kf.get("name", ""))
        candidates = [run_dir / str(kf.get("file", "")), run_dir / "keyframes" / f"{name}.png"]
        image = next((p for p in candidates if p.is_file()), None)
        if image is None:
            continue
        caption = f"{name}, t = {format_value(kf.get('t'))} s: {kf.get('caption', '')}"
        items.append(f'<figure><img src="{_data_uri(image, "image/png")}" alt="{name}">'
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    return f"<h2>Key frames</h2>{''.join(items)}" if items else ""


def _video_html(run_dir: Path) -> str:
    """``views.mp4`` embedded (up to ``VIDEO_EMBED_LIMIT`` bytes) or linked."""
    path = run_dir / "views.mp4"
    if not path.is_file():
        return ""
    if path.stat().st_size <= VIDEO_EMBED_LIMIT:
        source = _data_uri(path, "video/mp4")
        link = ""
    else:
        source = path.name
        link = f'<p><a href="{path.name}">{path.name}</a> (too large to embed)</p>'
    return (f'<h2>Camera views</h2><video controls loop muted><source src="{source}" '
            f'type="video/mp4"></video>{link}')


def _names(run_dir: Path, metrics: dict) -> tuple[list[str] | None, list[str] | None]:
    """The run's camera and feature names, from the cell it kept (as ``cellsight diagnose``
    names them); None, None when that cell cannot be read (then ``cam<c>`` and ``#<j>``)."""
    try:
        cell = run_cell(metrics, run_dir)
        part = cell.workpiece(metrics["workpiece"])
    except (CellsightError, OSError, ValueError, KeyError):
        return None, None
    return [c.name for c in cell.cameras], list(part.feature_names)


def _wrong_corners_html(run_dir: Path, metrics: dict, shown: int = 12) -> str:
    """The run's wrong corners by camera, feature and span of time, most accepted first
    (:mod:`cellsight.runfolder.wrong_corners`; ``cellsight diagnose`` prints them all)."""
    try:
        spans = wrong_corner_spans(run_dir, *_names(run_dir, metrics))
    except (OSError, ValueError, KeyError):
        return ""
    if not spans:
        return ""
    head = "".join(f"<th>{h}</th>" for h in ("camera", "feature", "t [s]", "phase", "frames",
                                             "accepted", "rejected", "unused", "truly",
                                             "predicted"))
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (
            s.camera, s.feature, f"{s.t_start:.2f}-{s.t_end:.2f}", s.phase, s.frames,
            s.accepted, s.rejected, s.unused, s.truth, s.predicted)) + "</tr>"
        for s in spans[:shown])
    more = f" (the first {shown} of {len(spans)} spans)" if len(spans) > shown else ""
    try:
        crops = wrong_corner_crops(run_dir, spans, metrics=metrics)
    except Exception as exc:  # a picture the report can go without; said in it
        note = html.escape(str(exc))
        crops, body = [], body + f"<tr><td colspan=9>(no pictures: {note})</td></tr>"
    pictures = "".join(f'<figure><img src="{p.name}" alt="{p.stem}"><figcaption>{p.stem}'
                       "</figcaption></figure>" for p in crops)
    return (f"<h2>Wrong corners</h2><p>Corners measured more than 3 px from the true "
            f"projection, by camera and feature (as <code>cellsight diagnose</code> names them), "
            f"most accepted first{more}. Pictures: the worst accepted spans' first frames, "
            f"re-rendered, around the feature's true projection (green cross).</p>"
            f"<table><tr>{head}</tr>{body}</table>{pictures}")


def _calibration_html(metrics: dict) -> str:
    """The calibration the run took as its model (``--calibration``): its verdict, its
    residuals per camera and view (its ``residuals.png``) and, made in the simulated world,
    each estimate's error against the world's truth (mm, deg, %, px)."""
    if not metrics.get("calibration_folder"):
        return ""
    folder = Path(str(metrics["calibration_folder"]))
    try:
        verdict = str(json.loads((folder / "calibration.json").read_text()).get("verdict", ""))
    except (OSError, ValueError, AttributeError) as exc:
        return (f"<h2>Calibration</h2><p>{html.escape(str(folder))}: not readable now "
                f"({html.escape(str(exc))}).</p>")
    out = (f"<h2>Calibration</h2><p>The cameras and robot bases of "
           f"<code>{html.escape(str(folder))}</code>: {html.escape(verdict)}.</p>")
    errors = metrics.get("calibration_errors") or {}
    rows = [(name, e) for kind in ("cameras", "robots")
            for name, e in (errors.get(kind) or {}).items()]
    if rows:
        keys = list(dict.fromkeys(k for _, e in rows for k in e))
        head = "".join(f"<th>{html.escape(k)}</th>" for k in ["against the truth", *keys])
        body = "".join(f"<tr><td>{html.escape(name)}</td>"
                       + "".join(f"<td class=v>{format_value(e.get(k))}</td>" for k in keys)
                       + "</tr>" for name, e in rows)
        out += f"<table><tr>{head}</tr>{body}</table>"
    picture = folder / "residuals.png"
    if picture.is_file():
        out += (f'<figure><img src="{_data_uri(picture, "image/png")}" alt="residuals">'
                "<figcaption>The calibration's residuals per camera and view (px)"
                "</figcaption></figure>")
    return out


def _log_html(run_dir: Path) -> str:
    """``run.log`` in a collapsed block."""
    path = run_dir / "run.log"
    if not path.is_file():
        return ""
    text = path.read_text(errors="replace")
    return (f"<details><summary>Run log ({len(text.splitlines())} lines)</summary>"
            f"<pre>{html.escape(text)}</pre></details>")


def _header_html(run: Run) -> str:
    """Title, run description and a banner for interrupted runs."""
    m = run.metrics
    occ = m.get("occlusion_prediction")
    occ_text = "?" if occ is None else ("on" if occ else "off")
    source = (f"tracked from recording {m['recording']}" if m.get("recording") else
              f"experiment {m.get('experiment', '?')} · seed {m.get('seed', '?')}")
    sub = (f"{source} · sensor {m.get('sensor', '?')} · occlusion prediction {occ_text} · "
           + (f"{m['tracker']} tracker · " if m.get("tracker")
              else "kinematic prior on · " if m.get("kinematic_prior") else "")
           + f"{run.frames.n} frames")
    out = f"<h1>cellsight run report</h1><p class=sub>{html.escape(sub)}</p>"
    if m.get("error"):
        out += (f"<p class=warn>Failed run ({html.escape(str(m['error']))}); results are "
                f"incomplete.</p>")
    elif m.get("interrupted") or not m:
        out += "<p class=warn>Partial run: interrupted or unfinished; results are incomplete.</p>"
    return out


def write_report(run_dir: Path, metrics: dict | None = None) -> Path:
    """Write the figures (``fig_*.png``) and ``report.html`` into ``run_dir``; returns the
    report's path. Works on partial runs (few frames, short or missing ``metrics.json``).
    ``metrics``: the run's metrics, when its ``metrics.json`` is not written yet
    (:func:`report_inputs`).
    Each file is written whole or not at all; a failure is a
    :class:`~cellsight.runfolder.writes.WriteError` naming it."""
    run = report_inputs(Path(run_dir), metrics)
    body = "".join([_header_html(run), _metrics_html(run.metrics),
                    _calibration_html(run.metrics),
                    _figures_html(write_figures(run)), _keyframes_html(run.dir),
                    _video_html(run.dir), _wrong_corners_html(run.dir, run.metrics),
                    _log_html(run.dir)])
    m = run.metrics
    title = (f"cellsight track: {Path(str(m['recording'])).name}" if m.get("recording") else
             f"cellsight run: experiment {m.get('experiment', '?')}, seed {m.get('seed', '?')}")
    page = (f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head>"
            f"<body>{body}</body></html>\n")
    return write_file(run.dir / "report.html", page)

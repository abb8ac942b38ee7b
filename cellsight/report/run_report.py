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
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.report.corner_crops import wrong_corner_crops
from cellsight.report.run_figures import (
    Run,
    occluder_colours,
    plot_error,
    plot_health,
    plot_timing,
    plot_trajectory,
    plot_visibility,
    plot_visibility_agreement,
    report_inputs,
)
from cellsight.runfolder.replay import run_cell
from cellsight.runfolder.writes import write_file
from cellsight.runfolder.wrong_corners import wrong_corner_spans

VIDEO_EMBED_LIMIT = 25 * 1024 * 1024  # bytes; larger videos are linked, not embedded
UNITS = ("mm", "deg", "px", "ms", "s")  # unit tokens in metric keys, e.g. error_px_median


# --------------------------------------------------------------------------- figures




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

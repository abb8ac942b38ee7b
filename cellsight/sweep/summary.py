"""A sweep's results as tables and plots: ``summary.csv`` (one row per run, every scalar
metric and the per-phase errors), ``summary.md`` (the README's tables: each group of runs over
its seeds (:mod:`.aggregate`), the paired comparisons, then every run's whole-task figures and
the position error per phase) and ``summary.png`` (position RMSE and largest position error per
experiment, sensor and variant, one dot per seed)."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from cellsight.control import Phase  # noqa: E402
from cellsight.runfolder.writes import write_figure, write_file  # noqa: E402
from cellsight.sweep.aggregate import aggregate_markdown  # noqa: E402
from cellsight.sweep.grid import RunSpec  # noqa: E402
from cellsight.sweep.lines import (  # noqa: E402
    lines_markdown,
    passing_markdown,
    passing_summary,
    pick_summary,
)
from cellsight.visibility import OBJECT_BVH  # noqa: E402

COLUMNS = (
    ("grasp_success", "grasp", "{}"),
    ("in_view_fraction", "in view", "{:.2f}"),
    ("lost_in_view_s", "lost s", "{:.2f}"),
    ("position_rmse_mm", "pos. RMSE mm", "{:.2f}"),
    ("max_position_error_mm", "max pos. mm", "{:.2f}"),
    ("orientation_rmse_deg", "orient. RMSE deg", "{:.2f}"),
    ("pnp_position_rmse_mm", "PnP pos. RMSE mm", "{:.2f}"),
    ("visibility_accuracy", "visibility acc.", "{:.4f}"),
    ("wrong_measurements", "wrong", "{}"),
    ("wrong_accepted", "wrong accepted", "{}"),
    ("grasp_position_error_mm", "grasp err. mm", "{:.2f}"),
)
"""The whole-task columns of ``summary.md``: metric key, header, format."""
VARIANT_NAMES = {"kinematic": "kinematic", "plain": "plain (the paper's)",
                 "nopred": "kinematic, **no prediction**",
                 "offsets": "kinematic + experimental camera offsets",
                 "unknown": "kinematic + experimental unknown occluders",
                 "calibrated": "kinematic, cell calibrated on the seed"}
RUN_KEYS = ("cell", "experiment", "sensor", "variant", "seed")
LINES_HEADER = "Lines, each part picked in turn (every part's own figures):"
"""The line above the lines' table in ``summary.md`` (:func:`~.lines.lines_markdown`)."""
PASSING_HEADER = "Parts passing through the views on a line, not picked (each part's own figures):"
"""The line above the passing parts' table in ``summary.md`` (:func:`~.lines.passing_markdown`)."""


def _fmt(metrics: dict, key: str, pattern: str) -> str:
    value = metrics.get(key)
    return "–" if value is None else pattern.format(value)


def _phases() -> list[str]:
    return [str(p) for p in Phase.working()]


def flat_row(spec: RunSpec, metrics: dict) -> dict[str, object]:
    """One run's CSV row: its grid coordinates, ``status``, the scalar metrics and the
    per-phase ``<phase>_<metric>`` figures."""
    status = "failed" if metrics.get("error") else "done"
    row: dict[str, object] = {"cell": spec.folder.parent.name, "experiment": spec.experiment,
                              "sensor": spec.sensor, "variant": spec.variant,
                              "realism": spec.realism, "structure": spec.structure,
                              "seed": spec.seed, "status": status,
                              "error": metrics.get("error", "")}
    row.update({k: v for k, v in metrics.items()
                if k not in row and isinstance(v, int | float | str | bool | None)})
    for phase, figures in (metrics.get("phases") or {}).items():
        row.update({f"{phase}_{k}": v for k, v in figures.items()})
    row.update({f"kidnap_{k}": v for k, v in (metrics.get("kidnap") or {}).items()
                if isinstance(v, int | float | str | bool | None)})
    row.update(pick_summary(metrics))
    row.update(passing_summary(metrics))
    return row


def kidnap_markdown(specs: Sequence[RunSpec], results: Sequence[dict]) -> str:
    """The kidnapped runs' table (empty when there are none): per run, the fault and how the
    tracker met it (``kidnap`` in ``metrics.json``; s)."""
    lines = ["| cell | exp. | sensor | realism | seed | moved mm | turned deg | noticed s | "
             "said tracking while >10 mm off s | visible s | recovered s (<= 10 mm) | "
             "re-acquired s (<= 2 mm) | error before / 1 s after mm | grasp |",
             "|" + "---|" * 14]
    for spec, m in zip(specs, results, strict=True):
        k = m.get("kidnap")
        if not k or m.get("error"):
            continue
        cells = [spec.folder.parent.name, spec.experiment, spec.sensor, spec.realism, spec.seed,
                 f"{k['distance_mm']:.0f}", f"{k['turn_deg']:.0f}"]
        cells += [_fmt(k, key, "{:.2f}") for key in ("noticed_s", "wrong_tracking_s",
                                                      "visible_s", "recovered_s",
                                                      "reacquired_s")]
        cells.append(f"{_fmt(k, 'before_mm', '{:.1f}')} / {_fmt(k, 'settled_mm', '{:.1f}')}")
        lines.append("| " + " | ".join(map(str, cells + [m.get("grasp_success")])) + " |")
    return "\n".join(lines) + "\n" if len(lines) > 2 else ""


def write_csv(path: Path, rows: Sequence[dict]) -> None:
    """``summary.csv``: the union of the rows' columns, in first-seen order."""
    header = list(dict.fromkeys(k for row in rows for k in row))
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, header)
    writer.writeheader()
    writer.writerows(rows)
    write_file(path, text.getvalue())


def markdown(specs: Sequence[RunSpec], results: Sequence[dict]) -> str:
    """The two Markdown tables: whole-task metrics per run, then position RMSE / max (mm) per
    working phase."""
    lead = ["cell", "exp.", "sensor", "occlusion prediction", "seed"]
    phases = _phases()

    worlds = any(s.realism != "exact" or s.structure != OBJECT_BVH for s in specs)
    if worlds:
        lead[2] = "sensor (realism, structure)"

    def cells(spec: RunSpec) -> list[str]:
        sensor = f"{spec.sensor} ({spec.realism}, {spec.structure})" if worlds else spec.sensor
        return [spec.folder.parent.name, str(spec.experiment), sensor,
                VARIANT_NAMES[spec.variant], str(spec.seed)]

    lines = ["| " + " | ".join(lead + [c[1] for c in COLUMNS]) + " |",
             "|" + "---|" * (len(lead) + len(COLUMNS))]
    for spec, m in zip(specs, results, strict=True):
        values = ([f"failed: {m['error'][:60]}"] + [""] * (len(COLUMNS) - 1) if m.get("error")
                  else [_fmt(m, key, pattern) for key, _, pattern in COLUMNS])
        lines.append("| " + " | ".join(cells(spec) + values) + " |")
    lines += ["", "Position RMSE / max (mm) per phase:", "",
              "| " + " | ".join(lead + phases) + " |", "|" + "---|" * (len(lead) + len(phases))]
    for spec, m in zip(specs, results, strict=True):
        per = m.get("phases") or {}
        values = [f"{_fmt(per.get(p, {}), 'position_rmse_mm', '{:.2f}')} / "
                  f"{_fmt(per.get(p, {}), 'max_position_error_mm', '{:.2f}')}" for p in phases]
        lines.append("| " + " | ".join(cells(spec) + values) + " |")
    return "\n".join(lines) + "\n"


def plot(path: Path, specs: Sequence[RunSpec], results: Sequence[dict]) -> None:
    """``summary.png``: per (cell, experiment, sensor, variant, realism, structure) group,
    position RMSE and the largest position error (mm, whole task), one dot per seed and a bar
    at their mean."""
    groups: dict[tuple, list[dict]] = {}
    for spec, m in zip(specs, results, strict=True):
        if not m.get("error"):
            key = (spec.folder.parent.name, spec.experiment, spec.sensor, spec.variant,
                   spec.realism, spec.structure)
            groups.setdefault(key, []).append(m)
    names = [f"{c} e{e}\n{s} {v}" + (f"\n{r} {b}" if r != "exact" or b != OBJECT_BVH else "")
             for c, e, s, v, r, b in groups]
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.9 * len(groups) + 2), 6.5), sharex=True)
    for ax, key, label in ((axes[0], "position_rmse_mm", "position RMSE (mm)"),
                           (axes[1], "max_position_error_mm", "largest position error (mm)")):
        for x, runs in enumerate(groups.values()):
            values = [float(m[key]) for m in runs if m.get(key) is not None]
            if values:
                ax.bar(x, sum(values) / len(values), color="#9ecae1", width=0.7)
                ax.plot([x] * len(values), values, "o", color="#08519c", ms=4)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[1].set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
    axes[0].set_title("sweep: whole task, every frame in view (bar: mean over seeds)")
    fig.tight_layout()
    write_figure(path, fig, dpi=110)
    plt.close(fig)


def write_summary(out: Path, specs: Sequence[RunSpec], results: Sequence[dict]) -> list[Path]:
    """Write ``summary.csv``, ``summary.md`` and ``summary.png`` into ``out``; their paths. A
    run's collisions are counted as the contact monitor counts them now
    (:func:`~cellsight.world.contacts.merge_episodes`: a run written before its flickering
    contacts were merged into episodes is summarised as one written after)."""
    out = Path(out)
    results = [_merged_collisions(m) for m in results]
    paths = [out / "summary.csv", out / "summary.md", out / "summary.png"]
    write_csv(paths[0], [flat_row(s, m) for s, m in zip(specs, results, strict=True)])
    kidnaps, lines = kidnap_markdown(specs, results), lines_markdown(specs, results)
    passing = passing_markdown(specs, results)
    write_file(paths[1], aggregate_markdown(specs, results) + "\n" + markdown(specs, results)
               + (f"\nKidnapped runs:\n\n{kidnaps}" if kidnaps else "")
               + (f"\n{LINES_HEADER}\n\n{lines}" if lines else "")
               + (f"\n{PASSING_HEADER}\n\n{passing}" if passing else ""))
    plot(paths[2], specs, results)
    return paths


def _merged_collisions(metrics: dict) -> dict:
    """``metrics`` with its collisions in episodes apart by :data:`~cellsight.world.contacts.
    APART_S` at least (unchanged when they already are, or when it has none)."""
    from cellsight.world.contacts import merge_episodes

    if not metrics.get("collisions"):
        return metrics
    merged = merge_episodes(metrics["collisions"])
    return {**metrics, "collisions": merged, "collision_count": len(merged)}

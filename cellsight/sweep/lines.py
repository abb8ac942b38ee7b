"""A sweep's lines (runs whose robot picks several parts in turn, ``picks`` in
``metrics.json``): each run's picks summed up, and the table of ``summary.md`` that groups them.

Per run (:func:`pick_summary`): how many parts were picked of how many, the worst part's
position RMSE (in the grasping arm's frame where the cameras were registered to it, and in the
cell's), the largest error of any part while its status said ``tracking``, the frames of any
part more than 10 mm off while ``tracking``, and the identity swaps (a part's estimate nearer
another part's true position than its own, :mod:`cellsight.runfolder.picks`). Per group of
runs (:func:`lines_markdown`, groups as :mod:`.aggregate` forms them): runs with every part
picked, the per-part arm-frame RMSE (mean over parts and seeds, and the worst part), and the
sums and worst of the rest. A line's passing parts (carried through the views, not picked:
``passing`` in ``metrics.json``) have their own table (:func:`passing_markdown`): how many
entered the views and were then estimated, how long after they were wholly in one camera's
image (median and worst), their
arm-frame RMSE, the worst error while ``tracking``, the frames said ``tracking`` with the part
out of every view, and the identity swaps. Lengths mm, times s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.sweep.aggregate import GroupKey, group_key
from cellsight.sweep.grid import RunSpec


def _worst(picks: list[dict], key: str) -> float | None:
    values = [p[key] for p in picks if p.get(key) is not None]
    return max(values) if values else None


def pick_summary(metrics: dict) -> dict[str, object]:
    """One line run's picks summed up (module docstring) as ``picks_*`` scalars; empty for a
    run of one part."""
    picks = metrics.get("picks") or []
    if not picks:
        return {}
    return {
        "picks": len(picks),
        "picks_picked": sum(bool(p.get("picked")) for p in picks),
        "picks_worst_rmse_arm_mm": _worst(picks, "position_rmse_arm_mm"),
        "picks_worst_rmse_mm": _worst(picks, "position_rmse_mm"),
        "picks_max_error_tracking_mm": _worst(picks, "max_error_tracking_mm"),
        "picks_confident_wrong_frames": sum(p.get("confident_wrong_frames") or 0 for p in picks),
        "picks_identity_swaps": sum(p.get("identity_swaps") or 0 for p in picks),
    }


def passing_summary(metrics: dict) -> dict[str, object]:
    """One line run's passing parts summed up (module docstring) as ``passing_*`` scalars;
    empty for a run without any."""
    passing = metrics.get("passing") or []
    if not passing:
        return {}
    return {
        "passing": len(passing),
        "passing_entered": sum(p.get("entered_s") is not None for p in passing),
        "passing_acquired": sum(p.get("acquired_after_s") is not None for p in passing),
        "passing_worst_acquired_after_s": _worst(passing, "acquired_after_s"),
        "passing_worst_rmse_arm_mm": _worst(passing, "position_rmse_arm_mm"),
        "passing_max_error_tracking_mm": _worst(passing, "max_error_tracking_mm"),
        "passing_tracking_out_of_view_frames": sum(p.get("tracking_out_of_view_frames") or 0
                                                   for p in passing),
        "passing_identity_swaps": sum(p.get("identity_swaps") or 0 for p in passing),
    }


def _fmt(value: float | None, pattern: str = "{:.2f}") -> str:
    return "–" if value is None or not np.isfinite(value) else pattern.format(value)


def _groups(specs: Sequence[RunSpec], results: Sequence[dict],
            key: str) -> dict[GroupKey, list[dict]]:
    """The runs that have ``key`` (``picks`` or ``passing``) and no error, grouped as
    :mod:`.aggregate` groups them."""
    groups: dict[GroupKey, list[dict]] = {}
    for spec, m in zip(specs, results, strict=True):
        if m.get(key) and not m.get("error"):
            groups.setdefault(group_key(spec), []).append(m)
    return groups


def lines_markdown(specs: Sequence[RunSpec], results: Sequence[dict]) -> str:
    """The lines' table (empty when the sweep has none): per group, the runs with every part
    picked, the parts' arm-frame RMSE (mean and worst part), the worst error while
    ``tracking``, the runs with a part more than 10 mm off while ``tracking`` (frames in all)
    and the identity swaps."""
    groups = _groups(specs, results, "picks")
    if not groups:
        return ""
    lines = ["| cell | exp. | realism | structure | sensor | variant | seeds | every part picked "
             "| parts picked | part arm-frame RMSE mm, mean | worst part | worst error while "
             "`tracking` mm | runs with a part >10 mm off said `tracking` (frames) | identity "
             "swaps (frames) |", "|" + "---|" * 14]
    for key, runs in groups.items():
        parts = [p for m in runs for p in m["picks"]]
        rmse = np.array([p["position_rmse_arm_mm"] for p in parts
                         if p.get("position_rmse_arm_mm") is not None])
        summaries = [pick_summary(m) for m in runs]
        wrong = [s["picks_confident_wrong_frames"] for s in summaries]
        worst_tracking = _worst(summaries, "picks_max_error_tracking_mm")
        cells = [*map(str, key), str(len(runs)),
                 f"{sum(s['picks_picked'] == s['picks'] for s in summaries)}/{len(runs)}",
                 f"{sum(s['picks_picked'] for s in summaries)}/{len(parts)}",
                 _fmt(float(rmse.mean()) if len(rmse) else None),
                 _fmt(float(rmse.max()) if len(rmse) else None), _fmt(worst_tracking),
                 f"{sum(w > 0 for w in wrong)} ({sum(wrong)})",
                 str(sum(s["picks_identity_swaps"] for s in summaries))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def passing_markdown(specs: Sequence[RunSpec], results: Sequence[dict]) -> str:
    """The passing parts' table (empty when the sweep has none; module docstring)."""
    groups = _groups(specs, results, "passing")
    if not groups:
        return ""
    lines = ["| cell | exp. | realism | structure | sensor | variant | seeds | parts entered the "
             "views | estimated after entering | s from wholly in view to the estimate, median | "
             "worst | part arm-frame RMSE mm, mean | worst part | worst error while `tracking` "
             "mm | frames said `tracking` out of view | identity swaps (frames) |",
             "|" + "---|" * 16]
    for key, runs in groups.items():
        parts = [p for m in runs for p in m["passing"]]
        after = np.array([p["acquired_after_s"] for p in parts
                          if p.get("acquired_after_s") is not None])
        rmse = np.array([p["position_rmse_arm_mm"] for p in parts
                         if p.get("position_rmse_arm_mm") is not None])
        summaries = [passing_summary(m) for m in runs]
        cells = [*map(str, key), str(len(runs)),
                 f"{sum(s['passing_entered'] for s in summaries)}/{len(parts)}",
                 f"{sum(s['passing_acquired'] for s in summaries)}/"
                 f"{sum(s['passing_entered'] for s in summaries)}",
                 _fmt(float(np.median(after)) if len(after) else None, "{:.1f}"),
                 _fmt(float(after.max()) if len(after) else None, "{:.1f}"),
                 _fmt(float(rmse.mean()) if len(rmse) else None),
                 _fmt(float(rmse.max()) if len(rmse) else None),
                 _fmt(_worst(summaries, "passing_max_error_tracking_mm")),
                 str(sum(s["passing_tracking_out_of_view_frames"] for s in summaries)),
                 str(sum(s["passing_identity_swaps"] for s in summaries))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"

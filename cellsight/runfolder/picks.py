"""A line's run folder: one frame log per picked part, and each part's figures.

On a line (a cell file's ``experiments.picks``) the run's ``frames.csv`` logs the first pick and
``parts/<name>/frames.csv`` each other one, every frame (:class:`~cellsight.session.rows.
FramesCsv`). :func:`line_figures` reads them back: each part's estimation figures
(:func:`~cellsight.runfolder.figures.frame_metrics`) and its identity swaps, the frames in which
its estimate lies nearer another pick's true position than its own, and more than
:data:`~cellsight.runfolder.figures.CONFIDENT_WRONG_MM` from its own (the tracker took one part
for another). A line's passing parts (carried through the views, not picked) are logged the
same way, in ``parts/<name>/frames.csv``; :func:`passing_figures` adds when each entered the
views, was wholly in one, and left them (its features truly in a camera's image), how long
after it was wholly in view it was first estimated, and its frames said ``tracking`` while
out of every view.
Positions m in the base frame; figures mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cellsight.runfolder.figures import (
    CONFIDENT_WRONG_MM,
    evaluated_frames,
    frame_metrics,
    in_image,
    position_rmse_in_arm_frame_mm,
)
from cellsight.runfolder.framelog import FrameLog

KEPT = ("frames", "evaluated_frames", "first_estimate_s", "position_rmse_mm",
        "orientation_rmse_deg", "max_position_error_mm", "lost_in_view_s",
        "visibility_accuracy", "confident_wrong_frames", "max_error_tracking_mm",
        "wrong_accepted")
"""The figures of :func:`~cellsight.runfolder.figures.frame_metrics` kept for each pick."""


def part_log_name(picks: Sequence[str], name: str) -> str:
    """The frame log of pick ``name`` in a line's run folder, relative to it (``picks``: the
    picks' names in order): the first's is the run's ``frames.csv``."""
    return "frames.csv" if name == picks[0] else f"parts/{name}/frames.csv"


def line_figures(out: Path, picks: Sequence[str], arm_error_m: np.ndarray | None,
                 passing: Sequence[str] = ()) -> dict[str, dict]:
    """Each pick's and passing part's figures (module docstring) from the logs in run folder
    ``out``: :data:`KEPT`, ``position_rmse_arm_mm`` (with ``arm_error_m``, the grasping arm's
    own error at HOME, m; None without it) and ``identity_swaps`` (frames; against every
    logged part), and a passing part's :func:`passing_figures`; no figures when a log is
    missing."""
    names = [*picks, *passing]
    paths = {name: out / part_log_name(picks, name) for name in names}
    if not all(path.is_file() for path in paths.values()):  # a run that failed as it began
        return {name: {} for name in names}
    logs = {name: FrameLog.read(path) for name, path in paths.items()}
    truths = np.stack([logs[name].poses("true")[:, :3] for name in names])  # (P, N, 3)
    out_figures = {}
    for k, (name, log) in enumerate(logs.items()):
        figures = frame_metrics(log)
        kept = {key: figures.get(key) for key in KEPT}
        kept["position_rmse_arm_mm"] = (None if arm_error_m is None
                                        else position_rmse_in_arm_frame_mm(log, arm_error_m))
        kept["identity_swaps"] = identity_swaps(log.poses("est")[:, :3], truths, k,
                                                evaluated_frames(log))
        if name in passing:
            kept.update(passing_figures(log))
        out_figures[name] = kept
    return out_figures


def passing_figures(log: FrameLog) -> dict[str, float | int | None]:
    """A passing part's entry and exit (module docstring): ``entered_s`` (s: a feature in
    some camera's image), ``whole_in_view_s`` (s: every feature in one camera's image) and
    ``left_s`` (s: none in any image again; None: never in view, or still in view at the end),
    ``acquired_after_s`` (s from the first frame wholly in view to the first estimate after
    entering; negative: estimated before it was; None: no estimate, or never wholly in view),
    and ``tracking_out_of_view_frames``."""
    t = log.floats("t")
    inside = in_image(log)  # (N, C, F)
    seen, whole = inside.any(axis=(1, 2)), inside.all(axis=2).any(axis=1)
    status = np.array(log.text("status"), dtype=str)
    figures: dict[str, float | int | None] = {
        "entered_s": None, "whole_in_view_s": None, "left_s": None, "acquired_after_s": None,
        "tracking_out_of_view_frames": int(np.sum(~seen & (status == "tracking")))}
    if not seen.any():
        return figures
    first = int(np.argmax(seen))
    last = len(seen) - 1 - int(np.argmax(seen[::-1]))
    figures["entered_s"] = float(t[first])
    figures["left_s"] = None if last == len(seen) - 1 else float(t[last + 1])
    estimated = log.present("est_x") & (np.arange(log.n) >= first)
    if whole.any():
        figures["whole_in_view_s"] = float(t[int(np.argmax(whole))])
        if estimated.any():
            figures["acquired_after_s"] = round(float(t[int(np.argmax(estimated))]
                                                      - figures["whole_in_view_s"]), 4)
    return figures


def identity_swaps(estimate: np.ndarray, truths: np.ndarray, k: int, frames: np.ndarray) -> int:
    """How many of ``frames`` ((N,) bool) have pick ``k``'s ``estimate`` ((N, 3) m, NaN where
    none) nearer another pick's true position than its own (``truths`` (P, N, 3) m) and more
    than :data:`CONFIDENT_WRONG_MM` from its own."""
    distance = np.linalg.norm(truths - estimate[None], axis=2)  # (P, N)
    own = distance[k]
    others = np.delete(distance, k, axis=0)
    nearest_other = np.where(np.isnan(others), np.inf, others).min(axis=0, initial=np.inf)
    swapped = frames & (own > CONFIDENT_WRONG_MM * 1e-3) & (nearest_other < own)
    return int(np.sum(swapped))

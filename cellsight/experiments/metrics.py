"""Metrics of a run, computed from its ``frames.csv`` rows alone (so they can be recomputed).

- Estimation errors (``position_rmse_mm``, ``orientation_rmse_deg``, ``max_position_error_mm``,
  ``pnp_position_rmse_mm``, ``pnp_orientation_rmse_deg``) over the *metric window*: from the
  first frame with an estimate up to (not including) the first frame where the jaws are closed
  on the part (the end of the run if they never close). The orientation error is the angle of
  ``R_est^T R_true``. The PnP baseline is taken on the same frames (those where it has a pose).
- ``visibility_accuracy``: fraction of frame x camera x feature labels where the prediction (at
  the tracker's predicted pose) equals the simulator's truth; ``false_visible`` counts labels
  predicted visible but truly hidden, ``false_hidden`` the reverse. All frames.
  ``visibility_accuracy_in_view``: the same over the labels of features that truly project
  inside the image (leaving out the easy ones: the part out of view).
- ``measurements``: features measured; ``rejected_measurements``: of those, rejected by the EKF's
  gate; ``wrong_measurements``: measured more than ``WRONG_PX`` from the true projection (another
  image point: an occluder's corner); ``wrong_accepted``: wrong and not rejected. All frames.
- ``pixels_grabbed_fraction``: mean over frames and cameras of the fraction of pixels grabbed.
- ``extraction_error_px_median``: median over frames and cameras of each frame's median
  extraction error (px); None when no frame has one (ideal sensor).
- ``timing_ms``: median per stage (ms) over the frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.experiments.framelog import POSE, STAGES
from cellsight.geometry.transforms import pose_errors


def _pose_columns(rows: Sequence[dict[str, str]], prefix: str) -> np.ndarray:
    """(n, 6) poses, NaN rows where missing."""
    out = np.full((len(rows), 6), np.nan)
    for i, row in enumerate(rows):
        if row[f"{prefix}_x"] != "":
            out[i] = [float(row[f"{prefix}_{a}"]) for a in POSE]
    return out


def metric_window(rows: Sequence[dict[str, str]]) -> tuple[int, int]:
    """Row indices ``[start, stop)`` of the metric window (module docstring)."""
    start = next((i for i, r in enumerate(rows) if r["est_x"] != ""), len(rows))
    stop = next((i for i, r in enumerate(rows) if i >= start and r["jaws_closed"] == "1"),
                len(rows))
    return start, stop


def _bits(text: str) -> np.ndarray:
    """A '0'/'1' string as a boolean mask."""
    return np.frombuffer(text.encode(), dtype=np.uint8) == ord("1")


def _rmse(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else None


def _scaled(x: float | None, factor: float) -> float | None:
    return None if x is None else x * factor


def frame_metrics(rows: Sequence[dict[str, str]], n_cameras: int) -> dict:
    """The metrics of the module docstring from ``frames.csv`` rows (dicts of strings)."""
    truth = _pose_columns(rows, "true")
    start, stop = metric_window(rows)
    win = slice(start, stop)
    est_pos, est_ang = pose_errors(_pose_columns(rows, "est")[win], truth[win])
    pnp_pos, pnp_ang = pose_errors(_pose_columns(rows, "pnp")[win], truth[win])
    agree = total = false_visible = false_hidden = agree_in_view = in_view = 0
    counts = dict.fromkeys(("measurements", "rejected_measurements", "wrong_measurements",
                            "wrong_accepted"), 0)
    grabbed, errors = [], []
    for row in rows:
        for c in range(1, n_cameras + 1):
            pred, true = _bits(row[f"vis_pred_c{c}"]), _bits(row[f"vis_true_c{c}"])
            agree += int(np.sum(pred == true))
            total += len(pred)
            inside = np.array([r not in ("outside", "behind")
                               for r in row[f"occ_true_c{c}"].split(";")])
            agree_in_view += int(np.sum((pred == true) & inside))
            in_view += int(inside.sum())
            false_visible += int(np.sum(pred & ~true))
            false_hidden += int(np.sum(~pred & true))
            meas, rej, wrong = (_bits(row[f"{k}_c{c}"]) for k in ("meas", "rej", "wrong"))
            counts["measurements"] += int(meas.sum())
            counts["rejected_measurements"] += int(rej.sum())
            counts["wrong_measurements"] += int(wrong.sum())
            counts["wrong_accepted"] += int(np.sum(wrong & ~rej))
            grabbed.append(float(row[f"grab_c{c}"]))
            if row[f"err_px_c{c}"] != "":
                errors.append(float(row[f"err_px_c{c}"]))
    t = np.array([float(r["t"]) for r in rows])
    timing = {
        s: float(np.median([float(r[f"t_{s}_ms"]) for r in rows])) if rows else None
        for s in STAGES
    }
    finite_pos = est_pos[np.isfinite(est_pos)]
    return {
        "frames": len(rows),
        "metric_window_s": [float(t[start]), float(t[stop - 1])] if stop > start else None,
        "metric_frames": stop - start,
        "position_rmse_mm": _scaled(_rmse(est_pos), 1e3),
        "orientation_rmse_deg": _scaled(_rmse(est_ang), 180.0 / np.pi),
        "max_position_error_mm": float(finite_pos.max() * 1e3) if len(finite_pos) else None,
        "pnp_position_rmse_mm": _scaled(_rmse(pnp_pos), 1e3),
        "pnp_orientation_rmse_deg": _scaled(_rmse(pnp_ang), 180.0 / np.pi),
        "visibility_accuracy": agree / total if total else None,
        "visibility_accuracy_in_view": agree_in_view / in_view if in_view else None,
        "false_visible": false_visible,
        "false_hidden": false_hidden,
        **counts,
        "pixels_grabbed_fraction": float(np.mean(grabbed)) if grabbed else None,
        "extraction_error_px_median": float(np.median(errors)) if errors else None,
        "timing_ms": timing,
    }

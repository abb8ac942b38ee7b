"""Metrics of a run, computed from its ``frames.csv`` rows alone (so they can be recomputed).

Which frames count:

- *in view*: the part (at its true pose) has at least one feature point projecting inside at
  least one camera's image, hidden or not (its true occluder label is neither ``outside`` nor
  ``behind``);
- *evaluated*: every in-view frame from the first frame with an estimate on, through the whole
  task (approach, grasp, manipulate, release and after): nothing is left out because the
  estimate is no longer used for control.

Estimation errors over the evaluated frames that have an estimate: ``position_rmse_mm``,
``orientation_rmse_deg`` (the angle of ``R_est^T R_true``), ``max_position_error_mm``; the
per-frame PnP baseline on the same measurements over the evaluated frames where it has a pose:
``pnp_position_rmse_mm``, ``pnp_orientation_rmse_deg``. ``lost_in_view_s``: seconds of evaluated
frames without an estimate (each frame counts one vision period). ``in_view_fraction``: fraction
of the frames from the first estimate on that are in view. ``phases``: the same figures per task
phase (``approach``, ``grasp``, ``manipulate``, ``release``), each over that phase's evaluated
frames.

Visibility: ``visibility_accuracy`` is the fraction of frame x camera x feature labels *in
view* (the feature projects inside that camera's image) where the prediction (at the tracker's
predicted pose) equals the simulator's truth; ``visibility_accuracy_all`` the same over every
label of every frame (out-of-view labels are trivially right). ``false_visible`` counts labels
predicted visible but truly hidden, ``false_hidden`` the reverse, over every label.

Measurements, over all frames: ``measurements`` (features measured), ``rejected_measurements``
(of those, rejected by the EKF's gate), ``wrong_measurements`` (measured more than ``WRONG_PX``
from the true projection: another image point, such as an occluder's corner),
``wrong_accepted`` (wrong and not rejected). ``pixels_grabbed_fraction``: mean over frames and
cameras of the fraction of pixels grabbed. ``extraction_error_px_median``: median over frames
and cameras of each frame's median extraction error (px); None when no frame has one (ideal
sensor). ``timing_ms``: median per stage (ms) over the frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.experiments.framelog import POSE, STAGES
from cellsight.geometry.transforms import pose_errors

PHASES = ("approach", "grasp", "manipulate", "release")
OUT_OF_VIEW = ("outside", "behind")  # true occluder labels of a feature not in the image


def _pose_columns(rows: Sequence[dict[str, str]], prefix: str) -> np.ndarray:
    """(n, 6) poses, NaN rows where missing."""
    out = np.full((len(rows), 6), np.nan)
    for i, row in enumerate(rows):
        if row[f"{prefix}_x"] != "":
            out[i] = [float(row[f"{prefix}_{a}"]) for a in POSE]
    return out


def _bits(text: str) -> np.ndarray:
    """A '0'/'1' string as a boolean mask."""
    return np.frombuffer(text.encode(), dtype=np.uint8) == ord("1")


def _in_image(row: dict[str, str], c: int) -> np.ndarray:
    """Per feature: truly projects inside camera ``c``'s image (1-based)."""
    return np.array([r not in OUT_OF_VIEW for r in row[f"occ_true_c{c}"].split(";")])


def _rmse(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else None


def _scaled(x: float | None, factor: float) -> float | None:
    return None if x is None else x * factor


def evaluated_frames(rows: Sequence[dict[str, str]], n_cameras: int) -> np.ndarray:
    """Boolean mask over rows: in view and at or after the first estimate (module docstring)."""
    start = next((i for i, r in enumerate(rows) if r["est_x"] != ""), len(rows))
    in_view = np.array([any(_in_image(r, c).any() for c in range(1, n_cameras + 1))
                        for r in rows], dtype=bool)
    after = np.arange(len(rows)) >= start
    return in_view & after


def _errors(est: np.ndarray, pnp: np.ndarray, truth: np.ndarray, mask: np.ndarray,
            period: float) -> dict:
    """The estimation figures over the rows in ``mask``."""
    est_pos, est_ang = pose_errors(est[mask], truth[mask])
    pnp_pos, pnp_ang = pose_errors(pnp[mask], truth[mask])
    finite = est_pos[np.isfinite(est_pos)]
    return {
        "evaluated_frames": int(mask.sum()),
        "position_rmse_mm": _scaled(_rmse(est_pos), 1e3),
        "orientation_rmse_deg": _scaled(_rmse(est_ang), 180.0 / np.pi),
        "max_position_error_mm": float(finite.max() * 1e3) if len(finite) else None,
        "pnp_position_rmse_mm": _scaled(_rmse(pnp_pos), 1e3),
        "pnp_orientation_rmse_deg": _scaled(_rmse(pnp_ang), 180.0 / np.pi),
        "lost_in_view_s": round(float(np.sum(~np.isfinite(est_pos))) * period, 4),
    }


def frame_metrics(rows: Sequence[dict[str, str]], n_cameras: int) -> dict:
    """The metrics of the module docstring from ``frames.csv`` rows (dicts of strings)."""
    truth = _pose_columns(rows, "true")
    est, pnp = _pose_columns(rows, "est"), _pose_columns(rows, "pnp")
    t = np.array([float(r["t"]) for r in rows])
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    evaluated = evaluated_frames(rows, n_cameras)
    first = int(np.argmax(np.isfinite(est[:, 0]))) if np.isfinite(est[:, 0]).any() else None
    phase = np.array([r["phase"] for r in rows])
    agree = total = false_visible = false_hidden = agree_in_view = in_view = 0
    counts = dict.fromkeys(("measurements", "rejected_measurements", "wrong_measurements",
                            "wrong_accepted"), 0)
    grabbed, px_errors = [], []
    for row in rows:
        for c in range(1, n_cameras + 1):
            pred, true = _bits(row[f"vis_pred_c{c}"]), _bits(row[f"vis_true_c{c}"])
            inside = _in_image(row, c)
            agree += int(np.sum(pred == true))
            total += len(pred)
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
                px_errors.append(float(row[f"err_px_c{c}"]))
    timing = {
        s: float(np.median([float(r[f"t_{s}_ms"]) for r in rows])) if rows else None
        for s in STAGES
    }
    after_first = np.arange(len(rows)) >= (first if first is not None else len(rows))
    return {
        "frames": len(rows),
        "first_estimate_s": None if first is None else float(t[first]),
        "in_view_fraction": (float(evaluated.sum() / after_first.sum())
                             if after_first.any() else None),
        **_errors(est, pnp, truth, evaluated, period),
        "phases": {p: _errors(est, pnp, truth, evaluated & (phase == p), period)
                   for p in PHASES},
        "visibility_accuracy": agree_in_view / in_view if in_view else None,
        "visibility_accuracy_all": agree / total if total else None,
        "false_visible": false_visible,
        "false_hidden": false_hidden,
        **counts,
        "pixels_grabbed_fraction": float(np.mean(grabbed)) if grabbed else None,
        "extraction_error_px_median": float(np.median(px_errors)) if px_errors else None,
        "timing_ms": timing,
    }

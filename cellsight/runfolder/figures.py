"""Metrics of a run, computed from its ``frames.csv`` alone (so they can be recomputed from any
run folder, old ones included): :func:`frame_metrics`.

Which frames count:

- *in view*: the part (at its true pose) has at least one feature point projecting inside at
  least one camera's image, hidden or not (its true occluder label is neither ``outside`` nor
  ``behind``);
- *evaluated*: every in-view frame from the first frame with an estimate on, through the whole
  task (approach, grasp, manipulate, release and after): nothing is left out because the
  estimate is no longer used for control.

A frame without a truth (a tracked recording that has no true pose there: empty ``vis_true``)
is never in view; a log without any truth has no estimation, visibility or wrong-corner
figures (None).

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
(of those, rejected by the EKF's gate), ``wrong_measurements`` (measured more than
:data:`~cellsight.runfolder.framelog.WRONG_PX` from the true projection: another image point,
such as an occluder's corner), ``wrong_accepted`` (wrong, not rejected, and used: frames of a
part being acquired, ``waiting`` or ``lost``, used nothing: no fix came of them, nor did a
camera the camera check held out of the filter, ``held_out_c{c}``).
``pixels_grabbed_fraction``: mean over frames and cameras of the fraction of pixels grabbed.
``extraction_error_px_median``: median over frames and cameras of each frame's median extraction
error (px); None when no frame has one (ideal sensor). ``timing_ms``: median per stage (ms)
over the frames. Health (the tracker's statuses, :mod:`cellsight.tracking.health`):
``degraded_s`` (seconds with the status ``degraded``), ``degraded_episodes`` (how many times it
became degraded), ``confident_wrong_frames`` (evaluated frames more than
:data:`CONFIDENT_WRONG_MM` off while the status says ``tracking``: the failure that matters)
and ``max_error_tracking_mm`` (the largest error over the evaluated frames said ``tracking``).
``fewest_visible``: per working phase, per camera, the fewest features truly
visible in any frame of it (how deeply the occluders blinded each camera: experiment 3's
meaning, per seed), each camera at its own worst frame, not at one instant.
:func:`position_rmse_in_arm_frame_mm` takes one more input, an arm's own error (the world's
truth, not in the log): the run's ``position_rmse_arm_mm``.
"""

from __future__ import annotations

import numpy as np

from cellsight.control import Phase
from cellsight.geometry.transforms import pose_errors
from cellsight.runfolder.framelog import FrameLog, camera_column, timing_column
from cellsight.tracking.timing import STAGES
from cellsight.visibility import BEHIND, OUTSIDE

PHASES = tuple(str(p) for p in Phase.working())  # the task's phases, in order
OUT_OF_VIEW = (OUTSIDE, BEHIND)  # true occluder labels of a feature not in the image
CONFIDENT_WRONG_MM = 10.0  # mm: an estimate this far off while the status says tracking


def _per_camera(log: FrameLog, name: str, decode: str) -> np.ndarray:
    """(N, C, F) of a per-camera column, ``decode`` 'bits' (bool) or 'labels' (str)."""
    read = log.bits if decode == "bits" else log.labels
    F = log.n_features
    out = [read(camera_column(name, c), F) for c in range(1, log.n_cameras + 1)]
    return np.stack(out, axis=1) if out else np.zeros((log.n, 0, F), dtype=bool)


def in_image(log: FrameLog) -> np.ndarray:
    """(N, C, F) bool: the feature truly projects inside that camera's image."""
    return ~np.isin(_per_camera(log, "occ_true", "labels"), OUT_OF_VIEW)


def evaluated_frames(log: FrameLog) -> np.ndarray:
    """(N,) bool: in view and at or after the first estimate (module docstring)."""
    has_estimate = log.present("est_x")
    start = int(np.argmax(has_estimate)) if has_estimate.any() else log.n
    in_view = in_image(log).any(axis=(1, 2)) & _truth_rows(log)
    return in_view & (np.arange(log.n) >= start)


def _rmse(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else None


def _scaled(x: float | None, factor: float) -> float | None:
    return None if x is None else x * factor


def _errors(est: np.ndarray, pnp: np.ndarray, truth: np.ndarray, mask: np.ndarray,
            period: float) -> dict:
    """The estimation figures over the rows in ``mask`` (poses (N, 6), NaN where missing;
    ``period``: one frame's duration, s)."""
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


def _estimation(log: FrameLog) -> dict:
    """First estimate, in-view fraction and the estimation errors, whole run and per phase."""
    truth, est, pnp = log.poses("true"), log.poses("est"), log.poses("pnp")
    t = log.floats("t")
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    evaluated = evaluated_frames(log)
    has_estimate = np.isfinite(est[:, 0])
    first = int(np.argmax(has_estimate)) if has_estimate.any() else None
    after_first = np.arange(log.n) >= (first if first is not None else log.n)
    phase = np.array(log.text("phase"))
    return {
        "first_estimate_s": None if first is None else float(t[first]),
        "in_view_fraction": (float(evaluated.sum() / after_first.sum())
                             if after_first.any() and _truth_rows(log).any() else None),
        **_errors(est, pnp, truth, evaluated, period),
        "phases": {p: _errors(est, pnp, truth, evaluated & (phase == p), period)
                   for p in PHASES},
    }


def position_rmse_in_arm_frame_mm(log: FrameLog, arm_error_m: np.ndarray) -> float | None:
    """``position_rmse_mm`` against the true positions as an arm's model sees them: each less
    ``arm_error_m`` (3,) m, where the arm's TCP truly stands less where its model puts it
    (``arm_home_error_mm`` of ``metrics.json``). Cameras registered to that arm take its error
    in, and so does every estimate made with them: this is the error no image of the cell
    shows (None: no evaluated frame with an estimate)."""
    truth, est = log.poses("true"), log.poses("est")
    mask = evaluated_frames(log)
    gap = est[mask, :3] - (truth[mask, :3] - np.asarray(arm_error_m, dtype=float))
    return _scaled(_rmse(np.linalg.norm(gap, axis=1)), 1e3)


def _visibility(log: FrameLog) -> dict:
    """Predicted against true visibility labels (module docstring), over the frames that have
    a truth (a recording may have none: then None)."""
    known = _truth_rows(log)
    if not known.any():
        return dict.fromkeys(("visibility_accuracy", "visibility_accuracy_all", "false_visible",
                              "false_hidden"))
    pred = _per_camera(log, "vis_pred", "bits")[known]
    true = _per_camera(log, "vis_true", "bits")[known]
    inside = in_image(log)[known]
    agree = pred == true
    return {
        "visibility_accuracy": (int(np.sum(agree & inside)) / int(inside.sum())
                                if inside.any() else None),
        "visibility_accuracy_all": int(agree.sum()) / agree.size if agree.size else None,
        "false_visible": int(np.sum(pred & ~true)),
        "false_hidden": int(np.sum(~pred & true)),
    }


def _health(log: FrameLog) -> dict:
    """The tracker's health statuses against the truth (module docstring)."""
    status = np.array(log.text("status"), dtype=str)
    degraded = np.char.startswith(status, "degraded")
    t = log.floats("t")
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    error_mm = pose_errors(log.poses("est"), log.poses("true"))[0] * 1e3
    tracking = evaluated_frames(log) & (status == "tracking") & np.isfinite(error_mm)
    starts = degraded & ~np.concatenate([[False], degraded[:-1]])
    return {
        "degraded_s": round(float(degraded.sum()) * period, 4),
        "degraded_episodes": int(starts.sum()),
        "confident_wrong_frames": int(np.sum(error_mm[tracking] > CONFIDENT_WRONG_MM)),
        "max_error_tracking_mm": float(error_mm[tracking].max()) if tracking.any() else None,
    }


def _measurements(log: FrameLog) -> dict:
    """Measurement counts, pixels grabbed and extraction error (module docstring)."""
    meas, rej, wrong = (_per_camera(log, k, "bits") for k in ("meas", "rej", "wrong"))
    grabbed, px = (_row_major(log, name) for name in ("grab", "err_px"))
    px = px[np.isfinite(px)]
    return {
        "measurements": int(meas.sum()),
        "rejected_measurements": int(rej.sum()),
        "wrong_measurements": int(wrong.sum()) if _truth_rows(log).any() else None,
        "wrong_accepted": (int(np.sum((wrong & ~rej)[log.used_by_camera()]))
                           if _truth_rows(log).any() else None),
        "pixels_grabbed_fraction": float(np.mean(grabbed)) if grabbed.size else None,
        "extraction_error_px_median": float(np.median(px)) if px.size else None,
    }


def _row_major(log: FrameLog, name: str) -> np.ndarray:
    """A per-camera float column of every camera, frame by frame (N * C,)."""
    values = [log.floats(camera_column(name, c)) for c in range(1, log.n_cameras + 1)]
    return np.column_stack(values).ravel() if values else np.zeros(0)


def _timing(log: FrameLog) -> dict[str, float | None]:
    """Median time per tracker stage (ms) over the frames that have it."""
    out: dict[str, float | None] = {}
    for s in STAGES:
        ms = log.floats(timing_column(s))
        ms = ms[np.isfinite(ms)]
        out[s] = float(np.median(ms)) if ms.size else None
    return out


def fewest_visible(log: FrameLog) -> dict[str, list[int]]:
    """Per working phase, per camera: the fewest features truly visible in any of its frames
    (how deeply an occluder blinded each camera; an experiment's meaning, checked per seed)."""
    known = _truth_rows(log)
    visible = _per_camera(log, "vis_true", "bits").sum(axis=2)[known]
    phases = np.array(log.text("phase"))[known]
    return {p: visible[phases == p].min(axis=0).astype(int).tolist()
            for p in PHASES if np.any(phases == p)}


def _truth_rows(log: FrameLog) -> np.ndarray:
    """(N,) bool: the frames with the simulator's (or a recording's) visibility truth."""
    if log.n_cameras == 0:
        return np.zeros(log.n, dtype=bool)
    return log.present(camera_column("vis_true", 1))


def frame_metrics(log: FrameLog) -> dict:
    """The metrics of the module docstring from a run's frame log."""
    return {
        "frames": log.n,
        "fewest_visible": fewest_visible(log),
        **_estimation(log),
        **_visibility(log),
        **_measurements(log),
        **_health(log),
        "timing_ms": _timing(log),
    }

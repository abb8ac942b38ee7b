"""A run's metrics as flat table rows (``cellsight run``'s summary, ``cellsight compare``)."""

from __future__ import annotations

SUMMARY_KEYS = (
    "experiment", "seed", "realism", "structure", "sensor", "tracker",
    "occlusion_prediction", "kinematic_prior", "frames",
    "grasp_success", "grasp_position_error_mm", "in_view_fraction", "lost_in_view_s",
    "position_rmse_mm", "orientation_rmse_deg", "max_position_error_mm", "pnp_position_rmse_mm",
    "pnp_orientation_rmse_deg", "visibility_accuracy", "visibility_accuracy_all",
    "false_visible", "false_hidden", "measurements", "rejected_measurements",
    "wrong_measurements", "wrong_accepted", "pixels_grabbed_fraction",
    "extraction_error_px_median", "frames_dropped", "collision_count", "wall_s",
)


PHASE_SUMMARY_KEYS = ("position_rmse_mm", "max_position_error_mm", "orientation_rmse_deg",
                      "lost_in_view_s")


def metric_rows(metrics: dict) -> dict[str, object]:
    """The scalar metrics, the per-phase errors flattened to ``<phase>_<metric>`` and the
    stage timings to ``timing_<stage>_ms``."""
    rows = {k: metrics.get(k) for k in SUMMARY_KEYS}
    for phase, figures in (metrics.get("phases") or {}).items():
        rows.update({f"{phase}_{k}": figures.get(k) for k in PHASE_SUMMARY_KEYS})
    rows.update({f"timing_{k}_ms": v for k, v in (metrics.get("timing_ms") or {}).items()})
    return rows

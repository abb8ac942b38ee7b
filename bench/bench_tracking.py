"""Per-frame cost of the tracking loop (paper Fig. 5) without image processing.

The built-in cell's workpiece (16 feature points) rides the conveyor past its two cameras. Per
frame, on the same data for every stage:

- predict: EKF prediction to the frame time and the predicted pose;
- selection: optimal selection (at most 11 points) among the features the BSP predictor finds
  visible at the predicted pose;
- windowing: innovation covariances of the selected features and the window plan, both cameras;
- update: observations of the windowed features (true projections + 0.5 px noise, made outside
  the timed region) and the gated Joseph-form EKF update;
- total: the sum of the four, against the 0.5 ms budget.

The BSP occlusion prediction (``cellsight.occlusion``, benchmarked in bench_cell_occlusion) is
timed alongside for reference, outside the total. A second scenario makes all 16 points visible
in both cameras (32 candidates, the selection's worst case). Medians over warm frames.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from cellsight import load_cell
from cellsight.geometry.transforms import pose_from_xyz_rpy, xyz_rpy_from_pose
from cellsight.occlusion.backends import visibility_predictor
from cellsight.rates import VISION_HZ
from cellsight.tracking import (
    ChiSquareGate,
    ConstantVelocity,
    Observation,
    PinholeMeasurement,
    PoseEKF,
    plan_windows,
    select_features,
)

FRAMES = 260
WARMUP = 20
PERIOD = 1.0 / VISION_HZ
BUDGET_S = 0.5e-3
GATE = ChiSquareGate()  # the tracker's default gate
STAGES = ("predict", "selection", "windowing", "update")


def _trajectory(t: float, T0: np.ndarray) -> np.ndarray:
    xyz, rpy = xyz_rpy_from_pose(T0)
    return pose_from_xyz_rpy(
        xyz + [0.05 * t - 0.1, 0.01 * np.sin(0.8 * t), 0.0], rpy + [0.0, 0.0, 0.1 * np.sin(t)]
    )


def _scenario(all_visible: bool, seed: int = 0) -> dict[str, list[float]]:
    cell = load_cell()
    part = cell.workpieces[0]
    cams = cell.cameras
    models = [PinholeMeasurement(c, 0.5) for c in cams]
    predictor = visibility_predictor(cell)
    rng = np.random.default_rng(seed)
    pts = part.feature_points
    T0 = _trajectory(0.0, part.T_base_part)
    xyz, rpy = xyz_rpy_from_pose(T0)
    P0 = np.diag([1e-6] * 3 + [1e-4] * 3 + [1e-3] * 6)
    ekf = PoseEKF(ConstantVelocity(), np.concatenate([xyz, rpy, np.zeros(6)]), P0, 0.0)
    times: dict[str, list[float]] = {s: [] for s in (*STAGES, "total", "occlusion (BSP)")}
    for k in range(1, FRAMES + WARMUP):
        t = k * PERIOD
        T_true = _trajectory(t, part.T_base_part)
        true_px = [c.project(pts @ T_true[:3, :3].T + T_true[:3, 3]) for c in cams]

        t0 = time.perf_counter()
        ekf.predict(t)
        T_pred = ekf.pose
        t1 = time.perf_counter()
        vis = predictor.predict(None, {part.name: T_pred})[part.name]
        t2 = time.perf_counter()
        pixels = np.stack([v.pixels for v in vis])
        visible = np.stack([v.visible for v in vis])
        if all_visible:
            visible[:] = True
        centroid = pts.mean(axis=0) @ T_pred[:3, :3].T + T_pred[:3, 3]
        rho = np.array([c.focal_px / c.depth(centroid[None])[0] for c in cams])
        sel = select_features(pixels, visible, rho)
        t3 = time.perf_counter()
        plans = []
        for c, cam in enumerate(cams):
            idx = np.flatnonzero(sel.selected[c])
            own = np.searchsorted(np.flatnonzero(visible[c]), idx)
            _, S = ekf.innovation_covariance(models[c], c, pts[idx])
            plans.append(plan_windows(pixels[c, idx], idx, S, cam.width, cam.height,
                                      pixels[c][visible[c]], own))
        t4 = time.perf_counter()
        measured = [true_px[c][p.features] + rng.normal(0, 0.5, (len(p.features), 2))
                    for c, p in enumerate(plans)]
        t5 = time.perf_counter()
        obs = [Observation(models[c], c, p.features, pts[p.features], measured[c])
               for c, p in enumerate(plans) if len(p.features)]
        ekf.update(obs, GATE)
        t6 = time.perf_counter()
        if k <= WARMUP:
            continue
        stages = {"predict": t1 - t0, "selection": t3 - t2, "windowing": t4 - t3,
                  "update": t6 - t5}
        for s, v in stages.items():
            times[s].append(v)
        times["total"].append(sum(stages.values()))
        times["occlusion (BSP)"].append(t2 - t1)
    return times


def run() -> list[dict]:
    """One row per scenario and stage: median and 90th percentile per frame (s)."""
    rows = []
    for name, all_visible in (("built-in cell, BSP visibility", False),
                              ("all 16 points visible in both cameras", True)):
        times = _scenario(all_visible)
        for stage, values in times.items():
            rows.append({
                "scenario": name,
                "stage": stage,
                "median_s": statistics.median(values),
                "p90_s": float(np.percentile(values, 90)),
                "frames": len(values),
            })
    return rows


def main() -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Tracking loop per frame, 2 cameras, 16 points (no image processing)")
    for col in ("scenario", "stage", "median (us)", "p90 (us)", "budget 500 us"):
        table.add_column(col, justify="left" if col in ("scenario", "stage") else "right")
    for row in run():
        verdict = ""
        if row["stage"] == "total":
            verdict = "ok" if row["median_s"] <= BUDGET_S else "OVER"
        table.add_row(row["scenario"], row["stage"], f"{row['median_s'] * 1e6:.0f}",
                      f"{row['p90_s'] * 1e6:.0f}", verdict)
    Console().print(table)


if __name__ == "__main__":
    main()

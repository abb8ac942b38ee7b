"""A sweep's runs summed up over their seeds, and the paired comparisons of its variants.

A *group* is every finished run with the same cell, experiment, realism profile, structure,
sensor and variant. Per group (:func:`group_rows`): grasps that held, whole-task position RMSE
in the grasping arm's frame (what the grasp needs: mean with its 95 % confidence interval
(Student t), and worst seed), in the cell's frame (mean with its interval, 95th percentile and
worst seed), the 95th
percentile and worst of the per-run largest errors, orientation RMSE (mean, worst), in-view
visibility accuracy (mean and worst seed), time lost in view (worst), wrong corners accepted
(mean, worst), collisions (all seeds) and, for experiment 3, how many seeds the crossing
blinded as designed (:func:`crossing_as_designed`). The default tracker's variant
(``kinematic``) is compared with each other variant on the seeds both ran (:func:`paired_rows`):
on how many its RMSE is lower (in the arm's frame where both have it, else the cell's), and
the mean difference with its 95 % interval (the ``calibrated`` variant against it: what the
calibration brings, :func:`calibration_rows` its errors). The health table
(:func:`health_rows`) asks of each group whether the tracker knew when it was wrong: runs with
a frame more than 10 mm off while the status said ``tracking`` (and those frames in all), the
worst error while ``tracking``, wrong corners accepted as a percentage of the measurements
(all runs together, and the worst run), time degraded and runs that dropped a camera.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

from cellsight.sweep.grid import RunSpec

BASELINE = "kinematic"
"""The variant the others are compared with: the default tracker."""

GroupKey = tuple[str, int, str, str, str, str]


def group_key(spec: RunSpec) -> GroupKey:
    """The group a run belongs to: its cell, experiment, realism, structure, sensor and variant."""
    return (spec.folder.parent.name, spec.experiment, spec.realism, spec.structure,
            spec.sensor, spec.variant)


def _values(runs: list[dict], key: str) -> np.ndarray:
    return np.array([float(m[key]) for m in runs if m.get(key) is not None])


def mean_ci(x: np.ndarray) -> tuple[float, float]:
    """Mean and the half-width of its 95 % confidence interval (Student t; nan for n < 2)."""
    if len(x) == 0:
        return float("nan"), float("nan")
    if len(x) < 2:
        return float(x.mean()), float("nan")
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    return float(x.mean()), float(half)


def crossing_as_designed(metrics: dict) -> bool | None:
    """Experiment 3's meaning on one run (None for other experiments or missing figures): the
    crossing robot leaves at most two features visible in camera 2 during Approach or Grasp,
    and none in camera 1 during Manipulate (``fewest_visible`` of ``metrics.json``)."""
    fewest = metrics.get("fewest_visible") or {}
    if metrics.get("experiment") != 3 or "manipulate" not in fewest:
        return None
    before = [fewest[p][1] for p in ("approach", "grasp") if p in fewest and len(fewest[p]) > 1]
    return bool(before) and min(before) <= 2 and fewest["manipulate"][0] == 0


def _groups(specs: Sequence[RunSpec], results: Sequence[dict]) -> dict[GroupKey, dict]:
    groups: dict[GroupKey, dict] = {}
    for spec, m in zip(specs, results, strict=True):
        g = groups.setdefault(group_key(spec), {"runs": [], "seeds": [], "failed": 0})
        if m.get("error"):
            g["failed"] += 1
        else:
            g["runs"].append(m)
            g["seeds"].append(spec.seed)
    return groups


def _fmt(x: float, pattern: str = "{:.2f}") -> str:
    return "–" if not np.isfinite(x) else pattern.format(x)


def _stat(x: np.ndarray, how: str, pattern: str = "{:.2f}") -> str:
    """``how`` (mean, p95, max, min) of ``x``, formatted; "–" when ``x`` is empty."""
    if len(x) == 0:
        return "–"
    value = {"mean": np.mean, "max": np.max, "min": np.min,
             "p95": lambda v: np.percentile(v, 95)}[how](x)
    return _fmt(float(value), pattern)


def _group_row(key: GroupKey, g: dict) -> list[str]:
    runs = g["runs"]
    rmse, peak = _values(runs, "position_rmse_mm"), _values(runs, "max_position_error_mm")
    orient, vis = _values(runs, "orientation_rmse_deg"), _values(runs, "visibility_accuracy")
    lost, wrong = _values(runs, "lost_in_view_s"), _values(runs, "wrong_accepted")
    mean, half = mean_ci(rmse)
    arm = _values(runs, "position_rmse_arm_mm")
    arm_mean, arm_half = mean_ci(arm)
    held = sum(bool(m.get("grasp_success")) for m in runs)
    crossing = [c for c in map(crossing_as_designed, runs) if c is not None]
    return [key[0], str(key[1]), key[2], key[3], key[4], key[5],
            f"{len(runs)}" + (f" (+{g['failed']} failed)" if g["failed"] else ""),
            f"{held}/{len(runs)}", f"{_fmt(arm_mean)} ± {_fmt(arm_half)}", _stat(arm, "max"),
            f"{_fmt(mean)} ± {_fmt(half)}", _stat(rmse, "p95"),
            _stat(rmse, "max"), _stat(peak, "p95"), _stat(peak, "max"), _stat(orient, "mean"),
            _stat(orient, "max"), _stat(vis, "mean", "{:.4f}"), _stat(vis, "min", "{:.4f}"),
            _stat(lost, "max"), _stat(wrong, "mean", "{:.1f}"), _stat(wrong, "max", "{:.0f}"),
            str(sum(int(m.get("collision_count") or 0) for m in runs)),
            f"{sum(crossing)}/{len(crossing)}" if crossing else "–"]


GROUP_HEADER = ["cell", "exp.", "realism", "structure", "sensor", "variant", "seeds", "grasps",
                "arm-frame pos. RMSE mm, mean ± 95% CI", "worst",
                "cell-frame pos. RMSE mm, mean ± 95% CI", "p95", "worst", "max err. mm p95",
                "worst",
                "orient. RMSE deg mean", "worst", "vis. acc. mean", "worst seed",
                "lost in view s, worst", "wrong accepted mean", "worst", "collisions",
                "crossing as designed"]


def group_rows(specs: Sequence[RunSpec], results: Sequence[dict]) -> list[list[str]]:
    """One row of :data:`GROUP_HEADER` per group of runs (module docstring)."""
    return [_group_row(k, g) for k, g in _groups(specs, results).items()]


def _health_row(key: GroupKey, g: dict) -> list[str]:
    runs = g["runs"]
    wrong = np.array([float(m.get("confident_wrong_frames") or 0) for m in runs])
    worst = _values(runs, "max_error_tracking_mm")
    accepted = np.array([float(m.get("wrong_accepted") or 0) for m in runs])
    measured = np.array([float(m.get("measurements") or 0) for m in runs])
    share = 100 * accepted / np.maximum(measured, 1)
    whole = 100 * accepted.sum() / max(measured.sum(), 1)
    return [key[0], str(key[1]), key[2], key[3], key[4], key[5], str(len(runs)),
            f"{int(np.sum(wrong > 0))} ({int(wrong.sum())})", _stat(worst, "max", "{:.1f}"),
            f"{_fmt(whole)} ({_stat(share, 'max')})",
            _stat(_values(runs, "degraded_s"), "mean", "{:.1f}"),
            str(sum(bool(m.get("cameras_dropped")) for m in runs))]


HEALTH_HEADER = ["cell", "exp.", "realism", "structure", "sensor", "variant", "seeds",
                 "runs with a frame >10 mm off said `tracking` (frames in all)",
                 "worst error while `tracking` mm",
                 "wrong corners accepted, % of measurements (worst run)",
                 "degraded s, mean", "runs that dropped a camera"]


def health_rows(specs: Sequence[RunSpec], results: Sequence[dict]) -> list[list[str]]:
    """One row of :data:`HEALTH_HEADER` per group of runs (module docstring)."""
    return [_health_row(k, g) for k, g in _groups(specs, results).items()]


def _paired_values(g: dict, other: dict) -> tuple[dict, dict, str]:
    """Seed -> RMSE (mm) of two groups: in the grasping arm's frame where both runs of every
    seed have it, else in the cell's frame (a plain tracker's run has no arm-frame figure)."""
    for key in ("position_rmse_arm_mm", "position_rmse_mm"):
        a = {s: m.get(key) for s, m in zip(g["seeds"], g["runs"], strict=True)}
        b = {s: m.get(key) for s, m in zip(other["seeds"], other["runs"], strict=True)}
        common = [s for s in a if s in b]
        if all(a[s] is not None and b[s] is not None for s in common):
            break
    frame = "arm" if key == "position_rmse_arm_mm" else "cell"
    keep = [s for s in common if a[s] is not None and b[s] is not None]
    return {s: a[s] for s in keep}, {s: b[s] for s in keep}, frame


def paired_rows(specs: Sequence[RunSpec], results: Sequence[dict]) -> list[list[str]]:
    """Per group and variant after the first: the first variant against it on their common
    seeds (module docstring)."""
    groups = _groups(specs, results)
    rows = []
    for key, g in groups.items():
        if key[5] != BASELINE:
            continue
        others = [(k, o) for k, o in groups.items() if k[:5] == key[:5] and k[5] != key[5]]
        for other_key, other in others:
            a, b, frame = _paired_values(g, other)
            seeds = list(a)  # the seeds both ran, each with its figure
            diff = np.array([b[s] - a[s] for s in seeds])
            better = int(np.sum(diff > 0))
            mean, half = mean_ci(diff)
            rows.append([key[0], str(key[1]), key[2], key[3], key[4],
                         f"{key[5]} vs {other_key[5]} ({frame} frame)", f"{better}/{len(seeds)}",
                         f"{_fmt(mean)} ± {_fmt(half)}"])
    return rows


PAIRED_HEADER = ["cell", "exp.", "realism", "structure", "sensor", "comparison",
                 f"seeds where {BASELINE} has the lower RMSE",
                 f"RMSE gain mm (other - {BASELINE}), mean ± 95% CI"]


CALIBRATION_HEADER = ["cell", "realism", "calibrations", "camera at the work area mm, mean",
                      "worst", "camera rotation deg, mean", "worst", "focal %, mean", "worst",
                      "principal point px, mean", "worst", "image at the work area px, mean",
                      "worst", "the cell file's, mean", "worst", "other robots' bases mm, mean",
                      "worst", "the cell file's, mean", "other robots' bases deg, worst"]


def calibration_rows(specs: Sequence[RunSpec], results: Sequence[dict]) -> list[list[str]]:
    """Per cell and realism, the calibrations the ``calibrated`` runs took (one per seed):
    each estimate's error against the world's truth (``calibration_errors`` of the runs'
    metrics, :mod:`cellsight.calibration.score`), mean and worst over the seeds and the
    cameras, or the other robots' bases; beside the image and the bases, the cell file's own
    (where the calibration started; "–" for calibrations made before they were kept)."""
    by_world: dict[tuple[str, str], dict[int, dict]] = {}
    for spec, m in zip(specs, results, strict=True):
        if m.get("calibration_errors") and not m.get("error"):
            key = (spec.folder.parent.name, spec.realism)
            by_world.setdefault(key, {})[spec.seed] = m["calibration_errors"]
    rows = []
    for (cell, realism), per_seed in by_world.items():
        cameras = [e for errors in per_seed.values() for e in errors["cameras"].values()]
        bases = [e for errors in per_seed.values() for e in errors["robots"].values()]
        before = [errors.get("cell_file", {}) for errors in per_seed.values()]
        cameras_before = [e for b in before for e in b.get("cameras", {}).values()]
        bases_before = [e for b in before for e in b.get("robots", {}).values()]

        def both(items: list[dict], key: str, pattern: str = "{:.2f}") -> list[str]:
            x = np.array([float(e[key]) for e in items])
            return [_stat(x, "mean", pattern), _stat(x, "max", pattern)]

        rows.append([cell, realism, str(len(per_seed)),
                     *both(cameras, "position_at_work_mm"),
                     *both(cameras, "rotation_deg", "{:.3f}"),
                     *both(cameras, "focal_percent", "{:.3f}"),
                     *both(cameras, "principal_point_px"), *both(cameras, "image_at_work_px"),
                     *both(cameras_before, "image_at_work_px"), *both(bases, "origin_mm"),
                     both(bases_before, "origin_mm")[0],
                     both(bases, "rotation_deg", "{:.3f}")[1]])
    return rows


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *["| " + " | ".join(r) + " |" for r in rows]]


def aggregate_markdown(specs: Sequence[RunSpec], results: Sequence[dict]) -> str:
    """The group and health tables and, when the sweep has them, the paired comparisons
    (Markdown)."""
    lines = ["Over the seeds of each group (whole task, every frame in view):", "",
             *_table(GROUP_HEADER, group_rows(specs, results))]
    lines += ["", "Does the tracker know when it is wrong (the same groups):", "",
              *_table(HEALTH_HEADER, health_rows(specs, results))]
    paired = paired_rows(specs, results)
    if paired:
        lines += ["", f"Paired on the same seeds (`{BASELINE}`, the default tracker, against "
                  "each other variant):", "",
                  *_table(PAIRED_HEADER, paired)]
    calibrations = calibration_rows(specs, results)
    if calibrations:
        lines += ["", "The calibrations the `calibrated` runs took (`cellsight calibrate` in "
                  "each run's own world, one per seed), against the world's truth:", "",
                  *_table(CALIBRATION_HEADER, calibrations)]
    return "\n".join(lines) + "\n"

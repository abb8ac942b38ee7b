"""``cellsight sweep`` (issue 15): the grid, resuming, the summary, and the same results on a
local pool and on a Dask ``LocalCluster`` (each run's own metrics.json is the oracle)."""

from __future__ import annotations

import csv
import json

import pytest

from cellsight.cli import main
from cellsight.errors import CellsightError
from cellsight.sweep.command import run_sweep
from cellsight.sweep.engine import map_jobs
from cellsight.sweep.grid import RunSpec, SweepAxes, sweep_grid

DURATION = 0.6  # s of simulated time per run: a few frames, enough to compare
COMPARED = ("frames", "position_rmse_mm", "max_position_error_mm", "visibility_accuracy",
            "measurements")


def _square(x: int) -> int:
    return x * x


def _crash(x: int) -> int:
    """A segmentation fault in native code (reading address 0) on job 1."""
    if x == 1:
        import ctypes
        ctypes.string_at(0)
    return x


def test_grid_is_the_product_with_comparisons_on_the_first_seeds():
    specs = sweep_grid(SweepAxes(["dual-arm", "ur-cell"], [1, 3], ["ideal"],
                                 ["kinematic", "nopred"], [0, 1, 2]), variant_seeds=1)
    assert len(specs) == 2 * 2 * (3 + 1)
    assert {s.seed for s in specs if s.variant == "nopred"} == {0}
    assert len({s.folder for s in specs}) == len(specs)
    assert str(RunSpec("cells/my_cell.yaml", 3, "ideal", "kinematic", 2).folder) == \
        "my_cell/e3_ideal_kinematic_s2"


@pytest.mark.parametrize("kwargs, needle", [
    ({"sensors": ["camera"]}, "--sensors"), ({"variants": ["fast"]}, "--variants"),
    ({"experiments": [4]}, "--experiments"), ({"seeds": [-1]}, "--seeds"),
    ({"variant_seeds": 0}, "--variant-seeds")])
def test_grid_refuses_bad_values(kwargs, needle):
    args = {"cells": ["dual-arm"], "experiments": [1], "sensors": ["ideal"],
            "variants": ["kinematic"], "seeds": [0]} | kwargs
    variant_seeds = args.pop("variant_seeds", None)
    with pytest.raises(CellsightError, match=needle):
        sweep_grid(SweepAxes(**args), variant_seeds)


def test_engine_gives_every_result_once_in_process_and_on_a_pool():
    for workers in (1, 2):
        got = dict(map_jobs(_square, list(range(7)), workers=workers, progress=False))
        assert got == {i: i * i for i in range(7)}


def test_a_worker_that_crashes_in_native_code_prints_its_python_stack(capfd):
    from concurrent.futures.process import BrokenProcessPool

    with pytest.raises(BrokenProcessPool):
        dict(map_jobs(_crash, [0, 1], workers=2, progress=False))
    err = capfd.readouterr().err
    assert "Segmentation fault" in err and "in _crash" in err


@pytest.mark.slow
def test_a_crashing_job_is_recorded_and_the_others_still_run():
    """Job 1 kills its worker wherever it runs: it alone gets ``on_crash``'s result, every
    other job its own, on a pool of 2 (the job running beside it is run again)."""
    got = dict(map_jobs(_crash, list(range(7)), workers=2, progress=False,
                        on_crash=lambda job: f"crashed {job}"))
    assert got == {0: 0, 1: "crashed 1", 2: 2, 3: 3, 4: 4, 5: 5, 6: 6}


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    specs = sweep_grid(SweepAxes(["dual-arm"], [1, 3], ["ideal"], ["kinematic"], [0]),
                       duration=DURATION)
    return out, specs, run_sweep(specs, out, jobs=2, progress=False)


def test_sweep_writes_each_run_and_a_summary_of_them(local_sweep):
    out, specs, results = local_sweep
    with (out / "summary.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(specs)
    for spec, metrics, row in zip(specs, results, rows, strict=True):
        own = json.loads((out / spec.folder / "metrics.json").read_text())
        assert own["experiment"] == spec.experiment == int(row["experiment"])
        for key in COMPARED:
            assert metrics[key] == own[key]
            assert float(row[key]) == pytest.approx(float(own[key]))
    assert (out / "summary.png").stat().st_size > 10_000
    assert "pos. RMSE mm" in (out / "summary.md").read_text()


def test_sweep_resumes_finished_runs_and_redoes_interrupted_ones(local_sweep):
    out, specs, _ = local_sweep
    first, second = (out / s.folder / "metrics.json" for s in specs)
    interrupted = json.loads(second.read_text()) | {"interrupted": True, "signal": "SIGINT"}
    second.write_text(json.dumps(interrupted))
    stamp = first.stat().st_mtime_ns
    results = run_sweep(specs, out, jobs=1, progress=False)
    assert results[0].get("reused") and first.stat().st_mtime_ns == stamp
    assert not results[1].get("reused") and not json.loads(second.read_text())["interrupted"]


@pytest.mark.slow
def test_dask_cluster_gives_the_local_results(local_sweep, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, specs, local = local_sweep
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        status = main(["sweep", "--out", str(tmp_path), "--experiments", "1", "3",
                       "--sensors", "ideal", "--duration", str(DURATION), "--quiet",
                       "--scheduler", cluster.scheduler_address])
    assert status == 0
    for spec, metrics in zip(specs, local, strict=True):
        remote = json.loads((tmp_path / spec.folder / "metrics.json").read_text())
        assert {k: remote[k] for k in COMPARED} == {k: metrics[k] for k in COMPARED}


def test_unreachable_scheduler_is_a_clear_error(tmp_path, capsys):
    status = main(["sweep", "--out", str(tmp_path), "--experiments", "1", "--sensors", "ideal",
                   "--duration", "0.1", "--quiet", "--scheduler", "tcp://127.0.0.1:9",
                   "--scheduler-timeout", "1"])
    assert status == 2
    assert "--scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_on_a_cell_file_changed_since_is_run_again(tmp_path):
    from cellsight.model.loader import cell_path

    cell = tmp_path / "my_cell.yaml"
    cell.write_text(cell_path("dual-arm").read_text())
    specs = sweep_grid(SweepAxes([str(cell)], [1], ["ideal"], ["kinematic"], [0]), duration=0.2)
    run_sweep(specs, tmp_path / "out", jobs=1, progress=False)
    assert run_sweep(specs, tmp_path / "out", jobs=1, progress=False)[0].get("reused")
    cell.write_text(cell.read_text() + "\n# moved a camera\n")
    again = run_sweep(specs, tmp_path / "out", jobs=1, progress=False)[0]
    assert not again.get("reused") and not again.get("error")


def test_groups_over_seeds_and_paired_comparison_against_numpy():
    import numpy as np
    from scipy import stats

    from cellsight.sweep.aggregate import group_rows, mean_ci, paired_rows

    rng = np.random.default_rng(5)
    on, off = rng.uniform(0.5, 1.5, 8), rng.uniform(0.8, 2.0, 8)
    specs, results = [], []
    for variant, values in (("kinematic", on), ("nopred", off)):
        for seed, v in enumerate(values):
            specs.append(RunSpec("dual-arm", 3, "rendered", variant, seed, realism="lab"))
            results.append({"experiment": 3, "position_rmse_mm": v, "grasp_success": seed != 2,
                            "position_rmse_arm_mm": v / 2,
                            "max_position_error_mm": 3 * v, "visibility_accuracy": 1 - v / 100,
                            "collision_count": 1 if seed == 4 else 0,
                            "fewest_visible": {"approach": [9, 1], "manipulate": [seed % 2, 5]}})
    specs.append(RunSpec("dual-arm", 3, "rendered", "kinematic", 9, realism="lab"))
    results.append({"error": "RuntimeError: boom"})
    rows = {r[5]: r for r in group_rows(specs, results)}
    mean, half = mean_ci(on)
    t = stats.t.ppf(0.975, 7) * on.std(ddof=1) / np.sqrt(8)
    assert half == pytest.approx(t) and mean == pytest.approx(on.mean())
    row = rows["kinematic"]
    assert row[6] == "8 (+1 failed)" and row[7] == "7/8"
    assert row[8] == f"{on.mean() / 2:.2f} ± {t / 2:.2f}" and row[9] == f"{on.max() / 2:.2f}"
    assert row[10] == f"{on.mean():.2f} ± {t:.2f}"
    assert row[11] == f"{np.percentile(on, 95):.2f}" and row[12] == f"{on.max():.2f}"
    assert row[18] == f"{(1 - on / 100).min():.4f}" and row[22] == "1"
    assert row[23] == "4/8"  # camera 1 left with nothing in Manipulate on the even seeds
    (paired,) = paired_rows(specs, results)  # the default against the others, arm frame
    assert paired[5] == "kinematic vs nopred (arm frame)"
    assert paired[6] == f"{int(np.sum(off > on))}/8"
    gain = (off - on) / 2
    assert paired[7] == f"{gain.mean():.2f} ± {mean_ci(gain)[1]:.2f}"


def test_health_rows_count_confident_wrong_frames_and_wrong_corners():
    import numpy as np

    from cellsight.sweep.aggregate import health_rows

    rng = np.random.default_rng(7)
    wrong = [0, 3, 0, 12, 1]
    accepted, measured = rng.integers(0, 50, 5), rng.integers(500, 2000, 5)
    worst = rng.uniform(1, 30, 5)
    specs = [RunSpec("dual-arm", 1, "rendered", "kinematic", s, realism="harsh") for s in range(5)]
    results = [{"experiment": 1, "confident_wrong_frames": w, "max_error_tracking_mm": e,
                "wrong_accepted": int(a), "measurements": int(n), "degraded_s": float(s),
                "cameras_dropped": {"cam2": 3.0} if s == 4 else {}}
               for s, (w, e, a, n) in enumerate(zip(wrong, worst, accepted, measured,
                                                                  strict=True))]
    (row,) = health_rows(specs, results)
    share = 100 * accepted / measured
    assert row[6] == "5" and row[7] == "3 (16)" and row[8] == f"{worst.max():.1f}"
    assert row[9] == f"{100 * accepted.sum() / measured.sum():.2f} ({share.max():.2f})"
    assert row[10] == "2.0" and row[11] == "1"


def test_realism_and_structure_name_their_folders_and_bad_profiles_stop_the_grid(tmp_path):
    spec = RunSpec("dual-arm", 3, "rendered", "kinematic", 4, realism="lab", structure="frame-bsp")
    assert str(spec.folder) == "dual-arm/e3_rendered_kinematic_lab_frame-bsp_s4"
    assert str(RunSpec("dual-arm", 3, "ideal", "plain", 4).folder) == "dual-arm/e3_ideal_plain_s4"
    bad = tmp_path / "bad.yaml"
    bad.write_text("timing: {latency_ms: -3}\n")
    with pytest.raises(CellsightError, match="timing.latency_ms"):
        sweep_grid(SweepAxes(["dual-arm"], [1], ["ideal"], ["kinematic"], [0],
                             realisms=[str(bad)]))


def test_each_variant_sets_the_runs_options(tmp_path):
    from cellsight.trackers import DEFAULT_TRACKER

    tracker = {v: RunSpec("dual-arm", 3, "rendered", v, 0).config(tmp_path).tracker
               for v in ("kinematic", "plain", "nopred", "offsets", "unknown", "calibrated")}
    assert tracker["kinematic"] == DEFAULT_TRACKER and tracker["kinematic"].kinematic
    assert not tracker["plain"].kinematic and tracker["plain"].occlusion_prediction
    assert not tracker["nopred"].occlusion_prediction and tracker["nopred"].kinematic
    assert tracker["offsets"].camera_offsets_px == 5.0 and tracker["offsets"].kinematic
    assert tracker["unknown"].unknown_occluders and not tracker["kinematic"].unknown_occluders
    config = RunSpec("dual-arm", 3, "rendered", "offsets", 0).config(tmp_path)
    assert config.out == tmp_path / "dual-arm/e3_rendered_offsets_s0"
    assert config.calibration is None
    calibrated = RunSpec("dual-arm", 2, "rendered", "calibrated", 7, realism="lab")
    assert calibrated.config(tmp_path).tracker == DEFAULT_TRACKER
    assert calibrated.config(tmp_path).calibration == tmp_path / "dual-arm/calibration_lab_s7"
    from cellsight.sweep.grid import VARIANTS
    from cellsight.sweep.summary import VARIANT_NAMES

    assert set(VARIANT_NAMES) == set(VARIANTS)  # every variant has its summary name


def test_calibration_rows_give_each_seeds_calibration_once_against_numpy():
    """One calibration per seed, shared by its experiments' runs: counted once, its cameras'
    and other bases' errors summarised over seeds and cameras."""
    import numpy as np

    from cellsight.sweep.aggregate import calibration_rows

    rng = np.random.default_rng(3)
    keys = ("position_at_work_mm", "rotation_deg", "focal_percent", "principal_point_px",
            "image_at_work_px")
    def errors_of_one() -> dict:
        return {"cameras": {c: dict(zip(keys, rng.uniform(0, 3, 5), strict=True))
                            for c in ("cam1", "cam2")},
                "robots": {"R6AX": {"origin_mm": rng.uniform(0, 1),
                                    "rotation_deg": rng.uniform(0, 0.1)}}}

    errors = {seed: {**errors_of_one(), "cell_file": errors_of_one()} for seed in range(4)}
    specs = [RunSpec("dual-arm", e, "rendered", "calibrated", s, realism="lab")
             for e in (1, 2) for s in range(4)]
    results = [{"calibration_errors": errors[spec.seed]} for spec in specs]
    specs.append(RunSpec("dual-arm", 1, "rendered", "kinematic", 0, realism="lab"))
    results.append({"calibration_errors": None})
    (row,) = calibration_rows(specs, results)
    at_work = [e["cameras"][c]["position_at_work_mm"] for e in errors.values()
               for c in ("cam1", "cam2")]
    pp = [e["cameras"][c]["principal_point_px"] for e in errors.values() for c in ("cam1", "cam2")]
    bases = [e["robots"]["R6AX"]["origin_mm"] for e in errors.values()]
    image_before = [e["cell_file"]["cameras"][c]["image_at_work_px"] for e in errors.values()
                    for c in ("cam1", "cam2")]
    bases_before = [e["cell_file"]["robots"]["R6AX"]["origin_mm"] for e in errors.values()]
    assert row[:3] == ["dual-arm", "lab", "4"]
    assert row[3:5] == [f"{np.mean(at_work):.2f}", f"{np.max(at_work):.2f}"]
    assert row[9:11] == [f"{np.mean(pp):.2f}", f"{np.max(pp):.2f}"]
    assert row[13:15] == [f"{np.mean(image_before):.2f}", f"{np.max(image_before):.2f}"]
    assert row[15:18] == [f"{np.mean(bases):.2f}", f"{np.max(bases):.2f}",
                          f"{np.mean(bases_before):.2f}"]


def test_the_summary_counts_a_flickering_contact_once():
    """Runs written before the contact monitor merged a flickering contact into one episode
    are summarised as the monitor counts now; merged or absent collisions are unchanged."""
    from cellsight.sweep.summary import _merged_collisions

    touch = [{"bodies": ["R7AX.gripper", "conveyor"], "t_start_s": t, "t_end_s": t + 0.02,
              "depth_mm": d} for t, d in ((10.0, 0.1), (10.03, 0.2), (10.06, 0.05), (11.0, 0.1))]
    merged = _merged_collisions({"collisions": touch, "collision_count": 4})
    assert merged["collision_count"] == 2
    assert merged["collisions"][0] == {"bodies": ["R7AX.gripper", "conveyor"], "t_start_s": 10.0,
                                       "t_end_s": 10.08, "depth_mm": 0.2}
    again = _merged_collisions(merged)
    assert again["collisions"] == merged["collisions"]
    assert _merged_collisions({"collision_count": 0}) == {"collision_count": 0}

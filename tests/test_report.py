"""Report: overlay colours at the drawn points, even composite sizes, the MP4 writer round trip,
frames.csv parsing, and write_report on a synthetic full run and a partial (interrupted) one."""

from __future__ import annotations

import base64
import csv
import json
import os
import re
import subprocess
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import pytest

from cellsight.rates import VISION_HZ
from cellsight.report import overlay
from cellsight.report.overlay import FeatureMarks, compose_views, draw_camera_overlay
from cellsight.report.run_figures import (
    Run,
    orientation_error_deg,
    position_error_mm,
    report_inputs,
    runs_of,
)
from cellsight.report.run_report import write_report
from cellsight.report.video import VideoWriter
from cellsight.runfolder.framelog import POSE, FrameLog
from cellsight.tracking.timing import STAGES

F = 16
CAMERAS = ("cam1", "cam2")


def _overlay(image, inputs: dict, truth_visible=None, **extra) -> np.ndarray:
    """:func:`draw_camera_overlay` of the inputs (the marks' fields and the rest)."""
    names = ("pixels", "visible", "selected", "measured", "rejected")
    marks = FeatureMarks(*(inputs[n] for n in names), truth_visible)
    rest = {k: v for k, v in inputs.items() if k not in names}
    return draw_camera_overlay(image, marks, **rest, **extra)


def _overlay_inputs() -> dict:
    """Four features on a 320 x 240 canvas, away from the title and legend boxes."""
    pixels = np.array([[150.0, 60.0], [250.0, 120.0], [np.nan, np.nan], [200.0, 200.0]])
    return dict(
        pixels=pixels,
        visible=np.array([True, False, True, True]),
        selected=np.array([True, False, False, False]),
        measured=np.array([[np.nan, np.nan], [np.nan, np.nan], [np.nan, np.nan],
                           [280.0, 200.0]]),
        rejected=np.array([False, False, False, True]),
        boxes=np.array([[200, 20, 260, 60]]),
        title="cam1",
    )


def test_overlay_colours_at_the_drawn_points():
    img = _overlay(None, _overlay_inputs(), size=(320, 240))
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    assert tuple(img[60, 150]) == overlay.VISIBLE  # filled disc centre
    assert tuple(img[120, 250 + overlay.POINT_RADIUS]) == overlay.OCCLUDED  # ring
    assert tuple(img[120, 250]) == (128, 128, 128)  # hollow: canvas shows through
    assert tuple(img[60, 150 + overlay.RING_RADIUS]) == overlay.SELECTED
    assert tuple(img[120, 250 + overlay.RING_RADIUS]) != overlay.SELECTED  # not selected
    assert tuple(img[20, 230]) == overlay.WINDOW  # top edge, row v0
    assert tuple(img[59, 230]) == overlay.WINDOW  # bottom edge, row v1 - 1 (half-open)
    assert tuple(img[200, 280]) == overlay.REJECTED  # cross centre
    assert (img == overlay.MISMATCH).all(axis=2).sum() == 0  # no truth given


def test_overlay_marks_disagreement_with_truth_and_keeps_the_image():
    gray = np.full((240, 320), 10, dtype=np.uint8)
    inputs = _overlay_inputs()
    inputs["measured"][3] = [np.nan, np.nan]
    truth = np.array([False, False, True, True])  # feature 1 predicted visible, truly hidden
    img = _overlay(gray, inputs, truth)
    d = overlay.MISMATCH_HALF
    assert tuple(img[60 - d, 145]) == overlay.MISMATCH
    assert tuple(img[200 - d, 195]) != overlay.MISMATCH  # feature 4 agrees
    assert tuple(img[230, 310]) == (10, 10, 10)  # untouched pixels keep the image


def test_overlay_needs_a_size_without_an_image():
    with pytest.raises(ValueError):
        _overlay(None, _overlay_inputs())


def test_compose_sizes_are_even():
    views = [np.zeros((75, 101, 3), np.uint8), np.zeros((60, 91, 3), np.uint8)]
    for scale in (1.0, 0.7, 0.33):
        for caption in ("", "t = 12.3 s  grasp"):
            out = compose_views(views, scale=scale, caption=caption)
            assert out.shape[0] % 2 == 0 and out.shape[1] % 2 == 0
            assert abs(out.shape[1] - 192 * scale) <= 2
    same = compose_views([np.zeros((48, 64, 3), np.uint8)] * 2)
    assert same.shape == (48, 128, 3)


def test_video_round_trip(tmp_path):
    path = tmp_path / "v" / "clip.mp4"
    with VideoWriter(path, fps=10) as vw:
        for k in range(10):
            vw.add(np.full((48, 64, 3), 20 * k, dtype=np.uint8))
        with pytest.raises(ValueError):
            vw.add(np.zeros((50, 64, 3), np.uint8))
    assert vw.frames == 10
    n_frames, _ = imageio_ffmpeg.count_frames_and_secs(str(path))
    assert n_frames == 10
    cap = cv2.VideoCapture(str(path))  # an independent decoder
    frames = []
    while (frame := cap.read())[0]:
        frames.append(frame[1])
    cap.release()
    assert len(frames) == 10 and frames[-1].shape == (48, 64, 3)
    assert abs(float(frames[-1].mean()) - 180.0) < 6.0
    vw.close()  # a second close is harmless


def test_video_starts_ffmpeg_without_fork_handlers(tmp_path):
    """Starting ffmpeg runs no fork handlers: a real ``fork()`` runs the BLAS's, which waited
    for another thread's matrix product while that product waited for it (a run hung so).
    Python runs its own handlers wherever it forks for a ``preexec_fn`` (imageio-ffmpeg's
    ``write_frames`` passed one): the check sees such a start."""
    forks = []
    os.register_at_fork(before=lambda: forks.append(1))
    with VideoWriter(tmp_path / "clip.mp4", fps=10) as vw:
        vw.add(np.zeros((48, 64, 3), np.uint8))
    assert forks == [] and vw.frames == 1
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-version"], check=True,
                   stdout=subprocess.DEVNULL, preexec_fn=os.setpgrp)
    assert forks == [1]


def test_video_that_ffmpeg_cannot_finish_raises_its_message(tmp_path):
    """ffmpeg refusing the file (an ending that names no format it knows) is raised on close,
    with the file and ffmpeg's own last lines (it cannot open the file), not printed on the
    terminal and lost."""
    vw = VideoWriter(tmp_path / "clip.notavideo", fps=10)
    with pytest.raises(OSError) as failed:
        for _ in range(50):
            vw.add(np.zeros((48, 64, 3), np.uint8))
        vw.close()
    assert failed.value.filename == str(tmp_path / "clip.notavideo")
    assert "ffmpeg ended with exit code" in failed.value.strerror
    assert "Error opening output file" in failed.value.strerror
    vw.close()  # closing again after the failure is harmless


# --------------------------------------------------------------------------- synthetic runs


def _flags(mask: np.ndarray) -> str:
    return "".join("1" if b else "0" for b in mask)


def _frame_rows(n: int, rng: np.random.Generator) -> list[dict]:
    """``n`` frames following the runner's frames.csv contract."""
    phases = ["waiting"] * 5 + ["approach"] * 15 + ["grasp"] * 10 + ["manipulate"] * (n - 30)
    rows = []
    for k in range(n):
        t = k / VISION_HZ
        true = np.array([0.6 + 0.05 * t, -0.2 + 0.02 * t, 0.9, 0.0, 0.0, 0.3 + 0.1 * t])
        row = {"t": t, "phase": phases[k], "stage": "s", "status":
               "waiting" if k < 3 else "tracking"}
        row.update({f"true_{p}": v for p, v in zip(POSE, true, strict=True)})
        est = true + rng.normal(0, [0.002] * 3 + [0.01] * 3)
        pnp = true + rng.normal(0, [0.005] * 3 + [0.03] * 3)
        row.update({f"est_{p}": (None if k < 3 else v) for p, v in zip(POSE, est, strict=True)})
        row.update({f"pnp_{p}": (None if k % 4 == 0 else v)
                    for p, v in zip(POSE, pnp, strict=True)})
        row.update(gripper_x=0.4 + 0.01 * k, gripper_y=-0.1, gripper_z=1.2 - 0.005 * k,
                   jaw_opening=0.04, jaws_closed=int(k >= 25), grasped=int(k >= 28))
        for c in (1, 2):
            row.update(_camera_fields(c, k, rng))
        row.update({f"t_{s}_ms": float(rng.uniform(0.1, 3.0)) for s in STAGES})
        rows.append(row)
    return rows


def _camera_fields(c: int, k: int, rng: np.random.Generator) -> dict:
    """One camera's per-feature columns for frame ``k`` (no prediction while waiting)."""
    vis_true = rng.random(F) < 0.7
    vis_true[0] = False  # feature 1 hidden, numeric-looking flags start with '0'
    vis = vis_true.copy()
    vis[rng.integers(1, F)] ^= True  # one disagreement per frame
    sel = vis & (rng.random(F) < 0.8)
    meas = sel & (rng.random(F) < 0.9)
    rej = meas & (rng.random(F) < 0.1)
    occluders = np.array(["self", "R7AX.gripper", "table", "R6AX.link4"])
    occ = np.where(vis, "", occluders[rng.integers(0, 4, F)])
    occ_true = np.where(vis_true, "", "self")
    waiting = k < 3
    return {
        f"vis_pred_c{c}": None if waiting else _flags(vis),
        f"vis_true_c{c}": _flags(vis_true),
        f"sel_c{c}": _flags(sel & ~waiting),
        f"meas_c{c}": _flags(meas & ~waiting),
        f"rej_c{c}": _flags(rej & ~waiting),
        f"occ_pred_c{c}": None if waiting else ";".join(occ),
        f"occ_true_c{c}": ";".join(occ_true),
        f"grab_c{c}": 0.02,
        f"err_px_c{c}": None if waiting else 0.4,
    }


def _write_frames(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), quoting=csv.QUOTE_NONNUMERIC)
        writer.writeheader()
        writer.writerows(rows)


METRICS = {
    "experiment": 1, "seed": 7, "sensor": "rendered", "occlusion_prediction": True,
    "frames": 40, "grasp_success": True, "grasp_position_error_mm": 3.21,
    "position_rmse_mm": 12.3456, "orientation_rmse_deg": 0.789, "max_position_error_mm": 31.5,
    "pnp_position_rmse_mm": 27.25, "pnp_orientation_rmse_deg": 1.5,
    "in_view_fraction": 1.0, "lost_in_view_s": 0.0, "visibility_accuracy": 0.9375,
    "visibility_accuracy_all": 0.95, "false_visible": 11,
    "false_hidden": 9, "pixels_grabbed_fraction": 0.0412, "extraction_error_px_median": 0.41,
    "timing_ms": {"occlusion": 1.5, "selection": 0.2, "windowing": 0.1, "extraction": 2.25,
                  "ekf": 0.3, "total": 4.35},
    "wall_s": 9.5, "cameras": list(CAMERAS), "features": F, "robot": "R7AX",
    "workpiece": "part",
    "phase_intervals": [["waiting", 0.0, 0.19], ["approach", 0.19, 0.77],
                        ["grasp", 0.77, 1.15], ["manipulate", 1.15, 1.54]],
    "phases": {"approach": {"evaluated_frames": 15, "position_rmse_mm": 4.5,
                            "max_position_error_mm": 9.25, "orientation_rmse_deg": 0.5,
                            "pnp_position_rmse_mm": 20.5, "lost_in_view_s": 0.0}},
    "interrupted": False,
}


def _write_keyframe(run_dir: Path) -> None:
    inputs = _overlay_inputs()
    views = [_overlay(None, {**inputs, "title": cam}, size=(320, 240))
             for cam in CAMERAS]
    rgb = compose_views(views, scale=0.5, caption="t = 1.00 s  grasp")
    (run_dir / "keyframes").mkdir()
    cv2.imwrite(str(run_dir / "keyframes" / "grasp.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    (run_dir / "keyframes.json").write_text(json.dumps(
        [{"name": "grasp", "t": 1.0, "caption": "jaws close on the part",
          "file": "keyframes/grasp.png"}]))


@pytest.fixture
def full_run(tmp_path) -> Path:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_frames(run_dir / "frames.csv", _frame_rows(40, np.random.default_rng(0)))
    (run_dir / "metrics.json").write_text(json.dumps(METRICS))
    (run_dir / "run.log").write_text("0.00 s phase waiting\n1.15 s phase <manipulate>\n")
    _write_keyframe(run_dir)
    with VideoWriter(run_dir / "views.mp4", fps=VISION_HZ) as vw:
        for k in range(3):
            vw.add(np.full((32, 48, 3), 60 * k, dtype=np.uint8))
    return run_dir


def test_frames_keep_flag_strings_and_missing_values(full_run):
    run = report_inputs(full_run)
    assert run.frames.n == 40 and run.cameras == list(CAMERAS) and run.n_features == F
    vis = run.frames.bits("vis_pred_c1", F)
    assert vis.shape == (40, F) and not vis[:, 0].any() and vis[3:].any()
    assert not run.frames.present("vis_pred_c1")[:3].any()
    assert np.isnan(run.frames.floats("est_x")[:3]).all()
    labels = run.frames.labels("occ_pred_c2", F)
    assert set(labels[3:, 0]) <= {"self", "R7AX.gripper", "table", "R6AX.link4"}


def test_pose_errors():
    frames = FrameLog({"t": ["0", "1"], **{f"true_{p}": ["0", "0"] for p in POSE},
                     "est_x": ["0.003", ""], "est_y": ["0.004", ""], "est_z": ["0", ""],
                     "est_roll": ["0", ""], "est_pitch": ["0", ""],
                     "est_yaw": [str(np.radians(10.0)), ""]}, 2)
    run = Run(Path("."), frames, {}, [], 0)
    pos = position_error_mm(run, "est")
    assert pos[0] == pytest.approx(5.0) and np.isnan(pos[1])
    ori = orientation_error_deg(run, "est")
    assert ori[0] == pytest.approx(10.0) and np.isnan(ori[1])


def test_runs_of():
    starts, stops = runs_of(np.array([1, 1, 0, 0, 1, 0, 1], dtype=bool))
    assert starts.tolist() == [0, 4, 6] and stops.tolist() == [2, 5, 7]


def test_write_report_full_run(full_run):
    out = write_report(full_run)
    assert out == full_run / "report.html"
    page = out.read_text()
    names = ["fig_trajectory.png", "fig_error.png", "fig_health.png", "fig_visibility_cam1.png",
             "fig_visibility_cam2.png", "fig_visibility_agreement.png", "fig_timing.png"]
    for name in names:
        assert (full_run / name).stat().st_size > 5000
        assert f'alt="{name}"' in page
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == len(names) + 1  # figures + one key frame
    assert all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in images)
    assert "data:video/mp4;base64," in page
    for text in ("12.35 mm", "0.9375", "27.25 mm", "timing_ms.extraction", "<h3>Phases</h3>",
                 "<td>approach</td><td class=v>0.19</td><td class=v>0.77</td><td class=v>15</td>"
                 "<td class=v>4.5</td><td class=v>9.25</td>",
                 "2.25 ms", "0.41 px", "yes", "jaws close on the part", "&lt;manipulate&gt;",
                 "experiment 1 · seed 7 · sensor rendered · occlusion prediction on"):
        assert text in page, text
    assert "Partial run" not in page


def test_write_report_partial_run(tmp_path):
    run_dir = tmp_path / "partial"
    run_dir.mkdir()
    rows = _frame_rows(40, np.random.default_rng(1))[:4]
    _write_frames(run_dir / "frames.csv", rows)
    with open(run_dir / "frames.csv", "a") as f:
        f.write('0.2,"approach","s"')  # a row cut off mid-write
    (run_dir / "metrics.json").write_text(json.dumps(
        {"experiment": 2, "seed": 1, "interrupted": True, "frames": 4}))
    page = write_report(run_dir).read_text()
    assert "Partial run" in page and "experiment 2 · seed 1" in page
    assert report_inputs(run_dir).cameras == ["cam1", "cam2"]
    assert (run_dir / "fig_visibility_cam2.png").exists()
    assert page.count("data:image/png;base64,") == 7


def test_a_calibrated_runs_report_shows_its_calibration(tmp_path):
    """A run made on a calibration (``--calibration``) shows its verdict, its residuals
    picture and each estimate's error against the world's truth; one whose folder is gone
    says so."""
    import matplotlib.pyplot as plt

    calibration = tmp_path / "cal"
    calibration.mkdir()
    (calibration / "calibration.json").write_text(json.dumps(
        {"verdict": "calibrated 2 cameras from 34 views: reprojection RMS 0.297 px"}))
    fig = plt.figure(figsize=(2, 1))
    fig.savefig(calibration / "residuals.png")
    plt.close(fig)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_frames(run_dir / "frames.csv", _frame_rows(10, np.random.default_rng(2)))
    errors = {"cameras": {"cam1": {"position_at_work_mm": 2.3746, "principal_point_px": 2.838}},
              "robots": {"R6AX": {"origin_mm": 0.6977}}}
    metrics = {"experiment": 3, "seed": 0, "calibration_folder": str(calibration),
               "calibration_errors": errors}
    (run_dir / "metrics.json").write_text(json.dumps(metrics))
    page = write_report(run_dir).read_text()
    section = page[page.index("<h2>Calibration</h2>"):]
    for text in ("reprojection RMS 0.297 px", "<td>cam1</td><td class=v>2.375</td>",
                 "<td class=v>2.838</td>", "<td>R6AX</td>", "0.6977", 'alt="residuals"'):
        assert text in section, text
    assert "calibration_errors" not in page  # not flattened into the metrics table as well
    (calibration / "calibration.json").unlink()
    assert "not readable now" in write_report(run_dir).read_text()

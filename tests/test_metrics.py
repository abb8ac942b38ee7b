"""Run metrics from a frame log (cellsight.runfolder.figures) on a small hand-made log whose
figures are worked out here by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.runfolder.figures import (
    evaluated_frames,
    frame_metrics,
    position_rmse_in_arm_frame_mm,
)
from cellsight.runfolder.framelog import FrameLog, FrameWriter, pose_fields, timing_fields
from cellsight.runfolder.metrics import RunDataError, checked_metrics
from cellsight.tracking.timing import STAGES

PERIOD = 0.04  # s

# frame: phase, est offset (mm along x; None = no estimate), pnp offset (mm), occ_true labels,
# vis_pred, vis_true, meas, rej, wrong, grab, err_px
FRAMES = [
    ("waiting", None, None, "outside;outside;outside", "000", "000", "000", "000", "000", 0.0,
     None),
    ("approach", 1.0, 3.0, ";self;", "101", "101", "101", "000", "000", 0.1, 0.2),
    ("approach", 2.0, None, ";;outside", "110", "100", "100", "000", "000", 0.2, 0.4),
    ("grasp", None, 4.0, ";R7AX.gripper;", "111", "101", "111", "010", "011", 0.3, None),
    ("grasp", 5.0, 1.0, "behind;behind;behind", "000", "000", "000", "000", "000", 0.4, None),
]


@pytest.fixture
def log(tmp_path: Path) -> FrameLog:
    return _hand_made_log(tmp_path)


def _hand_made_log(tmp_path: Path, held_out: int | None = None) -> FrameLog:
    """The log of ``FRAMES``; ``held_out``: the frame whose camera the camera check held out
    of the filter."""
    T_true = pose_from_xyz_rpy([0.5, 0.1, 0.6], [0.0, 0.0, 0.3])
    with FrameWriter(tmp_path / "frames.csv", 1) as writer:
        for k, (phase, est, pnp, occ, vis_pred, vis_true, meas, rej, wrong, grab, px) in \
                enumerate(FRAMES):
            row = {"t": k * PERIOD, "phase": phase, **pose_fields("true", T_true),
                   "vis_pred_c1": vis_pred, "vis_true_c1": vis_true, "occ_true_c1": occ,
                   "meas_c1": meas, "rej_c1": rej, "wrong_c1": wrong, "grab_c1": grab,
                   "err_px_c1": px, "held_out_c1": int(k == held_out),
                   **timing_fields(dict.fromkeys(STAGES, k * 1e-3))}
            for prefix, mm in (("est", est), ("pnp", pnp)):
                if mm is not None:
                    T = T_true.copy()
                    T[0, 3] += mm * 1e-3
                    row.update(pose_fields(prefix, T))
            writer.write(row)
    return FrameLog.read(tmp_path / "frames.csv")


def test_metrics_of_a_hand_made_log(log: FrameLog):
    m = frame_metrics(log)
    # evaluated: in view (some feature neither outside nor behind) from the first estimate on
    assert evaluated_frames(log).tolist() == [False, True, True, True, False]
    assert m["frames"] == 5 and m["first_estimate_s"] == pytest.approx(PERIOD)
    assert m["in_view_fraction"] == pytest.approx(3 / 4)
    assert m["evaluated_frames"] == 3
    assert m["position_rmse_mm"] == pytest.approx(np.sqrt((1 + 4) / 2))
    assert m["max_position_error_mm"] == pytest.approx(2.0)
    assert m["orientation_rmse_deg"] == pytest.approx(0.0, abs=1e-6)
    assert m["pnp_position_rmse_mm"] == pytest.approx(np.sqrt((9 + 16) / 2))
    assert m["lost_in_view_s"] == pytest.approx(PERIOD)  # frame 3 has no estimate
    assert m["phases"]["approach"]["evaluated_frames"] == 2
    assert m["phases"]["grasp"]["position_rmse_mm"] is None
    assert m["phases"]["grasp"]["lost_in_view_s"] == pytest.approx(PERIOD)
    assert m["phases"]["release"]["evaluated_frames"] == 0
    # labels in view: frame 1: 3, frame 2: 2 (one agrees wrongly), frame 3: 3 (one wrong)
    assert m["visibility_accuracy"] == pytest.approx(6 / 8)
    assert m["visibility_accuracy_all"] == pytest.approx(13 / 15)
    assert m["false_visible"] == 2 and m["false_hidden"] == 0
    assert (m["measurements"], m["rejected_measurements"], m["wrong_measurements"],
            m["wrong_accepted"]) == (6, 1, 2, 1)
    assert m["pixels_grabbed_fraction"] == pytest.approx(0.2)
    assert m["extraction_error_px_median"] == pytest.approx(0.3)
    assert m["timing_ms"] == {s: pytest.approx(2.0) for s in STAGES}


def test_a_camera_held_out_of_the_filter_accepts_no_wrong_corner(tmp_path: Path):
    """The wrong corner the gate let through in frame 3 counts as accepted; with the camera
    held out of the filter in that frame (a knocked camera, dropped and still measured) it
    went into nothing: not accepted, and its span says ``unused``."""
    from cellsight.runfolder.wrong_corners import wrong_corner_spans

    for held_out, accepted in ((None, 1), (3, 0)):
        folder = tmp_path / str(held_out)
        folder.mkdir()
        m = frame_metrics(_hand_made_log(folder, held_out))
        assert (m["measurements"], m["wrong_measurements"], m["wrong_accepted"]) == (6, 2, accepted)
        spans = {s.feature: s for s in wrong_corner_spans(folder)}
        assert (spans["#2"].accepted, spans["#2"].unused) == (accepted, 1 - accepted)


def test_the_position_error_in_an_arm_s_frame(log: FrameLog):
    """The estimates are 1 and 2 mm along x off the truth (the evaluated frames with one). An
    arm whose TCP truly stands 1 mm further along x than its model says sees the part 1 mm
    short: against that, the estimates are 2 and 3 mm off; 1 mm the other way, 0 and 1 mm."""
    along = position_rmse_in_arm_frame_mm(log, np.array([0.001, 0.0, 0.0]))
    assert along == pytest.approx(np.sqrt((4 + 9) / 2))
    back = position_rmse_in_arm_frame_mm(log, np.array([-0.001, 0.0, 0.0]))
    assert back == pytest.approx(np.sqrt((0 + 1) / 2))
    across = position_rmse_in_arm_frame_mm(log, np.array([0.0, 0.002, 0.0]))
    assert across == pytest.approx(np.sqrt((1 + 4 + 4 + 4) / 2))


def test_metrics_of_an_empty_log(tmp_path: Path):
    FrameWriter(tmp_path / "frames.csv", 2).close()  # interrupted before the first frame
    m = frame_metrics(FrameLog.read(tmp_path / "frames.csv"))
    assert m["frames"] == 0 and m["position_rmse_mm"] is None
    assert m["visibility_accuracy"] is None and m["pixels_grabbed_fraction"] is None
    assert m["timing_ms"] == dict.fromkeys(STAGES)


def test_the_metrics_sections_cover_every_field_once_and_keep_the_json_flat():
    """``metrics.json``'s typed sections: every field of RunMetrics in exactly one section,
    and a section read from a flat metrics object holds the very values of its keys."""
    from cellsight.runfolder.metric_sections import SECTIONS, AccuracyMetrics, RunMetrics

    owners = [name for section in SECTIONS for name in section.model_fields]
    assert sorted(owners) == sorted(RunMetrics.model_fields) and len(set(owners)) == len(owners)
    flat = {"metrics_version": 1, "seed": 4, "position_rmse_mm": 0.7, "phases": {},
            "wall_s": 3.0, "extra_key": "kept"}
    metrics = RunMetrics.model_validate(flat)
    accuracy = metrics.section(AccuracyMetrics)
    assert accuracy.position_rmse_mm == 0.7 and accuracy.phases == {}
    assert metrics.model_dump(exclude_unset=True) == flat


def test_each_phase_is_typed_like_the_whole_task(tmp_path: Path) -> None:
    """``phases``: phase -> the whole task's estimation figures (PhaseAccuracy); a wrong type
    inside one phase is refused naming the phase and the field."""
    from cellsight.runfolder.metric_sections import AccuracyMetrics, PhaseAccuracy, RunMetrics

    whole = set(PhaseAccuracy.model_fields)
    assert whole < set(AccuracyMetrics.model_fields)
    flat = {"phases": {"grasp": {"position_rmse_mm": 0.4, "evaluated_frames": 12}}}
    phase = RunMetrics.model_validate(flat).section(AccuracyMetrics).phases["grasp"]
    assert phase.position_rmse_mm == 0.4 and phase.evaluated_frames == 12
    bad = {"phases": {"grasp": {"position_rmse_mm": "small"}}}
    with pytest.raises(RunDataError, match=r"phases\.grasp\.position_rmse_mm.*expected a number"):
        checked_metrics(tmp_path, bad)

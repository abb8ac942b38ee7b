"""Re-acquisition from the whole image (:mod:`cellsight.tracking.search`) and the kidnapping
fault (:mod:`cellsight.world.faults`), against the simulator's truth: the search on rendered
frames at random part poses, a tracker started far from the part, the fault itself, the loss
rule, and a short run in which the part is kidnapped."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.tracking.acquisition import TWIN_TOL, twin_turns
from cellsight.tracking.extraction import CornerExtractor
from cellsight.tracking.loss import LossRule
from cellsight.tracking.search import PlaneSearch
from cellsight.world import World
from cellsight.world.faults import Kidnap
from cellsight.world.imperfections import Imperfections


def _moved(T: np.ndarray, shift, turn: float) -> np.ndarray:
    """``T`` moved by ``shift`` (2,) m and turned by ``turn`` (rad) about the vertical."""
    c, s = math.cos(turn), math.sin(turn)
    out = np.array(T, dtype=float)
    out[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ out[:3, :3]
    out[:2, 3] += shift
    return out


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def test_search_finds_the_part_anywhere_on_its_plane_in_rendered_frames(cell):
    """Random poses 10-30 cm from the nominal, turned up to 45 deg; rendered by MuJoCo,
    corners by OpenCV. Of 8 poses where some camera truly sees at least 6 of its points, the
    candidates the tracker verifies (the first ``verify``) hold one within 3 mm and 2 deg of
    the simulator's pose in at least 6 (today 7: the miss is a part only camera 2 sees, 6
    points), and the best candidate is that one in at least 5."""
    part = cell.workpieces[0]
    world = World(cell, seed=0)
    rng = np.random.default_rng(7)
    detector, search = CornerExtractor(), PlaneSearch()
    tried, found, first, errors = 0, 0, 0, []
    try:
        while tried < 8:
            heading, turn = rng.uniform(0, 2 * math.pi), rng.uniform(-math.pi / 4, math.pi / 4)
            shift = rng.uniform(0.1, 0.3) * np.array([math.cos(heading), math.sin(heading)])
            world.place_part(part.name, _moved(part.T_base_part, shift, turn))
            world.step({}, {})
            if max(int(v.visible.sum()) for v in world.true_views()[part.name]) < 6:
                continue
            tried += 1
            corners = [detector.detect(image) for image in world.render()]
            candidates = search.candidates(cell.cameras, part.feature_points, part.T_base_part,
                                           part.T_base_part[None, :2, 3], corners)
            truth = world.true_part_poses()[part.name]
            right = [_close(c.T_base_part, truth) for c in candidates[:search.verify]]
            found += any(right)
            first += bool(right) and right[0]
            errors.append([round(1e3 * np.linalg.norm(c.T_base_part[:3, 3] - truth[:3, 3]), 1)
                           for c in candidates[:search.verify]])
    finally:
        world.close()
    assert found >= 6 and first >= 5, (found, first, errors)


def _close(T: np.ndarray, truth: np.ndarray) -> bool:
    """Within 3 mm and 2 deg."""
    angle = np.arccos(np.clip((np.trace(T[:3, :3].T @ truth[:3, :3]) - 1) / 2, -1, 1))
    return bool(np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 3e-3 and angle < math.radians(2.0))


def test_search_finds_nothing_in_empty_images_or_out_of_view(cell):
    part = cell.workpieces[0]
    centre = part.T_base_part[None, :2, 3]
    for corners in ([np.zeros((0, 2)) for _ in cell.cameras], [None] * len(cell.cameras)):
        assert PlaneSearch().candidates(cell.cameras, part.feature_points, part.T_base_part,
                                        centre, corners) == []
    # a square no camera sees: nothing to score, nothing proposed
    far = [np.array([[100.0, 100.0]]) for _ in cell.cameras]
    assert PlaneSearch().candidates(cell.cameras, part.feature_points, part.T_base_part,
                                    centre + 50.0, far) == []


def test_tracker_started_far_from_the_part_finds_it_from_the_whole_image(cell):
    """The part 22 cm and 30 deg from where the cell file says (far beyond the acquisition's
    64 px windows at the nominal pose): the whole-image search finds it in the first frame,
    and the acquired pose is within 1 mm of the simulator's; without the search it is never
    found."""
    from cellsight.rates import VISION_HZ
    from cellsight.tracking import Tracker, TrackerParts

    part = cell.workpieces[0]
    world = World(cell, seed=1)
    world.place_part(part.name, _moved(part.T_base_part, [-0.12, -0.18], math.radians(30)))
    predictor = visibility_predictor(cell)
    tracker = Tracker.from_cell(cell, predictor)
    blind = Tracker.from_cell(cell, predictor, components=TrackerParts(search=None))
    try:
        world.step({}, {})
        images, joints = world.render(), world.measured_joints()
        rec = tracker.step(images, joints, 0.0).parts[part.name]
        truth = world.true_part_poses()[part.name]
        assert rec.status == "acquired"
        assert np.linalg.norm(rec.T_base_part[:3, 3] - truth[:3, 3]) < 1e-3
        for k in range(5):
            status = blind.step(images, joints, k / VISION_HZ).parts[part.name].status
            assert status == "waiting"
    finally:
        world.close()


def test_a_part_let_go_onto_the_table_is_searched_for_on_the_table(cell):
    """The part lying on the table beside the conveyor, 7 cm below the belt the cell file puts
    it on: told (the kinematic prior's ``supports``) that it lies on the table where it was let
    go (5 cm and 20 deg from where it came to rest), the whole-image search finds it within
    1 mm of the simulator's pose in the first frame; searched for on the belt's plane, as
    before the prior, it is not found there."""
    from cellsight.tracking import Tracker

    part = cell.workpieces[0]
    world = World(cell, seed=1)
    on_table = _moved(part.T_base_part, [0.88 - part.T_base_part[0, 3], -0.28], 0.3)
    table_top = max(v[2] for obj in cell.static if obj.name == "table"
                    for v in (obj.solids[0].vertices @ obj.T_base_obj[:3, :3].T
                              + obj.T_base_obj[:3, 3]))
    bottom = (part.solid.vertices @ on_table[:3, :3].T + on_table[:3, 3])[:, 2].min()
    on_table[2, 3] += table_top - bottom
    world.place_part(part.name, on_table)
    let_go = _moved(on_table, [0.04, -0.03], math.radians(20))
    predictor = visibility_predictor(cell)
    told, untold = Tracker.from_cell(cell, predictor), Tracker.from_cell(cell, predictor)
    try:
        world.step({}, {})
        images, joints = world.render(), world.measured_joints()
        truth = world.true_part_poses()[part.name]
        rec = told.step(images, joints, 0.0, supports={part.name: let_go}).parts[part.name]
        assert rec.status == "acquired"
        assert np.linalg.norm(rec.T_base_part[:3, 3] - truth[:3, 3]) < 1e-3
        rec = untold.step(images, joints, 0.0).parts[part.name]
        assert (rec.status != "acquired"
                or np.linalg.norm(rec.T_base_part[:3, 3] - truth[:3, 3]) > 5e-3)
    finally:
        world.close()


def test_kidnap_moves_a_free_part_once_and_the_conveyor_keeps_the_move(cell):
    from cellsight.world import ConveyorPath

    part = cell.workpieces[0]
    start = part.T_base_part[:2, 3]
    kidnap = Kidnap(part.name, 0.1, 0.2, np.array([0.1, -0.05]), math.radians(20))
    conveyor = ConveyorPath([start, start + [0.5, 0.0]], speed=0.1)
    world = World(cell, conveyor=conveyor, errors=Imperfections(kidnap=kidnap))
    plain = World(cell, conveyor=conveyor)
    try:
        for _ in range(200):  # 0.4 s
            world.step({}, {})
            plain.step({}, {})
            if world.time < kidnap.t_move - 1e-9:
                np.testing.assert_allclose(world.true_part_poses()[part.name],
                                           plain.true_part_poses()[part.name], atol=1e-9)
        expected = _moved(plain.true_part_poses()[part.name], kidnap.shift, kidnap.turn)
        np.testing.assert_allclose(world.true_part_poses()[part.name], expected, atol=1e-6)
        assert world.faults.moved is True
        assert kidnap.blind(0.1) and kidnap.blind(0.29) and not kidnap.blind(0.3)
    finally:
        world.close()
        plain.close()


@settings(max_examples=100, deadline=None)
@given(st.floats(-math.pi, math.pi), st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_rotation_helpers_match_their_closed_forms(angle, axis):
    """``rotation_z`` is the textbook matrix; ``rotation_angle`` is ``acos((tr R - 1) / 2)``,
    the angle the kidnap and knock figures report, and SciPy's axis-angle magnitude."""
    from scipy.spatial.transform import Rotation

    from cellsight.geometry.transforms import rotation_angle, rotation_z

    c, s = math.cos(angle), math.sin(angle)
    np.testing.assert_allclose(rotation_z(angle), [[c, -s, 0], [s, c, 0], [0, 0, 1]],
                               atol=1e-12)
    R = Rotation.from_rotvec(np.asarray(axis) * angle).as_matrix()
    expected = math.acos(min(1.0, max(-1.0, (np.trace(R) - 1) / 2)))
    assert rotation_angle(R) == pytest.approx(expected, abs=1e-6)
    assert rotation_angle(R) == pytest.approx(Rotation.from_matrix(R).magnitude(), abs=1e-12)


def test_lost_after_looking_in_vain_or_after_long_without_measurements():
    rule = LossRule(lost_after_s=2.0, unseen_s=0.3, min_looked=4, min_found=0.34)
    assert rule.in_vain(11, 1) is True  # one wrong corner fitting a wide prediction
    assert rule.in_vain(11, 3) is True  # three of eleven: clutter at the old place
    assert rule.in_vain(12, 5) is False and rule.in_vain(3, 0) is None
    assert rule.in_vain(3, 1) is False
    assert rule.in_vain(0, 0, in_view=False) is True  # a prediction flown out of every view
    assert not rule.lost(1.0, 0.5, math.inf)
    assert not rule.lost(1.0, 0.5, 0.8)
    assert rule.lost(1.1, 0.5, 0.8)
    assert rule.lost(2.6, 0.5, math.inf)


def test_a_coasting_track_resumes_on_half_of_what_it_looked_for():
    rule = LossRule(min_looked=4, resume_found=0.5)
    assert rule.resume_support(11) == 6  # four wrong corners of eleven do not resume it
    assert rule.resume_support(16) == 8
    assert rule.resume_support(3) == 0  # too few looked for to judge: the plain gate


def test_kidnap_profile_puts_the_part_back_in_a_cameras_view(cell):
    from cellsight.realism.draws import KIDNAP_MARGIN_PX, draw_world

    for seed in range(10):
        k = draw_world("kidnap", cell, seed).errors.kidnap
        part = cell.workpieces[0]
        assert 0.1 <= np.hypot(*k.shift) <= 0.3 and abs(k.turn) <= math.radians(45)
        there = _moved(part.T_base_part, k.shift, 0.0)[:3, 3]
        assert any(c.sees(there[None], KIDNAP_MARGIN_PX / 2)[0] for c in cell.cameras)
    assert draw_world("kidnap/faults", cell, 0).errors.kidnap is not None
    assert draw_world("lab", cell, 0).errors.kidnap is None


PROFILE = """
profiles:
  early-kidnap:
    faults:
      kidnap_probability: 1.0
      kidnap_time_s: 1.5
      kidnap_blind_s: 1.0
      kidnap_distance_mm: 180.0
      kidnap_direction_deg: 200.0
      kidnap_turn_deg: 30.0
"""


def test_a_kidnapped_part_is_noticed_and_found_again(tmp_path):
    """Experiment 1, ideal sensor: blind from 1.5 s to 2.5 s, the part moved 18 cm and turned
    30 deg at 2.0 s. When the cameras see again, a wrong corner in camera 2 fits the wide
    prediction for one frame (said ``tracking``, 170 mm off), then the track is degraded;
    within 0.5 s of seeing again the tracker drops it and finds the part from the whole
    image, within 2 mm of the truth within 1 s of the part being visible."""
    from cellsight.experiments import RunConfig, run_experiment

    profile = tmp_path / "kidnap.yaml"
    profile.write_text(PROFILE)
    metrics = run_experiment(RunConfig(1, tmp_path / "run", sensor="ideal",
                                       realism=f"{profile}:early-kidnap", duration=3.4,
                                       progress=False, video_every=0))
    k = metrics["kidnap"]
    assert k["moved"] is True and k["distance_mm"] == pytest.approx(180.0)
    assert k["wrong_tracking_s"] <= 0.1
    assert k["noticed_s"] is not None and k["noticed_s"] <= 0.5
    assert k["reacquired_s"] is not None and k["reacquired_s"] <= 1.0
    assert k["recovered_s"] <= k["reacquired_s"] and k["before_mm"] < 2.0
    assert metrics["confident_wrong_frames"] <= 2
    log = (tmp_path / "run" / "run.log").read_text()
    assert "kidnapping noticed" in log and "found again" in log


KNOCK = """
profiles:
  early-knock:
    faults:
      knock_probability: 1.0
      knock_camera: 1
      knock_time_s: 2.0
"""


def test_a_knocked_camera_is_dropped_and_its_pose_re_estimated(tmp_path):
    """Experiment 1, ideal sensor: camera 2 moved 20 mm and turned 1 deg at 2.0 s (rendering
    and truth). Its features leave their windows; within 2 s the check finds them all at one
    image offset, twice, and drops the camera (nothing dropped before the knock; today 1.0 s
    after it); camera 1 alone then holds the estimate within 2.5 mm RMSE and 6 mm at most of
    the truth (today 1.2 mm and 2.4 mm; 1.9 and 5.1 mm when the camera was dropped at the first
    look, 0.3 s earlier, still converging from the knock: the issue asks 2 mm, the depth along
    one camera is not that good), and the camera's re-estimated pose (refitted to 60 points of
    a still part seen over about 1 s) is within 15 mm and 0.5 deg of its true one (today 7.8 mm
    and 0.27 deg) and projects the part's feature points within 2.5 px of the true camera
    (today 0.4 px: the estimate's own error; one place fixes the pose there)."""
    from cellsight.experiments import RunConfig, run_experiment
    from cellsight.runfolder.framelog import FrameLog

    profile = tmp_path / "knock.yaml"
    profile.write_text(KNOCK)
    run = tmp_path / "run"
    metrics = run_experiment(RunConfig(1, run, sensor="ideal", realism=f"{profile}:early-knock",
                                       duration=4.5, progress=False, video_every=0))
    k = metrics["knock"]
    assert k["camera"] == "cam2" and k["shift_mm"] == pytest.approx(20.0)
    assert 0.0 < k["detected_s"] <= 2.0 and metrics["cameras_dropped"] == {"cam2": pytest.approx(
        2.0 + k["detected_s"])}
    error = k["recovered"]["error"]
    assert error["mm"] < 15.0 and error["deg"] < 0.5
    assert k["recovered"]["error_px"] < 2.5
    log = FrameLog.read(run / "frames.csv")
    t = log.floats("t")
    true, est = log.poses("true"), log.poses("est")
    late = t >= 2.0 + k["detected_s"] + 0.5
    error = np.linalg.norm(true[late, :3] - est[late, :3], axis=1)
    assert np.sqrt(np.mean(error**2)) < 2.5e-3 and error.max() < 6e-3, error
    assert "camera cam2 disagrees" in (run / "run.log").read_text()


@pytest.mark.parametrize(("moved", "seen", "wanders", "turn_deg", "dropped"),
                         [(12, 12, False, 0.0, True), (8, 12, False, 0.0, False),
                          (12, 12, True, 0.0, False), (12, 12, False, 2.0, True),
                          (12, 12, False, 8.0, False), (8, 10, False, 0.0, True),
                          (7, 10, False, 0.0, False)])
def test_a_camera_is_dropped_for_one_offset_of_nearly_all_its_features(cell, moved, seen, wanders,
                                                                       turn_deg, dropped):
    """Both cameras agree for a second (all 12 features found, unbiased innovations); then
    camera 2 finds 4 of them for a second while camera 1 finds them all. When its whole image
    holds all 12 moved by one offset, looked at twice, it was knocked: dropped, and between
    the two looks it updates nothing; so it is when they are also turned by 2 deg about the
    image's centre (a knock turns the camera: 7 of 12 within 2.5 px of one offset then), not
    by 8 deg (more than a knock turns it). When only 8 (67 %) line up at one offset (clutter
    beside an occluder), it is kept; so it is when all 12 line up at an offset that is another
    at each look (clutter that lines up by chance, as a cell's 500 whole-image corners did),
    and it is held out only until the second look disagrees. A camera that never agreed is
    never dropped (the last check). With 10 of them predicted visible (a gripper hides the
    others), 8 found at one offset are a knock (a carried part's knocked camera: 8 of 10 at
    one offset, 10 of 10 nowhere), 7 are not."""
    from cellsight.tracking.camera_check import CameraCheckRule, CheckFrame

    rng = np.random.default_rng(4)
    F = 12
    pixels = np.stack([rng.uniform([100, 100], [600, 450], (F, 2)) for _ in range(2)])
    clutter = rng.uniform([0, 0], [760, 570], (40, 2))
    looks = []
    visible = np.ones((2, F), bool)
    visible[1, seen:] = False

    def corners(c: int) -> np.ndarray:
        if c == 0:
            return pixels[0]
        looks.append(len(looks))
        offset = [40.0, -25.0] if not wanders or len(looks) % 2 else [-30.0, 35.0]
        a = np.radians(turn_deg)
        turned = (pixels[1] - [380.0, 285.0]) @ np.array([[np.cos(a), np.sin(a)],
                                                           [-np.sin(a), np.cos(a)]])
        return np.concatenate([(turned + [380.0, 285.0])[:moved] + offset, clutter])

    def run(agree_first: bool):
        check = CameraCheckRule().check(cell.cameras)
        held_out = 0
        for k in range(60):
            measured = pixels.copy()
            if k >= 30 or not agree_first:
                measured[1, 4:] = np.nan
            innovation = np.where(np.isfinite(measured), rng.normal(0, 0.3, measured.shape),
                                  np.nan)
            if not agree_first:
                innovation[1] = np.nan
            check.update(k / 26, CheckFrame(
                innovation, measured, pixels, visible, np.ones((2, F), bool),
                True, rng.normal(size=(F, 3)), corners))
            held_out += 1 not in check.dropped and not check.usable(1)
        return check, held_out

    check, held_out = run(agree_first=True)
    assert (1 in check.dropped) is dropped and 0 not in check.dropped
    assert looks
    if moved == 12 and turn_deg < 5:  # an offset found: held out for the 0.25 s to the second
        assert len(looks) >= 2 and 5 <= held_out <= 7  # look, no longer
    elif moved == 12:
        assert held_out == 0
    assert not run(agree_first=False)[0].dropped


def test_a_knocked_camera_half_hidden_at_its_first_look_is_looked_at_again_soon(cell):
    """A carried part's knocked camera: at the first look the gripper hides 4 of the 12
    features at the knock's offset (8 of 12 there, short of 75 %: a near miss, looked at again
    0.25 s later, the camera kept in the filter meanwhile); for 0.35 s after the first look
    only 7 of them are predicted visible (too few to judge by: those frames are not looks);
    then all 12 are seen at the same offset (the second look, 0.38 s after the first: held
    out), and again 0.27 s later (dropped), 0.65 s after the first look. At the code before,
    a near miss waited a second, and a frame of 7 visible spent the look: not dropped within
    the test's 3 s."""
    from cellsight.tracking.camera_check import CameraCheckRule, CheckFrame

    rng = np.random.default_rng(7)
    F = 12
    pixels = np.stack([rng.uniform([100, 100], [600, 450], (F, 2)) for _ in range(2)])
    clutter = rng.uniform([0, 0], [760, 570], (40, 2))
    looks: list[int] = []
    k = 0

    def corners(c: int) -> np.ndarray:
        if c == 0:
            return pixels[0]
        looks.append(k)
        shown = 8 if len(looks) == 1 else F
        return np.concatenate([pixels[1, :shown] + [40.0, -25.0], clutter])

    check = CameraCheckRule().check(cell.cameras)
    dropped_at, held_out = None, []
    for k in range(80):
        measured = pixels.copy()
        if k >= 30:
            measured[1, 4:] = np.nan
        innovation = np.where(np.isfinite(measured), rng.normal(0, 0.3, measured.shape), np.nan)
        visible = np.ones((2, F), bool)
        if looks and looks[0] < k <= looks[0] + 9:
            visible[1, 7:] = False
        check.update(k / 26, CheckFrame(innovation, measured, pixels, visible,
                                        np.ones((2, F), bool), True, rng.normal(size=(F, 3)),
                                        corners))
        if dropped_at is None and 1 in check.dropped:
            dropped_at = k
        if not check.usable(1) and 1 not in check.dropped:
            held_out.append(k)
    assert looks and dropped_at is not None, looks
    first = looks[0]
    assert looks[:3] == [first, first + 10, first + 17] and dropped_at == first + 17, looks
    assert held_out == list(range(first + 10, first + 17)), held_out
    assert 0 not in check.dropped


def test_a_part_s_twins_turn_half_its_points_or_more_onto_its_own(cell):
    """``twin_turns`` against a count by hand: the built-in part (a U-shaped prism) maps all
    16 feature points onto its own under a half turn about its y axis (upside down), and 8 of
    16 (the outer box's corners; the notch's move 20 mm) under half turns about x and z through
    its box's centre; quarter turns put fewer than half within 2 % of its size. A part of
    random points has no twin."""
    points = cell.workpieces[0].feature_points
    turns = twin_turns(points)
    tol = TWIN_TOL * np.linalg.norm(np.ptp(points, axis=0))
    matched = []
    for turn in turns:
        moved = points @ turn[:3, :3].T + turn[:3, 3]
        near = np.linalg.norm(moved[:, None] - points[None], axis=2).min(axis=1) <= tol
        matched.append(int(near.sum()))
        assert np.isclose(abs(np.trace(turn[:3, :3])), 1.0)  # a half turn: trace -1
    assert sorted(matched) == [8, 8, 16]
    rng = np.random.default_rng(0)
    assert twin_turns(rng.uniform(-0.05, 0.05, (16, 3))) == []

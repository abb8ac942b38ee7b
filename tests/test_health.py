"""Tracking health (:mod:`cellsight.tracking.health`): the NIS window against its chi-square
band on innovations drawn from the model, the not-found and rejected fractions of hand-made
records, the status text, and a short real run without a false alarm."""

from __future__ import annotations

import numpy as np
import pytest

from cellsight.tracking import (
    HealthMonitor,
    HealthRule,
    PartFrame,
    TrackHealthReport,
    TrackStatus,
)
from cellsight.tracking.health import nis_band

HZ = 26.0  # frames per second, as the vision rate
CAMS = ["cam1", "cam2"]


def _innovations(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    """Squared Mahalanobis distances (n,) of innovations drawn from N(0, S) for random 2x2
    covariances S, times ``scale`` on the innovation; computed with numpy, not the package."""
    A = rng.normal(size=(n, 2, 2))
    S = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(2)
    nu = scale * np.einsum("nij,nj->ni", np.linalg.cholesky(S), rng.normal(size=(n, 2)))
    return np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def _feed_windows(rule: HealthRule, n_windows: int, features: int, scale: float,
                  seed: int = 0) -> list[TrackHealthReport]:
    """Frames at ``HZ`` with every feature of both cameras visible, selected, found and
    accepted; the report at the end of each full, non-overlapping window."""
    rng = np.random.default_rng(seed)
    monitor = rule.monitor(CAMS)
    shape = (len(CAMS), features)
    per_window = int(round(rule.window_s * HZ))
    ones, none = np.ones(shape, dtype=bool), np.zeros(shape, dtype=bool)
    reports = []
    for k in range(n_windows * per_window):
        d2 = _innovations(rng, ones.size, scale).reshape(shape)
        report = monitor.update(k / HZ, ones, ones, np.zeros(shape + (2,)), none, d2)
        if k % per_window == per_window - 1:
            reports.append(report)
    return reports


def test_the_band_holds_the_chi_square_sums_drawn_with_numpy():
    rng = np.random.default_rng(1)
    for dof, p in [(20, 0.99), (260, 0.99), (60, 0.9)]:
        sums = np.square(rng.normal(size=(200_000, dof))).sum(axis=1)
        low, high = nis_band(dof, p)
        assert np.mean(sums < low) == pytest.approx((1 - p) / 2, abs=0.002)
        assert np.mean(sums > high) == pytest.approx((1 - p) / 2, abs=0.002)


def test_the_band_is_scipy_s_chi_square_quantiles_to_the_bit():
    from scipy.stats import chi2

    for p in (0.9, 0.99, 0.999):
        tail = (1 - p) / 2
        for dof in range(1, 3001):
            assert nis_band(dof, p) == (chi2.ppf(tail, dof), chi2.isf(tail, dof)), (dof, p)


def test_a_consistent_filter_stays_in_the_band_and_scaled_innovations_are_flagged():
    rule = HealthRule(window_s=1.0, band_probability=0.99)
    reports = _feed_windows(rule, 300, features=5, scale=1.0)
    assert all(np.all(r.nis_dof == 2 * 26 * 5) for r in reports)
    inside = np.array([~(r.nis_above | r.nis_below) for r in reports])
    assert 0.975 <= inside.mean() <= 0.998, inside.mean()  # 99 %, neither wider nor narrower
    ratios = np.array([r.nis_ratio for r in reports])
    assert ratios.mean() == pytest.approx(1.0, abs=0.01)
    assert not any(r.reasons for r in reports)
    scaled = _feed_windows(rule, 20, features=5, scale=3.0, seed=2)
    assert all(r.nis_above.all() and not r.nis_below.any() for r in scaled)
    assert all(6.5 < ratio < 11.5 for r in scaled for ratio in r.nis_ratio)  # 9 +- 3 sd
    assert np.mean([r.nis_ratio for r in scaled]) == pytest.approx(9.0, abs=0.3)
    assert all([reason.split()[0] for reason in r.reasons] == ["NIS", "NIS"] for r in scaled)
    assert scaled[0].reasons[1].endswith("x in cam2")


def test_a_small_window_is_not_judged():
    """Fewer accepted measurements than ``min_measurements``: far out of the band, no reason."""
    rule = HealthRule(min_measurements=30)
    shape = (2, 4)
    ones, none = np.ones(shape, dtype=bool), np.zeros(shape, dtype=bool)
    monitor = rule.monitor(CAMS)
    for k in range(7):  # 28 measurements per camera
        report = monitor.update(k / HZ, ones, ones, np.zeros(shape + (2,)), none,
                                np.full(shape, 50.0))
    assert report.nis_above.all() and report.nis_ratio == pytest.approx([25.0, 25.0])
    assert report.reasons == ()
    report = monitor.update(7 / HZ, ones, ones, np.zeros(shape + (2,)), none,
                            np.full(shape, 50.0))
    assert report.reasons == ("NIS 25.0x in cam1", "NIS 25.0x in cam2")


def _frame(visible, selected, found, rejected, d2=None):
    """A hand-made frame of two cameras and six features (rows: cameras)."""
    found = np.array(found, dtype=bool)
    measured = np.where(found[..., None], 100.0, np.nan) * np.ones(2)
    d2 = np.where(found, 2.0, np.nan) if d2 is None else np.array(d2, dtype=float)
    return (np.array(visible, dtype=bool), np.array(selected, dtype=bool), measured,
            np.array(rejected, dtype=bool), d2)


def test_not_found_and_rejected_fractions_of_hand_made_records():
    rule = HealthRule(window_s=1.0, missing_limit=0.5, rejected_limit=0.25, min_measurements=1)
    monitor = HealthMonitor(rule, CAMS)
    # cam1: 4 selected visible features (feature 4 is selected but predicted hidden: not
    # counted as looked for), 2 of them found, plus feature 4; feature 1 rejected.
    # cam2: 3 selected, all found and accepted.
    first = _frame(visible=[[1, 1, 1, 1, 0, 0], [1] * 6],
                   selected=[[1, 1, 1, 1, 1, 0], [1, 1, 1, 0, 0, 0]],
                   found=[[1, 1, 0, 0, 1, 0], [1, 1, 1, 0, 0, 0]],
                   rejected=[[0, 1, 0, 0, 0, 0], [0] * 6],
                   d2=[[1.0, 500.0, np.nan, np.nan, 3.0, np.nan], [4.0, 4.0, 4.0] + [np.nan] * 3])
    report = monitor.update(0.0, *first)
    np.testing.assert_allclose(report.missing_fraction, [2 / 4, 0.0])
    np.testing.assert_allclose(report.rejected_fraction, [1 / 3, 0.0])
    np.testing.assert_allclose(report.nis_ratio, [(1.0 + 3.0) / 4, 12.0 / 6])  # rejected: out
    np.testing.assert_array_equal(report.nis_dof, [4, 6])
    assert report.reasons == ("33% rejected in cam1",)  # 50 % not found is not above 50 %
    # cam1 finds none of its 4 this time; cam2 selects nothing (its figures stay)
    second = _frame(visible=[[1, 1, 1, 1, 0, 0], [0] * 6],
                    selected=[[1, 1, 1, 1, 0, 0], [0] * 6],
                    found=[[0] * 6, [0] * 6], rejected=[[0] * 6, [0] * 6])
    report = monitor.update(0.5, *second)
    np.testing.assert_allclose(report.missing_fraction, [6 / 8, 0.0])
    np.testing.assert_allclose(report.rejected_fraction, [1 / 3, 0.0])
    assert report.reasons == ("75% not found in cam1", "33% rejected in cam1")
    # at 1.2 s the first frame has left the 1 s window: cam2 has nothing left to judge
    report = monitor.update(1.2, *second)
    np.testing.assert_allclose(report.missing_fraction[0], 1.0)
    assert np.isnan(report.missing_fraction[1]) and np.isnan(report.rejected_fraction).all()
    assert np.isnan(report.nis_ratio).all() and not report.nis_above.any()
    assert report.reasons == ("100% not found in cam1",)
    monitor.reset(0.5)  # a new filter, a window (1 s) before the next frame
    report = monitor.update(2.0, *first)
    np.testing.assert_allclose(report.missing_fraction, [2 / 4, 0.0])


def _found(k: int) -> tuple:
    """cam1 finds ``k`` of its 6 selected visible features (none rejected), cam2 all of its."""
    return _frame(visible=[[1] * 6, [1] * 6], selected=[[1] * 6, [1] * 6],
                  found=[[1] * k + [0] * (6 - k), [1] * 6], rejected=[[0] * 6, [0] * 6])


def test_a_reason_holds_until_its_figure_falls_below_the_release_fraction():
    """Hysteresis: 67 % not found passes the 50 % limit; 50 % and 33 % not found (above 0.6
    of it, 30 %) keep the reason; 17 % releases it; 33 % again does not bring it back."""
    rule = HealthRule(window_s=0.01, missing_limit=0.5, min_measurements=1, release=0.6)
    monitor = HealthMonitor(rule, CAMS)
    reasons = [monitor.update(0.1 * i, *_found(k)).reasons
               for i, k in enumerate([6, 3, 2, 3, 4, 5, 4])]
    assert reasons == [(), (), ("67% not found in cam1",), ("50% not found in cam1",),
                       ("33% not found in cam1",), (), ()]
    monitor.update(1.0, *_found(2))
    assert monitor.update(1.1, *_found(4)).reasons == ("33% not found in cam1",)
    monitor.reset(1.5)  # a new filter: nothing held
    assert monitor.update(2.0, *_found(4)).reasons == ()
    without = HealthMonitor(HealthRule(window_s=0.01, missing_limit=0.5, min_measurements=1,
                                       release=1.0), CAMS)
    assert [without.update(0.1 * i, *_found(k)).reasons != ()
            for i, k in enumerate([2, 3, 2, 3])] == [True, False, True, False]


def test_rule_refuses_nonsense():
    for bad in ({"window_s": 0.0}, {"band_probability": 1.0}, {"missing_limit": 1.5},
                {"rejected_limit": -0.1}, {"min_measurements": 0}, {"nis_ratio_limit": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            HealthRule(**bad)


def _record(status: TrackStatus, reasons: tuple[str, ...]) -> PartFrame:
    rec = PartFrame.empty("part", status, 2, 6, None, None, None)
    nan = np.full(2, np.nan)
    rec.health = TrackHealthReport(nan, np.zeros(2, dtype=int), np.zeros(2, dtype=bool),
                                   np.zeros(2, dtype=bool), nan, nan, reasons)
    return rec


def test_status_text_says_why_a_track_is_degraded():
    reasons = ("NIS 6.3x in cam2", "60% not found in cam1")
    assert _record(TrackStatus.DEGRADED, reasons).status_text == (
        "degraded: NIS 6.3x in cam2; 60% not found in cam1")
    assert _record(TrackStatus.TRACKING, ()).status_text == "tracking"
    assert _record(TrackStatus.COASTING, reasons).status_text == "coasting"
    assert PartFrame.empty("part", TrackStatus.LOST, 2, 6, None, None, None).status_text == "lost"
    assert TrackStatus.DEGRADED.has_estimate and TrackStatus.COASTING.has_estimate
    assert TrackStatus.TRACKING.has_estimate and TrackStatus.ACQUIRED.has_estimate
    assert not TrackStatus.LOST.has_estimate and not TrackStatus.WAITING.has_estimate
    assert [s.value for s in TrackStatus] == [
        "waiting", "acquired", "tracking", "degraded", "coasting", "lost"]


@pytest.mark.slow
def test_a_real_short_run_on_the_exact_world_raises_no_alarm(tmp_path):
    """Experiment 1, ideal sensor, exact world, 4 s: the monitor judges every camera once its
    window has filled, and never finds the track inconsistent; before that, the new track is
    tentative."""
    from cellsight.experiments import RunConfig
    from cellsight.experiments.runner import ExperimentRun
    from cellsight.runfolder.framelog import FrameLog

    run = ExperimentRun(RunConfig(1, tmp_path / "run", sensor="ideal", realism="exact",
                                  duration=4.0, progress=False, video_every=0))
    records, step = [], run.tracker.step

    def recording_step(*args, **kwargs):
        frame = step(*args, **kwargs)
        records.append((frame.t, frame.parts[run.part.name]))
        return frame

    run.tracker.step = recording_step
    run.run()
    statuses = FrameLog.read(tmp_path / "run" / "frames.csv").text("status")
    assert len(statuses) == len(records) > 90
    acquired = next(t for t, r in records if r.status == "acquired")
    window = HealthRule().window_s
    for t, r in records:
        new = 0 < t - acquired < window - 1e-9
        assert r.status_text == (f"degraded: acquired {t - acquired:.2f} s ago" if new
                                 else str(r.status)), t
    assert all(s == "tracking" for (t, _), s in zip(records, statuses, strict=True)
               if t - acquired >= window - 1e-9)
    records = [r for _, r in records]
    judged = [r.health for r in records[30:] if r.health is not None]
    assert len(judged) > 60
    assert all((h.nis_dof >= 2 * HealthRule().min_measurements).all() for h in judged)
    assert all(not h.reasons and not h.nis_above.any() for h in judged)


def test_a_held_part_off_its_holder_is_a_reason_with_hysteresis():
    """The holder's figure is the frame's own (no window), judged where one camera alone has
    accepted measurements: off by more than the limit it is a reason naming the distance and
    that camera, held down to ``release`` of the limit, cleared when the part is not held or
    both cameras measure it; the camera figures are not touched."""
    rule = HealthRule(holder_limit=0.006, release=0.7)
    monitor = HealthMonitor(rule, CAMS)

    def seen_by(*cams: int, rejected_in: int | None = None) -> tuple:
        found = [[1] * 6 if c in cams else [0] * 6 for c in range(2)]
        rejected = [[1] * 6 if c == rejected_in else [0] * 6 for c in range(2)]
        return _frame(visible=[[1] * 6] * 2, selected=[[1] * 6] * 2, found=found,
                      rejected=rejected)

    cam2, cam1, both = seen_by(1), seen_by(0), seen_by(0, 1)
    cam1_rejected = seen_by(0, 1, rejected_in=1)  # cam2 finds its features, all gated out
    steps = [(0.004, cam2, ()),  # within the limit
             (0.0087, cam2, ("8.7 mm from the gripper's hold, cam2 alone",)),
             (0.0045, cam2, ("4.5 mm from the gripper's hold, cam2 alone",)),  # 0.75: held
             (0.0040, cam2, ()),  # 0.67 of the limit: released
             (0.0050, cam1, ()),  # back above release, not above the limit: not again
             (0.0070, cam1_rejected, ("7.0 mm from the gripper's hold, cam1 alone",)),
             (0.0070, both, ()),  # both cameras: no figure
             (0.0050, cam1, ()),  # and no reason held over
             (None, cam1, ())]  # not held
    # the same frames, held just where the gripper says: the camera figures alone
    plain = HealthMonitor(rule, CAMS)
    for k, (off, frame, reasons) in enumerate(steps):
        report = monitor.update(k / HZ, *frame, off_holder=off)
        cameras = plain.update(k / HZ, *frame, off_holder=0.0).reasons
        assert report.reasons == cameras + reasons, (k, off)
    with pytest.raises(ValueError, match="holder_limit"):
        HealthRule(holder_limit=0.0)


def test_a_free_part_seen_by_one_camera_over_the_window_is_a_reason():
    """A part not held whose accepted measurements come from one camera alone over the whole
    window is degraded, naming that camera; a measurement of the other within the window, a
    held part, or a tracker with one camera is not."""
    rule = HealthRule(window_s=0.5)
    only = {c: [[1] * 6 if k == c else [0] * 6 for k in range(2)] for c in (0, 1)}
    cam = {c: _frame(visible=only[c], selected=only[c], found=only[c], rejected=[[0] * 6] * 2)
           for c in (0, 1)}  # the other camera's view of the part blocked
    both = _frame(visible=[[1] * 6] * 2, selected=[[1] * 6] * 2, found=[[1] * 6] * 2,
                  rejected=[[0] * 6] * 2)
    # cam1 found everything but cam2's features were all gated out: cam1 alone accepted
    gated = _frame(visible=[[1] * 6] * 2, selected=[[1] * 6] * 2, found=[[1] * 6] * 2,
                   rejected=[[0] * 6, [1] * 6])
    free, held = HealthMonitor(rule, CAMS), HealthMonitor(rule, CAMS)
    alone = "cam1 alone: depth from one view"
    n_window = int(rule.window_s * HZ)  # 13 frames: a frame 13 / HZ old has left the window
    for k in range(n_window):
        assert alone not in free.update(k / HZ, *(both if k == 0 else cam[0])).reasons, k
        assert not held.update(k / HZ, *(both if k == 0 else cam[0]), off_holder=0.0).reasons
    assert free.update(n_window / HZ, *cam[0]).reasons == (alone,)  # the last of cam2 gone
    assert alone in free.update((n_window + 1) / HZ, *gated).reasons
    assert alone not in free.update((n_window + 2) / HZ, *cam[1]).reasons  # both in the window
    assert not held.update(n_window / HZ, *cam[0], off_holder=0.0).reasons
    single = HealthMonitor(rule, ["cam1"])
    one = tuple(np.asarray(a)[:1] for a in cam[0])
    assert not any(single.update(k / HZ, *one).reasons for k in range(2 * n_window))


def test_a_new_filter_is_tentative_for_a_window():
    """After a (re)start at ``t0`` every frame less than ``window_s`` later says how long ago
    the part was acquired, after the figures' own reasons; from a window on, the figures
    alone; a monitor never reset (no filter start known) has no such reason."""
    rule = HealthRule(window_s=0.5)
    both = _frame(visible=[[1] * 6] * 2, selected=[[1] * 6] * 2, found=[[1] * 6] * 2,
                  rejected=[[0] * 6] * 2)
    monitor, t0 = HealthMonitor(rule, CAMS), 3.0
    monitor.reset(t0)
    n_window = int(rule.window_s * HZ)  # 13 frames: the 13th is 0.5 s after the start
    for k in range(1, n_window):
        assert monitor.update(t0 + k / HZ, *both).reasons == (f"acquired {k / HZ:.2f} s ago",)
    assert monitor.update(t0 + n_window / HZ, *both).reasons == ()
    cam1 = _frame(visible=[[1] * 6] * 2, selected=[[1] * 6] * 2,
                  found=[[1] * 6, [0] * 6], rejected=[[0] * 6] * 2)
    monitor.reset(10.0)
    assert monitor.update(10.1, *cam1, off_holder=0.009).reasons == (
        "9.0 mm from the gripper's hold, cam1 alone", "acquired 0.10 s ago")
    assert HealthMonitor(rule, CAMS).update(0.0, *both).reasons == ()

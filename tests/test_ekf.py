"""EKF pieces: motion model, measurement Jacobian, update, gating, adaptive noise, PnP."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from cellsight import load_cell
from cellsight.camera import Camera
from cellsight.geometry.transforms import look_at, pose_from_xyz_rpy, xyz_rpy_from_pose
from cellsight.tracking import (
    AdaptiveNoise,
    ConstantVelocity,
    Observation,
    PinholeMeasurement,
    PoseEKF,
    estimate_pose,
    estimate_pose_robust,
    solve_pnp_camera,
)
from cellsight.tracking.ekf import HELD, RESTING, SUPPORT_RATES
from cellsight.tracking.gate import ChiSquareGate
from cellsight.tracking.measurement import rotation_of_state

K = np.array([[1200.0, 0.0, 380.0], [0.0, 1180.0, 290.0], [0.0, 0.0, 1.0]])
TARGET = np.array([0.6, 0.0, 0.6])
GATE = ChiSquareGate(0.999)


def _cameras() -> list[Camera]:
    return [
        Camera(K, 768, 576, look_at([0.2, 1.2, 1.7], TARGET), name="a"),
        Camera(K, 768, 576, look_at([1.4, 1.0, 1.6], TARGET), name="b"),
    ]


def _prism() -> np.ndarray:
    """16 corners of a non-convex octagonal prism, ~10 cm across, 3.5 cm thick (part frame)."""
    ang = np.deg2rad(22.5 + 45.0 * np.arange(8))
    r = np.full(8, 0.05)
    r[3] = 0.025  # one vertex pushed in: non-convex
    xy = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    return np.vstack([np.column_stack([xy, np.zeros(8)]), np.column_stack([xy, np.full(8, 0.035)])])


def _state(xyz, rpy, vel=(0.0,) * 6) -> np.ndarray:
    return np.concatenate([xyz, rpy, vel])


def _observe(cams, pts, state, sigma, rng, ids=None):
    ids = np.arange(len(pts)) if ids is None else ids
    out = []
    for c, cam in enumerate(cams):
        model = PinholeMeasurement(cam, 0.5)
        px = model.function(state, pts[ids]) + rng.normal(0, sigma, (len(ids), 2))
        out.append(Observation(model, c, ids, pts[ids], px))
    return out


def test_process_noise_matches_continuous_white_acceleration():
    """Q equals the integral of the continuous model (Van Loan, independent of the formula)."""
    model = ConstantVelocity(q_linear=0.3, q_angular=2.0)
    dt = 1 / 26
    F = np.zeros((12, 12))
    F[:6, 6:] = np.eye(6)
    Qc = np.zeros((12, 12))
    Qc[6:, 6:] = np.diag([0.3] * 3 + [2.0] * 3)
    M = np.block([[-F, Qc], [np.zeros((12, 12)), F.T]]) * dt
    E = expm(M)
    Q_ref = E[12:, 12:].T @ E[:12, 12:]
    np.testing.assert_allclose(model.covar(dt), Q_ref, atol=1e-12)
    np.testing.assert_allclose(model.matrix(dt), expm(F * dt), atol=1e-12)


@pytest.mark.parametrize("skew", [0.0, 3.0])
def test_measurement_jacobian_matches_finite_differences(skew):
    Ks = K.copy()
    Ks[0, 1] = skew
    cam = Camera(Ks, 768, 576, look_at([0.2, 1.2, 1.7], TARGET))
    model = PinholeMeasurement(cam)
    pts = _prism()
    rng = np.random.default_rng(3)
    for _ in range(5):
        xyz, rpy = TARGET + rng.normal(0, 0.05, 3), rng.uniform(-0.6, 0.6, 3)
        state = _state(xyz, rpy, rng.normal(0, 1, 6))
        pix, J = model.evaluate(state, pts)
        T = pose_from_xyz_rpy(xyz, rpy)
        np.testing.assert_allclose(pix, cam.project(pts @ T[:3, :3].T + xyz), atol=1e-9)
        J_fd = np.zeros_like(J)
        h = 1e-6
        for i in range(12):
            d = np.zeros(12)
            d[i] = h
            diff = model.function(state + d, pts) - model.function(state - d, pts)
            J_fd[:, i] = diff.ravel() / (2 * h)
        np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-4)
        assert np.all(J[:, 6:] == 0)


def test_update_matches_information_form_and_stays_symmetric():
    """One Joseph-form update equals the information-form posterior (same linearisation)."""
    cams = _cameras()
    pts = _prism()
    truth = _state(TARGET, [0.05, -0.02, 0.3])
    rng = np.random.default_rng(0)
    obs = _observe(cams, pts, truth, 0.5, rng)
    x0 = truth + np.concatenate([[0.002, -0.001, 0.001, 0.01, -0.01, 0.02], np.zeros(6)])
    P0 = np.diag([1e-4] * 3 + [1e-3] * 3 + [0.04] * 3 + [0.25] * 3)
    ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
    H = np.concatenate([o.model.evaluate(x0, o.points_model)[1] for o in obs])
    R = 0.25 * np.eye(len(H))
    P_info = np.linalg.inv(np.linalg.inv(P0) + H.T @ np.linalg.inv(R) @ H)
    nu = np.concatenate([(o.pixels - o.model.function(x0, o.points_model)).ravel() for o in obs])
    x_info = x0 + P_info @ H.T @ np.linalg.inv(R) @ nu
    report = ekf.update(obs)
    assert report.n_accepted == 2 * len(pts)
    np.testing.assert_allclose(ekf.covariance, P_info, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(ekf.state, x_info, atol=1e-9)
    assert np.allclose(ekf.covariance, ekf.covariance.T)
    assert np.all(np.linalg.eigvalsh(ekf.covariance) > 0)


def test_resting_on_a_support_matches_the_information_form():
    """``fuse_prior`` with ``RESTING``: the pseudo-measurement of height, roll, pitch (from
    the support's pose) and their rates (zero) equals the information-form posterior with H
    selecting those six states; the roll innovation is taken the short way round the circle,
    and the roll it gives wrapped to [-pi, pi)."""
    rng = np.random.default_rng(1)
    x0 = np.concatenate([[0.6, 0.1, 0.63, np.pi - 0.01, -0.02, 0.3], rng.normal(0, 0.05, 6)])
    A = rng.normal(size=(12, 12))
    P0 = 1e-3 * (A @ A.T + np.eye(12))  # correlated: the update moves the other states too
    rest = pose_from_xyz_rpy([0.5, 0.0, 0.62], [-np.pi + 0.01, 0.0, 0.1])
    std = (0.002, 0.01)
    ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
    ekf.fuse_prior(rest, RESTING, [std[0], std[1], std[1], std[0], std[1], std[1]])
    rows = [2, 3, 4, 8, 9, 10]
    H = np.eye(12)[rows]
    R = np.diag(np.array([std[0], std[1], std[1], std[0], std[1], std[1]]) ** 2)
    nu = np.array([0.62 - 0.63, 0.02, 0.02, 0.0, 0.0, 0.0]) - np.r_[0, 0, 0, x0[[8, 9, 10]]]
    P_info = np.linalg.inv(np.linalg.inv(P0) + H.T @ np.linalg.inv(R) @ H)
    x_info = x0 + P_info @ H.T @ np.linalg.inv(R) @ nu
    x_info[3] -= 2 * np.pi  # past pi: wrapped
    np.testing.assert_allclose(ekf.covariance, P_info, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(ekf.state, x_info, atol=1e-9)
    assert abs(ekf.state[2] - 0.62) < 2 * std[0] and np.all(np.linalg.eigvalsh(ekf.covariance) > 0)


def test_rates_fused_at_a_bound_match_the_information_form():
    """``fuse_prior`` with ``SUPPORT_RATES`` and given ``rates``: the pseudo-measurement that
    the x, y and yaw rates are those rates (the pose's states unmeasured) equals the
    information-form posterior with H selecting those three states."""
    rng = np.random.default_rng(3)
    x0 = np.concatenate([[0.6, 0.1, 0.63, 0.01, -0.02, 0.3], [0.3, -0.2, 0.0, 0.0, 0.0, 0.5]])
    A = rng.normal(size=(12, 12))
    P0 = 1e-3 * (A @ A.T + np.eye(12))
    rates = np.array([0.04, -0.03, 0.0, 0.0, 0.0, 0.1])
    std = np.array([0.005, 0.005, 0.01])
    ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
    ekf.fuse_prior(pose_from_xyz_rpy([9.0, 9.0, 9.0], [1.0, 1.0, 1.0]), SUPPORT_RATES, std,
                   rates=rates)
    H = np.eye(12)[SUPPORT_RATES]
    nu = rates[[0, 1, 5]] - x0[SUPPORT_RATES]
    P_info = np.linalg.inv(np.linalg.inv(P0) + H.T @ np.diag(std**-2.0) @ H)
    x_info = x0 + P_info @ H.T @ np.diag(std**-2.0) @ nu
    np.testing.assert_allclose(ekf.covariance, P_info, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(ekf.state, x_info, atol=1e-9)


def test_held_by_a_gripper_matches_the_information_form():
    """``fuse_prior`` with ``HELD``: the pseudo-measurement of the whole pose (the holder's)
    equals the information-form posterior with H selecting the six pose states; the yaw
    innovation is taken the short way round, and the rates move only through their
    correlation with the pose."""
    rng = np.random.default_rng(2)
    x0 = np.concatenate([[0.4, -0.2, 0.9, 0.1, -0.05, -np.pi + 0.02], rng.normal(0, 0.05, 6)])
    A = rng.normal(size=(12, 12))
    P0 = 1e-3 * (A @ A.T + np.eye(12))
    hold = pose_from_xyz_rpy([0.41, -0.19, 0.905], [0.12, -0.04, np.pi - 0.03])
    std = np.array([0.002, 0.002, 0.002, 0.02, 0.02, 0.02])
    ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
    ekf.fuse_prior(hold, HELD, std)
    H = np.eye(12)[:6]
    R = np.diag(std**2)
    xyz, rpy = xyz_rpy_from_pose(hold)
    nu = np.concatenate([xyz, rpy]) - x0[:6]
    nu[5] = -0.05  # from -pi + 0.02 to pi - 0.03 the short way
    P_info = np.linalg.inv(np.linalg.inv(P0) + H.T @ np.linalg.inv(R) @ H)
    x_info = x0 + P_info @ H.T @ np.linalg.inv(R) @ nu
    x_info[5] = (x_info[5] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(ekf.covariance, P_info, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(ekf.state, x_info, atol=1e-9)
    assert np.linalg.norm(ekf.state[:3] - xyz) < 3 * std[0]


def test_no_measurement_only_predicts():
    motion = ConstantVelocity()
    x0 = _state(TARGET, [0, 0, 0.1], [0.1, 0, 0, 0, 0, 0.2])
    P0 = np.eye(12) * 1e-3
    ekf = PoseEKF(motion, x0, P0, 1.0)
    ekf.predict(1.0 + 1 / 26)
    report = ekf.update([])
    A, Q = motion.matrix(1 / 26), motion.covar(1 / 26)
    np.testing.assert_allclose(ekf.state, A @ x0)
    np.testing.assert_allclose(ekf.covariance, A @ P0 @ A.T + Q)
    assert report.n_accepted == 0 and len(report.accepted) == 0


def test_static_pose_converges_within_its_covariance():
    cams = _cameras()
    pts = _prism()
    truth = _state(TARGET, [0.1, 0.05, -0.4])
    rng = np.random.default_rng(1)
    x0 = truth + np.concatenate([[0.01, -0.01, 0.005, 0.05, -0.05, 0.05], np.zeros(6)])
    P0 = np.diag([0.02**2] * 3 + [0.1**2] * 3 + [0.1**2] * 3 + [0.3**2] * 3)
    ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
    for k in range(1, 60):
        ekf.predict(k / 26)
        ekf.update(_observe(cams, pts, truth, 0.5, rng), GATE)
    err = ekf.state[:6] - truth[:6]
    assert np.linalg.norm(err[:3]) < 1e-3 and np.linalg.norm(err[3:]) < 5e-3
    nees = err @ np.linalg.solve(ekf.covariance[:6, :6], err)
    assert nees < 22.5  # chi-square(6) 0.999 quantile


def test_gating_rejects_an_outlier_and_records_it():
    cams = _cameras()
    pts = _prism()
    truth = _state(TARGET, [0.0, 0.0, 0.2])
    P0 = np.diag([1e-5] * 3 + [1e-4] * 3 + [1e-3] * 6)
    obs = _observe(cams, pts, truth, 0.5, np.random.default_rng(2))
    bad = obs[1].pixels.copy()
    bad[4] += [15.0, -10.0]
    obs_bad = [obs[0], Observation(obs[1].model, 1, obs[1].feature_ids, obs[1].points_model, bad)]
    keep = np.arange(len(pts)) != 4
    clean = [obs[0], Observation(obs[1].model, 1, obs[1].feature_ids[keep],
                                 obs[1].points_model[keep], bad[keep])]
    ekf_a = PoseEKF(ConstantVelocity(), truth, P0, 0.0)
    ekf_b = PoseEKF(ConstantVelocity(), truth, P0, 0.0)
    report = ekf_a.update(obs_bad, GATE)
    ekf_b.update(clean, GATE)
    rejected = ~report.accepted
    assert rejected.sum() == 1
    assert report.camera_index[rejected][0] == 1 and report.feature_ids[rejected][0] == 4
    assert report.mahalanobis2[rejected][0] > 3 * GATE.threshold
    np.testing.assert_allclose(ekf_a.state, ekf_b.state, atol=1e-12)
    ekf_c = PoseEKF(ConstantVelocity(), truth, P0, 0.0)
    ekf_c.update(obs_bad)  # no gate
    err_gated = np.linalg.norm(ekf_a.state[:3] - truth[:3])
    assert np.linalg.norm(ekf_c.state[:3] - truth[:3]) > 5 * err_gated


def test_adaptive_noise_finds_the_true_pixel_noise():
    cams = _cameras()
    pts = _prism()
    truth = _state(TARGET, [0.0, 0.1, 0.2])
    rng = np.random.default_rng(4)
    P0 = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-2] * 6)
    ekf = PoseEKF(ConstantVelocity(q_linear=1e-6, q_angular=1e-6), truth, P0, 0.0,
                  adaptive=AdaptiveNoise(window=400))
    for k in range(1, 80):
        ekf.predict(k / 26)
        ekf.update(_observe(cams, pts, truth, 1.5, rng), GATE)
    for c, cam in enumerate(cams):
        assert ekf.sigma_px(PinholeMeasurement(cam, 0.5), c) == pytest.approx(1.5, rel=0.15)


def test_pnp_single_and_fused_recover_the_pose():
    cams = _cameras()
    pts = _prism()
    T = pose_from_xyz_rpy(TARGET + [0.03, -0.02, 0.01], [0.1, -0.05, 0.7])
    xyz, rpy = xyz_rpy_from_pose(T)
    state = _state(xyz, rpy)
    exact = _observe(cams, pts, state, 0.0, np.random.default_rng(0))
    for o in exact:
        np.testing.assert_allclose(solve_pnp_camera(o), T, atol=1e-6)
    fix = estimate_pose(exact)
    np.testing.assert_allclose(fix.T_base_part, T, atol=1e-8)
    assert fix.n_points == 32 and fix.n_cameras == 2 and fix.rms_px < 1e-6
    errs_single, errs_fused = [], []
    for seed in range(10):
        noisy = _observe(cams, pts, state, 0.5, np.random.default_rng(seed))
        errs_single.append(np.linalg.norm(solve_pnp_camera(noisy[0])[:3, 3] - T[:3, 3]))
        errs_fused.append(np.linalg.norm(estimate_pose(noisy).T_base_part[:3, 3] - T[:3, 3]))
    assert np.mean(errs_fused) < 0.5 * np.mean(errs_single)
    assert estimate_pose([exact[0].__class__(exact[0].model, 0, np.arange(3), pts[:3],
                                             exact[0].pixels[:3])]) is None


def test_state_rotation_follows_the_transforms_convention():
    rng = np.random.default_rng(9)
    for _ in range(20):
        rpy = rng.uniform(-np.pi, np.pi, 3) * [1, 0.49, 1]
        state = _state(np.zeros(3), rpy)
        R = pose_from_xyz_rpy(np.zeros(3), rpy)[:3, :3]
        np.testing.assert_allclose(rotation_of_state(state), R, atol=1e-12)


@pytest.mark.parametrize("points", [
    np.zeros((5, 3)),  # all at one point
    np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0], [0.03, 0.0, 0.0]]),  # a line
])
def test_pnp_on_degenerate_points_gives_no_pose(points):
    """Degenerate point sets make OpenCV's SQPnP raise; the baseline reports no pose."""
    cam = load_cell().cameras[0]
    obs = Observation(PinholeMeasurement(cam), 0, np.arange(len(points)), points,
                      np.full((len(points), 2), 300.0))
    assert solve_pnp_camera(obs) is None
    assert estimate_pose([obs]) is None


def _observations(seed: int, ids_of, wrong: tuple[int, int, list[float]]):
    """The built-in part at its nominal pose seen by every camera of the built-in cell: camera
    ``c`` measures features ``ids_of(c)`` with 0.2 px of noise; ``wrong`` = (camera, row,
    shift px) moves one corner. Returns (observations, ``T_base_part``)."""
    cell = load_cell()
    part = cell.workpieces[0]
    T = part.T_base_part
    pts = part.feature_points
    rng = np.random.default_rng(seed)
    obs = []
    for c, cam in enumerate(cell.cameras):
        ids = ids_of(c)
        px = cam.project(pts[ids] @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.2, (len(ids), 2))
        if c == wrong[0]:
            px[wrong[1]] += wrong[2]
        obs.append(Observation(PinholeMeasurement(cam), c, ids, pts[ids], px))
    return obs, T


def test_robust_pnp_drops_a_wrong_corner():
    """One corner 8 px off spoils the plain fused PnP (RMS above 2 px); the robust one drops it
    and recovers the pose."""
    obs, T = _observations(3, lambda c: np.arange(0, 16, 2) + c, (0, 3, [8.0, -5.0]))
    assert estimate_pose(obs).rms_px > 2.0
    fix = estimate_pose_robust(obs, max_rms_px=2.0)
    assert fix.rms_px < 0.5 and fix.n_points == 15
    assert np.linalg.norm(fix.T_base_part[:3, 3] - T[:3, 3]) < 1e-3


def test_robust_pnp_drops_a_wrong_corner_hidden_under_a_small_rms():
    """Among 32 corners one 7 px off leaves the fused PnP's RMS under 2 px; the bound on each
    point's residual drops it all the same, and the fix names it."""
    obs, T = _observations(5, lambda c: np.arange(16), (1, 9, [5.0, -5.0]))
    assert estimate_pose_robust(obs, max_rms_px=2.0).dropped == ()
    fix = estimate_pose_robust(obs, max_rms_px=2.0, max_residual_px=4.0)
    assert fix.dropped == ((1, 9),) and fix.n_points == 31
    assert np.linalg.norm(fix.T_base_part[:3, 3] - T[:3, 3]) < 1e-3


def _oracle_fit(cam: Camera, pts: np.ndarray, state: np.ndarray, pixels: np.ndarray) -> float:
    """Sum of squared reprojection residuals (px^2) of ``pts`` at ``state``, by the camera's
    own projection; infinite when a point lies behind the camera."""
    T = pose_from_xyz_rpy(state[:3], state[3:6])
    base = pts @ T[:3, :3].T + T[:3, 3]
    if np.any(cam.depth(base) <= 0):
        return np.inf
    return float(np.sum((cam.project(base) - pixels) ** 2))


def test_an_update_that_fits_worse_than_its_prediction_is_refused():
    """The case of a wrong acquisition: a prior far along the camera's ray (-0.8 to 1.5 m)
    with the nearly singular covariance of a four-point PnP there, then two to four corners
    in that camera. The linearised update (the textbook form, computed here) sometimes lands
    farther from the pixels than the prediction, or behind the camera. The filter applies it
    exactly when it fits no worse (residuals by the camera's own projection), and otherwise
    keeps its prediction and reports the update refused; both cases occur. (Steps under 1 cm
    and 0.05 rad are applied unchecked; none of those here fits worse.)"""
    cams, prism = _cameras(), _prism()
    rng = np.random.default_rng(3)
    applied = refused = 0
    for _ in range(300):
        pts = prism[rng.choice(16, rng.integers(2, 5), replace=False)]
        truth = _state(TARGET + rng.normal(0, 0.05, 3), rng.normal(0, 0.3, 3))
        obs = _observe(cams[:1], pts, truth, 0.5, rng)
        ray = truth[:3] - cams[0].T_base_cam[:3, 3]
        x0 = truth.copy()
        x0[:3] += ray / np.linalg.norm(ray) * rng.uniform(-0.8, 1.5)
        x0[3:6] += rng.normal(0, 0.3, 3)
        if np.any(cams[0].depth(pts @ rotation_of_state(x0).T + x0[:3]) <= 0):
            continue
        J = obs[0].model.evaluate(x0, prism[:4])[1][:, :6]
        P0 = np.zeros((12, 12))
        P0[:6, :6] = 4 * 0.25 * np.linalg.inv(J.T @ J + 1e-9 * np.eye(6))
        P0[6:, 6:] = np.diag([0.04] * 3 + [0.25] * 3)
        H = obs[0].model.evaluate(x0, pts)[1]
        S = H @ P0 @ H.T + 0.25 * np.eye(len(H))
        nu = (obs[0].pixels - obs[0].model.function(x0, pts)).ravel()
        x_new = x0 + P0 @ H.T @ np.linalg.solve(S, nu)
        x_new[[3, 5]] = (x_new[[3, 5]] + np.pi) % (2 * np.pi) - np.pi
        worse = (_oracle_fit(cams[0], pts, x_new, obs[0].pixels)
                 > _oracle_fit(cams[0], pts, x0, obs[0].pixels))
        ekf = PoseEKF(ConstantVelocity(), x0, P0, 0.0)
        report = ekf.update(obs)
        assert report.refused == worse
        if worse:
            refused += 1
            np.testing.assert_array_equal(ekf.state, x0)
            assert report.n_accepted == 0
        else:
            applied += 1
            np.testing.assert_allclose(ekf.state, x_new, rtol=1e-6, atol=1e-6)
    assert applied >= 100 and refused >= 5, (applied, refused)

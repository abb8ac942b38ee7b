"""Extended Kalman filter of one workpiece's pose from stacked multi-camera pixel measurements.

State and motion model: :mod:`cellsight.tracking.motion`; per-camera measurement model:
:mod:`cellsight.tracking.measurement`. One filter per workpiece.

Recursion, per vision frame:

* predict: ``w- = A w``, ``P- = A P A^T + Q`` (a frame without measurement stops here);
* innovation of feature ``j`` in camera ``c``: ``nu_j = z_j - h_j(w-)`` (2,), with covariance
  ``S_j = C_j P- C_j^T + sigma_c^2 I`` (2x2);
* gating (beyond the paper, :mod:`cellsight.tracking.gate`): ``d_j^2 = nu_j^T S_j^-1 nu_j``;
  a feature the gate rejects (a wrong corner, an unpredicted occlusion) is reported, not used;
* update with the accepted features stacked: ``S = C P- C^T + R``, ``K = P- C^T S^-1``,
  ``w = w- + K nu`` and the Joseph form ``P = (I - K C) P- (I - K C)^T + K R K^T``;
  roll and yaw are wrapped to ``[-pi, pi)``;
* check (beyond the paper): an update that moves the pose by 1 cm or 0.05 rad or more must put
  the accepted features in front of their cameras and reproject them no worse than the
  prediction did, else it is refused (:func:`_fits`): the linearisation, not the
  features, would have moved it. Smaller steps are not checked: at a metre or more from the
  cameras the projection is then linear to a few hundredths of a pixel.

Carried part (optional, beyond the paper: the kinematic prior): while a robot holds the part,
:meth:`PoseEKF.predict_carried` moves the estimate by the holder's measured motion since the
last frame instead of the constant-velocity model, and adds a small random-walk noise for slip
and kinematic error; :meth:`PoseEKF.fuse_prior` then fuses the pseudo-measurement that the pose
is where the holder puts it (:data:`HELD`), and the images update it as usual: a wrong corner
can no longer carry a held part's estimate away from the gripper for good.

Resting part (optional, beyond the paper: the kinematic prior): while a part lies on a level
support (a conveyor's belt, a table; the base frame's z up), :meth:`PoseEKF.fuse_prior` fuses
the pseudo-measurement that its height, roll and pitch are the support's and do not change
(their rates zero; :data:`RESTING`), each with its own sigma (constrained Kalman filtering by
pseudo-measurements): with one camera alone, the estimate can no longer slide along that
camera's rays into the support. A part a holder let go lies still: :data:`STILL` fuses that its
rates are zero.

Adaptive noise (optional, beyond the paper): a scalar pixel variance per camera re-estimated by
robust covariance matching over a sliding window of the last innovations
(:class:`~cellsight.tracking.adaptive_noise.AdaptiveNoise`).

Camera offsets (optional, beyond the paper: :mod:`cellsight.tracking.offsets`): two more states per
camera, its calibration error as an image offset added to every pixel it predicts; the filter
then runs on the augmented state ``[w, b_1, ..., b_C]``, and ``state`` / ``covariance`` are the
part's block of it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cellsight.geometry.transforms import make_pose, xyz_rpy_from_pose
from cellsight.tracking._ekf_kernel import innovation_blocks, joseph_update
from cellsight.tracking.adaptive_noise import AdaptiveNoise
from cellsight.tracking.gate import mahalanobis2
from cellsight.tracking.interfaces import Gate, MotionModel
from cellsight.tracking.measurement import Observation, PinholeMeasurement, rotation_of_state
from cellsight.tracking.motion import POSE_DIM, POSITION, STATE_DIM
from cellsight.tracking.offsets import CameraOffsets, with_offset

MIN_FOR_MEDIAN = 3  # features for a camera's median innovation to stand for its offset
LONE_SIGMA_PX = 2.0  # widest prediction (px, 1 sigma) a camera of fewer features is gated on
SMALL_STEP = (0.01, 0.05)  # m, rad: an update's pose change below which it is not checked
RESTING = np.array([2, 3, 4, 8, 9, 10])  # state rows a level support fixes: z, roll, pitch, rates
HELD = np.arange(6)  # state rows a holder fixes: the whole pose (its rates follow the holder)
STILL = np.arange(6, 12)  # state rows a part at rest fixes: every rate (zero)
SUPPORT_RATES = np.array([6, 7, 11])  # the rates a support moves a lying part at: x, y, yaw
FORGOTTEN = 1.0  # m^2, rad^2: the variance of a state whose estimate is forgotten


@dataclass(frozen=True)
class UpdateReport:
    """Per-feature outcome of an update, rows in the order of the observations' features.

    ``innovation`` (m, 2) px, ``mahalanobis2`` (m,), ``accepted`` (m,) bool; ``sigma_px`` is the
    pixel noise used for each camera index; ``refused``: the gate accepted features, but the
    update they gave fitted them worse than the prediction, and was not applied
    (:func:`_fits`; none is then ``accepted``).
    """

    camera_index: np.ndarray
    feature_ids: np.ndarray
    innovation: np.ndarray
    mahalanobis2: np.ndarray
    accepted: np.ndarray
    sigma_px: dict[int, float]
    refused: bool = False

    @property
    def n_accepted(self) -> int:
        """Number of features used by the update."""
        return int(self.accepted.sum())


class PoseEKF:
    """EKF of one workpiece: a motion model (constant velocity by default), stacked pinhole
    measurements.

    ``state`` (12,) and ``covariance`` (12x12) at time ``t`` (s). ``adaptive`` enables the
    per-camera noise estimate. ``camera_offsets`` adds each camera's image offset to the state,
    starting from its prior or from ``offsets`` (mean (2C,), covariance (2C x 2C) px^2: a previous
    filter's :attr:`offsets`). The gate is the caller's (:meth:`update`).
    """

    def __init__(
        self,
        motion: MotionModel,
        state: np.ndarray,
        covariance: np.ndarray,
        t: float,
        adaptive: AdaptiveNoise | None = None,
        camera_offsets: CameraOffsets | None = None,
        offsets: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        state = np.asarray(state, dtype=float)
        covariance = np.asarray(covariance, dtype=float)
        if state.shape != (STATE_DIM,) or covariance.shape != (STATE_DIM, STATE_DIM):
            raise ValueError(
                f"PoseEKF: state must be (12,) and covariance (12, 12), got {state.shape} and "
                f"{covariance.shape}"
            )
        self.motion = motion
        self.camera_offsets = camera_offsets
        b, Pb = (np.zeros(0), np.zeros((0, 0))) if camera_offsets is None else (
            camera_offsets.prior() if offsets is None else offsets)
        n = STATE_DIM + len(b)
        self._x = np.concatenate([state, b])
        self._P = np.zeros((n, n))
        self._P[:STATE_DIM, :STATE_DIM] = covariance
        self._P[STATE_DIM:, STATE_DIM:] = Pb
        self.t = float(t)
        self.adaptive = adaptive
        self._transition: tuple[float, np.ndarray, np.ndarray] | None = None

    @property
    def state(self) -> np.ndarray:
        """The part's state (12,): pose and rates (:mod:`cellsight.tracking.motion`)."""
        return self._x[:STATE_DIM]

    @property
    def covariance(self) -> np.ndarray:
        """The part's state covariance (12x12)."""
        return self._P[:STATE_DIM, :STATE_DIM]

    @property
    def offsets(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The cameras' image offsets (2C,) px and their covariance (2C x 2C), copies; None
        without ``camera_offsets``."""
        if self.camera_offsets is None:
            return None
        return self._x[STATE_DIM:].copy(), self._P[STATE_DIM:, STATE_DIM:].copy()

    @property
    def pose(self) -> np.ndarray:
        """Current pose estimate ``T_base_part`` (4x4)."""
        return make_pose(rotation_of_state(self.state), self.state[POSITION])

    def predict(self, t: float, at_rest: bool = False) -> None:
        """Propagate state and covariance to time ``t`` (s), ``t >= self.t``; the camera
        offsets keep their values and gain their random walk. ``at_rest``: the part came to
        rest (its holder let it go): its rates are zeroed first, their covariance kept (the
        holder's motion was known to it)."""
        dt = float(t) - self.t
        if dt < 0:
            raise ValueError(f"PoseEKF.predict: time goes backwards ({self.t} -> {t})")
        if self._transition is None or self._transition[0] != dt:
            self._transition = (dt, self.motion.matrix(dt), self.motion.covar(dt))
        _, A, Q = self._transition
        k, P = STATE_DIM, self._P.copy()  # new arrays: records keep the old ones
        x = self._x[:k].copy()
        if at_rest:
            x[POSE_DIM:] = 0.0
        self._x = np.concatenate([A @ x, self._x[k:]])
        P[:k, :k] = A @ P[:k, :k] @ A.T + Q
        model = self.camera_offsets
        if model is not None:
            P[:k, k:] = A @ P[:k, k:]
            P[k:, :k] = P[:k, k:].T
            P[k:, k:] += model.walk(dt)
        self._P = P
        self.t = float(t)

    def predict_carried(self, t: float, motion: np.ndarray, noise: tuple[float, float]) -> None:
        """Propagate to time ``t`` (s) by a rigid motion of the part: ``motion`` (4x4) maps the
        base frame to itself (the holder's ``T_base_holder(t) T_base_holder(t_prev)^-1``); the
        rates become the pose change over the interval. ``noise`` = (m^2/s, rad^2/s): random-walk
        densities added to the pose's covariance (slip, kinematic error)."""
        dt = float(t) - self.t
        if dt < 0:
            raise ValueError(f"PoseEKF.predict_carried: time goes backwards ({self.t} -> {t})")
        xyz, rpy = xyz_rpy_from_pose(np.asarray(motion, dtype=float) @ self.pose)
        x, P = self._x.copy(), self._P.copy()  # new arrays: records keep the old ones
        old = x[:POSE_DIM].copy()
        turn = _wrapped(rpy - old[3:])
        x[:POSE_DIM] = np.concatenate([xyz, old[3:] + turn])
        if dt > 0:
            x[POSE_DIM:STATE_DIM] = (x[:POSE_DIM] - old) / dt
        q = np.array([noise[0]] * 3 + [noise[1]] * 3) * dt
        P[np.arange(POSE_DIM), np.arange(POSE_DIM)] += q
        model = self.camera_offsets
        if model is not None:
            P[STATE_DIM:, STATE_DIM:] += model.walk(dt)
        self._x, self._P, self.t = x, P, float(t)

    def fuse_prior(self, T_base_part: np.ndarray, rows: np.ndarray, std: np.ndarray | None,
                   forget: bool = False, rates: np.ndarray | None = None,
                   covariance: np.ndarray | None = None) -> None:
        """Fuse the pseudo-measurement (module docstring) that the states ``rows`` (indices
        into the 12 of the pose and its rates; :data:`RESTING`, :data:`HELD`, :data:`STILL`) are
        those of the part at ``T_base_part`` (4x4) moving at ``rates`` ((6,) m/s and rad/s,
        the state's order; None: zero), each with its own one sigma ``std`` (m, rad, m/s,
        rad/s per row), or with the (len(rows), len(rows)) ``covariance`` instead (for a
        prior along some directions only). A linear update (Joseph form); angle
        innovations are taken the short way round, roll and yaw wrapped. ``forget``: the
        estimate of those states is no longer trusted: their covariance is made wide
        (``FORGOTTEN``) and uncorrelated first, so that they come out at the prior's values and
        sigmas."""
        rows = np.asarray(rows)
        xyz, rpy = xyz_rpy_from_pose(np.asarray(T_base_part, dtype=float))
        moving = np.zeros(POSE_DIM) if rates is None else np.asarray(rates, dtype=float)
        nu = np.concatenate([xyz, rpy, moving])[rows] - self._x[rows]
        angles = (rows >= 3) & (rows < POSE_DIM)
        nu[angles] = _wrapped(nu[angles])
        R = np.diag(np.asarray(std, dtype=float) ** 2) if covariance is None else covariance
        P = self._P
        if forget:
            P = P.copy()
            P[rows, :] = 0.0
            P[:, rows] = 0.0
            P[rows, rows] = FORGOTTEN
        S = P[np.ix_(rows, rows)] + R
        K = np.linalg.solve(S, P[rows]).T  # P H^T S^-1
        IKH = np.eye(len(self._x))
        IKH[:, rows] -= K
        P_new = IKH @ P @ IKH.T + K @ R @ K.T
        x = self._x + K @ nu
        x[[3, 5]] = _wrapped(x[[3, 5]])  # roll and yaw
        self._x, self._P = x, 0.5 * (P_new + P_new.T)

    def sigma_px(self, model: PinholeMeasurement, camera_index: int) -> float:
        """Pixel noise sigma (px) used for a camera: adaptive estimate or the model's default."""
        if self.adaptive is None:
            return model.sigma_px
        return self.adaptive.sigma(camera_index, model.sigma_px)

    def innovation_covariance(
        self, model: PinholeMeasurement, camera_index: int, points_model: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predicted pixels (n, 2) and innovation covariances ``S_j`` (n, 2, 2) at the current
        state, for the windows of the features ``points_model`` (n, 3) in one camera."""
        pixels, H = self._offset(camera_index, *model.evaluate(self.state, points_model))
        sigma2 = np.full(len(pixels), self.sigma_px(model, camera_index) ** 2)
        return pixels, innovation_blocks(H, self._P, sigma2)

    def _offset_free_d2(self, cam: np.ndarray, nu: np.ndarray, H: np.ndarray,
                        sigma2: np.ndarray, S: np.ndarray) -> np.ndarray:
        """Gating distances with the cameras' offsets (:mod:`.offsets`). In a camera of at least
        ``MIN_FOR_MEDIAN`` features measured, each innovation less the camera's median innovation,
        against the covariance of its difference from the camera's mean (Jacobian rows less
        their mean: no common shift, be it the offset or the part's translation across the
        view), so that a wrong corner stands out of the shift the whole camera shares, however
        large that is. In a camera with fewer features, each innovation against its whole
        covariance, and only where that is narrow (at most ``LONE_SIGMA_PX`` along its widest
        axis, once the camera's offset is known): else its offset would take up whatever one
        wrong corner says, and keep it (infinite distance: left out)."""
        d2 = mahalanobis2(nu, S)
        d2[np.linalg.eigvalsh(S)[:, 1] > LONE_SIGMA_PX**2] = np.inf
        for c in np.unique(cam):
            rows = np.flatnonzero(cam == c)
            n = len(rows)
            if n < MIN_FOR_MEDIAN:
                continue
            Hc = H.reshape(-1, 2, H.shape[1])[rows]
            D = (Hc - Hc.mean(axis=0)).reshape(2 * n, -1)
            S_diff = innovation_blocks(D, self._P, sigma2[rows] * (1 + 1 / n))
            d2[rows] = mahalanobis2(nu[rows] - np.median(nu[rows], axis=0), S_diff)
        return d2

    def _offset(self, camera_index: int, pred: np.ndarray, H: np.ndarray,
                x: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """A camera's predicted pixels and Jacobian with its offset (unchanged without), that of
        the augmented state ``x`` (default: the filter's)."""
        if self.camera_offsets is None:
            return pred, H
        x = self._x if x is None else x
        return with_offset(pred, H, camera_index, x[STATE_DIM:], STATE_DIM, len(x))

    def update(
        self, observations: list[Observation], gate: Gate | None = None
    ) -> UpdateReport:
        """Gate the observations of all cameras, then fuse the accepted features in one
        Joseph-form update. ``gate`` None accepts every feature. A camera exposed before the
        filter's time (``Observation.lag_s``) measures the pose of its exposure. With camera
        offsets, the gate sees the distances of :meth:`_offset_free_d2`.

        An empty list (or one where every feature is gated out) leaves the prediction unchanged.
        """
        R_part = rotation_of_state(self.state)
        cams, ids, nus, Hs, sig, s2 = [], [], [], [], {}, []
        for obs in observations:
            n = len(obs.feature_ids)
            if n == 0:
                continue
            pred, H = self._offset(obs.camera_index, *obs.evaluate(self.state, R_part))
            sigma = self.sigma_px(obs.model, obs.camera_index)
            sig[obs.camera_index] = sigma
            cams.append(np.full(n, obs.camera_index))
            s2.append(np.full(n, sigma**2))
            ids.append(np.asarray(obs.feature_ids))
            nus.append(np.asarray(obs.pixels, dtype=float) - pred)
            Hs.append(H)
        if not nus:
            empty = np.zeros(0, dtype=int)
            return UpdateReport(empty, empty, np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool), {})
        cam, nu, H, sigma2 = (np.concatenate(x) for x in (cams, nus, Hs, s2))
        S = innovation_blocks(H, self._P, sigma2)
        if self.camera_offsets is None:
            d2 = mahalanobis2(nu, S)
        else:
            d2 = self._offset_free_d2(cam, nu, H, sigma2, S)
        accepted = np.ones(len(d2), dtype=bool) if gate is None else gate.accepts(d2)
        report = UpdateReport(cam, np.concatenate(ids), nu, d2, accepted, sig)
        if self.adaptive is not None:
            trace = S[:, 0, 0] + S[:, 1, 1] - 2 * sigma2  # tr(C_j P C_j^T)
            for c in np.unique(cam):
                rows = cam == c
                self.adaptive.add(int(c), nu[rows], trace[rows])
        if accepted.any():
            state, P_new = joseph_update(self._x, self._P, H, nu, sigma2, accepted)
            state[[3, 5]] = _wrapped(state[[3, 5]])  # roll and yaw
            if _small_step(state, self._x) or _fits(self, observations, state, nu, accepted):
                self._x, self._P = state, P_new
            else:
                report = replace(report, accepted=np.zeros_like(accepted), refused=True)
        return report


def _fits(ekf: PoseEKF, observations: list[Observation], state: np.ndarray, nu: np.ndarray,
          accepted: np.ndarray) -> bool:
    """Whether an updated ``state`` of ``ekf`` (the augmented one) explains the accepted features at
    least as well as the prediction did: every one in front of its camera, and the sum of
    their squared residuals no larger than that of their innovations. A linear update
    always passes (the residual is ``R S^-1 nu``, shorter than ``nu``); one that the
    linearisation throws far (a wide covariance along a direction the features barely
    see) does not, and is refused."""
    part = state[:STATE_DIM]
    R_part, rows, residual = rotation_of_state(part), 0, 0.0
    for obs in observations:
        n = len(obs.feature_ids)
        if n == 0:
            continue
        pred, _ = ekf._offset(obs.camera_index, *obs.evaluate(part, R_part), state)
        used = accepted[rows:rows + n]
        points = obs.points_model[used] @ R_part.T + obs.exposed_state(part)[:3]
        if np.any(obs.model.camera.depth(points) <= 0):
            return False
        residual += float(np.sum((np.asarray(obs.pixels)[used] - pred[used]) ** 2))
        rows += n
    return residual <= float(np.sum(nu[accepted] ** 2)) * (1 + 1e-9)


def _wrapped(angles: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped to ``[-pi, pi)``."""
    return (angles + np.pi) % (2 * np.pi) - np.pi


def _small_step(new: np.ndarray, old: np.ndarray) -> bool:
    """Whether an update moves the pose from ``old`` to ``new`` (states) by less than
    ``SMALL_STEP`` (m, rad): where the projection is that close to linear,
    :func:`_fits` need not look (it costs as much as the update)."""
    step = np.abs(new[:POSE_DIM] - old[:POSE_DIM])
    return bool(np.all(step[:3] < SMALL_STEP[0]) and np.all(step[3:] < SMALL_STEP[1]))

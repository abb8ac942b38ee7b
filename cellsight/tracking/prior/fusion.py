"""The kinematic prior fused into the tracker's filter (for :mod:`cellsight.tracking.tracker`):
a held part kept with its holder (along a lone camera's sight line every frame), a part lying
on its support kept there and no faster than the support moves, a part let go kept at rest,
and a fix off the support it lies on, or away from where it was just let go, refused."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import rotation_angle
from cellsight.tracking.config import TrackerConfig
from cellsight.tracking.ekf import (
    HELD,
    RESTING,
    STILL,
    SUPPORT_RATES,
    PoseEKF,
    UpdateReport,
)
from cellsight.tracking.motion import POSE_DIM, POSITION

HOLD_SIGMAS = 3.0  # a held part's estimate this many holder sigmas off has left the grasp
ACROSS_SIGHT = 1.0  # m: the sigma across a lone camera's sight line of the hold along it
LYING_TOL = (0.015, 0.15)  # m, rad: a fix this far from its support's height and tilt is wrong
LET_GO_TOL = 0.02  # m: a fix this far across its support from where a part was let go is wrong
LET_GO_TRUST_S = 5.0  # s: ... for this long after it was let go


class Resting(Protocol):
    """What :func:`fits_prior` reads of a track: the pose it lies at on its support (None:
    held, or not known) and when a holder last let it go (s; None: never, or held again
    since)."""

    lying: np.ndarray | None
    let_go_t: float | None


class Fused(Resting, Protocol):
    """What :func:`fuse_priors` reads and writes of a track: what :class:`Resting` says, its
    filter, and the times of its last accepted measurement and since when it was looked for
    in vain (s)."""

    ekf: PoseEKF
    last_update: float
    unseen_since: float


def fuse_priors(track: Fused, t: float, holder: np.ndarray | None,
                 config: TrackerConfig) -> None:
    """The kinematic prior's pseudo-measurements of a tracked part at time ``t`` (s;
    :meth:`PoseEKF.fuse_prior`): held, it is kept with its ``holder`` (:func:`_hold`) and never
    lost (the holder measures it); lying on a support, it keeps the support's height, roll and
    pitch (``RESTING``); let go, it stays where it came to rest (``STILL``: every rate zero;
    a wrong corner's update can no longer set it moving). ``config.rest_std`` gives the
    sigmas of the height and the angles and of their rates per second."""
    if holder is not None:
        _hold(track.ekf, holder, config.hold_std)
        track.last_update, track.unseen_since = float(t), np.inf
        return
    h, a = config.rest_std
    if track.lying is not None:
        track.ekf.fuse_prior(track.lying, RESTING, [h, a, a, h, a, a])
        _keep_support_speed(track.ekf, config.support_speed)
    if track.let_go_t is not None:
        track.ekf.fuse_prior(track.ekf.pose, STILL, [h, h, h, a, a, a])


def _keep_support_speed(ekf: PoseEKF, speed: tuple[float, float]) -> None:
    """A part lying on its support moves no faster than the support does (``speed``: m/s
    across it, rad/s about its normal; ``TrackerConfig.support_speed``): where the filter's
    rates go past that, they are fused at the bound (the nearest rates within it, a tenth of
    the bound as sigma; an inequality constraint held by its active set). In ``harsh`` runs
    re-acquired under the approaching gripper, the first update made 5 mm of disagreement a
    velocity of 0.17 m/s, which carried the estimate 60 mm off while it coasted."""
    lin, ang = speed
    rates = ekf.state[POSE_DIM:].copy()
    across, turn = float(np.hypot(rates[0], rates[1])), float(rates[5])
    if across <= lin and abs(turn) <= ang:
        return
    rates[:2] *= min(1.0, lin / max(across, 1e-12))
    rates[5] = np.clip(turn, -ang, ang)
    ekf.fuse_prior(ekf.pose, SUPPORT_RATES, [0.1 * lin, 0.1 * lin, 0.1 * ang], rates=rates)


def fits_prior(track: Resting, T_base_part: np.ndarray, t: float) -> bool:
    """Whether a pose found for a part at time ``t`` (s) agrees with the kinematic prior: it
    lies on its support (:func:`lies_on`), and for ``LET_GO_TRUST_S`` after a holder let the
    part go, within ``LET_GO_TOL`` (m) across the support of where it came to rest (the
    holder's pose, known to the arm's accuracy, lowered onto the support). On a line, a part
    lost as the jaws opened over it was found again 50 mm off, its corners fitted by the
    opening jaws'; afterwards it may have been moved (pushed, taken away)."""
    if not lies_on(track.lying, T_base_part):
        return False
    if track.lying is None or track.let_go_t is None or t - track.let_go_t > LET_GO_TRUST_S:
        return True
    return float(np.hypot(*(T_base_part[:2, 3] - track.lying[:2, 3]))) <= LET_GO_TOL


def lies_on(lying: np.ndarray | None, T_base_part: np.ndarray) -> bool:
    """Whether a pose found for a part lies on the support the kinematic prior says it lies on
    (``lying``: ``T_base_part`` there; None: nothing known): its height within
    ``LYING_TOL[0]`` (m) and its tilt from the lying pose within ``LYING_TOL[1]`` (rad)."""
    if lying is None:
        return True
    R = T_base_part[:3, :3] @ lying[:3, :3].T
    tilt = float(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))
    return abs(T_base_part[2, 3] - lying[2, 3]) <= LYING_TOL[0] and tilt <= LYING_TOL[1]


def _hold(ekf: PoseEKF, holder: np.ndarray, std: tuple[float, float]) -> None:
    """Keep a held part's estimate with its holder's pose ``holder`` (the kinematic prior;
    ``std``: its one sigma, m and rad): where the filter knows the pose less well than the
    holder does, fuse the holder's pose; where the estimate is more than ``HOLD_SIGMAS`` of
    them from it (wrong corners carried it off, or the cameras' shared calibration error
    did), forget it and take the holder's. In between the images alone update it: a holder's
    error is a bias, and fused every frame it would soon outweigh every camera."""
    T, P = ekf.pose, ekf.covariance
    wide = _widest_above(P[:3, :3], std[0] ** 2) or _widest_above(P[3:6, 3:6], std[1] ** 2)
    off = (np.linalg.norm(T[:3, 3] - holder[:3, 3]) / std[0] > HOLD_SIGMAS
           or rotation_angle(T[:3, :3].T @ holder[:3, :3]) / std[1]
           > HOLD_SIGMAS)  # the turn only where the move is not off already
    if wide or off:
        ekf.fuse_prior(holder, HELD, np.repeat(std, 3), forget=off)


def _widest_above(A: np.ndarray, limit: float) -> bool:
    """Whether the largest eigenvalue of the symmetric positive semi-definite ``A`` exceeds
    ``limit``: at least its largest diagonal entry, at most its trace, the eigenvalues
    themselves only between the two."""
    diagonal = np.diagonal(A)
    if diagonal.max() > limit:
        return True
    if diagonal.sum() <= limit:
        return False
    return bool(np.linalg.eigvalsh(A)[-1] > limit)


def hold_along_sight(ekf: PoseEKF, holder: np.ndarray, cameras: Sequence[Camera],
                      report: UpdateReport, std: float) -> None:
    """A held part that one camera alone updated (``report``): fuse its ``holder``'s position
    along that camera's line of sight to it, with one sigma ``std`` (m; ``ACROSS_SIGHT``
    across it: no prior there). One camera measures the part across its sight line well and
    along it hardly at all: there the estimate drifted while carried (5-8 mm over 10 s with
    a knocked camera dropped, the gripper exact), and the holder, fused only once the estimate
    was ``HOLD_SIGMAS`` off (:func:`_hold`), let it. Along that line the holder is all there
    is to know, so it is fused every such frame; across it the camera rules."""
    seen = np.unique(report.camera_index[report.accepted])
    if len(seen) != 1:
        return
    sight = ekf.state[POSITION] - cameras[int(seen[0])].center
    along = np.outer(sight, sight) / float(sight @ sight)
    covariance = std**2 * along + ACROSS_SIGHT**2 * (np.eye(3) - along)
    ekf.fuse_prior(holder, HELD[:3], None, covariance=covariance)


def off_holder(ekf: PoseEKF, holder: np.ndarray | None) -> float | None:
    """A held part's estimate's distance (m) from its ``holder``'s pose, for the health
    monitor; None when it is not held."""
    return None if holder is None else float(np.linalg.norm(ekf.pose[:3, 3] - holder[:3, 3]))

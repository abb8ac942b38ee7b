"""Acquisition of a workpiece not tracked yet, or lost (beyond the paper's Fig. 5).

The occlusion predictor runs at a guess of the pose (the cell's nominal pose of the part, or
the last prediction of a lost part); every usable predicted-visible feature gets a square
window of ``window_px``; the corners found there give a fused multi-camera PnP that drops up to
three wrong corners (:func:`~cellsight.tracking.pnp.estimate_pose_robust`: while the RMS
reprojection error exceeds ``max_rms_px`` or a corner lies more than ``max_residual_px`` from
its reprojection). A fix whose RMS is at most ``coarse_rms_px`` is then verified against every
feature it predicts: the predictor runs at the fix, windows of ``verify_window_px`` are placed
on every usable feature it predicts visible, and the corners found there must give a fix again
(within ``max_rms_px``) of at least ``min_points`` points, and in some camera that looked for
at least ``verify_looked`` features, of at least ``verify_support`` of them
(:meth:`PnPAcquisition.confirms`: one found of the one looked for confirms nothing; on the
line, such a camera confirmed an L entering the views 46 mm and 138 deg off). The filter starts
from that second fix, with the PnP covariance inflated by ``pose_inflation`` and a velocity
uncertainty ``velocity_std`` (m/s, rad/s); the corners it dropped are recorded as rejected.

Why the verification: wide windows at a guess take whatever corner lies nearest to each
prediction, and a few of those corners (four in one camera, or each the corner next to the
right one) fit a pose far from the part's within the RMS limit. In the ``harsh`` world, before
it, nine acquisitions in ten from fewer than ten points were more than 20 mm off (the most
from four points: 0.3 m median), and one threw the filter out of the cell at its first update.
Where such a pose predicts the part's other features, narrow windows find nothing, or corners
that pose does not fit. With the verification, 6 of 74 acquisitions in 15 ``harsh`` runs were
more than 20 mm off, against 24 of 99 before; what it cannot tell is a pose every feature of
which lies on a neighbour's corner.

The first fix (at the guess, or at a candidate of the whole-image search, :mod:`.search`) is
coarse: it only has to bring the verification's narrow windows near, so it stands within
``coarse_rms_px``; the verifying fix must meet ``max_rms_px``. In ``harsh``, the right pose
from the 64 px windows at the nominal guess (11 points, a few of them a neighbour's corner)
was refused at 3.35 px, and the search then found the part's nearly symmetric turned twin,
which 10 points confirmed.

A part that is nearly symmetric has twins: poses turned a quarter or a half turn about an axis
through the centre of its feature points' box that put at least half of its feature points
within ``TWIN_TOL`` (of the box's size) of one of them (:func:`twin_turns`; the built-in part
has three: half turns about its three axes, one of them exact). Where a turned twin's features
fall on the part's own corners, the verification confirms it too (in ``harsh``, from 10
points against the part's 18); so the tracker verifies a confirmed fix's twins as well (those
turned about the vertical, which keep a lying part the right way up), and the confirmation of
the most points stands, the fix itself on a tie (an exact twin cannot be told from the
features: its features fall where the fix's do).

A part lying on a level support (the kinematic prior says where: ``support``) keeps its
height, roll and pitch there; where the six numbers cannot be fitted (fewer points than
``min_points``, or not within the limit), ``x``, ``y`` and the yaw are, from at least
``min_points_on_support`` points (:data:`~cellsight.tracking.pnp.ON_SUPPORT`), seeded by the
pose the windows were placed at (the tracker asks for it for the whole-image search's
candidates and their verification, :mod:`.search`). A part put back at the image's edge
with the arm before the other camera shows four points to one camera and one or two to the
other: no camera's PnP, and five points for six numbers, one of them a neighbour's corner,
fit anything; three numbers from five points drop the wrong one and hold.

With ``camera_offsets`` (on by default), a fix whose RMS is too large is tried once more with
each camera's median residual taken out of its pixels
(:func:`~cellsight.tracking.pnp.camera_shifts`): two cameras whose calibrations disagree by a
few pixels no longer keep a part from being acquired, and a filter that estimates each
camera's calibration error as an image offset (:mod:`.offsets`) starts from those offsets.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from cellsight.tracking.measurement import Observation
from cellsight.tracking.motion import POSE_DIM, STATE_DIM
from cellsight.tracking.pnp import PoseFix, camera_shifts, estimate_pose_robust

TWIN_TOL = 0.02  # a twin's turned feature point lies this close (share of the box) to one


def twin_turns(points: np.ndarray) -> list[np.ndarray]:
    """The part's twins (module docstring) as 4x4 motions in the part frame (a pose ``T``'s twin
    is ``T @ turn``), for its feature points (F, 3)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, tol = 0.5 * (lo + hi), TWIN_TOL * float(np.linalg.norm(hi - lo))
    tree, turns = cKDTree(points), []
    for axis in "xyz":
        for degrees in (90, 180, 270):
            R = Rotation.from_euler(axis, degrees, degrees=True).as_matrix()
            turned = (points - centre) @ R.T + centre
            if np.mean(tree.query(turned)[0] <= tol) >= 0.5:
                turn = np.eye(4)
                turn[:3, :3], turn[:3, 3] = R, centre - R @ centre
                turns.append(turn)
    return turns


def rates_covariance(std: tuple[float, float]) -> np.ndarray:
    """The 6x6 covariance of a filter's rates, ``std`` = (m/s, rad/s) one sigma on each of the
    three linear and the three angular rates, uncorrelated."""
    lin, ang = std
    return np.diag([lin**2] * 3 + [ang**2] * 3)


@dataclass(frozen=True)
class PnPAcquisition:
    """Acquisition by robust multi-camera PnP (module docstring). Units: px, m/s, rad/s."""

    window_px: float = 64.0
    max_rms_px: float = 2.0
    max_residual_px: float = 6.0
    velocity_std: tuple[float, float] = (0.2, 0.5)
    pose_inflation: float = 4.0
    search_m: float = 0.015
    search_step_m: float = 0.005
    camera_offsets: bool = True
    verify_window_px: float = 24.0
    verify_support: float = 0.6
    verify_looked: int = 4
    min_points: int = 6
    coarse_rms_px: float = 6.0
    min_points_on_support: int = 4

    def guess(self, base: np.ndarray, attempt: int) -> np.ndarray:
        """``base`` (``T_base_part``) moved by the ``attempt``-th offset of the search (module
        docstring; it starts over after the last)."""
        n = int(round(self.search_m / self.search_step_m)) if self.search_step_m > 0 else 0
        steps = np.arange(-n, n + 1) * self.search_step_m
        offsets = sorted(((x, y) for x in steps for y in steps),
                         key=lambda o: (round(np.hypot(*o), 9), o))
        T = np.array(base, dtype=float)
        T[:2, 3] += offsets[attempt % len(offsets)]
        return T

    def fix(self, observations: list[Observation], sigma_px: float,
            coarse: bool = False, guess: np.ndarray | None = None,
            support: tuple[np.ndarray, tuple[float, float]] | None = None) -> PoseFix | None:
        """The pose to start from, or None when the corners found do not give one within
        ``max_rms_px`` (``coarse_rms_px`` for a ``coarse`` first fix: module docstring).
        ``guess``: the pose the windows were placed at, where it is already near the part (a
        search's candidate, a fix being verified), seeds the PnP too
        (:func:`~cellsight.tracking.pnp.estimate_pose`). ``support``: ``(T_base_part, (m,
        rad))``, the part lying on a level support and one sigma of its height and of its roll
        and pitch there; where the six numbers cannot be fitted (too few points, or not within
        the limit), ``x``, ``y`` and the yaw are, on the support, from at least
        ``min_points_on_support`` points, those sigmas kept for the other three."""
        limit = self.coarse_rms_px if coarse else self.max_rms_px
        fix = self._fit(observations, sigma_px, limit, guess, None)
        good = fix is not None and fix.rms_px <= limit and self.enough(fix)
        if support is not None and not good:
            on = self._fit(observations, sigma_px, limit, guess, support[0])
            if on is not None and on.rms_px <= limit:
                h, a = support[1]
                covariance = on.covariance + np.diag([0.0, 0.0, h**2, a**2, a**2, 0.0])
                fix = replace(on, covariance=covariance)
        return fix if fix is not None and fix.rms_px <= limit else None

    def _fit(self, observations: list[Observation], sigma_px: float, limit: float,
             guess: np.ndarray | None, support: np.ndarray | None) -> PoseFix | None:
        """The robust PnP (on a ``support``, if given), once more with each camera's median
        residual taken out where its RMS is above ``limit`` px (module docstring)."""
        fix = estimate_pose_robust(observations, self.max_rms_px, sigma_px=sigma_px,
                                   max_residual_px=self.max_residual_px, guess=guess,
                                   support=support)
        if fix is not None and fix.rms_px > limit and self.camera_offsets:
            shifts = camera_shifts(observations, fix)
            moved = [replace(o, pixels=o.pixels - shifts.get(o.camera_index, 0.0))
                     for o in observations]
            fix = estimate_pose_robust(moved, self.max_rms_px, sigma_px=sigma_px,
                                       max_residual_px=self.max_residual_px, guess=guess,
                                       support=support)
            fix = None if fix is None else replace(fix, offsets_px=shifts)
        return fix

    def enough(self, fix: PoseFix) -> bool:
        """Whether ``fix`` has the points a fix needs: ``min_points``, or
        ``min_points_on_support`` for one fitted on a support (three numbers, not six)."""
        return fix.n_points >= (self.min_points_on_support if fix.on_support else self.min_points)

    def confirms(self, fix: PoseFix, looked: np.ndarray, used: np.ndarray) -> bool:
        """Whether a verifying fix (module docstring) stands: at least ``min_points`` points,
        and in some camera that looked for at least ``verify_looked`` features, at least
        ``verify_support`` of them. ``looked``, ``used`` (C,): per camera, the features looked
        for and those the fix kept."""
        looked, used = np.asarray(looked), np.asarray(used)
        support = np.divide(used, looked, out=np.zeros(len(used)),
                            where=looked >= max(self.verify_looked, 1))
        return self.enough(fix) and bool(np.any(support >= self.verify_support))

    def covariance(self, pose_covariance: np.ndarray) -> np.ndarray:
        """Initial 12x12 state covariance: ``pose_covariance`` (6x6, xyz + rpy) and the
        velocity uncertainty; the caller inflates a PnP covariance first (:meth:`start`)."""
        P = np.zeros((STATE_DIM, STATE_DIM))
        P[:POSE_DIM, :POSE_DIM] = pose_covariance
        P[POSE_DIM:, POSE_DIM:] = rates_covariance(self.velocity_std)
        return P

    def start(self, fix: PoseFix) -> np.ndarray:
        """Initial state covariance from a PnP fix (its covariance inflated)."""
        return self.covariance(self.pose_inflation * fix.covariance)

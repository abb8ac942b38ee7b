"""Optimal selection of the feature points to extract, across all cameras (paper Sec. IV).

Among the feature points predicted visible, choose ``k = min(max_points, available)`` of them
that maximise a quality ``J`` in ``[0, 1]`` (equivalently minimise the cost ``1 - J``).

Quality indexes, for camera ``c`` with selected projections ``x_j`` (``j = 1..n_c``, px) and
their centroid ``xbar``:

* spatial distribution (spread), normalised by the spread available in that camera::

      Q_s,c = min(1, mean_j |x_j - xbar| / r_c),   r_c = max_{i visible} |v_i - vbar|

  where ``v_i`` are all the camera's visible projections and ``vbar`` their centroid;
* angular distribution around the centroid, from the first two circular moments of the
  directions ``theta_j = atan2(x_j - xbar)``, ``m_k = |mean_j exp(i k theta_j)|``::

      Q_a,c = (1 - m_1) (1 - m_2)

  1 when the directions are evenly spread (``m_1 = m_2 = 0``), 0 when the points all lie on one
  side (``m_1 = 1``) or on one line through the centroid (``m_2 = 1``); a point on the centroid
  has no direction and adds nothing to the moments. (The circular-statistics form replaces a
  sorted-gap index (the largest gap between sorted directions): it needs no sorting and no
  ``atan2``, so the search runs at frame rate, and it rates collinear points 0 where the gap
  index gives ``1/3``.)
* per camera ``Q_c = Q_s,c Q_a,c`` (0 for a camera with fewer than two selected points);
* balance between cameras, weighted by resolution. A camera is *eligible* when at least
  ``min_per_camera`` of its points are visible. ``rho_c = f_c / z_c`` (px/m) is its resolution at
  the part's depth ``z_c``; ``w_c = rho_c / sum_{eligible} rho`` and the target count is
  ``n_c* = k w_c``::

      Q_b = 1 - sum_{eligible c} |n_c - n_c*| / (2 k)

* total::

      J = (sum_{eligible c} w_c Q_c) Q_b

Constraint: every camera contributes either nothing or at least ``min_per_camera`` points.

Search (compiled with Numba, runs at frame rate; :mod:`._selection_kernel`): greedy sets per
camera and count, the count vectors enumerated, then exchanges while they improve.

Tests compare it with exhaustive search over all subsets on small cases.

Cameras with few visible points (``few_point_cameras``, on by default): a camera that sees 1 to
``min_per_camera - 1`` points is not eligible, but all its visible points are selected besides
the eligible cameras' (the budget for those shrinks by as many; when less than
``min_per_camera`` would be left, the few-point cameras give nothing). The EKF takes any number of
measurements from any camera, and one or two points seen by a second camera fix the depth that
a single camera measures poorly (the paper's experiment 3: "only one point remains visible
... This event does not affect the accuracy of the pose estimation").

When no camera is eligible, every visible point is selected (up to ``max_points``, lowest
camera and feature indices first) and the selection is flagged ``fallback``: the EKF can still
use a few points where a per-camera PnP could not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellsight.camera import Camera
from cellsight.tracking._selection_kernel import balance_index, final_indexes, pack, search


@dataclass(frozen=True)
class SelectionConfig:
    """``max_points`` selected overall, ``min_per_camera`` per contributing camera,
    ``max_passes`` cycles of the exchange step, ``polish_slack`` the most the exchanges are
    assumed to improve a greedy ``Q_c`` (relative) when deciding which counts to polish,
    ``max_pair_exchanges`` the largest double-exchange neighbourhood searched (frame-rate cap),
    ``few_point_cameras``: a camera with 1 to ``min_per_camera - 1`` visible points gives all
    of them, out of the ``max_points`` budget (module docstring)."""

    max_points: int = 11
    min_per_camera: int = 4
    max_passes: int = 20
    polish_slack: float = 0.25
    max_pair_exchanges: int = 150
    few_point_cameras: bool = True

    def __post_init__(self) -> None:
        if (not 1 <= self.min_per_camera <= self.max_points or self.max_passes < 0
                or self.polish_slack < 0):
            raise ValueError(f"SelectionConfig: invalid {self}")


@dataclass(frozen=True)
class Selection:
    """Result: ``selected`` (C, F) bool; quality ``J`` and its indexes (``spread`` Q_s and
    ``angular`` Q_a per camera, ``balance`` Q_b), ``counts`` n_c and ``targets`` n_c*."""

    selected: np.ndarray
    quality: float
    spread: np.ndarray
    angular: np.ndarray
    balance: float
    counts: np.ndarray
    targets: np.ndarray
    fallback: bool

    @property
    def cost(self) -> float:
        """The minimised cost ``1 - J``."""
        return 1.0 - self.quality

    @classmethod
    def of(cls, selected: np.ndarray) -> Selection:
        """A selection made by another rule than :func:`select_features` (a custom
        :class:`~cellsight.tracking.interfaces.Selector`): the mask ``selected`` (C, F) bool and
        its counts; the quality indexes and targets unknown (NaN)."""
        selected = np.asarray(selected, dtype=bool)
        unknown = np.full(len(selected), np.nan)
        return cls(selected, float("nan"), unknown, unknown.copy(), float("nan"),
                   selected.sum(axis=1), unknown.copy(), False)


def _select_feasible(pixels, visible, rho, k_max, m_min, *args):
    """:func:`search` with the largest count ``k <= k_max`` that the eligible cameras can
    split (each 0 or at least ``m_min``): 5 + 5 visible points cannot give 6 with ``m_min = 4``,
    so 5 are taken from one camera."""
    while True:
        out = search(pixels, visible, rho, k_max, m_min, *args)
        quality, k, eligible = out[1], out[2], out[4]
        if quality >= 0 or not eligible.any() or k <= m_min:
            return out
        k_max = k - 1


def camera_resolution(cameras: Sequence[Camera], point: np.ndarray) -> np.ndarray:
    """``rho_c`` (C,) px/m: each camera's focal length over the depth of ``point`` (base frame,
    m; the part's centroid), the selection's weight of each camera (module docstring)."""
    return np.array([c.focal_px / max(c.depth(np.asarray(point)[None])[0], 1e-6)
                     for c in cameras])


def select_features(
    pixels: np.ndarray,
    visible: np.ndarray,
    resolution: np.ndarray,
    config: SelectionConfig | None = None,
) -> Selection:
    """Select the features to extract (module docstring).

    ``pixels`` (C, F, 2): predicted projections of the F features in the C cameras (px);
    ``visible`` (C, F) bool: predicted visible; ``resolution`` (C,): ``rho_c`` (px/m) at the
    part's depth.
    """
    cfg = config or SelectionConfig()
    pixels = np.ascontiguousarray(pixels, dtype=np.float64)
    visible = np.ascontiguousarray(visible, dtype=np.bool_)
    rho = np.ascontiguousarray(resolution, dtype=np.float64)
    if pixels.shape != (*visible.shape, 2) or rho.shape != visible.shape[:1]:
        raise ValueError(
            f"select_features: expected pixels (C, F, 2), visible (C, F), resolution (C,); got "
            f"{pixels.shape}, {visible.shape}, {rho.shape}"
        )
    n_visible = visible.sum(axis=1)
    few = (n_visible > 0) & (n_visible < cfg.min_per_camera) & cfg.few_point_cameras
    extra = visible & few[:, None]
    budget = cfg.max_points - int(extra.sum())
    args = (cfg.min_per_camera, cfg.max_passes, cfg.polish_slack, cfg.max_pair_exchanges)
    selected, quality, k, weights, eligible, radius = _select_feasible(
        pixels, visible & ~few[:, None], rho, max(budget, 0), *args)
    if eligible.any() and budget >= cfg.min_per_camera:
        selected |= extra
    else:  # no room for the few-point cameras, or no eligible one: the plain selection
        selected, quality, k, weights, eligible, radius = _select_feasible(
            pixels, visible, rho, cfg.max_points, *args)
    qs, qa = final_indexes(pixels, selected, radius)
    counts = selected.sum(axis=1)
    balance = balance_index(counts, weights, eligible, k)
    return Selection(
        selected, float(quality), qs, qa, balance, counts, k * weights, not bool(eligible.any())
    )


def selection_quality(
    pixels: np.ndarray,
    visible: np.ndarray,
    resolution: np.ndarray,
    selected: np.ndarray,
    min_per_camera: int = 4,
) -> float:
    """``J`` of a given selection (C, F) bool (module docstring), ``k`` being its number of
    points; ``-inf`` if it breaks the constraints (a point not visible or of an ineligible
    camera, or a camera with 1 to ``min_per_camera - 1`` points)."""
    pixels = np.ascontiguousarray(pixels, dtype=np.float64)
    visible = np.ascontiguousarray(visible, dtype=np.bool_)
    selected = np.ascontiguousarray(selected, dtype=np.bool_)
    rho = np.ascontiguousarray(resolution, dtype=np.float64)
    _, _, radius, eligible, weights = pack(pixels, visible, rho, min_per_camera)
    counts = selected.sum(axis=1)
    k = int(counts.sum())
    bad_count = (counts > 0) & (~eligible | (counts < min_per_camera))
    if k == 0 or np.any(selected & ~visible) or bad_count.any():
        return -np.inf
    qs, qa = final_indexes(pixels, selected, radius)
    return float(np.sum(weights * qs * qa) * balance_index(counts, weights, eligible, k))


@dataclass(frozen=True)
class OptimalSelector:
    """The tracker's default :class:`~cellsight.tracking.interfaces.Selector`: the optimal
    selection of the module docstring (:func:`select_features`) with ``config``."""

    config: SelectionConfig = SelectionConfig()

    def select(self, pixels: np.ndarray, usable: np.ndarray, resolution: np.ndarray) -> Selection:
        """Select among the ``usable`` (C, F) features with predicted pixels ``pixels``
        (C, F, 2) px, cameras weighted by ``resolution`` (C,) px/m."""
        return select_features(pixels, usable, resolution, self.config)

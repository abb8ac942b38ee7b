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

Search (compiled with Numba, runs at frame rate). For fixed counts ``n_c`` the balance ``Q_b`` is
fixed and ``J`` separates into independent per-camera problems, so:

1. greedy: per eligible camera, for every count ``n`` the other cameras can complete to ``k``
   (``k - n`` zero or at least ``min_per_camera``), two greedy sets: forward (farthest-point
   seed of ``min_per_camera`` points, then the best addition each time) and backward (from all
   the camera's visible points, the best removal each time); the better gives ``Q_c(n)``;
2. count vectors (each ``n_c`` 0 or feasible, summing to ``k``) are enumerated exhaustively
   (when none exists, e.g. 5 + 5 visible points, ``k = 6``, at least 4 each, ``k`` is lowered
   until one does);
3. exchange: the counts of the best vector are polished: first-improvement single exchanges
   (swap a selected point for an unselected one while ``Q_c`` improves) from both greedy sets,
   then, from the better, double exchanges (two for two), each followed by single ones, while
   they improve (when the double-exchange neighbourhood has at most ``max_pair_exchanges``
   members, which keeps the worst case, 16 visible points per camera, at frame rate).
   Steps 2-3 repeat, an unpolished ``Q_c`` counting as ``(1 + polish_slack)`` times its greedy
   value, until the best vector is made of polished counts only.

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

import numba
import numpy as np

from cellsight.camera import Camera


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


@numba.njit(cache=True)
def _indexes(px, members, n):
    """(Q_s numerator ``mean_j |x_j - xbar|``, Q_a) of the points ``px[members[:n]]``."""
    if n < 2:
        return 0.0, 0.0
    mx = 0.0
    my = 0.0
    for j in range(n):
        mx += px[members[j], 0]
        my += px[members[j], 1]
    mx /= n
    my /= n
    dsum = 0.0
    c1 = 0.0
    s1 = 0.0
    c2 = 0.0
    s2 = 0.0
    for j in range(n):
        dx = px[members[j], 0] - mx
        dy = px[members[j], 1] - my
        r2 = dx * dx + dy * dy
        if r2 > 0.0:
            r = np.sqrt(r2)
            dsum += r
            c1 += dx / r  # cos(theta)
            s1 += dy / r
            c2 += (dx * dx - dy * dy) / r2  # cos(2 theta)
            s2 += 2.0 * dx * dy / r2
    m1 = np.sqrt(c1 * c1 + s1 * s1) / n
    m2 = np.sqrt(c2 * c2 + s2 * s2) / n
    return dsum / n, max(0.0, (1.0 - m1) * (1.0 - m2))


@numba.njit(cache=True)
def _spread_index(spread, radius):
    """``Q_s = min(1, spread / r_c)`` (0 for a camera without spread to normalise by)."""
    return min(1.0, spread / radius) if radius > 0 else 0.0


@numba.njit(cache=True)
def _balance(counts, weights, eligible, k):
    """``Q_b = 1 - sum_{eligible c} |n_c - k w_c| / (2 k)`` (0 when ``k`` is 0)."""
    dev = 0.0
    for c in range(len(counts)):
        if eligible[c]:
            dev += abs(counts[c] - k * weights[c])
    return 1.0 - dev / (2.0 * k) if k else 0.0


@numba.njit(cache=True)
def _quality(px, members, n, radius):
    """``Q_c = Q_s Q_a`` of the points ``px[members[:n]]``."""
    spread, qa = _indexes(px, members, n)
    return _spread_index(spread, radius) * qa


@numba.njit(cache=True)
def _exchange(px, members, n, radius, passes):
    """First-improvement exchanges between ``members[:n]`` (selected) and ``members[n:]``,
    cycling over the selected slots until ``n`` slots in a row bring no improvement (a local
    optimum) or ``passes`` cycles are spent; returns the final ``Q_c``. ``members`` is a
    permutation of the camera's candidates."""
    F = len(members)
    q = _quality(px, members, n, radius)
    idle = 0
    a = 0
    for _ in range(passes * n):
        improved = False
        for b in range(n, F):
            members[a], members[b] = members[b], members[a]
            val = _quality(px, members, n, radius)
            if val > q + 1e-12:
                q = val
                improved = True
            else:
                members[a], members[b] = members[b], members[a]
        idle = 0 if improved else idle + 1
        if idle >= n:
            break
        a = (a + 1) % n
    return q


@numba.njit(cache=True)
def _chains(px, radius, n_lo, n_hi):
    """Greedy chains of one camera, ``Q_c`` and permutation (first ``n`` selected) for every
    count ``n`` in ``[n_lo, n_hi]``: row 0 forward (farthest-point seed of ``n_lo`` points, then
    the best addition each time), row 1 backward (from all the points, the best removal each
    time)."""
    F = len(px)
    q = np.full((2, n_hi + 1), -1.0)
    perms = np.zeros((2, n_hi + 1, F), dtype=np.int64)
    perm = np.arange(F)
    mx = 0.0
    my = 0.0
    for i in range(F):
        mx += px[i, 0] / F
        my += px[i, 1] / F
    b = 0
    far = -1.0
    for i in range(F):
        d = (px[i, 0] - mx) ** 2 + (px[i, 1] - my) ** 2
        if d > far:
            far = d
            b = i
    perm[0], perm[b] = perm[b], perm[0]
    mind = np.empty(F)
    for i in range(F):
        mind[i] = (px[i, 0] - px[b, 0]) ** 2 + (px[i, 1] - px[b, 1]) ** 2
    for j in range(1, n_lo):  # farthest-point seed
        b = j
        for i in range(j, F):
            if mind[perm[i]] > mind[perm[b]]:
                b = i
        perm[j], perm[b] = perm[b], perm[j]
        p = perm[j]
        for i in range(F):
            mind[i] = min(mind[i], (px[i, 0] - px[p, 0]) ** 2 + (px[i, 1] - px[p, 1]) ** 2)
    for n in range(n_lo, n_hi + 1):
        if n > n_lo:  # greedy addition into slot n - 1
            b_best = n - 1
            q_best = -1.0
            for b in range(n - 1, F):
                perm[n - 1], perm[b] = perm[b], perm[n - 1]
                val = _quality(px, perm, n, radius)
                if val > q_best:
                    q_best = val
                    b_best = b
                perm[n - 1], perm[b] = perm[b], perm[n - 1]
            perm[n - 1], perm[b_best] = perm[b_best], perm[n - 1]
        q[0, n] = _quality(px, perm, n, radius)
        perms[0, n] = perm
    perm = np.arange(F)
    if F <= n_hi:
        q[1, F] = _quality(px, perm, F, radius)
        perms[1, F] = perm
    for n in range(F - 1, n_lo - 1, -1):  # greedy removal into slot n
        a_best = n
        q_best = -1.0
        for a in range(n + 1):
            perm[a], perm[n] = perm[n], perm[a]
            val = _quality(px, perm, n, radius)
            if val > q_best:
                q_best = val
                a_best = a
            perm[a], perm[n] = perm[n], perm[a]
        perm[a_best], perm[n] = perm[n], perm[a_best]
        if n <= n_hi:
            q[1, n] = q_best
            perms[1, n] = perm
    return q, perms


@numba.njit(cache=True)
def _pair_exchange(px, members, n, radius, q):
    """One first-improvement double exchange (two selected points for two unselected ones);
    returns the new ``Q_c`` (``q`` if none improves)."""
    F = len(members)
    for a1 in range(n):
        for a2 in range(a1 + 1, n):
            for b1 in range(n, F):
                for b2 in range(b1 + 1, F):
                    members[a1], members[b1] = members[b1], members[a1]
                    members[a2], members[b2] = members[b2], members[a2]
                    val = _quality(px, members, n, radius)
                    if val > q + 1e-12:
                        return val
                    members[a2], members[b2] = members[b2], members[a2]
                    members[a1], members[b1] = members[b1], members[a1]
    return q


@numba.njit(cache=True)
def _polish(px, radius, n, starts, passes, max_pairs):
    """Single exchanges to a local optimum from the two chains' sets of ``n`` points (once if
    they are the same set), then from the better one double exchanges, each followed by single
    ones, while they improve (only when a double-exchange pass has at most ``max_pairs``
    candidates); returns the final ``Q_c`` and its permutation."""
    F = len(px)
    best_q = -1.0
    best_perm = starts[0].copy()
    mark = np.zeros(F, dtype=np.bool_)
    for a in range(n):
        mark[starts[0, a]] = True
    same = True
    for a in range(n):
        same = same and mark[starts[1, a]]
    for s in range(1 if same else 2):
        perm = starts[s].copy()
        q = _exchange(px, perm, n, radius, passes)
        if q > best_q + 1e-12:
            best_q = q
            best_perm = perm
    pairs = n * (n - 1) // 2 * ((F - n) * (F - n - 1) // 2)
    for _ in range(passes if pairs <= max_pairs else 0):  # double exchanges, then single ones
        q = _pair_exchange(px, best_perm, n, radius, best_q)
        if q <= best_q:
            break
        best_q = _exchange(px, best_perm, n, radius, passes)
    return best_q, best_perm


@numba.njit(cache=True)
def _best_counts(est, done, weights, eligible, k, m_min, slack):
    """Count vector (each count 0 or one with an estimate, summing to ``k``) of largest ``J``,
    an unpolished estimate counting as ``min(1, est (1 + slack))``."""
    C = len(weights)
    counts = np.zeros(C, dtype=np.int64)
    best_counts = np.zeros(C, dtype=np.int64)
    best_j = -1.0
    while True:  # odometer
        total = 0
        num = 0.0
        for c in range(C):
            total += counts[c]
            if eligible[c]:
                e = est[c, counts[c]]
                num += weights[c] * (e if done[c, counts[c]] else min(1.0, e * (1.0 + slack)))
        if total == k:
            J = num * _balance(counts, weights, eligible, k)
            if J > best_j:
                best_j = J
                best_counts[:] = counts
        c = 0
        while c < C:  # next feasible value of digit c, else reset it and carry
            counts[c] = max(counts[c] + 1, m_min)
            while counts[c] <= k and est[c, counts[c]] < 0:
                counts[c] += 1
            if counts[c] <= k:
                break
            counts[c] = 0
            c += 1
        if c == C:
            break
    return best_counts, best_j


@numba.njit(cache=True)
def _pack(pixels, visible, rho, m_min):
    """Visible candidates per camera (indices, count), radius ``r_c``, eligibility, ``w_c``."""
    C, F = visible.shape
    cand = np.zeros((C, F), dtype=np.int64)
    sizes = np.zeros(C, dtype=np.int64)
    radius = np.zeros(C)
    eligible = np.zeros(C, dtype=np.bool_)
    weights = np.zeros(C)
    for c in range(C):
        mx = 0.0
        my = 0.0
        for f in range(F):
            if visible[c, f] and np.isfinite(pixels[c, f, 0]) and np.isfinite(pixels[c, f, 1]):
                cand[c, sizes[c]] = f
                sizes[c] += 1
                mx += pixels[c, f, 0]
                my += pixels[c, f, 1]
        n = sizes[c]
        for j in range(n):
            f = cand[c, j]
            d = (pixels[c, f, 0] - mx / n) ** 2 + (pixels[c, f, 1] - my / n) ** 2
            radius[c] = max(radius[c], np.sqrt(d))
        eligible[c] = n >= m_min and rho[c] > 0
        if eligible[c]:
            weights[c] = rho[c]
    if weights.sum() > 0:
        weights /= weights.sum()
    return cand, sizes, radius, eligible, weights


@numba.njit(cache=True)
def _final_indexes(pixels, selected, radius):
    C, F = selected.shape
    qs = np.zeros(C)
    qa = np.zeros(C)
    members = np.zeros(F, dtype=np.int64)
    for c in range(C):
        n = 0
        for f in range(F):
            if selected[c, f]:
                members[n] = f
                n += 1
        spread, qa[c] = _indexes(pixels[c], members, n)
        qs[c] = _spread_index(spread, radius[c])
    return qs, qa


@numba.njit(cache=True)
def _select(pixels, visible, rho, k_max, m_min, passes, slack, max_pairs):
    """The whole selection; returns (selected (C, F), J, k, weights, eligible, radius)."""
    C, F = visible.shape
    cand, sizes, radius, eligible, weights = _pack(pixels, visible, rho, m_min)
    selected = np.zeros((C, F), dtype=np.bool_)
    if not eligible.any():  # fallback: every visible point, up to k_max
        left = k_max
        for c in range(C):
            for j in range(min(left, sizes[c])):
                selected[c, cand[c, j]] = True
            left -= min(left, sizes[c])
        return selected, 0.0, k_max - left, weights, eligible, radius
    avail = 0
    for c in range(C):
        if eligible[c]:
            avail += min(sizes[c], k_max)
    k = min(avail, k_max)
    est = np.full((C, k + 1), -1.0)  # Q_c estimates per count (-1: infeasible)
    done = np.zeros((C, k + 1), dtype=np.bool_)  # polished by exchanges
    chain_perms = np.zeros((C, 2, k + 1, F), dtype=np.int64)
    perms = np.zeros((C, k + 1, F), dtype=np.int64)
    cams_px = np.zeros((C, F, 2))
    for c in range(C):
        est[c, 0] = 0.0
        done[c, 0] = True
        n_hi = min(sizes[c], k)
        if eligible[c] and n_hi >= m_min:
            for j in range(sizes[c]):
                cams_px[c, j] = pixels[c, cand[c, j]]
            q, p = _chains(cams_px[c, : sizes[c]], radius[c], m_min, n_hi)
            others = avail - min(sizes[c], k_max)
            for n in range(m_min, n_hi + 1):
                # only counts the other cameras can complete to k (0 or >= m_min each)
                if n == k or m_min <= k - n <= others:
                    est[c, n] = max(q[0, n], q[1, n])
            chain_perms[c, :, : n_hi + 1, : sizes[c]] = p
    while True:  # polish the counts of the best vector until it is made of polished counts
        best_counts, best_j = _best_counts(est, done, weights, eligible, k, m_min, slack)
        fresh = False
        for c in range(C):
            n = best_counts[c]
            if not done[c, n]:
                F_c = sizes[c]
                q, p = _polish(cams_px[c, :F_c], radius[c], n, chain_perms[c, :, n, :F_c],
                               passes, max_pairs)
                est[c, n] = q
                perms[c, n, :F_c] = p
                done[c, n] = True
                fresh = True
        if not fresh:
            break
    for c in range(C):
        for j in range(best_counts[c]):
            selected[c, cand[c, perms[c, best_counts[c], j]]] = True
    return selected, best_j, k, weights, eligible, radius


def _select_feasible(pixels, visible, rho, k_max, m_min, *args):
    """:func:`_select` with the largest count ``k <= k_max`` that the eligible cameras can
    split (each 0 or at least ``m_min``): 5 + 5 visible points cannot give 6 with ``m_min = 4``,
    so 5 are taken from one camera."""
    while True:
        out = _select(pixels, visible, rho, k_max, m_min, *args)
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
    qs, qa = _final_indexes(pixels, selected, radius)
    counts = selected.sum(axis=1)
    balance = _balance(counts, weights, eligible, k)
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
    _, _, radius, eligible, weights = _pack(pixels, visible, rho, min_per_camera)
    counts = selected.sum(axis=1)
    k = int(counts.sum())
    bad_count = (counts > 0) & (~eligible | (counts < min_per_camera))
    if k == 0 or np.any(selected & ~visible) or bad_count.any():
        return -np.inf
    qs, qa = _final_indexes(pixels, selected, radius)
    return float(np.sum(weights * qs * qa) * _balance(counts, weights, eligible, k))


@dataclass(frozen=True)
class OptimalSelector:
    """The tracker's default :class:`~cellsight.tracking.interfaces.Selector`: the optimal
    selection of the module docstring (:func:`select_features`) with ``config``."""

    config: SelectionConfig = SelectionConfig()

    def select(self, pixels: np.ndarray, usable: np.ndarray, resolution: np.ndarray) -> Selection:
        """Select among the ``usable`` (C, F) features with predicted pixels ``pixels``
        (C, F, 2) px, cameras weighted by ``resolution`` (C,) px/m."""
        return select_features(pixels, usable, resolution, self.config)

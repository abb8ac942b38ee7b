"""Image windows around the selected features of one camera, and the regions to grab.

Pixel coordinates ``(u, v)`` = (column, row), pixel centres at integers (OpenCV). A window is a
float box ``[u_lo, u_hi] x [v_lo, v_hi]``; the pixels it grabs are those whose centres lie in it,
returned as the half-open integer box ``(u0, v0, u1, v1)`` (``image[v0:v1, u0:u1]``).

Per selected feature with predicted projection ``c`` and innovation covariance ``S`` (2x2, px^2):

1. size from the EKF: half-widths ``h_u = k sqrt(S_uu) + s``, ``h_v = k sqrt(S_vv) + s`` (``k`` =
   ``k_sigma``, the 3-sigma box; ``s`` = ``support_px``, the extent a corner needs around it),
   each full width ``2h`` clamped to ``[min_size_px, max_size_px]``;
2. conflicts: another feature's projection that falls in the window (grown by ``margin_px``) is
   cut away, ``margin_px`` short of it, either by moving one side of the window or by scaling
   the whole window towards ``c``; of these five cuts the one keeping the largest area is
   chosen. A cut must leave the ``keep`` box ``c +- support_px``; if none can, the feature is
   dropped;
3. clipped to the image; a window that no longer holds the ``keep`` box is dropped;
4. regions: windows are merged into their bounding box while that is cheaper, the cost of a
   region being its pixel count plus ``region_overhead_px`` (the fixed cost of one grab).
   Feature extraction still searches each feature's own window only.

The fraction of the image grabbed is ``sum(region pixels) / (width height)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from cellsight.camera import Camera

OK, SHRUNK, DROPPED = 0, 1, 2
_EMPTY_POINTS = np.zeros((0, 2))


@dataclass(frozen=True)
class WindowConfig:
    """Window sizing and merging parameters (px; see module docstring)."""

    k_sigma: float = 3.0
    support_px: float = 6.0
    min_size_px: float = 16.0
    max_size_px: float = 64.0
    margin_px: float = 2.0
    region_overhead_px: float = 64.0

    def __post_init__(self) -> None:
        if not (
            self.k_sigma > 0
            and self.support_px >= 0
            and 0 < self.min_size_px <= self.max_size_px
            and self.margin_px >= 0
            and self.region_overhead_px >= 0
        ):
            raise ValueError(f"WindowConfig: invalid {self}")


@dataclass(frozen=True)
class WindowPlan:
    """Windows of one camera.

    ``features`` (n,): feature index of each kept window; ``centers`` (n, 2) predicted pixels;
    ``boxes`` (n, 4) int ``(u0, v0, u1, v1)``; ``shrunk`` (n,) bool; ``dropped`` (d,): features
    dropped; ``regions`` (r, 4) int grabbed boxes; ``region_of`` (n,) region of each window;
    ``grabbed_px`` pixels grabbed; ``fraction`` of the image's pixels grabbed.
    """

    features: np.ndarray
    centers: np.ndarray
    boxes: np.ndarray
    shrunk: np.ndarray
    dropped: np.ndarray
    regions: np.ndarray
    region_of: np.ndarray
    grabbed_px: int
    fraction: float


@numba.njit(cache=True)
def _clip_segment(p0u, p0v, p1u, p1v, lo_u, lo_v, hi_u, hi_v):
    """Liang-Barsky: the part of a segment inside a box, as (ok, u_min, v_min, u_max, v_max)."""
    t0 = 0.0
    t1 = 1.0
    du = p1u - p0u
    dv = p1v - p0v
    for p, q in ((-du, p0u - lo_u), (du, hi_u - p0u), (-dv, p0v - lo_v), (dv, hi_v - p0v)):
        if p == 0.0:
            if q < 0.0:
                return False, 0.0, 0.0, 0.0, 0.0
        else:
            r = q / p
            if p < 0.0:
                t0 = max(t0, r)
            else:
                t1 = min(t1, r)
            if t0 > t1:
                return False, 0.0, 0.0, 0.0, 0.0
    au = p0u + t0 * du
    av = p0v + t0 * dv
    bu = p0u + t1 * du
    bv = p0v + t1 * dv
    return True, min(au, bu), min(av, bv), max(au, bu), max(av, bv)


@numba.njit(cache=True)
def _scale_limit(p0u, p0v, p1u, p1v, cu, cv, b, margin):
    """Largest ``lam`` such that the segment stays ``margin`` away (max-norm) from the box
    ``c + lam (b - c)``: ``min_t max_k l_k(t)`` over the four linear functions
    ``(+-(p(t) - c) - margin) / a_side``, checked at the ends and the pairwise crossings."""
    coef = np.empty((4, 2))  # l_k(t) = coef[k, 0] + coef[k, 1] t
    a = (b[2] - cu, cu - b[0], b[3] - cv, cv - b[1])
    sgn = (1.0, -1.0, 1.0, -1.0)
    for k in range(4):
        c0 = cu if k < 2 else cv
        q0 = p0u if k < 2 else p0v
        q1 = p1u if k < 2 else p1v
        coef[k, 0] = (sgn[k] * (q0 - c0) - margin) / a[k]
        coef[k, 1] = sgn[k] * (q1 - q0) / a[k]
    best = np.inf
    ts = [0.0, 1.0]
    for i in range(4):
        for j in range(i + 1, 4):
            d = coef[i, 1] - coef[j, 1]
            if d != 0.0:
                t = (coef[j, 0] - coef[i, 0]) / d
                if 0.0 < t < 1.0:
                    ts.append(t)
    for t in ts:
        m = -np.inf
        for k in range(4):
            m = max(m, coef[k, 0] + coef[k, 1] * t)
        best = min(best, m)
    return best


@numba.njit(cache=True)
def _windows(centers, half, own, others, width, height, keep, margin):
    """Float boxes (n, 4) ``(u_lo, v_lo, u_hi, v_hi)`` and status (OK/SHRUNK/DROPPED)."""
    n = len(centers)
    boxes = np.zeros((n, 4))
    status = np.zeros(n, dtype=np.int64)
    for w in range(n):
        cu = centers[w, 0]
        cv = centers[w, 1]
        b = np.array([cu - half[w, 0], cv - half[w, 1], cu + half[w, 0], cv + half[w, 1]])
        for i in range(len(others)):
            if i == own[w]:
                continue
            p0u = p1u = others[i, 0]
            p0v = p1v = others[i, 1]
            hit, umin, vmin, umax, vmax = _clip_segment(
                p0u, p0v, p1u, p1v, b[0] - margin, b[1] - margin, b[2] + margin, b[3] + margin
            )
            if not hit:
                continue
            best_area = -1.0
            best_side = -1
            best_val = 0.0
            # candidate cuts: right, left, bottom, top, or scaling the box towards the centre
            for side in range(5):
                if side == 0:
                    val = umin - margin
                    ok = val >= cu + keep
                    area = (val - b[0]) * (b[3] - b[1])
                elif side == 1:
                    val = umax + margin
                    ok = val <= cu - keep
                    area = (b[2] - val) * (b[3] - b[1])
                elif side == 2:
                    val = vmin - margin
                    ok = val >= cv + keep
                    area = (b[2] - b[0]) * (val - b[1])
                elif side == 3:
                    val = vmax + margin
                    ok = val <= cv - keep
                    area = (b[2] - b[0]) * (b[3] - val)
                else:
                    val = min(_scale_limit(p0u, p0v, p1u, p1v, cu, cv, b, margin), 1.0) - 1e-9
                    a_min = min(b[2] - cu, cu - b[0], b[3] - cv, cv - b[1])
                    ok = val * a_min >= keep
                    area = val * val * (b[2] - b[0]) * (b[3] - b[1])
                if ok and area > best_area:
                    best_area = area
                    best_side = side
                    best_val = val
            if best_side < 0:
                status[w] = DROPPED
                break
            status[w] = SHRUNK
            if best_side == 0:
                b[2] = min(b[2], best_val)
            elif best_side == 1:
                b[0] = max(b[0], best_val)
            elif best_side == 2:
                b[3] = min(b[3], best_val)
            elif best_side == 3:
                b[1] = max(b[1], best_val)
            else:
                b[0] = cu + best_val * (b[0] - cu)
                b[1] = cv + best_val * (b[1] - cv)
                b[2] = cu + best_val * (b[2] - cu)
                b[3] = cv + best_val * (b[3] - cv)
        b[0] = max(b[0], 0.0)
        b[1] = max(b[1], 0.0)
        b[2] = min(b[2], width - 1.0)
        b[3] = min(b[3], height - 1.0)
        if b[0] > cu - keep or b[1] > cv - keep or b[2] < cu + keep or b[3] < cv + keep:
            status[w] = DROPPED
        boxes[w] = b
    return boxes, status


@numba.njit(cache=True)
def _merge(boxes, overhead):
    """Greedy merging of integer boxes (n, 4) while the bounding box is cheaper than the pair.

    Returns the region boxes and the region index of every input box.
    """
    n = len(boxes)
    reg = boxes.copy()
    alive = np.ones(n, dtype=np.bool_)
    of = np.arange(n)
    while True:
        best = 0.0
        bi = -1
        bj = -1
        for i in range(n):
            if not alive[i]:
                continue
            ci = (reg[i, 2] - reg[i, 0]) * (reg[i, 3] - reg[i, 1]) + overhead
            for j in range(i + 1, n):
                if not alive[j]:
                    continue
                cj = (reg[j, 2] - reg[j, 0]) * (reg[j, 3] - reg[j, 1]) + overhead
                u0 = min(reg[i, 0], reg[j, 0])
                v0 = min(reg[i, 1], reg[j, 1])
                u1 = max(reg[i, 2], reg[j, 2])
                v1 = max(reg[i, 3], reg[j, 3])
                saving = ci + cj - ((u1 - u0) * (v1 - v0) + overhead)
                if saving > best:
                    best = saving
                    bi = i
                    bj = j
        if bi < 0:
            break
        reg[bi, 0] = min(reg[bi, 0], reg[bj, 0])
        reg[bi, 1] = min(reg[bi, 1], reg[bj, 1])
        reg[bi, 2] = max(reg[bi, 2], reg[bj, 2])
        reg[bi, 3] = max(reg[bi, 3], reg[bj, 3])
        alive[bj] = False
        for w in range(n):
            if of[w] == bj:
                of[w] = bi
    index = np.cumsum(alive) - 1
    return reg[alive], index[of]


@numba.njit(cache=True)
def _plan(centers, S, own, others, width, height, k_sigma, support, min_size,
          max_size, margin, overhead):
    """Steps 1-4 of the module docstring: status of every window, integer boxes of the kept
    ones, regions and the region of each kept window."""
    n = len(centers)
    half = np.empty((n, 2))
    for w in range(n):
        for a in range(2):
            size = 2.0 * (k_sigma * np.sqrt(max(S[w, a, a], 0.0)) + support)
            half[w, a] = 0.5 * min(max(size, min_size), max_size)
    boxes, status = _windows(centers, half, own, others, width, height, support, margin)
    n_kept = 0
    for w in range(n):
        n_kept += status[w] != DROPPED
    ints = np.empty((n_kept, 4), dtype=np.int64)
    i = 0
    for w in range(n):
        if status[w] != DROPPED:
            ints[i, 0] = np.ceil(boxes[w, 0])
            ints[i, 1] = np.ceil(boxes[w, 1])
            ints[i, 2] = np.floor(boxes[w, 2]) + 1
            ints[i, 3] = np.floor(boxes[w, 3]) + 1
            i += 1
    regions, region_of = _merge(ints, overhead)
    return status, ints, regions, region_of


def plan_windows(
    centers: np.ndarray,
    features: np.ndarray,
    innovation_cov: np.ndarray,
    width: int,
    height: int,
    others: np.ndarray | None = None,
    own: np.ndarray | None = None,
    config: WindowConfig | None = None,
) -> WindowPlan:
    """Plan the windows of one camera (module docstring).

    ``centers`` (n, 2): predicted pixels of the selected features ``features`` (n,);
    ``innovation_cov`` (n, 2, 2) px^2; ``others`` (m, 2): predicted pixels of every visible
    feature in this camera (any workpiece), ``own`` (n,) the row of ``others`` that is the
    window's own feature (-1 if none). (Features next to an occluder's silhouette are not
    selected in the first place: see ``near_occluder`` in
    :mod:`cellsight.occlusion.predictor`.)
    """
    cfg = config or WindowConfig()
    centers = np.ascontiguousarray(centers, dtype=np.float64).reshape(-1, 2)
    features = np.asarray(features, dtype=np.int64).reshape(-1)
    n = len(centers)
    S = np.ascontiguousarray(innovation_cov, dtype=np.float64).reshape(n, 2, 2)
    others = _EMPTY_POINTS if others is None else np.ascontiguousarray(others, dtype=np.float64)
    own = np.full(n, -1, dtype=np.int64) if own is None else np.asarray(own, dtype=np.int64)
    status, boxes, regions, region_of = _plan(
        centers, S, own, others, float(width), float(height), cfg.k_sigma,
        cfg.support_px, cfg.min_size_px, cfg.max_size_px, cfg.margin_px,
        float(cfg.region_overhead_px),
    )
    kept = status != DROPPED
    grabbed = int(np.sum((regions[:, 2] - regions[:, 0]) * (regions[:, 3] - regions[:, 1])))
    return WindowPlan(
        features=features[kept],
        centers=centers[kept],
        boxes=boxes,
        shrunk=status[kept] == SHRUNK,
        dropped=features[~kept],
        regions=regions,
        region_of=region_of,
        grabbed_px=grabbed,
        fraction=grabbed / float(width * height),
    )


@dataclass(frozen=True)
class CovarianceWindows:
    """The tracker's default :class:`~cellsight.tracking.interfaces.WindowPlanner`: windows
    sized by the innovation covariance and kept clear of the other predicted features
    (:func:`plan_windows`, module docstring) with ``config``."""

    config: WindowConfig = WindowConfig()

    def plan(self, camera: Camera, centers: np.ndarray, features: np.ndarray,
             covariance: np.ndarray, crowd: np.ndarray, own: np.ndarray,
             size_px: float | None = None) -> WindowPlan:
        """:func:`plan_windows` in ``camera``'s image; ``size_px`` (px): every window that full
        width and height whatever the covariance (acquisition), None: sized by it."""
        cfg = (self.config if size_px is None
               else replace(self.config, min_size_px=size_px, max_size_px=size_px))
        return plan_windows(centers, features, covariance, camera.width, camera.height, crowd,
                            own, cfg)

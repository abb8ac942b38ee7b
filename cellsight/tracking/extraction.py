"""Sub-pixel corner extraction inside the image windows of the selected features.

Inside a window (half-open integer box ``(u0, v0, u1, v1)`` of a grayscale image):

1. candidates: Shi-Tomasi corners (``cv2.goodFeaturesToTrack``, minimum-eigenvalue response);
   the one nearest to the predicted projection is kept;
2. sub-pixel refinement: ``cv2.cornerSubPix`` (the point where the image gradients of the
   surrounding pixels are orthogonal to the lines joining it to them: the common point of the
   edges of any junction, L, Y or X), started from the candidate and from three points 1 px
   around it; the runs must agree within ``max_spread_px`` (an ill-posed junction, e.g. two
   nearly parallel edges a few pixels apart, gives scattered runs) and their mean is kept;
3. credibility: the refined point must stay inside the window (``border_px`` from its sides) and
   within ``max_shift_px`` of the candidate; the gradient structure tensor ``G`` summed over the
   refinement patch (``N`` pixels, gradients in gray levels per pixel) must show two edge
   directions: ``sqrt(lambda_min(G) / N) >= min_gradient`` and
   ``lambda_min / lambda_max >= min_eigen_ratio`` (a straight edge or a flat patch fails);
4. the edge lines: where the least-squares intersection of the edges leaving the point lies
   within ``line_max_offset_px`` of it, it is the corner (:func:`_edge_intersection`).

OpenCV runs steps 1 and 2; the rest is compiled with numba (one call per window), with the
answers the same NumPy steps give (``tests/test_extraction.py``).

When any step fails the feature gets no measurement: a measurement is never forced.
Returned pixels are in full-image coordinates (u = column, v = row; OpenCV pixel centres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from cellsight.tracking.windowing import WindowPlan


@dataclass(frozen=True)
class ExtractionConfig:
    """Corner detection and acceptance parameters (px, gray levels; module docstring)."""

    max_candidates: int = 5
    image_corners: int = 500
    image_quality_level: float = 0.01
    image_min_distance_px: float = 5.0
    quality_level: float = 0.05
    min_distance_px: float = 3.0
    block_size: int = 3
    refine_half_px: int = 4
    max_shift_px: float = 2.5
    max_spread_px: float = 0.15
    line_inner_px: float = 2.5
    line_outer_px: float = 10.0
    line_threshold: float = 0.25
    line_max_offset_px: float = 1.0
    border_px: float = 2.0
    min_gradient: float = 2.0
    min_eigen_ratio: float = 0.03


def _to_gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return image


@numba.njit(cache=True, inline="always")
def _gradient_at(image, v, u):
    """``np.gradient`` of a float image (h, w), both at least 2, at pixel (v, u): (gy, gx),
    central differences inside, one-sided at the borders."""
    h, w = image.shape
    if 0 < v < h - 1:
        gy = (image[v + 1, u] - image[v - 1, u]) / 2.0
    else:
        gy = image[1, u] - image[0, u] if v == 0 else image[v, u] - image[v - 1, u]
    if 0 < u < w - 1:
        gx = (image[v, u + 1] - image[v, u - 1]) / 2.0
    else:
        gx = image[v, 1] - image[v, 0] if u == 0 else image[v, u] - image[v, u - 1]
    return gy, gx


@numba.njit(cache=True)
def _gradients(image):
    """``np.gradient`` of a float image (h, w), both at least 2: (gy, gx)
    (:func:`_gradient_at` at every pixel)."""
    h, w = image.shape
    gy, gx = np.empty((h, w)), np.empty((h, w))
    for v in range(h):
        for u in range(w):
            gy[v, u], gx[v, u] = _gradient_at(image, v, u)
    return gy, gx


@numba.njit(cache=True)
def _structure_tensor(patch):
    """The gradient structure tensor summed over ``patch``: (sum gx^2, sum gx gy, sum gy^2)."""
    gy, gx = _gradients(patch)
    return np.sum(gx * gx), np.sum(gx * gy), np.sum(gy * gy)


@numba.njit(cache=True)
def _two_directions(patch, min_gradient, min_eigen_ratio):
    """Whether the gradients of ``patch`` (float) show two edge directions: the eigenvalues
    of its structure tensor (:func:`_structure_tensor`) with ``sqrt(lambda_min / N) >=
    min_gradient`` (``N`` pixels; gray levels per pixel) and ``lambda_min / lambda_max >=
    min_eigen_ratio``. A straight edge or a flat patch fails."""
    sxx, sxy, syy = _structure_tensor(patch)
    mean, diff = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    lam_min, lam_max = mean - diff, mean + diff
    if lam_max <= 0:
        return False
    return (math.sqrt(max(lam_min, 0.0) / patch.size) >= min_gradient
            and lam_min / lam_max >= min_eigen_ratio)


@numba.njit(cache=True)
def _gradient_magnitude(image):
    """``sqrt(gx^2 + gy^2)`` of :func:`_gradients` (h, w), in one pass (np.hypot's values on
    gray levels' gradients; ``math.hypot`` took half of a window's acceptance)."""
    h, w = image.shape
    mag = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            gy, gx = _gradient_at(image, v, u)
            mag[v, u] = math.sqrt(gx * gx + gy * gy)
    return mag


_BINS = 36  # direction histogram of the edges around a corner: 10-degree bins


@numba.njit(cache=True)
def _principal_axes(a: float, b: float, c: float) -> tuple[float, float, float, float]:
    """Unit eigenvectors (largest, smallest eigenvalue) of the symmetric [[a, b], [b, c]]."""
    theta = 0.5 * math.atan2(2.0 * b, a - c)
    dx, dy = math.cos(theta), math.sin(theta)
    return dx, dy, -dy, dx


@numba.njit(cache=True)
def _band_box(qx, qy, dx, dy, nx, ny, offset, inner, outer, h, w):
    """The pixels of an (h, w) image that can lie in the band ``inner <= (p - q).d <= outer``,
    ``|p.n - offset| <= 1.5`` (``d``, ``n`` orthonormal): ``(u0, u1, v0, v1)``, half-open, the
    band's bounding box widened by a pixel."""
    along = qx * dx + qy * dy
    lo_u = lo_v = np.inf
    hi_u = hi_v = -np.inf
    for t in (inner, outer):
        for s in (offset - 1.5, offset + 1.5):
            u, v = (along + t) * dx + s * nx, (along + t) * dy + s * ny
            lo_u, hi_u = min(lo_u, u), max(hi_u, u)
            lo_v, hi_v = min(lo_v, v), max(hi_v, v)
    return (max(int(math.floor(lo_u)) - 1, 0), min(int(math.ceil(hi_u)) + 2, w),
            max(int(math.floor(lo_v)) - 1, 0), min(int(math.ceil(hi_v)) + 2, h))


@numba.njit(cache=True)
def _edge_intersection(mag, qx, qy, inner, outer, threshold, max_offset):
    """Corner as the least-squares intersection of the edges leaving ``(qx, qy)`` (crop px),
    on the crop's gradient magnitude ``mag`` (h, w; :func:`_gradient_magnitude`): ``(found,
    x, y)``.

    Edge directions: peaks of a 10-degree histogram of the directions from ``q`` of the strong
    gradient pixels (magnitude above ``threshold`` of the largest) in the ring ``inner..outer``
    px. Each edge starts as the line through ``q`` along its peak and is refitted three times
    by weighted total least squares to every pixel of the band within 1.5 px of the line and
    ``inner..outer`` along it (weights: gradient magnitude, whose centroid across an edge is
    the edge; a band symmetric about the line keeps the fit unbiased). Lines passing within
    ``max_offset`` px of ``q`` are intersected, weighted by their total gradient. Not found
    when fewer than two non-parallel edges are."""
    h, w = mag.shape
    ring_max = 0.0
    inner2, outer2 = inner * inner, outer * outer  # the ring by squared distances (no hypot)
    ring = np.zeros((h, w), np.bool_)
    # the ring's pixels lie in its box: the pixels outside it are more than ``outer`` away
    r0, r1 = max(int(math.floor(qy - outer)), 0), min(int(math.ceil(qy + outer)) + 1, h)
    c0, c1 = max(int(math.floor(qx - outer)), 0), min(int(math.ceil(qx + outer)) + 1, w)
    for v in range(r0, r1):
        for u in range(c0, c1):
            ring[v, u] = inner2 <= (u - qx) * (u - qx) + (v - qy) * (v - qy) <= outer2
            if ring[v, u] and mag[v, u] > ring_max:
                ring_max = mag[v, u]
    hist = np.zeros(_BINS)
    n_strong = 0
    for v in range(r0, r1):
        for u in range(c0, c1):
            if ring[v, u] and mag[v, u] >= threshold * ring_max:
                phi = math.atan2(v - qy, u - qx)
                hist[int((phi + math.pi) / (2 * math.pi) * _BINS) % _BINS] += mag[v, u]
                n_strong += 1
    if n_strong < 6:
        return False, 0.0, 0.0
    smooth = np.empty(_BINS)
    for k in range(_BINS):
        smooth[k] = hist[k] + 0.5 * (hist[(k - 1) % _BINS] + hist[(k + 1) % _BINS])
    total = smooth.sum()
    a00 = a01 = a11 = b0 = b1 = 0.0
    for k in range(_BINS):
        if not (smooth[k] >= smooth[(k - 1) % _BINS] and smooth[k] > smooth[(k + 1) % _BINS]
                and smooth[k] >= 0.1 * total):
            continue
        angle = (k + 0.5) * 2 * math.pi / _BINS - math.pi
        dx, dy = math.cos(angle), math.sin(angle)
        nx, ny = -dy, dx
        offset = nx * qx + ny * qy
        fitted = True
        weight = 0.0
        for _ in range(3):  # refit the line to the band around it
            sw = su = sv = 0.0
            count = 0
            u0, u1, v0, v1 = _band_box(qx, qy, dx, dy, nx, ny, offset, inner, outer, h, w)
            for v in range(v0, v1):
                for u in range(u0, u1):
                    t = (u - qx) * dx + (v - qy) * dy
                    if abs(u * nx + v * ny - offset) <= 1.5 and inner <= t <= outer:
                        sw += mag[v, u]
                        su += mag[v, u] * u
                        sv += mag[v, u] * v
                        count += 1
            if count < 6 or sw <= 0:
                fitted = False
                break
            mu, mv = su / sw, sv / sw
            cuu = cuv = cvv = 0.0
            for v in range(v0, v1):
                for u in range(u0, u1):
                    t = (u - qx) * dx + (v - qy) * dy
                    if abs(u * nx + v * ny - offset) <= 1.5 and inner <= t <= outer:
                        cuu += mag[v, u] * (u - mu) ** 2
                        cuv += mag[v, u] * (u - mu) * (v - mv)
                        cvv += mag[v, u] * (v - mv) ** 2
            ex, ey, nx, ny = _principal_axes(cuu, cuv, cvv)
            dx, dy = (ex, ey) if ex * dx + ey * dy > 0 else (-ex, -ey)
            offset = nx * mu + ny * mv
            weight = sw
        if fitted and abs(nx * qx + ny * qy - offset) <= max_offset:
            a00 += weight * nx * nx
            a01 += weight * nx * ny
            a11 += weight * ny * ny
            b0 += weight * nx * offset
            b1 += weight * ny * offset
    mean, diff = 0.5 * (a00 + a11), math.hypot(0.5 * (a00 - a11), a01)
    lam_max, lam_min = mean + diff, mean - diff
    if lam_max <= 0 or lam_min / lam_max < 0.05:
        return False, 0.0, 0.0
    det = a00 * a11 - a01 * a01
    return True, (a11 * b0 - a01 * b1) / det, (a00 * b1 - a01 * b0) / det


def extract_corner(
    image: np.ndarray,
    box: np.ndarray,
    predicted: np.ndarray,
    config: ExtractionConfig | None = None,
) -> np.ndarray | None:
    """Sub-pixel corner (2,) in the window ``box`` nearest to ``predicted`` (px), or None.

    OpenCV finds the candidates and refines them; the steps between and after them (the
    candidate nearest to the prediction, the checks, the edge-line intersection) are compiled
    (:func:`_nearest_start`, :func:`_accept`)."""
    cfg = config or ExtractionConfig()
    gray = _to_gray(image)
    u0, v0, u1, v1 = (int(x) for x in box)
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, gray.shape[1]), min(v1, gray.shape[0])
    crop = np.ascontiguousarray(gray[v0:v1, u0:u1], dtype=np.float32)
    if crop.shape[0] < 5 or crop.shape[1] < 5:
        return None
    found = cv2.goodFeaturesToTrack(
        crop,
        maxCorners=cfg.max_candidates,
        qualityLevel=cfg.quality_level,
        minDistance=cfg.min_distance_px,
        blockSize=cfg.block_size,
    )
    if found is None:
        return None
    starts, half = _nearest_start(found.reshape(-1, 2), float(predicted[0]) - u0,
                                  float(predicted[1]) - v0, crop.shape[0], crop.shape[1],
                                  cfg.refine_half_px)
    if half < 2:
        return None
    runs = cv2.cornerSubPix(crop, starts.reshape(-1, 1, 2).copy(), (half, half), (-1, -1),
                            _SUBPIX)  # it refines its input in place: the starts are kept
    ok, x, y = _accept(crop, runs.reshape(-1, 2), starts[0], half, cfg.max_spread_px,
                       cfg.border_px, cfg.max_shift_px, cfg.min_gradient, cfg.min_eigen_ratio,
                       cfg.line_inner_px, cfg.line_outer_px, cfg.line_threshold,
                       cfg.line_max_offset_px)
    return np.array([x + u0, y + v0]) if ok else None


_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)  # cornerSubPix's stop
_AROUND = np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, 1.0], [0.0, -1.0]])  # its four starts


@numba.njit(cache=True)
def _nearest_start(cand, pu, pv, h, w, refine_half):
    """The candidate of ``cand`` (k, 2) float32 (whole pixels, as Shi-Tomasi gives them)
    nearest to the prediction ``(pu, pv)`` in an (h, w) crop: ``(starts, half)``, the
    refinement's four starts (4, 2) float32 (the candidate first, then three points 1 px around
    it) and its half window (px): at most ``refine_half``, the start at least ``half + 1`` px
    inside, the crop at least ``2 half + 5`` px wide and high (cornerSubPix's needs)."""
    best, best_d = 0, np.inf
    for i in range(cand.shape[0]):
        d = (cand[i, 0] - pu) ** 2 + (cand[i, 1] - pv) ** 2
        if d < best_d:
            best, best_d = i, d
    su, sv = float(cand[best, 0]), float(cand[best, 1])
    half = int(min(float(refine_half), su - 1, sv - 1, (w - 2) - su, (h - 2) - sv,
                   float((w - 5) // 2), float((h - 5) // 2)))
    starts = np.empty((4, 2), np.float32)
    for k in range(4):
        starts[k, 0] = su + _AROUND[k, 0]
        starts[k, 1] = sv + _AROUND[k, 1]
    return starts, half


@numba.njit(cache=True)
def _round_half_even(x):
    """Python's ``round(x)`` of a float: the nearest integer, ties to the even one."""
    r = math.floor(x + 0.5)
    if r - x == 0.5 and r % 2 != 0:
        r -= 1
    return int(r)


@numba.njit(cache=True)
def _accept(crop, runs, start, half, max_spread, border, max_shift, min_gradient,
            min_eigen_ratio, inner, outer, threshold, max_offset):
    """The refined corner of an (h, w) float32 ``crop`` from cornerSubPix's four ``runs``
    (4, 2) started at and around ``start`` (crop px), or nothing: ``(found, x, y)``. The runs
    agree within ``max_spread`` px and their mean is kept; it lies ``border`` px inside the
    crop and within ``max_shift`` px of ``start``; its ``2 half + 1`` px patch shows two edge
    directions (``min_gradient``, ``min_eigen_ratio``: :func:`_two_directions`); then the
    edge-line intersection (:func:`_edge_intersection`, recentred once on its own result)
    replaces it where it lies within ``max_offset`` px of it (module docstring)."""
    h, w = crop.shape
    r = runs.astype(np.float64)
    mu, mv = 0.0, 0.0
    for k in range(4):
        mu, mv = mu + r[k, 0], mv + r[k, 1]
    mu, mv = mu / 4.0, mv / 4.0
    spread = 0.0
    for k in range(4):
        du, dv = r[k, 0] - mu, r[k, 1] - mv
        spread = max(spread, math.sqrt(du * du + dv * dv))
    if spread > max_spread:
        return False, 0.0, 0.0
    if not (border <= mu <= w - 1 - border and border <= mv <= h - 1 - border):
        return False, 0.0, 0.0
    if math.hypot(mu - start[0], mv - start[1]) > max_shift:
        return False, 0.0, 0.0
    iu, iv = _round_half_even(mu), _round_half_even(mv)
    image = crop.astype(np.float64)
    patch = image[max(iv - half, 0):iv + half + 1, max(iu - half, 0):iu + half + 1]
    if not _two_directions(patch, min_gradient, min_eigen_ratio):
        return False, 0.0, 0.0
    mag = _gradient_magnitude(image)
    qu, qv = mu, mv
    for _ in range(2):
        ok, lu, lv = _edge_intersection(mag, qu, qv, inner, outer, threshold, max_offset)
        if not ok or math.hypot(lu - mu, lv - mv) > max_offset:
            break
        qu, qv = lu, lv
    return True, qu, qv


@dataclass(frozen=True)
class CornerExtractor:
    """Extractor of the Tracker for real grayscale images: one corner per window."""

    config: ExtractionConfig = ExtractionConfig()

    def extract(
        self, camera_index: int, image: np.ndarray, plan: WindowPlan
    ) -> dict[int, np.ndarray]:
        """Measured pixels (distorted, as in the image) by feature index; missing = not found."""
        out: dict[int, np.ndarray] = {}
        if image is None:
            return out
        for f, box, c in zip(plan.features, plan.boxes, plan.centers, strict=True):
            px = extract_corner(image, box, c, self.config)
            if px is not None:
                out[int(f)] = px
        return out

    def detect(self, image: np.ndarray | None) -> np.ndarray:
        """(N, 2) px: the Shi-Tomasi corners of the whole image (at most ``image_corners``,
        quality ``image_quality_level``, ``image_min_distance_px`` apart), for the whole-image
        search (:mod:`.search`); none for a camera that gave nothing."""
        if image is None:
            return np.zeros((0, 2))
        cfg = self.config
        found = cv2.goodFeaturesToTrack(_to_gray(image), maxCorners=cfg.image_corners,
                                        qualityLevel=cfg.image_quality_level,
                                        minDistance=cfg.image_min_distance_px,
                                        blockSize=cfg.block_size)
        return np.zeros((0, 2)) if found is None else found.reshape(-1, 2).astype(float)

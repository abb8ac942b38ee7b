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
   ``lambda_min / lambda_max >= min_eigen_ratio`` (a straight edge or a flat patch fails).

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


def _structure_ok(patch: np.ndarray, cfg: ExtractionConfig) -> bool:
    sxx, sxy, syy = _structure_tensor(np.ascontiguousarray(patch, dtype=np.float64))
    mean, diff = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    lam_min, lam_max = mean - diff, mean + diff
    if lam_max <= 0:
        return False
    return bool(
        math.sqrt(max(lam_min, 0.0) / patch.size) >= cfg.min_gradient
        and lam_min / lam_max >= cfg.min_eigen_ratio
    )


@numba.njit(cache=True)
def _gradients(image):
    """``np.gradient`` of a float image (h, w), both at least 2: (gy, gx), central differences
    inside, one-sided at the borders."""
    h, w = image.shape
    gy, gx = np.empty((h, w)), np.empty((h, w))
    for v in range(h):
        for u in range(w):
            if 0 < v < h - 1:
                gy[v, u] = (image[v + 1, u] - image[v - 1, u]) / 2.0
            else:
                gy[v, u] = image[1, u] - image[0, u] if v == 0 else image[v, u] - image[v - 1, u]
            if 0 < u < w - 1:
                gx[v, u] = (image[v, u + 1] - image[v, u - 1]) / 2.0
            else:
                gx[v, u] = image[v, 1] - image[v, 0] if u == 0 else image[v, u] - image[v, u - 1]
    return gy, gx


@numba.njit(cache=True)
def _structure_tensor(patch):
    """The gradient structure tensor summed over ``patch``: (sum gx^2, sum gx gy, sum gy^2)."""
    gy, gx = _gradients(patch)
    return np.sum(gx * gx), np.sum(gx * gy), np.sum(gy * gy)


@numba.njit(cache=True)
def _gradient_magnitude(image):
    """``hypot`` of :func:`_gradients` (h, w)."""
    gy, gx = _gradients(image)
    return np.hypot(gx, gy)


def _intersect_edges(
    mag: np.ndarray, q: np.ndarray, cfg: ExtractionConfig
) -> np.ndarray | None:
    """Corner as the least-squares intersection of the edges leaving ``q`` (crop coordinates),
    on the crop's gradient magnitude ``mag`` (:func:`_gradient_magnitude`).

    Edge directions: peaks of a 10-degree histogram of the directions from ``q`` of the strong
    gradient pixels (magnitude above ``line_threshold`` of the largest) in the ring
    ``line_inner_px..line_outer_px``. Each edge starts as the line through ``q`` along its peak
    and is refitted three times by weighted total least squares to every pixel of the band
    within 1.5 px of the line and ``line_inner_px..line_outer_px`` along it (weights: gradient
    magnitude, whose centroid across an edge is the edge; a band symmetric about the line keeps
    the fit unbiased). Lines passing within ``line_max_offset_px`` of ``q`` are intersected,
    weighted by their total gradient. None when fewer than two non-parallel edges are found.
    """
    ok, x, y = _edge_intersection(mag, float(q[0]), float(q[1]), cfg.line_inner_px,
                                  cfg.line_outer_px, cfg.line_threshold, cfg.line_max_offset_px)
    return np.array([x, y]) if ok else None


_BINS = 36  # direction histogram of the edges around a corner: 10-degree bins


@numba.njit(cache=True)
def _principal_axes(a: float, b: float, c: float) -> tuple[float, float, float, float]:
    """Unit eigenvectors (largest, smallest eigenvalue) of the symmetric [[a, b], [b, c]]."""
    theta = 0.5 * math.atan2(2.0 * b, a - c)
    dx, dy = math.cos(theta), math.sin(theta)
    return dx, dy, -dy, dx


@numba.njit(cache=True)
def _edge_intersection(mag, qx, qy, inner, outer, threshold, max_offset):
    """Compiled body of :func:`_intersect_edges` on the gradient magnitude ``mag`` (h, w):
    ``(found, x, y)``."""
    h, w = mag.shape
    ring_max = 0.0
    for v in range(h):
        for u in range(w):
            r = math.hypot(u - qx, v - qy)
            if inner <= r <= outer and mag[v, u] > ring_max:
                ring_max = mag[v, u]
    hist = np.zeros(_BINS)
    n_strong = 0
    for v in range(h):
        for u in range(w):
            r = math.hypot(u - qx, v - qy)
            if inner <= r <= outer and mag[v, u] >= threshold * ring_max:
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
            for v in range(h):
                for u in range(w):
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
            for v in range(h):
                for u in range(w):
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
    """Sub-pixel corner (2,) in the window ``box`` nearest to ``predicted`` (px), or None."""
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
    cand = found.reshape(-1, 2)
    local = np.asarray(predicted, dtype=float) - (u0, v0)
    start = cand[np.argmin(np.sum((cand - local) ** 2, axis=1))]
    h, w = crop.shape
    # cornerSubPix needs the crop at least 2 half + 5 px wide and high
    half = int(min(cfg.refine_half_px, *(start - 1), *((w - 2, h - 2) - start),
                   (w - 5) // 2, (h - 5) // 2))
    if half < 2:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
    starts = start + np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, 1.0], [0.0, -1.0]])
    runs = cv2.cornerSubPix(
        crop, starts.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1), criteria
    ).reshape(-1, 2).astype(np.float64)
    spread = np.max(np.linalg.norm(runs - runs.mean(axis=0), axis=1))
    if spread > cfg.max_spread_px:
        return None
    refined = runs.mean(axis=0)
    b = cfg.border_px
    if not (b <= refined[0] <= w - 1 - b and b <= refined[1] <= h - 1 - b):
        return None
    if np.hypot(*(refined - start)) > cfg.max_shift_px:
        return None
    iu, iv = int(round(refined[0])), int(round(refined[1]))
    patch = crop[max(iv - half, 0) : iv + half + 1, max(iu - half, 0) : iu + half + 1]
    if not _structure_ok(patch, cfg):
        return None
    q = refined
    mag = _gradient_magnitude(crop.astype(np.float64))
    for _ in range(2):  # edge-line intersection, recentred once on its own result
        lines = _intersect_edges(mag, q, cfg)
        if lines is None or np.hypot(*(lines - refined)) > cfg.line_max_offset_px:
            break
        q = lines
    return q + (u0, v0)


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

"""Camera-view overlays: predicted feature visibility, selection, windows and measurements.

Pixel coordinates follow OpenCV: ``u`` is the column and ``v`` the row, both in pixels, the
origin at the top-left pixel's centre. Images are returned as RGB ``uint8`` arrays, so every
colour below is an ``(R, G, B)`` triple (OpenCV's drawing functions do not care about channel
order). Markers are drawn without anti-aliasing so that their colours are exact; only text is
anti-aliased.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellsight.tracking.unknown import Grid

VISIBLE = (40, 210, 70)  # filled disc: predicted visible
OCCLUDED = (235, 45, 45)  # hollow ring: predicted occluded
SELECTED = (255, 215, 0)  # outer ring: selected for a window
WINDOW = (70, 150, 255)  # rectangle: image window to grab
MEASURED = (0, 235, 235)  # cross: measured corner, accepted by the EKF gate
REJECTED = (255, 120, 0)  # cross: measured corner, rejected by the gate
MISMATCH = (230, 0, 230)  # square: prediction disagrees with the ray-cast truth
UNKNOWN = (255, 140, 0)  # shaded cells: the tracker's unknown-occluder map
UNKNOWN_ALPHA = 0.35  # opacity of that shade
TEXT = (255, 255, 255)
PANEL = (25, 25, 25)  # background of the title, legend and caption bars

POINT_RADIUS = 4  # px, visible disc / occluded ring
RING_RADIUS = 8  # px, selection ring
CROSS_HALF = 4  # px, half the arm of a measurement cross
MISMATCH_HALF = 11  # px, half the side of the mismatch square
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _canvas(image: np.ndarray | None, size: tuple[int, int] | None) -> np.ndarray:
    """RGB copy of a grayscale (H, W) or RGB (H, W, 3) image, or a mid-grey (W, H) canvas."""
    if image is None:
        if size is None:
            raise ValueError("size=(W, H) is required when image is None")
        width, height = size
        return np.full((height, width, 3), 128, dtype=np.uint8)
    image = np.asarray(image, dtype=np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    return image.copy()


def _point(uv: np.ndarray) -> tuple[int, int]:
    """Nearest integer pixel ``(u, v)`` of a sub-pixel position."""
    return int(round(float(uv[0]))), int(round(float(uv[1])))


def _text_box(img: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.45) -> None:
    """Text on a dark box whose top-left corner is ``origin`` (px)."""
    (w, h), base = cv2.getTextSize(text, FONT, scale, 1)
    x, y = origin
    cv2.rectangle(img, (x, y), (x + w + 6, y + h + base + 4), PANEL, cv2.FILLED)
    cv2.putText(img, text, (x + 3, y + h + 2), FONT, scale, TEXT, 1, cv2.LINE_AA)


def _cross(img: np.ndarray, centre: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """A diagonal cross of half-arm ``CROSS_HALF`` px centred on ``centre``."""
    u, v = centre
    d = CROSS_HALF
    cv2.line(img, (u - d, v - d), (u + d, v + d), colour, 1, cv2.LINE_8)
    cv2.line(img, (u - d, v + d), (u + d, v - d), colour, 1, cv2.LINE_8)


def _shade_cells(img: np.ndarray, grid: Grid) -> None:
    """Shade ``grid``'s set cells (:class:`~cellsight.tracking.unknown.Grid`) in ``UNKNOWN``
    and outline the shaded region."""
    cells = np.asarray(grid.cells, dtype=np.uint8)
    if not cells.any():
        return
    p = int(grid.pitch_px)
    region = np.kron(cells, np.ones((p, p), dtype=np.uint8))[: img.shape[0], : img.shape[1]]
    region = np.pad(region, ((0, img.shape[0] - region.shape[0]),
                             (0, img.shape[1] - region.shape[1])))
    inside = region.astype(bool)
    img[inside] = ((1 - UNKNOWN_ALPHA) * img[inside] + UNKNOWN_ALPHA * np.array(UNKNOWN)
                   ).astype(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, UNKNOWN, 1, cv2.LINE_8)


def _legend(img: np.ndarray, with_truth: bool, with_unknown: bool = False) -> None:
    """Compact legend with one icon per marker type, in the bottom-left corner."""
    entries = ["visible", "occluded", "selected", "window", "measured", "rejected"]
    if with_truth:
        entries.append("pred != truth")
    if with_unknown:
        entries.append("unknown occluder")
    scale, row = 0.38, 14
    width = 24 + max(cv2.getTextSize(e, FONT, scale, 1)[0][0] for e in entries)
    height = row * len(entries) + 6
    x0, y0 = 4, img.shape[0] - height - 4
    cv2.rectangle(img, (x0, y0), (x0 + width, y0 + height), PANEL, cv2.FILLED)
    for k, label in enumerate(entries):
        c = (x0 + 9, y0 + 10 + k * row)
        _legend_icon(img, label, c)
        cv2.putText(img, label, (x0 + 20, c[1] + 4), FONT, scale, TEXT, 1, cv2.LINE_AA)


def _legend_icon(img: np.ndarray, label: str, c: tuple[int, int]) -> None:
    """The marker for one legend entry, centred on ``c``."""
    u, v = c
    if label == "visible":
        cv2.circle(img, c, 4, VISIBLE, cv2.FILLED, cv2.LINE_8)
    elif label == "occluded":
        cv2.circle(img, c, 4, OCCLUDED, 2, cv2.LINE_8)
    elif label == "selected":
        cv2.circle(img, c, 5, SELECTED, 1, cv2.LINE_8)
    elif label == "window":
        cv2.rectangle(img, (u - 5, v - 4), (u + 5, v + 4), WINDOW, 1, cv2.LINE_8)
    elif label == "measured":
        _cross(img, c, MEASURED)
    elif label == "rejected":
        _cross(img, c, REJECTED)
    elif label == "unknown occluder":
        cv2.rectangle(img, (u - 5, v - 5), (u + 5, v + 5), UNKNOWN, cv2.FILLED, cv2.LINE_8)
    else:
        cv2.rectangle(img, (u - 5, v - 5), (u + 5, v + 5), MISMATCH, 1, cv2.LINE_8)


@dataclass(frozen=True)
class FeatureMarks:
    """The tracker's per-feature state in one camera: ``pixels`` (F, 2) predicted projections
    (u, v) in px, NaN rows skipped; ``visible``, ``selected``, ``rejected``: (F,) bool;
    ``measured``: (F, 2) measured corners (u, v) in px, NaN where none; ``truth_visible``:
    optional (F,) bool ray-cast truth."""

    pixels: np.ndarray
    visible: np.ndarray
    selected: np.ndarray
    measured: np.ndarray
    rejected: np.ndarray
    truth_visible: np.ndarray | None = None


def draw_camera_overlay(image: np.ndarray | None, marks: FeatureMarks, *, boxes: np.ndarray,
                        title: str, size: tuple[int, int] | None = None,
                        unknown: Grid | None = None) -> np.ndarray:
    """One camera's view with the tracker's per-feature state ``marks`` drawn on it.

    ``image``: (H, W) uint8 grayscale (an (H, W, 3) RGB image is also accepted), or None for a
    mid-grey canvas of ``size=(W, H)`` px. ``boxes``: (n, 4) int windows ``(u0, v0, u1, v1)``,
    half-open. Features whose predicted visibility disagrees with the marks' truth get a
    magenta square. ``unknown``: optional unknown-occluder map
    (:class:`~cellsight.tracking.unknown.Grid`), its cells shaded orange.

    Predicted-visible features are green filled discs, occluded ones red hollow rings, selected
    ones get a yellow outer ring; windows are blue rectangles, measured corners cyan crosses
    (orange when rejected by the EKF gate). Features are numbered from 1. Returns (H, W, 3)
    uint8 RGB.
    """
    img = _canvas(image, size)
    if unknown is not None:
        _shade_cells(img, unknown)
    pixels = np.asarray(marks.pixels, dtype=float)
    measured = np.asarray(marks.measured, dtype=float)
    visible, selected, rejected = marks.visible, marks.selected, marks.rejected
    truth_visible = marks.truth_visible
    for u0, v0, u1, v1 in np.asarray(boxes, dtype=int).reshape(-1, 4):
        cv2.rectangle(img, (int(u0), int(v0)), (int(u1) - 1, int(v1) - 1), WINDOW, 1, cv2.LINE_8)
    for j in range(len(pixels)):
        if not np.isfinite(pixels[j]).all():
            continue
        c = _point(pixels[j])
        if visible[j]:
            cv2.circle(img, c, POINT_RADIUS, VISIBLE, cv2.FILLED, cv2.LINE_8)
        else:
            cv2.circle(img, c, POINT_RADIUS, OCCLUDED, 2, cv2.LINE_8)
        if selected[j]:
            cv2.circle(img, c, RING_RADIUS, SELECTED, 1, cv2.LINE_8)
        if truth_visible is not None and bool(truth_visible[j]) != bool(visible[j]):
            d = MISMATCH_HALF
            cv2.rectangle(img, (c[0] - d, c[1] - d), (c[0] + d, c[1] + d), MISMATCH, 1)
        cv2.putText(img, str(j + 1), (c[0] + 7, c[1] - 7), FONT, 0.4, TEXT, 1, cv2.LINE_AA)
    for j in range(len(measured)):
        if np.isfinite(measured[j]).all():
            _cross(img, _point(measured[j]), REJECTED if rejected[j] else MEASURED)
    _text_box(img, title, (4, 4))
    _legend(img, truth_visible is not None, unknown is not None and bool(unknown.cells.any()))
    return img


def _even(n: float) -> int:
    """Nearest even integer >= 2 to ``n``."""
    return max(2, 2 * int(round(n / 2.0)))


def compose_views(views: list[np.ndarray], scale: float = 1.0, caption: str = "") -> np.ndarray:
    """Views side by side (top-aligned, padded to the tallest with black), scaled by ``scale``
    (``cv2.INTER_AREA``) to an even width and height, with an optional caption bar on top.

    ``views``: RGB (H_i, W_i, 3) uint8 images. Returns RGB uint8 whose width and height are both
    even, as H.264 with yuv420p needs.
    """
    if not views:
        raise ValueError("compose_views needs at least one view")
    height = max(v.shape[0] for v in views)
    padded = [np.pad(v, ((0, height - v.shape[0]), (0, 0), (0, 0))) for v in views]
    row = np.concatenate(padded, axis=1)
    size = (_even(row.shape[1] * scale), _even(row.shape[0] * scale))
    if size != (row.shape[1], row.shape[0]):
        row = cv2.resize(row, size, interpolation=cv2.INTER_AREA)
    if not caption:
        return np.ascontiguousarray(row)
    bar = np.full((24, row.shape[1], 3), PANEL, dtype=np.uint8)
    cv2.putText(bar, caption, (6, 17), FONT, 0.5, TEXT, 1, cv2.LINE_AA)
    return np.concatenate([bar, row], axis=0)
